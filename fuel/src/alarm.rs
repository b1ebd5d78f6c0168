//! The regime alarm: the most probable component turned into the reported driving regime and
//! its `regime_changed` events. One rule, applied inside [`crate::FuelMonitor`]'s step, so that
//! the service's vehicle stream and `railmon analyze fuel` (`events.csv`) raise the same events
//! from the same data.

use serde::{Deserialize, Serialize};

use crate::config::FuelMonitorConfig;
use crate::regime::ComponentName;

/// The alarm rule of the fuel stream: the reported regime changed. The event `regime_changed`
/// of the service and of `railmon analyze fuel` (`events.csv`) carries these fields.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegimeChange {
    pub from_regime: usize,
    pub to_regime: usize,
    /// What the regimes mean, named on this sample (the component left may have been renamed
    /// since it was entered: the name is of its statistics now). Names are unique per
    /// component, so they differ.
    pub from_name: ComponentName,
    pub to_name: ComponentName,
    /// Probability of the new regime on this sample.
    pub probability: f64,
}

/// The `kind` of a [`RegimeChange`] event.
pub const REGIME_CHANGED: &str = "regime_changed";

/// The confirmation of the reported regime (`regime_confirm_samples`): it follows the most
/// probable component once that has been the most probable for that many samples in a row; at
/// the first estimate it is that component at once. The reported regime itself is kept in the
/// published estimate (`MixtureEstimate::regime`), which the monitor hands back at each step.
///
/// Serialised as its streak alone, a pair `(regime, samples)`: the monitor's snapshots held
/// that pair before the rule had a type of its own, and a snapshot restores across the change.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub(crate) struct RegimeConfirmation {
    /// The most probable component and for how many samples in a row it has been.
    active_streak: (usize, usize),
}

impl RegimeConfirmation {
    /// One estimate: `active` the most probable component now, `previous` the regime reported
    /// on the previous estimate (`None` on the first), `names` and `probabilities` of every
    /// component on this sample. The reported regime and, when it differs from `previous`, the
    /// event.
    pub(crate) fn update(
        &mut self,
        config: &FuelMonitorConfig,
        active: usize,
        previous: Option<usize>,
        names: &[ComponentName],
        probabilities: &[f64],
    ) -> (usize, Option<RegimeChange>) {
        self.active_streak = match self.active_streak {
            (regime, n) if regime == active => (regime, n + 1),
            _ => (active, 1),
        };
        let regime = match previous {
            Some(reported) if self.active_streak.1 < config.regime_confirm_samples => reported,
            _ => active,
        };
        let change = previous
            .filter(|&reported| reported != regime)
            .map(|reported| RegimeChange {
                from_regime: reported,
                to_regime: regime,
                from_name: names[reported],
                to_name: names[regime],
                probability: probabilities[regime],
            });
        (regime, change)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regime::RegimeName;

    /// The reported regime and the changes over a hand-made sequence of most probable
    /// components, confirmed over `confirm` samples.
    fn reported(confirm: usize, active: &[usize]) -> (Vec<usize>, Vec<(usize, usize, usize)>) {
        let config = FuelMonitorConfig {
            regime_confirm_samples: confirm,
            ..FuelMonitorConfig::default()
        };
        let names = [
            RegimeName::Idle,
            RegimeName::Cruising,
            RegimeName::Accelerating,
        ]
        .map(ComponentName::bare);
        let probabilities = [0.2, 0.3, 0.5];
        let mut confirmation = RegimeConfirmation::default();
        let (mut previous, mut regimes, mut changes) = (None, Vec::new(), Vec::new());
        for (step, &a) in active.iter().enumerate() {
            let (regime, change) =
                confirmation.update(&config, a, previous, &names, &probabilities);
            if let Some(c) = change {
                assert_eq!(
                    (c.from_name, c.to_name),
                    (names[c.from_regime], names[regime])
                );
                assert_eq!(c.probability, probabilities[regime]);
                changes.push((step, c.from_regime, c.to_regime));
            }
            regimes.push(regime);
            previous = Some(regime);
        }
        (regimes, changes)
    }

    #[test]
    fn confirmation_on_a_hand_made_sequence() {
        let active = [2, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1];
        // At once: the pointer estimate itself, a change at every move.
        let (regimes, changes) = reported(1, &active);
        assert_eq!(regimes, active);
        assert_eq!(changes.len(), 4);
        // Over 3 samples: the first estimate's component at once, then only the runs of 3 or
        // more (0 at steps 4-6, confirmed at 6; 1 at 7-10, confirmed at 9).
        let (regimes, changes) = reported(3, &active);
        assert_eq!(regimes, [2, 2, 2, 2, 2, 2, 0, 0, 0, 1, 1]);
        assert_eq!(changes, [(6, 2, 0), (9, 0, 1)]);
    }
}
