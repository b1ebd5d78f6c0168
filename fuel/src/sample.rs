//! One 1 Hz sample of the vehicle's channels, and its validation.

use serde::{Deserialize, Serialize};

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

/// Plausible range `[min, max]` of every channel, in the channel's unit ([`Channel::unit`]): a
/// value outside it is a sensor, unit or file fault and the sample is refused before it reaches
/// the statistics (a single 1e200 would overflow `V` for good; speed in km/h read as m/s would
/// be estimated as if it were right). A property of the vehicle, not of the estimator, so a
/// table of its own: `Default` is a road car's ([`ChannelRanges::road_car`]),
/// [`ChannelRanges::railcar`] a diesel railcar's or locomotive's. `acceleration_m_s2` bounds
/// the speed's change since the last accepted sample ([`ChannelRanges::check_acceleration`]):
/// a km/h speed that stays inside the m/s range still accelerates 3.6 times too fast.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ChannelRanges {
    /// Plausible fuel flow `[low, high]`, cm^3/s.
    pub fuel_cm3_s: [f64; 2],
    /// Plausible speed `[low, high]`, m/s.
    pub speed_m_s: [f64; 2],
    /// Plausible accelerator pedal position `[low, high]`, %.
    pub pedal_pct: [f64; 2],
    /// Plausible engine torque `[low, high]`, N m.
    pub engine_torque_nm: [f64; 2],
    /// Plausible engine speed `[low, high]`, rpm.
    pub engine_speed_rpm: [f64; 2],
    /// Plausible gradient `[low, high]`, per mille (positive uphill).
    pub gradient_permille: [f64; 2],
    /// `(v_t - v_p) / (t - t_p)`, m/s^2, from the last accepted sample `p`: the vehicle's
    /// hardest braking and full-power acceleration (with margin), not its usual driving.
    pub acceleration_m_s2: [f64; 2],
}

impl Default for ChannelRanges {
    fn default() -> Self {
        Self::road_car()
    }
}

impl ChannelRanges {
    /// A road car (the Camry files): a 2.5 l petrol engine at full load burns ~10 cm^3/s, so
    /// 100 leaves a truck's worth of margin; small negative values are flow-meter noise around
    /// zero. Speed up to 70 m/s (252 km/h): a file in km/h at motorway speed (100+) is refused
    /// rather than read as 100 m/s. Gradients up to 35 % (350 per mille), the steepest roads.
    /// Acceleration within +-12 m/s^2: tyre grip bounds both braking and traction at
    /// `mu g`, and the peak road adhesion of dry asphalt is 0.8-0.9 (Wong, Theory of Ground
    /// Vehicles, table 1.1), 1.2 leaves margin for performance tyres; an ABS stop of a
    /// current car (100-0 km/h in ~36 m) averages ~10.7 m/s^2. The shipped data stay within
    /// 3.5 (docs/fuel.md). A launch-control EV exceeds it (Tesla Model S Plaid, 0-60 mph in
    /// 1.99 s by Tesla's figure: 13.5 m/s^2 on average): give such a car its own range.
    pub fn road_car() -> Self {
        ChannelRanges {
            fuel_cm3_s: [-1.0, 100.0],
            speed_m_s: [-5.0, 70.0],
            pedal_pct: [-1.0, 101.0],
            engine_torque_nm: [-1000.0, 5000.0],
            engine_speed_rpm: [-100.0, 20000.0],
            gradient_permille: [-350.0, 350.0],
            acceleration_m_s2: [-12.0, 12.0],
        }
    }

