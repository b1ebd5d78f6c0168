//! What the bogie stream shows: the JSON of `/api/v1/bogies...` and its history and events.
//! Damping in N s/m throughout (base units, so the JSON and the metrics carry the same numbers).

use serde::Serialize;
use utoipa::ToSchema;

use crate::outbox::Outbox;

/// The two monitored dampers, as API fields and metric labels.
pub const DAMPERS: [&str; 2] = ["csy", "csay"];

/// One damper of one bogie.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct DamperView {
    /// Healthy (design) damping, N s/m.
    pub nominal_n_s_per_m: f64,
    /// RBPF posterior mean and its 5% / 95% quantiles, N s/m; this and the health ratio
    /// are null until the bogie's first frame.
    #[schema(value_type = Option<f64>)]
    pub mean_n_s_per_m: f64,
    #[schema(value_type = Option<f64>)]
    pub q05_n_s_per_m: f64,
    #[schema(value_type = Option<f64>)]
    pub q95_n_s_per_m: f64,
    /// Mean over nominal.
    #[schema(value_type = Option<f64>)]
    pub health_ratio: f64,
    /// Flagged degraded: set when the whole 90% interval (its 95% quantile) falls below
    /// `estimator.alarm.degraded_below_ratio` x nominal, cleared when it (its 5% quantile) rises
    /// above `estimator.alarm.recovered_above_ratio` x nominal (`railmon_damper::DamperAlarm`).
    pub degraded: bool,
    /// The EKF baseline's estimate, N s/m (null when disabled or after it diverged).
    pub ekf_n_s_per_m: Option<f64>,
    /// How fast the health ratio falls per operating hour (`railmon_damper::trend`); null
    /// before two operating minutes.
    pub trend: Option<DamperTrendView>,
}

/// A damper's degradation trend: the weighted least-squares slope of its health ratio against
/// operating time (the time its filter learns: moving in its speed range, its model explaining
/// the data) over the last operating hour, in 10 s bins weighted by the posterior's variance
/// (docs/damper.md, "Degradation trend"). What a maintainer plans with; the alarm, not the
/// trend, is for a sudden failure.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct DamperTrendView {
    /// The fitted health ratio (mean over nominal) at the newest bin.
    pub health_ratio: f64,
    /// Change of the health ratio per operating hour (negative: degrading), and its 90 %
    /// interval.
    pub rate_per_operating_h: f64,
    pub rate_q05_per_operating_h: f64,
    pub rate_q95_per_operating_h: f64,
    /// Operating time the fit spans, h (up to 1).
    pub window_operating_h: f64,
    /// Operating hours until the health ratio reaches `estimator.alarm.degraded_below_ratio`
    /// at the fitted rate (0 once below it), and the earliest and latest at the rate's 90 %
    /// interval; null unless the rate is significantly negative (its 95 % bound below 0).
    pub operating_h_to_threshold: Option<f64>,
    pub operating_h_to_threshold_earliest: Option<f64>,
    pub operating_h_to_threshold_latest: Option<f64>,
}

impl From<railmon_damper::TrendEstimate> for DamperTrendView {
    fn from(t: railmon_damper::TrendEstimate) -> Self {
        let eta = t.time_to_threshold;
        Self {
            health_ratio: t.health_ratio,
            rate_per_operating_h: t.rate_per_h,
            rate_q05_per_operating_h: t.rate_q05_per_h,
            rate_q95_per_operating_h: t.rate_q95_per_h,
            window_operating_h: t.window_h,
            operating_h_to_threshold: eta.map(|e| e.hours),
            operating_h_to_threshold_earliest: eta.map(|e| e.earliest_hours),
            operating_h_to_threshold_latest: eta.map(|e| e.latest_hours),
        }
    }
}

/// One bogie's latest estimate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct BogieView {
    pub bogie: u32,
    /// Samples its monitor accepted from the current source (0: prior only).
    pub samples: u64,
    /// Stream time and run time of its last sample, s.
    pub time_s: Option<f64>,
    pub run_time_s: Option<f64>,
    pub csy: DamperView,
    pub csay: DamperView,
    /// Effective sample size of its particle filter (particles); null until its first frame.
    #[schema(value_type = Option<f64>)]
    pub effective_sample_size: f64,
    /// Mean normalised innovation squared of the filter over its last 1 s window (5 when its
    /// model explains the data); null until its first window is complete.
    #[schema(value_type = Option<f64>)]
    pub nis_window_mean: f64,
    /// `ok`, `no_samples`, `paused` (the speed is outside the filter's valid range,
    /// `estimator.speed`: the posterior is held and the health flags are not judged; the
    /// reason in `paused`), `model_mismatch`: the filter's model does not explain the data
    /// for a sustained time (a wrong vehicle or sensor noise in the configuration; the health
    /// flags are not judged meanwhile), or `held`: its innovations burst beyond what any
    /// hypothesis explains (a damper failing at speed, a shock), and `csy` / `csay` are the
    /// estimates from before the burst while the filter learns through it, until its
    /// innovations are back in their band (typically 0.2-0.6 s).
    pub status: String,
    /// Why the filter is paused: `low_speed`, `high_speed` or `gap`; null when it is not.
    pub paused: Option<String>,
    /// Vehicle speed of the last sample, m/s; null before the first.
    pub speed_m_s: Option<f64>,
    /// Which body mass above the bogie the filter takes: `measured` (the last frame's
    /// `half_body_mass_kg`, its air springs' load), `estimated` (the frame had none and the
    /// particles carry the mass, `estimator.rbpf.unmeasured_mass`: their posterior mean) or
    /// `design` (none, and that setting off: `estimator.vehicle.half_body_mass_kg`; also right
    /// after a restore from a snapshot, until the next frame); null before the first sample.
    pub mass_source: Option<String>,
    /// That mass, kg; null when `mass_source` is.
    pub half_body_mass_kg: Option<f64>,
    /// The sensors' noise as the filter estimates it online; null before the monitor exists
    /// (its first frame).
    pub noise_std_ratio: Option<SensorNoiseView>,
    /// Particles its filter runs now (fewer than configured while the compute is degraded);
    /// null before the monitor exists.
    pub particles: Option<usize>,
}

