//! Regimes with meaning (issue 14 item 3): each mixture component is named from its own
//! statistics (idle, accelerating, cruising, coasting, braking), so the regime the monitor
//! reports says what the vehicle is doing, not which of `m_c` anonymous clusters it is in.
//!
//! The rule reads the component's **operating point**: the mean of the data vector
//! `d = [y; psi]` the component has absorbed, `E_i[d] = V_i[., 1] / (V_i[1, 1] - epsilon)`, where `1` is the
//! constant element of `psi` (eq. 10: `V_i = V_0 + sum_t w_{i;t} d_t d_t'`, so the constant's
//! column is the weighted sum of the data and its diagonal the weighted count; the prior
//! `V_0 = epsilon I` adds nothing off the diagonal). From it, in physical units, the mean fuel,
//! speed and acceleration (the derived acceleration channel, or the difference of the speed
//! now and a lag ago when speed is lagged in `psi`). In this order:
//!
//! 1. fewer than `min_samples` weighted samples: `unsettled` (not converged);
//! 2. mean speed below `standstill_speed_m_s`: `idle` (with the standing share, see
//!    [`OperatingPoint::standing_share`]: that share above one half instead);
//! 3. mean acceleration at least `acceleration_m_s2`: `accelerating`;
//! 4. mean acceleration at most `-acceleration_m_s2`: `braking`;
//! 5. mean fuel at most `coasting_fuel_cm3_s` (no traction power: engine idling or fuel cut
//!    off): `coasting`;
//! 6. otherwise `cruising`.
//!
//! Several components may fall under one rule (two `cruising` components: an eco and a sporty
//! driver). Each component's [`ComponentName`] is unique within the mixture, so a move between
//! two of them is a change of name: the components of one regime are told apart by their mean
//! fuel (what a fuel monitor is about, and a channel every setting has), in tiers that differ
//! by at least `same_power_cm3_s` (sorted by mean fuel, a new tier where the next component
//! burns that much more than the previous): two tiers `_low_power` / `_high_power`, three with
//! `_mid_power`, more `_power_1` (lowest) .. `_power_k`. Components in one tier really are the
//! same regime as far as the statistics tell; they get an ordinal `_1`, `_2`, .. in component
//! order. A component alone under its rule keeps the bare name (`cruising`), so a consumer
//! reads the regime as the name up to its first qualifier ([`ComponentName::regime`]).
//!
//! The names are a function of the statistics and the configuration only: a monitor restored
//! from a snapshot names its components as before.

use railmon_filter::normal::normal_cdf;
use serde::{Deserialize, Serialize};

/// What a mixture component means.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegimeName {
    /// Standing (engine idling).
    Idle,
    /// Speeding up.
    Accelerating,
    /// Holding speed under power.
    Cruising,
    /// Moving without traction power (engine idling, or fuel cut off on overrun).
    Coasting,
    /// Slowing down faster than running resistance would.
    Braking,
    /// Too few samples to say (a component that has not converged, or has been forgotten).
    #[default]
    Unsettled,
}

impl RegimeName {
    /// Every name, in the order of the railcar simulator's labels, then `unsettled`.
    pub const ALL: [RegimeName; 6] = [
        RegimeName::Idle,
        RegimeName::Accelerating,
        RegimeName::Cruising,
        RegimeName::Coasting,
        RegimeName::Braking,
        RegimeName::Unsettled,
    ];

    /// The name as JSON, CSV and events write it.
    pub fn as_str(self) -> &'static str {
        match self {
            RegimeName::Idle => "idle",
            RegimeName::Accelerating => "accelerating",
            RegimeName::Cruising => "cruising",
            RegimeName::Coasting => "coasting",
            RegimeName::Braking => "braking",
            RegimeName::Unsettled => "unsettled",
        }
    }

    /// The name written `text` (as [`RegimeName::as_str`] gives it).
    pub fn parse(text: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|n| n.as_str() == text)
    }
}

