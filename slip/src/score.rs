//! Scoring detections against the true slip flag: precision, recall, F1 of
//! "probability > 0.5", and the detection delay of each slip event.

/// Counts one drive's detections step by step.
#[derive(Debug, Clone, Default)]
pub struct DetectionCounter {
    true_pos: usize,
    false_pos: usize,
    false_neg: usize,
    /// Step at which the current true event began, while it lasts and is not yet detected.
    pending_onset: Option<usize>,
    in_event: bool,
    events: usize,
    delays_steps: Vec<usize>,
    /// Whether the last step was detected, and whether the detection episode it belongs to
    /// has met a true slip step so far.
    in_detection: bool,
    episode_overlaps_truth: bool,
    detection_episodes: usize,
    false_episodes: usize,
    /// Length of the current detection episode and of the longest so far (steps).
    episode_steps: usize,
    longest_episode_steps: usize,
}

/// The score of one drive.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectionScore {
    /// `tp / (tp + fp)`; `None` when nothing was detected.
    pub precision: Option<f64>,
    /// `tp / (tp + fn)`; `None` when the drive never slipped.
    pub recall: Option<f64>,
    /// Harmonic mean of the two; `None` when either is undefined.
    pub f1: Option<f64>,
    /// Median over detected events of (first detected step - first true step) of the event.
    pub median_delay_steps: Option<f64>,
    pub true_pos: usize,
    pub false_pos: usize,
    pub false_neg: usize,
    /// True slip events (rising edges of the flag).
    pub events: usize,
    /// Events never detected while they lasted.
    pub missed_events: usize,
    /// Detection episodes (rising edges of the decision): for the alarm rule, the
    /// `slip_started` events a maintainer sees.
    pub detection_episodes: usize,
    /// Detection episodes with no true slip step in them (a false alarm as a maintainer counts
    /// it, however long); an episode still open at the end is counted by what it met so far.
    pub false_episodes: usize,
    /// The longest detection episode (steps detected in a row).
    pub longest_episode_steps: usize,
}

impl DetectionCounter {
    /// Adds step `step` with the detector's decision and the truth.
    pub fn push(&mut self, step: usize, detected: bool, truth: bool) {
        match (detected, truth) {
            (true, true) => self.true_pos += 1,
            (true, false) => self.false_pos += 1,
            (false, true) => self.false_neg += 1,
            (false, false) => {}
        }
        if truth && !self.in_event {
            self.events += 1;
            self.pending_onset = Some(step);
        }
        self.in_event = truth;
        if !truth {
            self.pending_onset = None;
        }
        if detected {
            if let Some(onset) = self.pending_onset.take() {
                self.delays_steps.push(step - onset);
            }
        }
        match (self.in_detection, detected) {
            (false, true) => {
                self.detection_episodes += 1;
                self.episode_overlaps_truth = truth;
            }
            (true, true) => self.episode_overlaps_truth |= truth,
            (true, false) if !self.episode_overlaps_truth => self.false_episodes += 1,
            _ => {}
        }
        self.in_detection = detected;
        self.episode_steps = if detected { self.episode_steps + 1 } else { 0 };
        self.longest_episode_steps = self.longest_episode_steps.max(self.episode_steps);
    }

    pub fn score(&self) -> DetectionScore {
        let ratio = |num: usize, den: usize| (den > 0).then(|| num as f64 / den as f64);
        let precision = ratio(self.true_pos, self.true_pos + self.false_pos);
        let recall = ratio(self.true_pos, self.true_pos + self.false_neg);
        let f1 = match (precision, recall) {
            (Some(p), Some(r)) if p + r > 0.0 => Some(2.0 * p * r / (p + r)),
            (Some(_), Some(_)) => Some(0.0),
            _ => None,
        };
        let median_delay_steps = if self.delays_steps.is_empty() {
            None
        } else {
            let d: Vec<f64> = self.delays_steps.iter().map(|&v| v as f64).collect();
            Some(railmon_filter::stats::median(&d))
        };
        DetectionScore {
            precision,
            recall,
            f1,
            median_delay_steps,
            true_pos: self.true_pos,
            false_pos: self.false_pos,
            false_neg: self.false_neg,
            events: self.events,
            missed_events: self.events - self.delays_steps.len(),
            detection_episodes: self.detection_episodes,
            false_episodes: self.false_episodes
                + usize::from(self.in_detection && !self.episode_overlaps_truth),
            longest_episode_steps: self.longest_episode_steps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_score() {
        // truth:    0 0 1 1 1 1 0 0 1 1 0
        // detected: 0 1 0 0 1 1 1 0 0 0 0
        let truth = [0, 0, 1, 1, 1, 1, 0, 0, 1, 1, 0];
        let det = [0, 1, 0, 0, 1, 1, 1, 0, 0, 0, 0];
        let mut c = DetectionCounter::default();
        for (t, (&d, &tr)) in det.iter().zip(&truth).enumerate() {
            c.push(t, d == 1, tr == 1);
        }
        let s = c.score();
        assert_eq!((s.true_pos, s.false_pos, s.false_neg), (2, 2, 4));
        assert_eq!(s.precision, Some(0.5));
        assert!((s.recall.unwrap() - 1.0 / 3.0).abs() < 1e-15);
        assert!((s.f1.unwrap() - 0.4).abs() < 1e-15);
        // event 1 starts at 2, detected at 4: delay 2; event 2 (8-9) missed.
        assert_eq!(s.median_delay_steps, Some(2.0));
        assert_eq!((s.events, s.missed_events), (2, 1));
        // Episodes 1-1 (false: no true step), 4-6 (meets event 1).
        assert_eq!((s.detection_episodes, s.false_episodes), (2, 1));
        assert_eq!(s.longest_episode_steps, 3);
    }

    #[test]
    fn episodes_split_by_a_gap_and_one_open_at_the_end() {
        // truth:    0 1 1 1 0 0 0 0 0
        // detected: 0 0 1 0 1 0 0 1 1
        // Episodes: 2 (true), 4 (after the truth ended: false), 7-8 (open at the end: false).
        let truth = [0, 1, 1, 1, 0, 0, 0, 0, 0];
        let det = [0, 0, 1, 0, 1, 0, 0, 1, 1];
        let mut c = DetectionCounter::default();
        for (t, (&d, &tr)) in det.iter().zip(&truth).enumerate() {
            c.push(t, d == 1, tr == 1);
        }
        let s = c.score();
        assert_eq!((s.detection_episodes, s.false_episodes), (3, 2));
        assert_eq!((s.events, s.missed_events), (1, 0));
    }

    #[test]
    fn healthy_drive_without_detections_has_undefined_ratios() {
        let mut c = DetectionCounter::default();
        for t in 0..10 {
            c.push(t, false, false);
        }
        let s = c.score();
        assert_eq!(
            (s.precision, s.recall, s.f1, s.median_delay_steps),
            (None, None, None, None)
        );
    }
}
