//! The model every filter of a bogie shares (the RBPF's particles and sentinels, the gain
//! table, the EKF baseline): the vehicle, its healthy dampers, the sample period and the
//! filters' noise model. A leaf: the filters take this and their own settings, not the whole
//! [`crate::DamperMonitorConfig`] (its fields of the same names, documented there, are the
//! settings this is built from: `DamperMonitorConfig::filter_model`).

use crate::kalman::NoiseCovariances;
use crate::model::BogieModel;
use crate::params::{non_negative, positive, BogieParams, Dampers};
use crate::sample::SensorNoise;
use crate::DamperError;

/// The filters' model of the vehicle and its noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterModel {
    /// The vehicle's design parameters.
    pub vehicle: BogieParams,
    /// The healthy dampers; health ratio = estimate / nominal.
    pub nominal: Dampers,
    /// Sample period `T` (s).
    pub dt_s: f64,
    /// The white track-velocity model: `Q_w = sigma^2 I` per step (m/s).
    pub track_velocity_std_m_s: f64,
    /// The sensor noise `Q_v`.
    pub sensors: SensorNoise,
    /// Standard deviation added to every state each step (`process_noise_floor_std_per_step`).
    pub process_noise_floor_std_per_step: f64,
    /// Rate at which the unobservable track position relaxes (1/s), `model` docs.
    pub drift_leak_per_s: f64,
}

impl FilterModel {
    /// Each field's check, in the order (and with the names) `DamperMonitorConfig::validate`
    /// has always reported them.
    pub fn validate(&self) -> Result<(), DamperError> {
        self.vehicle.validate()?;
        self.nominal.validate()?;
        positive("dt_s", self.dt_s)?;
        positive("track_velocity_std_m_s", self.track_velocity_std_m_s)?;
        self.sensors.validate()?;
        positive("drift_leak_per_s", self.drift_leak_per_s)?;
        non_negative(
            "process_noise_floor_std_per_step",
            self.process_noise_floor_std_per_step,
        )
    }

    /// `Q_w` and `Q_v` of the filter model.
    pub fn noise(&self) -> NoiseCovariances {
        NoiseCovariances {
            q_w: nalgebra::Matrix2::identity() * self.track_velocity_std_m_s.powi(2),
            q_v: self.sensors.covariance(),
            q_floor: self.process_noise_floor_std_per_step.powi(2),
        }
    }

    /// The plan-view model the filters run, at the vehicle's configured speed, with the
    /// drift leak.
    pub fn bogie_model(&self) -> Result<BogieModel, DamperError> {
        BogieModel::new(&self.vehicle, self.drift_leak_per_s)
    }
}