impl std::fmt::Display for RegimeName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The regimes given per sample with `pointer_regimes`, component `i` holding regime `i`
/// (component 0 the standing one, as with `pointer_standing`); the railcar simulator's labels
/// in its order.
pub const GIVEN_REGIMES: [RegimeName; 5] = [
    RegimeName::Idle,
    RegimeName::Accelerating,
    RegimeName::Cruising,
    RegimeName::Coasting,
    RegimeName::Braking,
];

/// The regime component `i` of `components` holds when every regime is given
/// (`pointer_regimes`): component 0 `idle`, then `(components - 1) / 4` components for each
/// moving regime in [`GIVEN_REGIMES`] order (within a regime the mixture learns which holds
/// what, as it learned every component before).
pub fn given_regime(i: usize, components: usize) -> RegimeName {
    let per_regime = ((components.max(5) - 1) / 4).max(1);
    match i {
        0 => RegimeName::Idle,
        _ => GIVEN_REGIMES[(1 + (i - 1) / per_regime).min(GIVEN_REGIMES.len() - 1)],
    }
}

/// What one sample says the vehicle does ([`RegimeNaming::physical_regime`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    pub speed_m_s: f64,
    pub acceleration_m_s2: f64,
    /// `a + g i / 1000`, the acceleration net of the grade.
    pub specific_force_m_s2: f64,
    /// The throttle notch (0: no traction).
    pub notch: i32,
    /// The full-power notch.
    pub full_notch: i32,
}

/// Thresholds of the naming rule (module documentation). A property of the vehicle (what
/// "standing" and "no traction power" look like), so two sets: `Default` is a road car's
/// ([`RegimeNaming::road_car`]), [`RegimeNaming::railcar`] a diesel railcar's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RegimeNaming {
    /// Weighted samples a component needs before it is named.
    #[schemars(range(min = 0.0))]
    pub min_samples: f64,
    /// Below this mean speed the component is standing, m/s.
    #[schemars(range(min = 0.0))]
    pub standstill_speed_m_s: f64,
    /// Mean acceleration beyond which the component is speeding up or braking, m/s^2.
    #[schemars(range(min = 0.0))]
    pub acceleration_m_s2: f64,
    /// Mean fuel at or below which a moving, steady component draws no traction power, cm^3/s.
    pub coasting_fuel_cm3_s: f64,
    /// Two components of one regime whose mean fuel differs by less than this are the same
    /// power tier (told apart by an ordinal only), cm^3/s.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub same_power_cm3_s: f64,
}

impl Default for RegimeNaming {
    fn default() -> Self {
        Self::road_car()
    }
}

impl RegimeNaming {
    /// A road car: fuel is cut off on overrun (~0 cm^3/s, the Camry files' most frequent
    /// value), below the ~0.2-0.3 cm^3/s of an idling 2.5 l engine; a deliberate acceleration
    /// or braking is 0.15 m/s^2 or more as a component's mean (a car's running resistance
    /// decelerates it by ~0.1-0.3 m/s^2 at speed, which coasting includes); 0.1 cm^3/s apart,
    /// about half an idling engine's fuel, is another power tier.
    pub fn road_car() -> Self {
        RegimeNaming {
            min_samples: 30.0,
            standstill_speed_m_s: 0.5,
            acceleration_m_s2: 0.15,
            coasting_fuel_cm3_s: 0.15,
            same_power_cm3_s: 0.1,
        }
    }

    /// A diesel railcar: engines idling with the auxiliaries on burn what they burn at a
    /// station (three QSK19-R: ~10 cm^3/s in `railcar.rs`'s map), so coasting is fuel below
    /// 1.5 times that; running resistance decelerates a train by ~0.05 m/s^2, service braking
    /// by ~0.7, notching up accelerates it by 0.1-0.75, so 0.15 m/s^2 as for a car. One notch
    /// of three QSK19-R is ~200 kW, ~14 cm^3/s in the map: 5 cm^3/s apart is another tier.
    pub fn railcar() -> Self {
        RegimeNaming {
            coasting_fuel_cm3_s: 15.0,
            same_power_cm3_s: 5.0,
            ..Self::road_car()
        }
    }

