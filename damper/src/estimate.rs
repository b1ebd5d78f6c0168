//! What a damper monitor says after each sample: the RBPF's posterior, the EKF baseline and
//! the monitor's own state (paused, model mismatch). A type of its own so that the rules that
//! judge it (`crate::alarm`, `crate::status`) need not know the monitor that makes it.

use crate::ekf::EkfEstimate;
use crate::rbpf::DamperPosterior;
use crate::speed::PauseReason;

/// The monitor's output after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperEstimate {
    /// Time since the monitor started (steps x dt).
    pub time_s: f64,
    /// RBPF posterior of `C_sy` and `C_say`.
    pub csy: DamperPosterior,
    pub csay: DamperPosterior,
    pub effective_sample_size: f64,
    /// The EKF baseline; `None` when disabled or after it diverged.
    pub ekf: Option<EkfEstimate>,
    /// Mean of the RBPF's normalised innovation squared over the last complete window
    /// (`consistency.window_s`; 5 when the filter's model is the plant's; `None` before).
    pub nis_window_mean: Option<f64>,
    /// The filter's model does not explain the data (`consistency`): a wrong configuration
    /// (vehicle, speed, noise), not a damper fault. The health alarm does not judge meanwhile.
    pub model_mismatch: bool,
    /// The sensors' noise standard deviation per channel as a ratio of the configured one, as
    /// the RBPF estimates it (`crate::noise_scale`; eq. (4) order: wheelset 1, wheelset 2,
    /// bogie, yaw gyro, body).
    pub noise_std_ratio: [f64; crate::model::N_OUTPUTS],
    /// The last sample's speed was outside `speed`'s range (or the filter is settling after
    /// such a stretch): the posterior is held as it was, not learnt from a model that is not
    /// valid there; the alarm does not judge meanwhile.
    pub paused: Option<PauseReason>,
    /// The innovations burst beyond what any hypothesis explains (a damper failing at speed,
    /// a shock; `crate::burst`): `csy` and `csay` are the posteriors published before the
    /// burst, held while the filter learns through it, until its innovations are back in
    /// their band (at most 3 time constants of the model's slowest mode).
    pub held_through_burst: bool,
    /// The last sample's speed (m/s).
    pub speed_m_s: f64,
    /// The last sample's measured body mass above the bogie (kg,
    /// `BogieSample::half_body_mass_kg`), which the filters take; `None`: the sample had none
    /// and they assume the design mass (`vehicle.half_body_mass_kg`).
    pub measured_half_body_mass_kg: Option<f64>,
}

/// Which body mass above the bogie the filter takes (`DamperMonitor::body_mass`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MassSource {
    /// The last sample's `half_body_mass_kg` (its air springs' load).
    Measured,
    /// The sample had none and the particles carry the mass (`rbpf.unmeasured_mass`): their
    /// posterior mean.
    Estimated,
    /// None measured and that setting off: the design mass (`vehicle.half_body_mass_kg`).
    Design,
}

impl MassSource {
    pub fn as_str(self) -> &'static str {
        match self {
            MassSource::Measured => "measured",
            MassSource::Estimated => "estimated",
            MassSource::Design => "design",
        }
    }
}

/// The body mass above the bogie the filter runs at, and where it comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyMass {
    pub source: MassSource,
    /// kg.
    pub half_body_mass_kg: f64,
}
