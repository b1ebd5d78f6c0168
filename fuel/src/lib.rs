//! Fuel consumption: recursive Bayesian mixture with data-dependent switching, vehicle simulator. No I/O.
//!
//! Following Suzdaleva's habilitation lecture (`../shared/seeds/002_*`) with the corrections of
//! `../shared/docs/seed-notes.md`:
//! - [`Mixture`]: Algorithm 3.4 on prepared vectors: normal regression components with
//!   Gauss-inverse-Wishart statistics (eq. 10, 11, 13 with the least-squares split), categorical
//!   components with Dirichlet counts (eq. 12, 15 normalised over categories), the
//!   data-dependent switching model (eq. 16, 17), the pointer weights in log space;
//! - [`FuelMonitor`]: the mixture on [`VehicleSample`]s with a validated [`FuelMonitorConfig`]:
//!   any subset of channels, discretised speed and fuel, initialisation from the first samples,
//!   forgetting; outputs the 0-step estimate, the honest 1-step forecast, a multi-step forecast,
//!   a virtual fuel sensor, regime probabilities and cumulative fuel ([`FuelEstimate`]);
//! - [`VehicleSimulator`]: a car following drive-cycle speed traces (passed in as data) with an
//!   eco or sporty driver, road load, a 6-speed gearbox and a fuel map with cut-off on overrun,
//!   giving the paper's channels at 1 Hz and the regime label of a [`VehicleScenario`];
//! - [`RailcarSimulator`]: a diesel multiple unit on a route (gradients, speed limits, station
//!   stops), notch traction and an engine fuel map, labelled idle / accelerating / cruising /
//!   coasting / braking ([`RailcarScenario`]).
//!
//! Results, commands and CSV layouts: `docs/fuel.md`.

pub mod alarm;
mod blend;
pub mod config;
pub mod counts;
mod data_vector;
pub mod error;
pub mod estimate;
mod forecast;
mod kernel;
pub mod kinematic;
pub mod mixture;
pub mod monitor;
pub mod predictive;
pub mod railcar;
pub mod regime;
pub mod regression;
pub mod routes;
pub mod sample;
pub mod simulator;

pub use alarm::{RegimeChange, REGIME_CHANGED};
pub use config::{CategoricalConfig, FuelMonitorConfig, InitialPartition};
pub use counts::CountTable;
pub use error::FuelError;
pub use estimate::{FuelEstimate, MixtureEstimate};
pub use mixture::{Mixture, MixtureInput, MixtureSpec};
pub use monitor::FuelMonitor;
pub use predictive::{central_interval, Interval, StudentT};
pub use railcar::{RailcarParameters, RailcarScenario, RailcarSimulator, RailcarTruth};
pub use regime::{
    given_regime, ComponentName, Motion, OperatingPoint, PowerTier, RegimeName, RegimeNaming,
    GIVEN_REGIMES,
};
pub use regression::RegressionStats;
pub use routes::{generated_line, scenario_toml, LineEnvelope, Split};
pub use sample::{bin_index, Channel, ChannelRanges, DerivedChannel, VehicleSample};
pub use simulator::{
    DriveCycle, DriverStyle, Segment, VehicleParameters, VehicleScenario, VehicleSimulator,
    VehicleTruth,
};