    /// Every component's unique name (module documentation): its regime by
    /// [`RegimeNaming::name`], qualified by power tier and ordinal where several components
    /// share that regime.
    pub fn names(&self, points: &[OperatingPoint]) -> Vec<ComponentName> {
        let regimes: Vec<RegimeName> = points.iter().map(|p| self.name(p)).collect();
        self.qualified(&regimes, points)
    }

    /// The unique names of components whose regimes are `regimes` (by the rule or given):
    /// qualified by power tier and ordinal where several share one (module documentation).
    pub fn qualified(
        &self,
        regimes: &[RegimeName],
        points: &[OperatingPoint],
    ) -> Vec<ComponentName> {
        let mut names: Vec<ComponentName> =
            regimes.iter().map(|&r| ComponentName::bare(r)).collect();
        for regime in RegimeName::ALL {
            let mut members: Vec<usize> = (0..points.len())
                .filter(|&i| regimes[i] == regime)
                .collect();
            if members.len() < 2 {
                continue;
            }
            // An unsettled component's mean fuel means nothing yet: ordinals only.
            let tier_of: Vec<usize> = if regime == RegimeName::Unsettled {
                vec![0; members.len()]
            } else {
                members.sort_by(|&i, &j| {
                    points[i]
                        .fuel_cm3_s
                        .total_cmp(&points[j].fuel_cm3_s)
                        .then(i.cmp(&j))
                });
                let mut tier = 0;
                let mut tiers = vec![0];
                for w in members.windows(2) {
                    let step = points[w[1]].fuel_cm3_s - points[w[0]].fuel_cm3_s;
                    // NaN (a broken statistic) is not a step: same tier.
                    if step >= self.same_power_cm3_s {
                        tier += 1;
                    }
                    tiers.push(tier);
                }
                tiers
            };
            let tiers = tier_of.last().map_or(1, |t| t + 1);
            for (k, &i) in members.iter().enumerate() {
                let t = tier_of[k];
                names[i].power = PowerTier::of(t, tiers);
                let same: Vec<usize> = members
                    .iter()
                    .zip(&tier_of)
                    .filter(|(_, &u)| u == t)
                    .map(|(&j, _)| j)
                    .collect();
                if same.len() > 1 {
                    let rank = same.iter().filter(|&&j| j < i).count() + 1;
                    names[i].ordinal = Some(rank as u32);
                }
            }
        }
        names
    }

    /// The rule of the module documentation.
    pub fn name(&self, point: &OperatingPoint) -> RegimeName {
        if point.samples.is_nan() || point.samples < self.min_samples {
            RegimeName::Unsettled
        } else if match point.standing_share {
            Some(share) => share > 0.5,
            None => point
                .speed_m_s
                .is_some_and(|v| v < self.standstill_speed_m_s),
        } {
            RegimeName::Idle
        } else if point
            .acceleration_m_s2
            .is_some_and(|a| a >= self.acceleration_m_s2)
        {
            RegimeName::Accelerating
        } else if point
            .acceleration_m_s2
            .is_some_and(|a| a <= -self.acceleration_m_s2)
        {
            RegimeName::Braking
        } else if point.fuel_cm3_s <= self.coasting_fuel_cm3_s {
            RegimeName::Coasting
        } else {
            RegimeName::Cruising
        }
    }

