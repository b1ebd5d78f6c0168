//! One 1 Hz sample of the vehicle's channels, and its validation.

use serde::{Deserialize, Serialize};

use crate::config::ChannelRanges;
use crate::FuelError;

/// The field of `$record` that holds `$channel`: a sample's value and a channel's range are
/// kept in fields of the same names (`fuel_cm3_s`, `speed_m_s`, ...), and this one match maps
/// a [`Channel`] to its field for both ([`VehicleSample::channel`], `ChannelRanges::of`).
macro_rules! channel_field {
    ($record:expr, $channel:expr) => {
        match $channel {
            Channel::Fuel => $record.fuel_cm3_s,
            Channel::Speed => $record.speed_m_s,
            Channel::Pedal => $record.pedal_pct,
            Channel::EngineTorque => $record.engine_torque_nm,
            Channel::EngineSpeed => $record.engine_speed_rpm,
            Channel::Gradient => $record.gradient_permille,
        }
    };
}
pub(crate) use channel_field;

/// A continuous channel of the vehicle (the paper's `y_{1..5;t}`, section 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Channel {
    /// Instantaneous fuel flow, cm^3/s (the paper's `y_1`, there in microlitres per sample).
    Fuel,
    /// Vehicle speed, m/s.
    Speed,
    /// Accelerator pedal, %.
    Pedal,
    /// Engine torque, N m.
    EngineTorque,
    /// Engine speed, rpm.
    EngineSpeed,
    /// Gradient of the track or road, per mille (rise per 1000 m run; positive uphill): the
    /// grade resistance `m g i / 1000` a railcar's fuel follows on a route.
    Gradient,
}

impl Channel {
    /// Every channel a sample can carry.
    pub const ALL: [Channel; 6] = [
        Channel::Fuel,
        Channel::Speed,
        Channel::Pedal,
        Channel::EngineTorque,
        Channel::EngineSpeed,
        Channel::Gradient,
    ];

    /// The paper's five channels (section 4.1: fuel, speed, pedal, torque, engine speed).
    pub const PAPER: [Channel; 5] = [
        Channel::Fuel,
        Channel::Speed,
        Channel::Pedal,
        Channel::EngineTorque,
        Channel::EngineSpeed,
    ];

    /// Name as written in configs and CSV headers.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Fuel => "fuel",
            Channel::Speed => "speed",
            Channel::Pedal => "pedal",
            Channel::EngineTorque => "engine_torque",
            Channel::EngineSpeed => "engine_speed",
            Channel::Gradient => "gradient",
        }
    }

    /// The unit every value of the channel is in (samples, frames and recordings alike).
    pub fn unit(self) -> &'static str {
        match self {
            Channel::Fuel => "cm^3/s",
            Channel::Speed => "m/s",
            Channel::Pedal => "%",
            Channel::EngineTorque => "N m",
            Channel::EngineSpeed => "rpm",
            Channel::Gradient => "per mille",
        }
    }

    /// The column of the channel in the railmon vehicle layout (name and unit).
    pub fn column(self) -> &'static str {
        match self {
            Channel::Fuel => "fuel_cm3_s",
            Channel::Speed => "speed_m_s",
            Channel::Pedal => "pedal_pct",
            Channel::EngineTorque => "engine_torque_nm",
            Channel::EngineSpeed => "engine_speed_rpm",
            Channel::Gradient => "gradient_permille",
        }
    }

    /// Smallest spread used when standardising the channel, so that a channel that happens to be
    /// constant during initialisation (pedal 0 while idling) does not get an infinite scale.
    pub(crate) fn min_scale(self) -> f64 {
        match self {
            Channel::Fuel => 0.05,
            Channel::Speed => 0.5,
            Channel::Pedal => 1.0,
            Channel::EngineTorque => 5.0,
            Channel::EngineSpeed => 50.0,
            Channel::Gradient => 1.0,
        }
    }
}

