//! The offline pipeline: one EKF bank feeding every adhesion method at once, so that all
//! methods see the same torque estimates (what `railmon analyze adhesion` and the benches run),
//! each with its own slip alarm.

use crate::adhesion::{AdhesionEstimator, AdhesionMethod};
use crate::alarm::{SlipAlarm, SlipAlarmEvent};
use crate::ekf::EkfBank;
use crate::error::SlipError;
use crate::fixed_lag::FixedLagLine;
use crate::monitor::SlipMonitorConfig;
use crate::sample::{validate_frame, DriveSample};
use crate::speed_reference::{
    validate_train_speed, SpeedReference, SpeedReferenceConfig, TrainSpeedCheck,
};

/// EKF bank plus, behind the fixed lag ([`FixedLagLine`]), one estimator and one alarm per
/// method: every value a step publishes belongs to the step [`MultiMethodPipeline::step_index`]
/// names, `FIXED_LAG_STEPS` frames back.
#[derive(Debug, Clone)]
pub struct MultiMethodPipeline {
    bank: EkfBank,
    line: FixedLagLine,
    methods: Vec<AdhesionMethod>,
    alarms: Vec<SlipAlarm>,
    /// Per method, the alarm's events of the last step published.
    events: Vec<Vec<SlipAlarmEvent>>,
    torque: Vec<f64>,
    /// Per method, its own train-speed test, as a [`crate::SlipMonitor`] of that method runs
    /// it (the test's calibration learns where the method does not flag, and the method's flag
    /// stands where the wheel has left the train): each method's probabilities, alarm and
    /// events are then those of the monitor, and `railmon analyze` raises the service's.
    train: Vec<TrainSpeedCheck>,
    /// Per method, its probability or, for the drives the train-speed test judges, the test's,
    /// of the last step published.
    combined: Vec<Vec<f64>>,
    /// Per method, what its last step published was judged against.
    references: Vec<SpeedReference>,
    /// Whether the last step published had a train speed.
    train_steps: bool,
}

impl MultiMethodPipeline {
    /// All methods of [`AdhesionMethod::ALL`] with the settings in `config`.
    pub fn new(config: &SlipMonitorConfig, n_drives: usize) -> Result<Self, SlipError> {
        Self::with_methods(config, n_drives, &AdhesionMethod::ALL)
    }

    pub fn with_methods(
        config: &SlipMonitorConfig,
        n_drives: usize,
        methods: &[AdhesionMethod],
    ) -> Result<Self, SlipError> {
        config.validate()?;
        let bank = EkfBank::new(config.model()?, &config.ekf, n_drives)?;
        let estimators = methods
            .iter()
            .map(|&m| AdhesionEstimator::new(m, &config.adhesion, n_drives))
            .collect::<Result<_, _>>()?;
        let alarms = methods
            .iter()
            .map(|_| SlipAlarm::new(config.alarm, n_drives))
            .collect::<Result<_, _>>()?;
        Ok(MultiMethodPipeline {
            bank,
            line: FixedLagLine::new(estimators, n_drives),
            methods: methods.to_vec(),
            alarms,
            events: vec![Vec::new(); methods.len()],
            torque: vec![0.0; n_drives],
            train: methods
                .iter()
                .map(|_| TrainSpeedCheck::new(SpeedReferenceConfig::default(), n_drives))
                .collect::<Result<_, _>>()?,
            combined: vec![vec![0.0; n_drives]; methods.len()],
            references: vec![SpeedReference::Group; methods.len()],
            train_steps: false,
        })
    }

    /// Sets the drives' geometry and the train-speed test (default:
    /// [`SpeedReferenceConfig::default`]).
    pub fn set_speed_reference(&mut self, config: SpeedReferenceConfig) -> Result<(), SlipError> {
        for t in &mut self.train {
            *t = TrainSpeedCheck::new(config, self.bank.n_drives())?;
        }
        Ok(())
    }

    /// Whether a gap of `missing_steps` relocks the EKFs: then [`MultiMethodPipeline::drain`]
    /// every pending step before [`MultiMethodPipeline::bridge`].
    pub fn relocks_after(&self, missing_steps: u64) -> bool {
        missing_steps > 0 && self.bank.relocks_after(missing_steps)
    }

    /// Carries every method over `missing_steps` periods no frame covered, as
    /// [`crate::SlipMonitor::bridge`]. After a gap the EKFs relock after
    /// ([`MultiMethodPipeline::relocks_after`]) the pending steps must have been drained: an
    /// error otherwise, not a silent loss.
    pub fn bridge(&mut self, missing_steps: u64) -> Result<(), SlipError> {
        if missing_steps == 0 {
            return Ok(());
        }
        if self.relocks_after(missing_steps) && self.line.pending() > 0 {
            return Err(SlipError::PendingBeforeGap {
                pending: self.line.pending(),
            });
        }
        if !self.bank.bridge(missing_steps) {
            return Ok(());
        }
        self.line.ekfs_relocked();
        for t in &mut self.train {
            t.reset();
        }
        Ok(())
    }

    /// One frame through the EKFs and every estimator; whether it published a step (that
    /// `FIXED_LAG_STEPS` before; not in the first `FIXED_LAG_STEPS`). A bad frame changes
    /// nothing.
    pub fn step(&mut self, samples: &[DriveSample]) -> Result<bool, SlipError> {
        self.step_with_train_speed(samples, None)
    }