    /// The regime of one sample from what the vehicle does, not from a component's
    /// statistics (`pointer_regimes`, issue 25 item 1), and without its fuel (the virtual
    /// sensor weighs it):
    ///
    /// 1. speed below `standstill_speed_m_s`: `idle` (as `pointer_standing`);
    /// 2. traction (the notch above 0): `accelerating` if the vehicle gains speed, by at least
    ///    `acceleration_m_s2` below the full-power notch (`full_notch`; a part notch that
    ///    holds the speed gives it up to one notch's surplus, ~0.05 m/s^2 for the railcar at
    ///    40 km/h), by any amount at it; else `cruising` (holding speed under power: at full
    ///    notch up a climb, balance speed is holding);
    /// 3. no traction: `braking` if the grade-corrected acceleration (specific force,
    ///    `a + g i / 1000`) is at most `-acceleration_m_s2`, else `coasting`. A coasting
    ///    vehicle's specific force is its running resistance per mass: for a train below
    ///    0.07 m/s^2 up to 160 km/h (Davis `A + B v + C v^2 / m` of `railcar.rs`, 190 t:
    ///    0.012 + 0.0044 + 0.045), well inside the 0.15 m/s^2 a deliberate brake application
    ///    exceeds. Under traction the specific force is no help: up a climb at balance speed it
    ///    is `g i`, the traction spent on the grade.
    ///
    /// No threshold here depends on a route: the notch, the standstill speed and the
    /// acceleration bound are the vehicle's. A decision, not a probability: weighing the rule
    /// softly (`ln Phi` of the margin over the speed filter's spread) let the fuel regressions
    /// pull the components back into fuel clusters (docs/notes/fuel-log.md).
    pub fn physical_regime(&self, m: &Motion) -> RegimeName {
        if m.speed_m_s < self.standstill_speed_m_s {
            RegimeName::Idle
        } else if m.notch > 0 {
            let bound = match m.notch >= m.full_notch {
                true => 0.0,
                false => self.acceleration_m_s2,
            };
            match m.acceleration_m_s2 > bound || m.acceleration_m_s2 >= self.acceleration_m_s2 {
                true => RegimeName::Accelerating,
                false => RegimeName::Cruising,
            }
        } else if m.specific_force_m_s2 <= -self.acceleration_m_s2 {
            RegimeName::Braking
        } else {
            RegimeName::Coasting
        }
    }

    /// How sure [`RegimeNaming::physical_regime`] is: `P` of each regime of
    /// [`GIVEN_REGIMES`] (that order) when the acceleration, and with it the specific force,
    /// is known to a standard deviation `acceleration_sd_m_s2` (the speed filter's), the
    /// speed, the notch and the grade exactly. The rule's thresholds become `Phi` of the
    /// margin: `P(braking) = Phi((-acceleration_m_s2 - f) / sd)` without traction,
    /// `P(accelerating) = Phi((a - bound) / sd)` under it (the bound as the rule's). With an
    /// `sd` of 0 the rule's decision, certain.
    ///
    /// Why: the rule is a decision, and the mixture learns from it as one (weighed softly the
    /// fuel regressions pulled the components back into fuel clusters, docs/notes/fuel-log.md);
    /// but a name published with probability 1 that a 0.25 m/s speed sensor makes a coin toss
    /// (coasting named braking on up to a third of its seconds on the generated lines) is
    /// confidently wrong. The published probabilities weigh the rule by this.
    pub fn physical_regime_probabilities(&self, m: &Motion, acceleration_sd_m_s2: f64) -> [f64; 5] {
        let mut p = [0.0; 5];
        let index = |r: RegimeName| GIVEN_REGIMES.iter().position(|&g| g == r).expect("given");
        if m.speed_m_s < self.standstill_speed_m_s || acceleration_sd_m_s2 <= 0.0 {
            p[index(self.physical_regime(m))] = 1.0;
            return p;
        }
        let sd = acceleration_sd_m_s2;
        let (upper, lower, share_upper) = if m.notch > 0 {
            let bound = match m.notch >= m.full_notch {
                true => 0.0,
                false => self.acceleration_m_s2,
            };
            let upper = normal_cdf((m.acceleration_m_s2 - bound) / sd);
            (RegimeName::Accelerating, RegimeName::Cruising, upper)
        } else {
            let braking = normal_cdf((-self.acceleration_m_s2 - m.specific_force_m_s2) / sd);
            (RegimeName::Braking, RegimeName::Coasting, braking)
        };
        p[index(upper)] = share_upper;
        p[index(lower)] = 1.0 - share_upper;
        p
    }

