//! The ingest side of the bogie stream: checked frames -> the bogie's `DamperMonitor` step ->
//! health flags and events -> history, snapshot and gauges once per batch.
//!
//! All bogies of a vehicle come from one publisher (frames interleaved, each with its bogie
//! id): a new publisher or run restarts every bogie's monitor.

use std::ops::RangeInclusive;
use std::sync::Arc;

use prometheus::{IntCounter, IntGauge};
use railmon_bus::{BogieFrame, FrameHeader};
use railmon_damper::gain_table::GainTable;
use railmon_damper::params::checked_half_body_mass_kg;
use railmon_damper::{
    BogieSample, BogieStatusWatch, DamperAlarm, DamperError, DamperEventKind, DamperId,
    DamperMonitor, DamperMonitorConfig, DamperMonitorState, DamperPosterior, PauseReason,
    Propagation, Rbpf, SampleRanges, MIN_DEGRADED_PARTICLES,
};
use railmon_records::gain_cache::GainCache;

use railmon_bus::StreamKind;

use super::compute::{ComputeChange, ComputeController, ComputeWindow};
use super::view::{
    BogieHistoryEntry, BogieHistoryPoint, BogieShared, BogieView, BogiesView, ComputeEventDetail,
    ComputeView, DamperEventDetail, DamperView, DAMPERS,
};
use super::warm::NodeWarmer;
use super::workers::{BogieWorkers, Done, Job, StepOutcome};
use super::BogieConfig;
use crate::ingest::{CompletedStep, Pipeline, RealTimeTracker, Rejection};
use crate::metrics::{EstimateGauge, EstimateIntGauge, Metrics};
use crate::outbox::{Stamp, Track};
use crate::snapshot::StateFormat;
use crate::store::ActiveAlarm;

/// Gauges of one damper of one bogie, looked up once.
struct DamperGauges {
    /// mean, q05, q95.
    damping: [EstimateGauge; 3],
    health: EstimateGauge,
    degraded: EstimateIntGauge,
    /// The degradation trend: rate, q05, q95 (per operating hour), and the operating hours to
    /// the threshold (NaN when none).
    trend: [EstimateGauge; 3],
    hours_to_threshold: EstimateGauge,
    /// degraded, recovered.
    events: [IntCounter; 2],
}

/// One configured bogie: its monitor (from the first frame of a source), health flags, gauges.
struct BogieSlot {
    id: u32,
    /// Boxed: it travels to a worker thread and back at each step.
    monitor: Option<Box<DamperMonitor>>,
    /// The health flags of `csy` and `csay` (the damper crate's rule).
    alarms: [DamperAlarm; 2],
    /// The status last reported (paused, model mismatch), for its change events.
    status: BogieStatusWatch,
    last_stamp: Option<Stamp>,
    dampers: [DamperGauges; 2],
    ess: EstimateGauge,
    /// `paused` gauges, one per reason (`PauseReason::ALL` order), and the speed.
    paused: [EstimateIntGauge; 3],
    speed: EstimateGauge,
    /// Particles its filter runs now.
    particles: IntGauge,
    /// The body masses its filter runs at (kg), for the gain-node thread: the measured one,
    /// or the span of the particles' own; updated every [`MASS_FOLLOW_STEPS`].
    masses_kg: Option<RangeInclusive<f64>>,
}

/// How often (steps of a bogie) the masses its filter runs at are passed to the gain-node
/// thread (`super::warm`): a second at 1 kHz; the particles' span is a pass over them.
const MASS_FOLLOW_STEPS: u64 = 1000;

impl BogieSlot {
    fn new(id: u32, metrics: &Metrics, alarms: [DamperAlarm; 2]) -> Self {
        let bogie = id.to_string();
        let dampers = DAMPERS.map(|damper| {
            let labels = [bogie.as_str(), damper];
            DamperGauges {
                damping: ["mean", "q05", "q95"].map(|q| {
                    metrics
                        .bogie
                        .damping
                        .with_label_values(&[bogie.as_str(), damper, q])
                }),
                health: metrics.bogie.health.with_label_values(&labels),
                degraded: metrics.bogie.degraded.with_label_values(&labels),
                trend: ["rate", "q05", "q95"].map(|q| {
                    metrics
                        .bogie
                        .trend
                        .with_label_values(&[bogie.as_str(), damper, q])
                }),
                hours_to_threshold: metrics.bogie.hours_to_threshold.with_label_values(&labels),
                events: ["degraded", "recovered"].map(|kind| {
                    metrics
                        .bogie
                        .events
                        .with_label_values(&[bogie.as_str(), damper, kind])
                }),
            }
        });
        Self {
            id,
            monitor: None,
            alarms,
            status: BogieStatusWatch::new(),
            last_stamp: None,
            dampers,
            ess: metrics
                .bogie
                .effective_sample_size
                .with_label_values(&[bogie.as_str()]),
            paused: PauseReason::ALL.map(|r| {
                metrics
                    .bogie
                    .paused
                    .with_label_values(&[bogie.as_str(), r.as_str()])
            }),
            speed: metrics.bogie.speed.with_label_values(&[bogie.as_str()]),
            particles: metrics.bogie.particles.with_label_values(&[bogie.as_str()]),
            masses_kg: None,
        }
    }
}