impl std::fmt::Display for Channel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A channel computed from the speed now `v_t` and a sample ago (`a_t = (v_t - v_{t-1}) / dt`,
/// 0 on the first sample): the terms of the tractive power a fuel map responds to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum DerivedChannel {
    /// `a_t`, m/s^2.
    Acceleration,
    /// `max(a_t, 0) v_t`, m^2/s^3: inertial power per unit mass while accelerating.
    PowerDemand,
    /// `v_t^2`, m^2/s^2.
    SpeedSquared,
    /// `v_t^3`, m^3/s^3: aerodynamic power per unit drag.
    SpeedCubed,
    /// `a_t + g i_t / 1000`, m/s^2, `i_t` the gradient (per mille, from the sample's gradient
    /// channel): the acceleration net of the grade, the specific force the engine and brakes
    /// (with the rolling resistance) act with. A coasting train speeds up downhill and slows
    /// uphill by its grade; net of it, it slows by its running resistance only.
    SpecificForce,
}

/// The gradient (per mille) the specific force nets out at speed `v_m_s`: the sample's while
/// moving, 0 below `standstill_speed_m_s`. Standing, the brakes hold the grade: no traction or
/// braking force is asked and the specific force is the acceleration alone (0), not `g i / 1000`
/// (which made each station's grade a level of its own: a standing component then spread over
/// the stations' grades, docs/fuel.md).
pub fn effective_gradient_permille(
    v_m_s: f64,
    gradient_permille: f64,
    standstill_speed_m_s: f64,
) -> f64 {
    if v_m_s < standstill_speed_m_s {
        0.0
    } else {
        gradient_permille
    }
}

/// Standard gravity, m/s^2 (the grade's share of the specific force).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

impl DerivedChannel {
    pub fn name(self) -> &'static str {
        match self {
            DerivedChannel::Acceleration => "acceleration",
            DerivedChannel::PowerDemand => "power_demand",
            DerivedChannel::SpeedSquared => "speed_squared",
            DerivedChannel::SpeedCubed => "speed_cubed",
            DerivedChannel::SpecificForce => "specific_force",
        }
    }

    /// The value from speed `v` (m/s) and acceleration `a` (m/s^2).
    /// (`gradient_permille` for [`DerivedChannel::SpecificForce`], ignored by the others).
    pub fn value(self, v: f64, a: f64, gradient_permille: f64) -> f64 {
        match self {
            DerivedChannel::Acceleration => a,
            DerivedChannel::PowerDemand => a.max(0.0) * v,
            DerivedChannel::SpeedSquared => v * v,
            DerivedChannel::SpeedCubed => v * v * v,
            DerivedChannel::SpecificForce => a + STANDARD_GRAVITY_M_S2 * gradient_permille / 1000.0,
        }
    }

    /// Smallest spread used when standardising (see [`Channel::min_scale`]).
    pub(crate) fn min_scale(self) -> f64 {
        match self {
            DerivedChannel::Acceleration => 0.05,
            DerivedChannel::PowerDemand => 0.5,
            DerivedChannel::SpeedSquared => 1.0,
            DerivedChannel::SpeedCubed => 10.0,
            DerivedChannel::SpecificForce => 0.05,
        }
    }
}

impl std::fmt::Display for DerivedChannel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One sample of the vehicle, what a CAN logger or a dynamometer gives at 1 Hz. Channels a
/// source does not have are `None` (the Camry files have only fuel and speed).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VehicleSample {
    pub time_s: f64,
    pub fuel_cm3_s: Option<f64>,
    pub speed_m_s: Option<f64>,
    pub pedal_pct: Option<f64>,
    pub engine_torque_nm: Option<f64>,
    pub engine_speed_rpm: Option<f64>,
    /// Track or road gradient, per mille (positive uphill).
    pub gradient_permille: Option<f64>,
    /// The categorical channel as the vehicle reports it: the selected gear of a car (-1
    /// reverse, 0 neutral, 1..6) or the throttle notch of a diesel railcar (0 idle .. 8).
    pub gear: Option<i32>,
}