    /// A diesel railcar (DMU) or diesel locomotive. Fuel up to 300 cm^3/s: a Cummins QSK95
    /// locomotive engine is rated 3281 kW (Cummins, Railway Age, 2 Oct 2015), which at an
    /// assumed 205 g/kWh and diesel at 0.835 g/cm^3 burns 224 cm^3/s; a QSK19-R railcar engine
    /// (567 kW, Cummins, 25 Apr 2014) 39 cm^3/s. Speed up to 60 m/s (216 km/h; DMUs run at
    /// 120-200 km/h): km/h at line speed is refused. Gradients up to 80 per mille (adhesion
    /// lines stay below ~70). Engine speed of a high-speed diesel (idle ~600, rated 1800-2100
    /// rpm), torque of a 95 l engine (~17 kN m at rated power). Acceleration within
    /// [-4, 2] m/s^2: wheel-rail adhesion is at most ~0.4 (dry, sanded rail; **assumed**, the
    /// upper end of the usual figures), and a DMU drives at most half its axles (one powered
    /// bogie per car, as the simulated 3 x QSK19-R set), so traction stays below
    /// 0.5 x 0.4 g = 2.0 m/s^2 (the simulator's 150 kN starting effort on 190 t: 0.77 at most);
    /// braking on every axle below 0.4 g = 3.9 m/s^2, beyond a tram's emergency braking with
    /// magnetic track brakes (at least 2.73 m/s^2, BOStrab section 36) and the simulator's
    /// service brake (0.7 m/s^2, up to 0.91 into a platform, and -3.3 in the last second where
    /// `railcar.rs` stops the train at the platform). A locomotive running light (all axles
    /// driven, no train) can exceed +2: give it its own range.
    pub fn railcar() -> Self {
        ChannelRanges {
            fuel_cm3_s: [-1.0, 300.0],
            speed_m_s: [-1.0, 60.0],
            pedal_pct: [-1.0, 101.0],
            engine_torque_nm: [-5000.0, 30000.0],
            engine_speed_rpm: [-100.0, 3000.0],
            gradient_permille: [-80.0, 80.0],
            acceleration_m_s2: [-4.0, 2.0],
        }
    }

    /// The range of one channel.
    pub fn of(&self, channel: Channel) -> [f64; 2] {
        channel_field!(self, channel)
    }

    pub(crate) fn validate(&self) -> Result<(), FuelError> {
        for c in Channel::ALL {
            let [min, max] = self.of(c);
            if !(min.is_finite() && max.is_finite() && min < max) {
                return Err(FuelError::invalid(
                    "ranges",
                    format!("{} = [{min}, {max}]", c.column()),
                    "each range must be finite with min < max",
                ));
            }
        }
        let [min, max] = self.acceleration_m_s2;
        if !(min.is_finite() && max.is_finite() && min < 0.0 && 0.0 < max) {
            return Err(FuelError::invalid(
                "ranges",
                format!("acceleration_m_s2 = [{min}, {max}]"),
                "must be finite with min < 0 < max (a vehicle keeping its speed is plausible)",
            ));
        }
        Ok(())
    }

    /// The acceleration `(speed_m_s - v_p) / (time_s - t_p)` from the last accepted sample
    /// `previous = (t_p, v_p)` (0 without one), checked against `acceleration_m_s2`. Refused
    /// samples are never `previous`, so a bad sample does not make the next good one look
    /// bad; after a gap or refused samples the step is longer and the quotient is the mean
    /// acceleration over it, which lies within the vehicle's bounds whenever every
    /// instantaneous one did (mean value theorem): a gap cannot cause a refusal either.
    pub fn check_acceleration(
        &self,
        previous: Option<(f64, f64)>,
        time_s: f64,
        speed_m_s: f64,
    ) -> Result<f64, FuelError> {
        let Some((previous_s, previous_speed_m_s)) = previous else {
            return Ok(0.0);
        };
        let step_s = time_s - previous_s;
        let acceleration_m_s2 = (speed_m_s - previous_speed_m_s) / step_s;
        let [min, max] = self.acceleration_m_s2;
        if (min..=max).contains(&acceleration_m_s2) {
            Ok(acceleration_m_s2)
        } else {
            Err(FuelError::AccelerationOutOfRange {
                speed_m_s,
                previous_speed_m_s,
                step_s,
                acceleration_m_s2,
                min,
                max,
                time_s,
            })
        }
    }

    /// The acceleration `implied` by a reading against the filtered speed `previous = (t_p,
    /// v_hat_p)` (`crate::kinematic`), checked against `acceleration_m_s2` widened by
    /// `allowance` on both sides (the noise's share), with the same error as
    /// [`ChannelRanges::check_acceleration`].
    pub fn check_implied_acceleration(
        &self,
        previous: (f64, f64),
        time_s: f64,
        speed_m_s: f64,
        implied: f64,
        allowance: f64,
    ) -> Result<(), FuelError> {
        let [min, max] = self.acceleration_m_s2;
        match (min - allowance..=max + allowance).contains(&implied) {
            true => Ok(()),
            false => Err(FuelError::AccelerationOutOfRange {
                speed_m_s,
                previous_speed_m_s: previous.1,
                step_s: time_s - previous.0,
                acceleration_m_s2: implied,
                min,
                max,
                time_s,
            }),
        }
    }
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