/// Why the estimator refused a sample, as a metric label: the estimator crate's own
/// ([`DamperError::reason`]); `estimator` for a failure that is not the sample's.
fn rejection_of(e: DamperError) -> Rejection {
    Rejection {
        reason: e.reason().unwrap_or("estimator"),
        message: e.to_string(),
    }
}

/// The gain table of `estimator` with its configured speed's node ready: from `cache` if it
/// is stored there, else solved (and stored). The other nodes are left to `super::warm`.
fn gain_table(
    estimator: &DamperMonitorConfig,
    cache: Option<&GainCache>,
) -> Result<Arc<GainTable>, DamperError> {
    let (model, rbpf, speed) = (estimator.filter_model(), &estimator.rbpf, &estimator.speed);
    let Some(cache) = cache else {
        return Rbpf::gain_table(&model, rbpf, speed);
    };
    let table = Rbpf::unsolved_gain_table(&model, rbpf, speed)?;
    let node = table.configured_node();
    if let Err(e) = cache.load(&table, node) {
        tracing::warn!("bogie gain table: {e}");
    }
    table.grid_at(node)?;
    if let Err(e) = cache.store(&table, node) {
        tracing::warn!("bogie gain table: node {node} not stored: {e}");
    }
    Ok(table)
}

pub struct BogiePipeline {
    config: BogieConfig,
    shared: Arc<BogieShared>,
    slots: Vec<BogieSlot>,
    /// The steady-state gain table (`None` for exact propagation), shared by every bogie and
    /// source: it depends only on the vehicle type. Built before the first frame: building
    /// it takes ~0.5 s, which on the first frame would stall the lossless publisher past its
    /// backpressure limit and lose frames.
    table: Result<Option<Arc<GainTable>>, Rejection>,
    track: Track<BogieHistoryPoint>,
    /// Frames checked and accepted whose step waits for the rest of their sample time, in
    /// arrival order: stepped together when every bogie has one, a bogie comes twice, or the
    /// batch ends ([`BogiePipeline::flush`]).
    pending: Vec<(FrameHeader, CheckedBogieSample)>,
    workers: BogieWorkers,
    /// Solves the gain table's speed nodes, nearest the vehicle's speed first, before a filter needs
    /// them (`super::warm`; none for exact propagation).
    warmer: Option<NodeWarmer>,
    done: Vec<Done>,
    /// Deferred steps that failed, for the ingest loop to count ([`Pipeline::take_rejections`]).
    rejections: Vec<(FrameHeader, Rejection)>,
    /// Deferred steps done, for the ingest loop's step times ([`Pipeline::take_completed`]).
    completed: Vec<CompletedStep>,
    snapshot_refused: IntCounter,
    /// Degraded compute (`super::compute`): the particles every filter runs, decided once per
    /// second of samples from the load and lag measured here as the stream's status measures
    /// them (`RealTimeTracker`), the compute time of `step`, `bridge` and `publish` counted.
    compute: ComputeController,
    realtime: RealTimeTracker,
    busy_ns: u64,
    /// Time spent building filters (a new source's or a restarted bogie's) since the last
    /// step's timing: a one-off, kept out of the load (`count_busy`).
    build_ns: u64,
    degradations: IntCounter,
    degradation_count: u64,
    compute_changed_time_s: Option<f64>,
}

impl BogiePipeline {
    /// `restored`: the alarms active when the service stopped (a damper flagged degraded stays
    /// flagged until an estimate clears it, with an event).
    pub fn new(
        config: BogieConfig,
        shared: Arc<BogieShared>,
        metrics: Arc<Metrics>,
        restored: &[ActiveAlarm],
    ) -> Self {
        Self::with_gain_cache(config, shared, metrics, restored, None)
    }