    pub(crate) fn validate(&self) -> Result<(), crate::FuelError> {
        let checks = [
            ("naming.min_samples", self.min_samples),
            ("naming.standstill_speed_m_s", self.standstill_speed_m_s),
            ("naming.acceleration_m_s2", self.acceleration_m_s2),
        ];
        for (field, v) in checks {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::FuelError::invalid(
                    field,
                    v,
                    "must be finite and >= 0",
                ));
            }
        }
        if !(self.same_power_cm3_s.is_finite() && self.same_power_cm3_s > 0.0) {
            return Err(crate::FuelError::invalid(
                "naming.same_power_cm3_s",
                self.same_power_cm3_s,
                "must be finite and > 0",
            ));
        }
        if !self.coasting_fuel_cm3_s.is_finite() {
            return Err(crate::FuelError::invalid(
                "naming.coasting_fuel_cm3_s",
                self.coasting_fuel_cm3_s,
                "must be finite",
            ));
        }
        Ok(())
    }
}

/// Where a component sits by mean fuel among the components of its regime.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PowerTier {
    Low,
    Mid,
    High,
    /// 1-based rank from the lowest, when there are more than three tiers.
    Rank(u32),
}

impl PowerTier {
    /// Tier `t` (0-based from the lowest) of `tiers`; `None` for a single tier.
    fn of(t: usize, tiers: usize) -> Option<Self> {
        match (tiers, t) {
            (0 | 1, _) => None,
            (_, 0) if tiers <= 3 => Some(PowerTier::Low),
            (2, _) | (3, 2) => Some(PowerTier::High),
            (3, _) => Some(PowerTier::Mid),
            _ => Some(PowerTier::Rank(t as u32 + 1)),
        }
    }
}

/// A component's name, unique within the mixture (module documentation): the regime, then
/// where needed its power tier and an ordinal. Written `cruising`, `cruising_high_power`,
/// `braking_power_4`, `idle_2`, `cruising_low_power_1`; serialised as that text.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ComponentName {
    /// What the component means.
    pub regime: RegimeName,
    /// Its tier by mean fuel among components of the same regime (`None`: one tier).
    pub power: Option<PowerTier>,
    /// 1-based, among components of the same regime and tier (`None`: the only one).
    pub ordinal: Option<u32>,
}

impl Default for ComponentName {
    fn default() -> Self {
        Self::bare(RegimeName::Unsettled)
    }
}

impl ComponentName {
    /// The regime's name without qualifier.
    pub fn bare(regime: RegimeName) -> Self {
        ComponentName {
            regime,
            power: None,
            ordinal: None,
        }
    }

    /// The name written `text` (as `Display` writes it); `None` if it is not one.
    pub fn parse(text: &str) -> Option<Self> {
        let (regime, mut rest) = RegimeName::ALL
            .into_iter()
            .find_map(|r| text.strip_prefix(r.as_str()).map(|rest| (r, rest)))?;
        let mut name = Self::bare(regime);
        let tier = [
            ("_low_power", PowerTier::Low),
            ("_mid_power", PowerTier::Mid),
            ("_high_power", PowerTier::High),
        ]
        .into_iter()
        .find_map(|(suffix, tier)| rest.strip_prefix(suffix).map(|r| (tier, r)));
        if let Some((tier, r)) = tier {
            name.power = Some(tier);
            rest = r;
        } else if let Some(r) = rest.strip_prefix("_power_") {
            let (rank, r) = leading_number(r)?;
            name.power = Some(PowerTier::Rank(rank));
            rest = r;
        }
        if let Some(r) = rest.strip_prefix('_') {
            let (ordinal, r) = leading_number(r)?;
            name.ordinal = Some(ordinal);
            rest = r;
        }
        rest.is_empty().then_some(name)
    }
}

/// A positive decimal number at the start of `text` (digits up to the next `_` or the end).
fn leading_number(text: &str) -> Option<(u32, &str)> {
    let end = text.find('_').unwrap_or(text.len());
    let n: u32 = text[..end].parse().ok().filter(|&n| n > 0)?;
    Some((n, &text[end..]))
}