/// Each sensor's noise standard deviation as a ratio of the configured one
/// (`estimator.sensors`), as the filter estimates it (`estimator.rbpf.noise_scale`,
/// `railmon_damper::NoiseScale`): 1 = as configured, all 1 with the estimate disabled, within
/// `[min_std_ratio, max_std_ratio]` (0.25-4 by default). A sensor far from 1 for long is worth
/// a look (a loose or failing sensor, or a configured noise that is not the sensor's).
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct SensorNoiseView {
    pub wheelset1_accel: f64,
    pub wheelset2_accel: f64,
    pub bogie_accel: f64,
    pub bogie_yaw_rate: f64,
    pub body_accel: f64,
}

impl From<[f64; 5]> for SensorNoiseView {
    /// From the filter's order (eq. (4): wheelset 1, wheelset 2, bogie, yaw gyro, body).
    fn from(r: [f64; 5]) -> Self {
        let [wheelset1_accel, wheelset2_accel, bogie_accel, bogie_yaw_rate, body_accel] = r;
        Self {
            wheelset1_accel,
            wheelset2_accel,
            bogie_accel,
            bogie_yaw_rate,
            body_accel,
        }
    }
}

/// `GET /api/v1/bogies`: every configured bogie.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct BogiesView {
    /// Stream time of the newest frame used, s; null before the first.
    pub time_s: Option<f64>,
    /// When that frame's sample was acquired, RFC 3339 UTC.
    pub time_utc: Option<String>,
    pub run: u32,
    pub run_time_s: Option<f64>,
    pub sequence: Option<u64>,
    /// Particles per bogie, as configured (`estimator.rbpf.particles`).
    pub particles: usize,
    /// Whether the filters run their configured particles or fewer to keep up with real time.
    pub compute: ComputeView,
    pub bogies: Vec<BogieView>,
}

/// The bogies' compute (`bogie.realtime`, docs/damper.md "Degraded compute"): `full`, or
/// `degraded` while the filters cannot keep up with real time at the configured particles and
/// run `particles` each instead (their 90 % intervals honestly wider).
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct ComputeView {
    /// `full` or `degraded`.
    pub mode: String,
    /// Particles each bogie's filter runs now.
    pub particles: usize,
    /// Cuts so far (`compute_degraded` events) since the service started.
    pub degradations: u64,
    /// Stream time of the last change, s; null before one.
    pub changed_time_s: Option<f64>,
}

/// The bogie stream's fields of a `compute_degraded` / `compute_restored` event (subject
/// `compute`): the particles every bogie's filter runs from then on, and what the window
/// that decided measured.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct ComputeEventDetail {
    pub particles: usize,
    pub configured_particles: usize,
    /// Compute time over sample time over that second of samples.
    pub realtime_load: f64,
    /// How far the estimates were behind the samples' clock, s.
    pub lag_s: f64,
}

/// One bogie in a history point.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct BogieHistoryEntry {
    pub bogie: u32,
    pub csy_n_s_per_m: f64,
    pub csay_n_s_per_m: f64,
    pub csy_health_ratio: f64,
    pub csay_health_ratio: f64,
    pub effective_sample_size: f64,
}

/// One point of the history ring: every bogie with samples at that time.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct BogieHistoryPoint {
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    pub bogies: Vec<BogieHistoryEntry>,
}

/// The bogie stream's fields of a `damper_degraded` / `damper_recovered` event (subject:
/// `<bogie>/<damper>`, e.g. `2/csay`).
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct DamperEventDetail {
    pub bogie: u32,
    /// `csy` or `csay`.
    pub damper: String,
    pub health_ratio: f64,
}

/// What the ingest thread shares with the HTTP side.
pub type BogieShared = Outbox<BogiesView, BogieHistoryPoint>;