    /// [`BogiePipeline::new`] keeping the gain table's solved speed nodes in `cache`: those
    /// stored there are loaded instead of solved (`super::warm`), those solved are stored.
    pub fn with_gain_cache(
        config: BogieConfig,
        shared: Arc<BogieShared>,
        metrics: Arc<Metrics>,
        restored: &[ActiveAlarm],
        cache: Option<GainCache>,
    ) -> Self {
        let slots = config
            .bogies
            .iter()
            .map(|&id| {
                let degraded = DAMPERS.map(|damper| {
                    let subject = format!("{id}/{damper}");
                    restored.iter().any(|a| {
                        a.stream == "bogie" && a.alarm == "degraded" && a.subject == subject
                    })
                });
                let estimator = &config.estimator;
                let alarms =
                    DamperAlarm::pair(&estimator.alarm, &estimator.filter_model(), degraded);
                BogieSlot::new(id, &metrics, alarms)
            })
            .collect();
        let track = Track::new(
            StreamKind::Bogie,
            config.estimator.dt_s,
            config.history_interval_ms,
        );
        let estimator = &config.estimator;
        let table = match estimator.rbpf.propagation {
            Propagation::SteadyState => gain_table(estimator, cache.as_ref())
                .map(Some)
                .map_err(rejection_of),
            Propagation::Exact => Ok(None),
        };
        if let Err(e) = &table {
            tracing::error!(
                "bogie estimator unusable, every frame will be rejected: {}",
                e.message
            );
        }
        let workers = BogieWorkers::new(config.worker_threads());
        let warmer = match &table {
            Ok(Some(t)) => Some(NodeWarmer::new(
                t.clone(),
                estimator.vehicle.speed_m_s,
                cache,
            )),
            _ => None,
        };
        let compute = ComputeController::new(
            estimator.rbpf.particles,
            MIN_DEGRADED_PARTICLES,
            config.realtime.lag_budget_ms as f64 * 1e-3,
        );
        let pipeline = Self {
            config,
            shared,
            slots,
            table,
            track,
            pending: Vec::new(),
            workers,
            warmer,
            done: Vec::new(),
            rejections: Vec::new(),
            completed: Vec::new(),
            snapshot_refused: metrics.bogie.snapshot_refused.clone(),
            compute,
            realtime: RealTimeTracker::default(),
            busy_ns: 0,
            build_ns: 0,
            degradations: metrics.bogie.compute_degradations.clone(),
            degradation_count: 0,
            compute_changed_time_s: None,
        };
        // The configured bogies are listed (without samples) before the first frame.
        pipeline
            .shared
            .snapshot
            .store(Arc::new(pipeline.view(None)));
        pipeline
    }

    fn slot_of(&self, frame: &BogieFrame) -> Result<usize, Rejection> {
        self.slots
            .iter()
            .position(|s| s.id == frame.bogie_id)
            .ok_or_else(|| Rejection {
                reason: "unknown_bogie",
                message: format!(
                    "bogie {} is not configured (bogie.bogies = {:?})",
                    frame.bogie_id, self.config.bogies
                ),
            })
    }

    /// The monitor of slot `k` for the current source (created on its first frame).
    fn monitor(&mut self, k: usize) -> Result<&mut DamperMonitor, Rejection> {
        let estimator = &self.config.estimator;
        let slot = &mut self.slots[k];
        if slot.monitor.is_none() {
            let start = std::time::Instant::now();
            let table = self.table.clone()?;
            let mut monitor =
                DamperMonitor::for_bogie(estimator, slot.id, table).map_err(rejection_of)?;
            // A new source while degraded: its filters start at the degraded count.
            monitor
                .set_particles(self.compute.particles())
                .map_err(rejection_of)?;
            slot.monitor = Some(Box::new(monitor));
            self.build_ns += start.elapsed().as_nanos() as u64;
        }
        Ok(slot.monitor.as_mut().expect("created above"))
    }

    /// The filters' stalls on unsolved gain nodes so far (ns, summed over the workers).
    fn filter_stall_ns(&self) -> u64 {
        match &self.table {
            Ok(Some(table)) => table.filter_stall_ns(),
            _ => 0,
        }
    }

    /// Adds the compute time since `start` to the window's, but for the one-offs in it: the
    /// filters built and their stalls on gain nodes since `stalled_before` (their sum over
    /// the workers, at most the time elapsed: the workers stall side by side). Neither scales
    /// with the particles, so a cut would not remove them: counted, the first second after a
    /// start (every bogie waiting for its speed's node) read a load of 11 and cut every filter
    /// to the floor (`scripts/bogie-realtime`, 16 bogies, 28 Nov). The lag still sees them.
    fn count_busy(&mut self, start: std::time::Instant, stalled_before: u64) {
        let one_off = std::mem::take(&mut self.build_ns)
            + self.filter_stall_ns().saturating_sub(stalled_before);
        self.busy_ns += (start.elapsed().as_nanos() as u64).saturating_sub(one_off);
    }