    /// [`MultiMethodPipeline::step`] with the train's measured speed (m/s) when there is one:
    /// every method's probability (and its alarm) is then the train-speed test's for the drives
    /// it judges, as [`crate::SlipMonitor::step_with_train_speed`].
    pub fn step_with_train_speed(
        &mut self,
        samples: &[DriveSample],
        train_speed_m_s: Option<f64>,
    ) -> Result<bool, SlipError> {
        validate_frame(samples, self.bank.n_drives())?;
        if let Some(v) = train_speed_m_s {
            validate_train_speed(v)?;
        }
        self.bank.step(samples)?;
        for (t, f) in self.torque.iter_mut().zip(self.bank.filters()) {
            *t = f.torque_nm();
        }
        let published = self.line.push(&self.bank, &self.torque, train_speed_m_s)?;
        if published {
            self.publish();
        }
        Ok(published)
    }

    /// Publishes the oldest step still behind the lag from the frames after it: call until
    /// `false` at the end of a run (and before a gap the EKFs relock after).
    pub fn drain(&mut self) -> Result<bool, SlipError> {
        let published = self.line.drain()?;
        if published {
            self.publish();
        }
        Ok(published)
    }

    /// Frames stepped whose step is not yet published.
    pub fn pending(&self) -> u64 {
        self.line.pending()
    }

    /// The step (frames since the start, from 0) the last published values belong to.
    pub fn step_index(&self) -> u64 {
        self.line.last().step
    }

    /// Frames stepped after the step last published when it was: `FIXED_LAG_STEPS` in a run,
    /// fewer for the steps drained.
    pub fn lag_steps(&self) -> u64 {
        self.line.last().lag_steps
    }

    /// The EKF states of the step last published, one per drive.
    pub fn published_states(&self) -> &[crate::model::DriveState] {
        self.line.last().states
    }

    /// Alarms and train-speed tests over the step the line just published.
    fn publish(&mut self) {
        let lagged = self.line.last();
        let model = self.bank.model();
        let Some(v) = lagged.train_speed_m_s else {
            if self.train_steps {
                for t in &mut self.train {
                    t.reset();
                }
                self.references.fill(SpeedReference::Group);
                self.train_steps = false;
            }
            for (i, (alarm, events)) in self.alarms.iter_mut().zip(&mut self.events).enumerate() {
                events.clear();
                alarm.update(self.line.probability(i), events);
            }
            return;
        };
        self.train_steps = true;
        for (i, (((alarm, events), combined), (train, reference))) in self
            .alarms
            .iter_mut()
            .zip(&mut self.events)
            .zip(&mut self.combined)
            .zip(self.train.iter_mut().zip(&mut self.references))
            .enumerate()
        {
            // The method's probability, replaced by the test's for the drives it judges.
            combined.copy_from_slice(self.line.probability(i));
            *reference = if train.update_states(model, lagged.states, v, combined.iter_mut()) {
                SpeedReference::TrainSpeed
            } else {
                SpeedReference::Group
            };
            events.clear();
            alarm.update(combined, events);
        }
    }

    /// `(method, what its last step's probabilities were judged against)` of every method.
    pub fn references(&self) -> impl Iterator<Item = (AdhesionMethod, SpeedReference)> + '_ {
        self.methods
            .iter()
            .copied()
            .zip(self.references.iter().copied())
    }

    /// `(method, its train-speed test)` (the low-passed slip velocities) of every method.
    pub fn train_speed_checks(&self) -> impl Iterator<Item = (AdhesionMethod, &TrainSpeedCheck)> {
        self.methods.iter().copied().zip(&self.train)
    }

    /// `(method, slip probability per drive)` of every method for the step last published: the
    /// method's own without a train speed, the train-speed test's for the drives it judges
    /// with one.
    pub fn slip_probability(&self) -> impl Iterator<Item = (AdhesionMethod, &[f64])> {
        let train = self.train_steps;
        self.methods.iter().enumerate().map(move |(i, &m)| {
            let p = if train {
                self.combined[i].as_slice()
            } else {
                self.line.probability(i)
            };
            (m, p)
        })
    }

    /// `(method, the method's own probabilities)` for the step last published.
    pub fn method_probability(&self) -> impl Iterator<Item = (AdhesionMethod, &[f64])> {
        self.methods
            .iter()
            .enumerate()
            .map(|(i, &m)| (m, self.line.probability(i)))
    }

    /// `(method, global torque M_z^(G))` for the step last published.
    pub fn global_torque_nm(&self) -> impl Iterator<Item = (AdhesionMethod, f64)> + '_ {
        self.methods
            .iter()
            .enumerate()
            .map(|(i, &m)| (m, self.line.global_torque_nm(i)))
    }

    /// The EKF bank (of the newest frame, not of the step published).
    pub fn bank(&self) -> &EkfBank {
        &self.bank
    }

    /// The EKF torque estimates of the newest frame.
    pub fn torque_nm(&self) -> &[f64] {
        &self.torque
    }

    /// `(method, slipping flag per drive)` of every method's alarm after the step published.
    pub fn slipping(&self) -> impl Iterator<Item = (AdhesionMethod, &[bool])> {
        self.methods
            .iter()
            .copied()
            .zip(self.alarms.iter().map(SlipAlarm::slipping))
    }

    /// `(method, alarm events of the step published)` of every method.
    pub fn events(&self) -> impl Iterator<Item = (AdhesionMethod, &[SlipAlarmEvent])> {
        self.methods
            .iter()
            .copied()
            .zip(self.events.iter().map(Vec::as_slice))
    }
}