impl std::fmt::Display for ComponentName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.regime.as_str())?;
        match self.power {
            Some(PowerTier::Low) => f.write_str("_low_power")?,
            Some(PowerTier::Mid) => f.write_str("_mid_power")?,
            Some(PowerTier::High) => f.write_str("_high_power")?,
            Some(PowerTier::Rank(k)) => write!(f, "_power_{k}")?,
            None => {}
        }
        if let Some(k) = self.ordinal {
            write!(f, "_{k}")?;
        }
        Ok(())
    }
}

impl Serialize for ComponentName {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for ComponentName {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        ComponentName::parse(&text)
            .ok_or_else(|| serde::de::Error::custom(format!("not a regime name: {text:?}")))
    }
}

/// A component's operating point: the mean of what it has absorbed, physical units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OperatingPoint {
    /// Weighted number of samples behind the means (`V[1, 1]` minus its prior).
    pub samples: f64,
    pub fuel_cm3_s: f64,
    /// `None` without a speed channel.
    pub speed_m_s: Option<f64>,
    /// `None` without the acceleration channel or a lagged speed.
    pub acceleration_m_s2: Option<f64>,
    /// The component's share of standing samples (speed below the standstill threshold): with
    /// `pointer_standing` standstill is a regime given, so 1 for the standing component and 0
    /// for the others; `None` without it. A mean speed mixes stops with slow coasting (a
    /// component holding both had a mean above the threshold and was named `coasting` at
    /// platforms); the share of standing does not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub standing_share: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(samples: f64, fuel: f64, v: f64, a: f64) -> OperatingPoint {
        OperatingPoint {
            samples,
            fuel_cm3_s: fuel,
            speed_m_s: Some(v),
            acceleration_m_s2: Some(a),
            standing_share: None,
        }
    }

    #[test]
    fn the_rule_names_each_regime_in_order() {
        let n = RegimeNaming::railcar();
        assert_eq!(n.name(&point(10.0, 10.0, 0.0, 0.0)), RegimeName::Unsettled);
        assert_eq!(n.name(&point(100.0, 10.0, 0.1, 0.0)), RegimeName::Idle);
        assert_eq!(
            n.name(&point(100.0, 100.0, 18.0, 0.36)),
            RegimeName::Accelerating
        );
        assert_eq!(
            n.name(&point(100.0, 10.4, 15.0, -0.72)),
            RegimeName::Braking
        );
        assert_eq!(
            n.name(&point(100.0, 12.0, 15.5, -0.003)),
            RegimeName::Coasting
        );
        assert_eq!(
            n.name(&point(100.0, 58.0, 28.8, 0.026)),
            RegimeName::Cruising
        );
        // Without speed and acceleration only fuel decides.
        let fuel_only = OperatingPoint {
            samples: 100.0,
            fuel_cm3_s: 40.0,
            speed_m_s: None,
            acceleration_m_s2: None,
            standing_share: None,
        };
        assert_eq!(n.name(&fuel_only), RegimeName::Cruising);
        // With the standing share, it decides idle, not the mean speed: a component holding
        // stops and slow coasting (mean speed 1.2 m/s) that stands 60 % of its weight is idle,
        // one at 0.3 m/s that stands 40 % is not.
        let share = |v: f64, s: f64| OperatingPoint {
            standing_share: Some(s),
            ..point(100.0, 10.4, v, -0.02)
        };
        assert_eq!(n.name(&share(1.2, 0.6)), RegimeName::Idle);
        assert_eq!(n.name(&share(0.3, 0.4)), RegimeName::Coasting);
        // NaN samples (a broken statistic) never get a name.
        assert_eq!(
            n.name(&point(f64::NAN, 10.0, 0.0, 0.0)),
            RegimeName::Unsettled
        );
    }

    /// Components under one rule are told apart by mean fuel tiers, and by an ordinal only
    /// where the fuel does not separate them; every name is unique, a lone component keeps the
    /// bare name, and the order of the components does not change which is which.
    #[test]
    fn components_of_one_regime_get_unique_names_by_power_tier() {
        let n = RegimeNaming::railcar();
        let cruising = |fuel: f64| point(100.0, fuel, 20.0, 0.0);
        let text = |points: &[OperatingPoint]| -> Vec<String> {
            n.names(points).iter().map(|c| c.to_string()).collect()
        };
        // The driving_style case: two cruising components, one idle.
        assert_eq!(
            text(&[cruising(60.0), point(100.0, 10.4, 0.0, 0.0), cruising(40.0)]),
            ["cruising_high_power", "idle", "cruising_low_power"]
        );
        assert_eq!(
            text(&[cruising(40.0), cruising(80.0), cruising(60.0)]),
            [
                "cruising_low_power",
                "cruising_high_power",
                "cruising_mid_power"
            ]
        );
        assert_eq!(
            text(&[
                cruising(70.0),
                cruising(20.0),
                cruising(30.0),
                cruising(50.0)
            ]),
            [
                "cruising_power_4",
                "cruising_power_1",
                "cruising_power_2",
                "cruising_power_3"
            ]
        );
        // Within `same_power_cm3_s` (5) of each other: one tier, ordinals in component order.
        assert_eq!(
            text(&[cruising(42.0), cruising(40.0), cruising(80.0)]),
            [
                "cruising_low_power_1",
                "cruising_low_power_2",
                "cruising_high_power"
            ]
        );
        // A chain of small steps is one tier (tiers are separated by a gap, not a width).
        assert_eq!(
            text(&[cruising(40.0), cruising(44.0), cruising(48.0)]),
            ["cruising_1", "cruising_2", "cruising_3"]
        );
        // Unsettled components: ordinals only, whatever their fuel.
        let few = |fuel: f64| point(5.0, fuel, 0.0, 0.0);
        assert_eq!(
            text(&[few(10.0), few(f64::NAN), few(90.0)]),
            ["unsettled_1", "unsettled_2", "unsettled_3"]
        );
        // Unique always, and the regime is the rule's.
        let points = [
            cruising(42.0),
            cruising(40.0),
            cruising(80.0),
            point(100.0, 100.0, 18.0, 0.36),
            point(100.0, 100.0, 18.0, 0.36),
            few(1.0),
        ];
        let names = n.names(&points);
        for (i, a) in names.iter().enumerate() {
            assert_eq!(a.regime, n.name(&points[i]));
            assert!(names[i + 1..].iter().all(|b| b != a), "{names:?}");
        }
    }

    #[test]
    fn component_names_round_trip_as_text_and_bare_names_still_read() {
        let names = [
            "idle",
            "cruising_low_power",
            "cruising_mid_power",
            "braking_high_power",
            "accelerating_power_12",
            "coasting_3",
            "cruising_high_power_2",
            "cruising_power_4_1",
        ];
        for text in names {
            let name = ComponentName::parse(text).unwrap();
            assert_eq!(name.to_string(), text);
            let json = serde_json::to_string(&name).unwrap();
            assert_eq!(json, format!("\"{text}\""));
            assert_eq!(serde_json::from_str::<ComponentName>(&json).unwrap(), name);
        }
        // A snapshot from before the qualifiers holds bare names: they read as bare names.
        assert_eq!(
            serde_json::from_str::<ComponentName>("\"cruising\"").unwrap(),
            ComponentName::bare(RegimeName::Cruising)
        );
        for bad in [
            "",
            "cruise",
            "cruising_",
            "cruising_0",
            "cruising_low",
            "cruising_low_power_mid_power",
            "cruising_power_",
            "cruising_2_3",
            "idle_x",
        ] {
            assert_eq!(ComponentName::parse(bad), None, "{bad}");
        }
    }

    /// The physical rule of each given regime, at the boundaries.
    #[test]
    fn the_physical_regime_reads_notch_acceleration_grade_and_standstill() {
        let n = RegimeNaming::railcar();
        let r = |v: f64, a: f64, f: f64, notch: i32| {
            n.physical_regime(&Motion {
                speed_m_s: v,
                acceleration_m_s2: a,
                specific_force_m_s2: f,
                notch,
                full_notch: 8,
            })
        };
        assert_eq!(r(0.2, 0.0, 0.0, 3), RegimeName::Idle);
        assert_eq!(r(5.0, 0.4, 0.4, 3), RegimeName::Accelerating);
        // Full notch: gaining speed beyond the noise is notching up, holding it is cruising
        // (up a 20 per mille climb the specific force is the grade's 0.2 either way).
        assert_eq!(r(30.0, 0.03, 0.03, 8), RegimeName::Accelerating);
        assert_eq!(r(15.0, -0.01, 0.2, 8), RegimeName::Cruising);
        assert_eq!(r(25.0, 0.1, 0.1, 4), RegimeName::Cruising);
        assert_eq!(r(25.0, 0.0, 0.2, 4), RegimeName::Cruising);
        // Coasting at 160 km/h decelerates by the running resistance only; down a grade the
        // train may gain speed and still coast.
        assert_eq!(r(44.0, -0.07, -0.07, 0), RegimeName::Coasting);
        assert_eq!(r(20.0, 0.1, -0.05, 0), RegimeName::Coasting);
        assert_eq!(r(44.0, -0.16, -0.16, 0), RegimeName::Braking);
        // Braking down a grade holds the speed: the grade-corrected acceleration tells.
        assert_eq!(r(20.0, 0.0, -0.3, 0), RegimeName::Braking);
    }

    /// How sure the rule is: its decision when the acceleration is exact or the train
    /// stands, a coin toss at a threshold, and the decision again far from one.
    #[test]
    fn the_physical_regime_probabilities_are_the_rule_s_margin() {
        let n = RegimeNaming::railcar();
        let motion = |v: f64, a: f64, f: f64, notch: i32| Motion {
            speed_m_s: v,
            acceleration_m_s2: a,
            specific_force_m_s2: f,
            notch,
            full_notch: 8,
        };
        let index = |r: RegimeName| GIVEN_REGIMES.iter().position(|&g| g == r).unwrap();
        for m in [motion(0.2, 0.0, 0.0, 3), motion(20.0, -0.14, -0.16, 0)] {
            let p = n.physical_regime_probabilities(&m, 0.0);
            assert_eq!(p[index(n.physical_regime(&m))], 1.0, "{m:?}");
        }
        let idle = n.physical_regime_probabilities(&motion(0.2, 0.5, 0.5, 3), 0.3);
        assert_eq!(idle[index(RegimeName::Idle)], 1.0);
        let threshold = -n.acceleration_m_s2;
        let at = n.physical_regime_probabilities(&motion(20.0, 0.0, threshold, 0), 0.2);
        assert!(
            (at[index(RegimeName::Braking)] - 0.5).abs() < 1e-6,
            "{at:?}"
        );
        assert!((at.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{at:?}");
        let coasting = n.physical_regime_probabilities(&motion(20.0, -0.05, -0.05, 0), 0.02);
        assert!(
            coasting[index(RegimeName::Coasting)] > 0.999,
            "{coasting:?}"
        );
        // Under a part notch the bound is the threshold; at full notch any gain of speed.
        let part = n.physical_regime_probabilities(&motion(20.0, n.acceleration_m_s2, 0.3, 4), 0.1);
        assert!(
            (part[index(RegimeName::Accelerating)] - 0.5).abs() < 1e-6,
            "{part:?}"
        );
        let full = n.physical_regime_probabilities(&motion(20.0, 0.0, 0.2, 8), 0.1);
        assert!(
            (full[index(RegimeName::Cruising)] - 0.5).abs() < 1e-6,
            "{full:?}"
        );
    }

    #[test]
    fn names_round_trip_as_text() {
        for n in RegimeName::ALL {
            assert_eq!(RegimeName::parse(n.as_str()), Some(n));
            assert_eq!(serde_json::to_string(&n).unwrap(), format!("\"{n}\""));
        }
    }
}