    /// Steps the pending frames, the bogies in parallel (each bogie's frames in order), then
    /// follows each in arrival order as a serial run would: the same estimates and events.
    fn flush(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let pending = std::mem::take(&mut self.pending);
        let jobs: Vec<Job> = pending
            .iter()
            .map(|(_, p)| Job {
                slot: p.slot,
                monitor: self.slots[p.slot]
                    .monitor
                    .take()
                    .expect("created when the frame was accepted"),
                sample: p.sample,
            })
            .collect();
        let mut done = std::mem::take(&mut self.done);
        self.workers.step_all(jobs, &mut done);
        let mut results: Vec<Option<StepOutcome>> = (0..self.slots.len()).map(|_| None).collect();
        for d in done.drain(..) {
            self.slots[d.slot].monitor = Some(d.monitor);
            results[d.slot] = Some(d.outcome);
        }
        self.done = done;
        let last_header = pending.last().map(|(h, _)| *h);
        let mut last_stamp = None;
        for (header, p) in pending {
            match results[p.slot].take() {
                Some(StepOutcome {
                    result: Ok(()),
                    step_ns,
                    done_at_ns,
                }) => {
                    self.completed.push(CompletedStep {
                        published_at_ns: header.published_at_ns,
                        step_ns,
                        done_at_ns,
                    });
                    let stamp = self.track.stamp(&header);
                    last_stamp = Some(stamp);
                    self.slots[p.slot].last_stamp = Some(stamp);
                    self.follow(p.slot, &stamp);
                }
                Some(StepOutcome { result: Err(e), .. }) => {
                    self.rejections.push((header, rejection_of(e)))
                }
                // A worker that stopped took the monitor: the bogie restarts from its prior.
                None => self.rejections.push((
                    header,
                    Rejection::new("estimator", "the bogie's worker thread stopped"),
                )),
            }
        }
        if let Some(header) = last_header {
            self.judge_compute(&header, last_stamp);
        }
    }

    /// The load and lag after the batch ending with `header` (the stamp of its last estimate,
    /// if one succeeded); once a second of samples, the compute controller's decision, applied
    /// to every filter, with its event.
    fn judge_compute(&mut self, header: &FrameHeader, stamp: Option<Stamp>) {
        let busy_ns = std::mem::take(&mut self.busy_ns);
        let (lag_ns, load) =
            self.realtime
                .observe(header.sample_time_ns, railmon_bus::monotonic_ns(), busy_ns);
        let Some(load) = load else { return };
        let window = ComputeWindow {
            load,
            lag_s: lag_ns as f64 * 1e-9,
        };
        tracing::debug!(load, lag_s = window.lag_s, "bogie compute window");
        let Some(change) = self.compute.observe(window) else {
            return;
        };
        let particles = self.compute.particles();
        for slot in &mut self.slots {
            if let Some(m) = &mut slot.monitor {
                if let Err(e) = m.set_particles(particles) {
                    tracing::error!(bogie = slot.id, "set_particles({particles}): {e}");
                }
            }
        }
        let restored = matches!(change, ComputeChange::Raise { .. }) && !self.compute.degraded();
        if let ComputeChange::Cut { .. } = change {
            self.degradations.inc();
            self.degradation_count += 1;
        }
        let kind = if restored {
            "compute_restored"
        } else {
            "compute_degraded"
        };
        let configured = self.compute.configured();
        tracing::warn!(
            particles,
            configured,
            realtime_load = window.load,
            lag_s = window.lag_s,
            "{kind}"
        );
        let stamp = stamp.unwrap_or_else(|| self.track.stamp(header));
        self.compute_changed_time_s = Some(stamp.time_s);
        let detail = ComputeEventDetail {
            particles,
            configured_particles: configured,
            realtime_load: window.load,
            lag_s: window.lag_s,
        };
        self.track
            .push_event(&stamp, kind, "compute".into(), &detail, None);
    }

    /// [`Pipeline::step`], timed there.
    fn step_timed(
        &mut self,
        header: &FrameHeader,
        input: CheckedBogieSample,
    ) -> Result<(), Rejection> {
        let k = input.slot;
        if self.pending.iter().any(|(_, p)| p.slot == k) {
            self.flush();
        }
        self.monitor(k)?;
        if let Some(w) = &self.warmer {
            w.follow(input.sample.speed_m_s);
        }
        self.follow_masses(k, input.sample.half_body_mass_kg);
        self.pending.push((*header, input));
        if self.pending.len() == self.slots.len() {
            self.flush();
        }
        Ok(())
    }