impl VehicleSample {
    /// The value of one continuous channel, if present.
    pub fn channel(&self, channel: Channel) -> Option<f64> {
        channel_field!(self, channel)
    }

    /// The value of `channel`, checked: present, finite and inside its plausible range
    /// (`ranges`, from the configuration: a railcar's fuel is not a car's).
    pub fn checked(&self, channel: Channel, ranges: &ChannelRanges) -> Result<f64, FuelError> {
        let time_s = self.time_s;
        let value = self
            .channel(channel)
            .ok_or(FuelError::MissingChannel { channel, time_s })?;
        if !value.is_finite() {
            return Err(FuelError::NonFinite {
                channel,
                value,
                time_s,
            });
        }
        let [min, max] = ranges.of(channel);
        if !(min..=max).contains(&value) {
            return Err(FuelError::OutOfRange {
                channel,
                value,
                min,
                max,
                time_s,
            });
        }
        Ok(value)
    }
}

/// Index of the bin of `value` given increasing bin `edges`: the number of edges `<= value`
/// (so `edges = [a, b]` gives 3 bins: `< a`, `[a, b)`, `>= b`). This is how the speed `s` and
/// the fuel `f` of section 4.2 are discretised.
pub fn bin_index(edges: &[f64], value: f64) -> usize {
    edges.partition_point(|e| *e <= value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_specific_force_is_the_acceleration_net_of_the_grade() {
        // Coasting down 12 per mille and speeding up by g * 0.012 - 0.05 m/s^2 (0.05 of
        // running resistance): net of the grade it slows by the resistance alone.
        let g = 9.80665;
        let a = g * 0.012 - 0.05;
        let f = DerivedChannel::SpecificForce.value(20.0, a, -12.0);
        assert!((f + 0.05).abs() < 1e-12, "{f}");
        // Uphill the same train slows by grade and resistance; net of the grade, 0.05 again.
        let f = DerivedChannel::SpecificForce.value(20.0, -g * 0.012 - 0.05, 12.0);
        assert!((f + 0.05).abs() < 1e-12, "{f}");
        // Standing on the same grade (brakes holding): 0, not g i / 1000; moving at the
        // threshold the grade counts.
        let standing = effective_gradient_permille(0.0, 12.0, 0.5);
        assert_eq!(DerivedChannel::SpecificForce.value(0.0, 0.0, standing), 0.0);
        assert_eq!(effective_gradient_permille(0.5, 12.0, 0.5), 12.0);
        // The others ignore the gradient.
        assert_eq!(DerivedChannel::PowerDemand.value(20.0, 0.5, 30.0), 10.0);
    }

    #[test]
    fn bins_count_edges_below() {
        let edges = [0.1, 1.0];
        assert_eq!(bin_index(&edges, -0.0), 0);
        assert_eq!(bin_index(&edges, 0.1), 1);
        assert_eq!(bin_index(&edges, 0.99), 1);
        assert_eq!(bin_index(&edges, 5.0), 2);
        assert_eq!(bin_index(&[], 5.0), 0);
    }

    #[test]
    fn checked_names_the_fault() {
        let s = VehicleSample {
            time_s: 3.0,
            fuel_cm3_s: Some(f64::NAN),
            speed_m_s: Some(1e9),
            ..Default::default()
        };
        let ranges = ChannelRanges::default();
        assert!(matches!(
            s.checked(Channel::Fuel, &ranges),
            Err(FuelError::NonFinite {
                channel: Channel::Fuel,
                ..
            })
        ));
        assert!(matches!(
            s.checked(Channel::Speed, &ranges),
            Err(FuelError::OutOfRange {
                channel: Channel::Speed,
                ..
            })
        ));
        assert!(matches!(
            s.checked(Channel::Pedal, &ranges),
            Err(FuelError::MissingChannel {
                channel: Channel::Pedal,
                ..
            })
        ));
        let msg = s.checked(Channel::Fuel, &ranges).unwrap_err().to_string();
        assert!(
            msg.contains("fuel") && msg.contains("NaN") && msg.contains("t = 3"),
            "{msg}"
        );
    }
}