    /// Every [`MASS_FOLLOW_STEPS`] of bogie `k` (and at its first), the masses its filter
    /// runs at for a frame with `half_body_mass_kg`, and the span over every bogie to the
    /// gain-node thread: a filter without a load signal needs the gains of each mass its
    /// particles carry (`Rbpf::particle_mass_span_kg`), up to 11 mass nodes per speed.
    fn follow_masses(&mut self, k: usize, half_body_mass_kg: Option<f64>) {
        let Some(warmer) = &self.warmer else { return };
        let slot = &mut self.slots[k];
        let Some(monitor) = &slot.monitor else { return };
        if slot.masses_kg.is_some() && monitor.steps() % MASS_FOLLOW_STEPS != 0 {
            return;
        }
        let estimator = &self.config.estimator;
        let design_kg = estimator.vehicle.half_body_mass_kg;
        slot.masses_kg = Some(match half_body_mass_kg {
            Some(m) => m..=m,
            // Before the particles have drawn theirs: the prior's.
            None => monitor
                .rbpf()
                .particle_mass_span_kg()
                .or_else(|| estimator.rbpf.unmeasured_mass.prior_masses_kg(design_kg))
                .unwrap_or(design_kg..=design_kg),
        });
        let (lo, hi) = self
            .slots
            .iter()
            .filter_map(|s| s.masses_kg.as_ref())
            .fold((f64::INFINITY, 0.0_f64), |(lo, hi), m| {
                (lo.min(*m.start()), hi.max(*m.end()))
            });
        warmer.follow_masses(lo..=hi);
    }

    fn compute_view(&self) -> ComputeView {
        ComputeView {
            mode: if self.compute.degraded() {
                "degraded"
            } else {
                "full"
            }
            .into(),
            particles: self.compute.particles(),
            degradations: self.degradation_count,
            changed_time_s: self.compute_changed_time_s,
        }
    }

    /// Health flags and events of slot `k` after its step (`railmon_damper::DamperAlarm`).
    fn follow(&mut self, k: usize, stamp: &Stamp) {
        let slot = &mut self.slots[k];
        let Some(monitor) = &slot.monitor else { return };
        let estimate = monitor.estimate();
        for (alarm, gauges) in slot.alarms.iter_mut().zip(&slot.dampers) {
            let Some(event) = alarm.update(estimate) else {
                continue;
            };
            let kind = event.kind.as_str();
            let damper = event.damper.name();
            let recovered = event.kind == DamperEventKind::DamperRecovered;
            gauges.events[usize::from(recovered)].inc();
            tracing::info!(
                bogie = slot.id,
                damper,
                health_ratio = event.health_ratio,
                time_s = stamp.time_s,
                "{kind}"
            );
            let detail = DamperEventDetail {
                bogie: slot.id,
                damper: damper.into(),
                health_ratio: event.health_ratio,
            };
            let subject = format!("{}/{damper}", slot.id);
            self.track.push_event(
                stamp,
                kind,
                subject,
                &detail,
                Some(("degraded", alarm.degraded())),
            );
        }
        // The status as events (after the health events, as `railmon analyze damper` writes
        // them): the same changes the view's `status` shows.
        for event in slot.status.update(estimate) {
            let kind = event.kind.as_str();
            tracing::info!(
                bogie = slot.id,
                reason = event.reason.map(PauseReason::as_str),
                speed_m_s = event.speed_m_s,
                time_s = stamp.time_s,
                "{kind}"
            );
            self.track.push_event(
                stamp,
                kind,
                slot.id.to_string(),
                &event.detail(slot.id),
                None,
            );
        }
        if self.track.history_due(stamp.time_s) {
            let bogies = self
                .slots
                .iter()
                .filter_map(|s| {
                    let e = s.monitor.as_ref()?.estimate();
                    Some(BogieHistoryEntry {
                        bogie: s.id,
                        csy_n_s_per_m: e.csy.mean_ns_per_m,
                        csay_n_s_per_m: e.csay.mean_ns_per_m,
                        csy_health_ratio: e.csy.health_ratio,
                        csay_health_ratio: e.csay.health_ratio,
                        effective_sample_size: e.effective_sample_size,
                    })
                })
                .collect();
            self.track.push_history(BogieHistoryPoint {
                time_s: stamp.time_s,
                run: stamp.header.run,
                run_time_s: stamp.run_time_s,
                bogies,
            });
        }
    }

    /// The view after the frame `stamp` (None: before the first, every bogie without samples).
    fn view(&self, stamp: Option<&Stamp>) -> BogiesView {
        let nominal = self.config.estimator.nominal;
        let nominals = [nominal.csy_ns_per_m, nominal.csay_ns_per_m];
        let bogies = self
            .slots
            .iter()
            .map(|s| {
                let estimate = s.monitor.as_ref().map(|m| m.estimate());
                let damper = |d: usize| {
                    let posterior: Option<DamperPosterior> = estimate.map(|e| [e.csy, e.csay][d]);
                    let ekf = estimate
                        .and_then(|e| e.ekf)
                        .map(|e| [e.dampers.csy_ns_per_m, e.dampers.csay_ns_per_m][d]);
                    let p = posterior.unwrap_or(DamperPosterior {
                        mean_ns_per_m: f64::NAN,
                        q05_ns_per_m: f64::NAN,
                        q95_ns_per_m: f64::NAN,
                        health_ratio: f64::NAN,
                    });
                    DamperView {
                        nominal_n_s_per_m: nominals[d],
                        mean_n_s_per_m: p.mean_ns_per_m,
                        q05_n_s_per_m: p.q05_ns_per_m,
                        q95_n_s_per_m: p.q95_ns_per_m,
                        health_ratio: p.health_ratio,
                        degraded: s.alarms[d].degraded(),
                        ekf_n_s_per_m: ekf,
                        trend: s
                            .monitor
                            .as_ref()
                            .and_then(|m| m.trend(DamperId::ALL[d]))
                            .map(Into::into),
                    }
                };
                let body_mass = estimate.and(s.monitor.as_ref()).map(|m| m.body_mass());
                BogieView {
                    bogie: s.id,
                    samples: s.monitor.as_ref().map_or(0, |m| m.steps()),
                    time_s: s.last_stamp.map(|t| t.time_s),
                    run_time_s: s.last_stamp.map(|t| t.run_time_s),
                    csy: damper(0),
                    csay: damper(1),
                    effective_sample_size: estimate.map_or(f64::NAN, |e| e.effective_sample_size),
                    nis_window_mean: estimate.and_then(|e| e.nis_window_mean).unwrap_or(f64::NAN),
                    status: match estimate {
                        None => "no_samples",
                        Some(e) if e.paused.is_some() => "paused",
                        Some(e) if e.model_mismatch => "model_mismatch",
                        Some(e) if e.held_through_burst => "held",
                        Some(_) => "ok",
                    }
                    .into(),
                    paused: estimate.and_then(|e| e.paused).map(|r| r.as_str().into()),
                    speed_m_s: estimate.map(|e| e.speed_m_s),
                    mass_source: body_mass.map(|m| m.source.as_str().into()),
                    half_body_mass_kg: body_mass.map(|m| m.half_body_mass_kg),
                    noise_std_ratio: estimate.map(|e| e.noise_std_ratio.into()),
                    particles: s.monitor.as_ref().map(|m| m.particles()),
                }
            })
            .collect();
        BogiesView {
            time_s: stamp.map(|s| s.time_s),
            time_utc: stamp.map(Stamp::time_utc),
            run: stamp.map_or(0, |s| s.header.run),
            run_time_s: stamp.map(|s| s.run_time_s),
            sequence: stamp.map(|s| s.header.sequence),
            particles: self.config.estimator.rbpf.particles,
            compute: self.compute_view(),
            bogies,
        }
    }

    /// Gauges from the view, so `/metrics` and the API agree.
    fn set_gauges(&self, view: &BogiesView) {
        for (slot, b) in self.slots.iter().zip(&view.bogies) {
            for (g, d) in slot.dampers.iter().zip([&b.csy, &b.csay]) {
                let values = [d.mean_n_s_per_m, d.q05_n_s_per_m, d.q95_n_s_per_m];
                for (gauge, v) in g.damping.iter().zip(values) {
                    gauge.set(v);
                }
                g.health.set(d.health_ratio);
                g.degraded.set(i64::from(d.degraded));
                let t = d.trend.as_ref();
                let trend = [
                    t.map(|t| t.rate_per_operating_h),
                    t.map(|t| t.rate_q05_per_operating_h),
                    t.map(|t| t.rate_q95_per_operating_h),
                ];
                for (gauge, v) in g.trend.iter().zip(trend) {
                    gauge.set(v.unwrap_or(f64::NAN));
                }
                g.hours_to_threshold.set(
                    t.and_then(|t| t.operating_h_to_threshold)
                        .unwrap_or(f64::NAN),
                );
            }
            slot.ess.set(b.effective_sample_size);
            for (gauge, reason) in slot.paused.iter().zip(PauseReason::ALL) {
                gauge.set(i64::from(b.paused.as_deref() == Some(reason.as_str())));
            }
            slot.speed.set(b.speed_m_s.unwrap_or(f64::NAN));
            slot.particles
                .set(b.particles.unwrap_or(self.compute.particles()) as i64);
        }
    }
}

/// A checked bogie frame: the configured bogie's slot and its validated sample.
pub struct CheckedBogieSample {
    slot: usize,
    sample: BogieSample,
}

/// What a bogie snapshot holds: each configured bogie's monitor (RBPF particles, weights and
/// Kalman states, the EKF, the consistency check) and stream time. The health flags are not
/// saved: the event store's active alarms, committed with their events, are newer and are
/// restored at start.
#[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct SavedBogies {
    bogies: Vec<(u32, Option<DamperMonitorState>)>,
    clock: crate::outbox::TrackClock,
}

/// The layout of [`SavedBogies`] around the monitors' states, and theirs (their crate's
/// `DamperMonitorState::STATE_FORMAT_VERSION`). Raise `version` with every change of what
/// `SavedBogies` holds beside them: a snapshot of another layout is refused by its version
/// instead of failing to decode, or decoding into other numbers.
const SAVED_BOGIES: StateFormat = StateFormat {
    magic: b"railmon-bogies\0",
    // 3: the RBPF's jump-search sentinels (`RbpfState`).
    // 4: the monitor state's layout has its own version (`estimator_version`), its crate's.
    version: 4,
    estimator_version: DamperMonitorState::STATE_FORMAT_VERSION,
    what: "bogie state",
};

impl Pipeline for BogiePipeline {
    type Frame = BogieFrame;
    type Checked = CheckedBogieSample;
    const REJECTION_REASONS: &'static [&'static str] = &[
        "not_finite",
        "unknown_bogie",
        "out_of_range",
        "speed_out_of_range",
        "mass_out_of_range",
        "unknown_channels",
    ];
    /// The bogies of one step share its time.
    const REPEATED_TIMES: bool = true;
    const DEFERS_STEPS: bool = true;

    fn sample_period_ns(&self) -> u64 {
        (self.config.estimator.dt_s * 1e9).round() as u64
    }

    fn check(
        &self,
        _header: &FrameHeader,
        frame: &BogieFrame,
    ) -> Result<CheckedBogieSample, Rejection> {
        let sample = frame
            .checked_sample()
            .map_err(|e| Rejection::new(e.reason(), e.to_string()))?;
        let slot = self.slot_of(frame)?;
        // The magnitudes, by the estimator crate's check (`railmon analyze damper` refuses
        // by the same one).
        let ranges = SampleRanges {
            max_abs_accel_m_s2: self.config.max_abs_accel_m_s2,
            max_abs_yaw_rate_rad_s: self.config.max_abs_yaw_rate_rad_s,
        };
        // A measured mass within its ratio of the design mass, here rather than at the
        // deferred step, so the refusal is counted with the frame's own checks.
        let design_kg = self.config.estimator.vehicle.half_body_mass_kg;
        ranges
            .check(&sample)
            .and_then(|_| {
                checked_half_body_mass_kg(design_kg, sample.half_body_mass_kg).map(|_| ())
            })
            .map_err(|e| {
                let reason = e.reason().unwrap_or("estimator");
                Rejection::new(reason, format!("bogie {}: {e}", frame.bogie_id))
            })?;
        Ok(CheckedBogieSample { slot, sample })
    }

    fn restart(&mut self) {
        // The old source's accepted frames first.
        self.flush();
        // Health flags carry over (never a silent clear): the new filter's estimates clear
        // them, with an event, once they say so.
        // The new source's clock has another offset; the compute stays as it is (its filters
        // start at the current count, `monitor`).
        self.realtime.restart();
        for slot in &mut self.slots {
            slot.monitor = None;
            slot.last_stamp = None;
            for alarm in &mut slot.alarms {
                alarm.restart();
            }
        }
        self.track.restart();
    }

    /// Accepts the frame and defers its step until its sample time is complete (every
    /// configured bogie has a frame) or the batch ends; a deferred step that fails is counted
    /// through [`Pipeline::take_rejections`].
    fn step(&mut self, header: &FrameHeader, input: CheckedBogieSample) -> Result<(), Rejection> {
        let start = std::time::Instant::now();
        let stalled_before = self.filter_stall_ns();
        let stepped = self.step_timed(header, input);
        self.count_busy(start, stalled_before);
        stepped
    }

    /// Every bogie's monitor settles its states again before it learns (`DamperMonitor::bridge`).
    /// The frames waiting for the rest of their sample time belong before the gap: stepped
    /// first.
    fn bridge(&mut self, skipped_periods: u64) {
        let start = std::time::Instant::now();
        let stalled_before = self.filter_stall_ns();
        self.flush();
        for slot in &mut self.slots {
            if let Some(m) = &mut slot.monitor {
                m.bridge(skipped_periods);
            }
        }
        self.count_busy(start, stalled_before);
    }

    fn take_rejections(&mut self) -> Vec<(FrameHeader, Rejection)> {
        std::mem::take(&mut self.rejections)
    }

    fn take_completed(&mut self) -> Option<Vec<CompletedStep>> {
        Some(std::mem::take(&mut self.completed))
    }

    fn settings(&self) -> String {
        serde_json::to_string(&self.config.estimator).unwrap_or_default()
    }

    fn save_state(&self) -> Option<Vec<u8>> {
        if self.slots.iter().all(|s| s.monitor.is_none()) {
            return None;
        }
        let saved = SavedBogies {
            bogies: self
                .slots
                .iter()
                .map(|s| (s.id, s.monitor.as_ref().map(|m| m.state())))
                .collect(),
            clock: self.track.clock(),
        };
        SAVED_BOGIES.encode(&saved)
    }

    /// Every bogie's monitor where the snapshot left it (built first: on error nothing
    /// changes); a bogie the snapshot does not hold starts from its prior on its first frame.
    fn resume_state(&mut self, state: &[u8]) -> Result<(), String> {
        let saved: SavedBogies = SAVED_BOGIES.decode(state)?;
        let table = self.table.clone().map_err(|r| r.message)?;
        let mut monitors = Vec::with_capacity(self.slots.len());
        for slot in &self.slots {
            let state = saved
                .bogies
                .iter()
                .find(|(id, _)| *id == slot.id)
                .and_then(|(_, m)| m.clone());
            monitors.push(match state {
                Some(state) => {
                    let mut m = DamperMonitor::resume(&self.config.estimator, table.clone(), state)
                        .map_err(|e| format!("bogie {}: {e}", slot.id))?;
                    // A state saved while degraded resumes at its own count; the filters run
                    // the controller's (the configured count at start) from here.
                    m.set_particles(self.compute.particles())
                        .map_err(|e| format!("bogie {}: {e}", slot.id))?;
                    Some(Box::new(m))
                }
                None => None,
            });
        }
        for (slot, monitor) in self.slots.iter_mut().zip(monitors) {
            slot.monitor = monitor;
        }
        self.track.resume_clock(saved.clock);
        Ok(())
    }

    /// A snapshot that does not fit: the bogies start from their prior, and the store gets a
    /// `snapshot_refused` event saying which file and why (the log has a warning too).
    fn snapshot_refused(&mut self, file: &std::path::Path, reason: &str) {
        self.snapshot_refused.inc();
        let event = crate::snapshot::refused_event(StreamKind::Bogie, file, reason);
        self.shared.store.append(vec![event]);
    }

    fn publish(&mut self) {
        let start = std::time::Instant::now();
        self.flush();
        if let Some(stamp) = self.track.flush(&self.shared) {
            let view = self.view(Some(&stamp));
            self.set_gauges(&view);
            self.shared.snapshot.store(Arc::new(view));
        }
        self.busy_ns += start.elapsed().as_nanos() as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_damper::DamperMonitorConfig;

    /// What the snapshot holds around the monitors' states is pinned under `SAVED_BOGIES`'s
    /// version (the states themselves under their crate's, `damper/tests/state_layout.rs`).
    #[test]
    fn state_layout_golden_is_pinned_under_the_format_version() {
        let mut c = DamperMonitorConfig::default();
        c.rbpf.particles = 4;
        let m = DamperMonitor::for_bogie(&c, 2, None).unwrap();
        let saved = SavedBogies {
            bogies: vec![(1, None), (2, Some(m.state()))],
            ..saved()
        };
        railmon_golden::check_state_layout(
            "state-layout-service-bogie.txt",
            SAVED_BOGIES.version,
            &[saved],
            &["state-layout-damper.txt"],
        );
    }

    fn saved() -> SavedBogies {
        let mut c = DamperMonitorConfig::default();
        c.rbpf.particles = 4;
        c.rbpf.propagation = Propagation::Exact;
        let m = DamperMonitor::for_bogie(&c, 2, None).unwrap();
        SavedBogies {
            bogies: vec![(1, None), (2, Some(m.state()))],
            clock: crate::outbox::TrackClock {
                run_offset_s: 3.0,
                last_time_s: Some(2.5),
                next_history_s: 2.6,
            },
        }
    }

    /// A bogie state comes back through its format (the versions are refused as in
    /// `snapshot::tests`), and a state written before versions is refused.
    #[test]
    fn a_bogie_state_comes_back_and_an_unversioned_one_is_refused() {
        let bytes = SAVED_BOGIES.encode(&saved()).unwrap();
        // Compared as bytes: the states hold NaN (no window yet), and NaN != NaN.
        let back: SavedBogies = SAVED_BOGIES.decode(&bytes).unwrap();
        assert_eq!(SAVED_BOGIES.encode(&back).unwrap(), bytes);
        let unversioned = bincode::serialize(&saved()).unwrap();
        let e = SAVED_BOGIES
            .decode::<SavedBogies>(&unversioned)
            .unwrap_err();
        assert!(e.contains("bogie state without a format version"), "{e}");
    }
}
