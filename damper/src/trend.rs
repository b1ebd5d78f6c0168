//! A damper's degradation trend (issue 24 item 3): how fast its health ratio (posterior mean
//! over nominal) falls per operating hour, with a 90 % interval, and when it will reach the
//! alarm's threshold at that rate: what a maintainer plans with. Pure maths, no I/O.
//!
//! **Definition.** Operating time is the time the filter learns (moving in its speed range, not
//! settling after a pause, its model explaining the data). It is cut into bins of
//! [`TREND_BIN_S`]; each bin keeps the mean of the posterior mean's health ratio `r_i` over it
//! and the mean posterior variance `v_i` of that ratio (from the 90 % interval,
//! `((q95 - q05) / (2 z_0.95))^2`). Over the last [`TREND_WINDOW_BINS`] bins (one operating
//! hour) the rate is the weighted least-squares slope of `r_i` on the bins' mid times `t_i`,
//! weights `w_i = 1 / v_i`:
//!
//! `b = sum w_i (t_i - t_w)(r_i - r_w) / S`, `S = sum w_i (t_i - t_w)^2`, `var b = s^2 / S`
//!
//! (`t_w`, `r_w` the weighted means; Draper & Smith, *Applied Regression Analysis*, eqs.
//! 9.2.6-9.2.10), with `s^2 = max(1, chi^2 / (n - 2))`, `chi^2 = sum w_i (r_i - fit_i)^2`: the
//! scatter about the line inflates the interval when the posterior's variance understates it
//! (a model the filter does not have), never narrows it. The interval is `b +- t_{0.95, n-2}
//! sqrt(var b)`. Each bin weighs by the posterior's variance, not by that over its samples:
//! the filter forgets with the time constant `tau = P / q` of its random walk
//! (`rbpf/wear_rate.rs` module docs: about 5 s at a healthy width of 1.5 % of nominal, less on
//! a ramp), so a bin's mean is about as uncertain as one posterior, and bins a few `tau`
//! apart are about independent.
//!
//! **Projected time to the threshold** (operating hours) from the fitted ratio at the newest
//! bin `r_now`: `(r_now - threshold) / -b`, its interval from the rate's 5 % and 95 % bounds
//! (the level's own uncertainty left out: a bin's is below 1 % of nominal, the rate's dominates
//! a projection); 0 once `r_now` is below the threshold; none when the rate is not
//! significantly negative (its 95 % bound is not below 0).
//!
//! **What it cannot see.** A change faster than the window: a step or a ramp of minutes
//! shows as a rate averaged with the flat hour before it (the alarm, not the trend, is for
//! those); wear slower than the window resolves (about 0.1-1 % of nominal per hour over one
//! operating hour, depending on the posterior's width); anything while the filter does not
//! learn (standing, settling, `model_mismatch`); a damper that recovers (a repair: the trend
//! mixes both until the window has passed). It restarts with the filter.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Operating time per bin (s).
pub const TREND_BIN_S: f64 = 10.0;
/// Bins in the window: one operating hour.
pub const TREND_WINDOW_BINS: usize = 360;
/// No trend before this many bins (two operating minutes): a slope needs a span.
pub const TREND_MIN_BINS: usize = 12;
/// The standard normal's 95 % quantile: a 90 % interval is `+- Z_95` standard deviations.
const Z_95: f64 = 1.644_853_626_951_472_2;

/// The 95 % quantile of Student's t with `dof` degrees of freedom, by the Cornish-Fisher
/// expansion about the normal one (Abramowitz & Stegun 26.7.5, three terms: 2.115 for 4 degrees
/// of freedom against 2.132, within 0.1 % from 10 on).
fn student_t_95(dof: f64) -> f64 {
    let z = Z_95;
    let (z3, z5) = (z.powi(3), z.powi(5));
    z + (z3 + z) / (4.0 * dof) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * dof * dof)
}

/// A projection of the time until the health ratio reaches the threshold (operating hours).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TimeToThreshold {
    /// At the fitted rate.
    pub hours: f64,
    /// At the rate's 5 % bound (the fastest plausible fall): the earliest.
    pub earliest_hours: f64,
    /// At the rate's 95 % bound (the slowest fall still significant): the latest.
    pub latest_hours: f64,
}

/// The trend of one damper over the window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrendEstimate {
    /// The fitted health ratio at the newest bin.
    pub health_ratio: f64,
    /// The health ratio's change per operating hour (negative: degrading) and its 90 %
    /// interval.
    pub rate_per_h: f64,
    pub rate_q05_per_h: f64,
    pub rate_q95_per_h: f64,
    /// The operating time the fit spans (h; up to one hour).
    pub window_h: f64,
    /// Bins in the fit.
    pub bins: usize,
    /// When the ratio reaches the threshold; `None` unless the rate is significantly negative.
    pub time_to_threshold: Option<TimeToThreshold>,
}

/// The binned history of one damper's health ratio and its trend.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DegradationTrend {
    threshold: f64,
    /// Operating time so far (s).
    operating_s: f64,
    /// The open bin: its operating time (s), sum of health ratios, of their variances, samples.
    open_s: f64,
    open_ratio_sum: f64,
    open_var_sum: f64,
    open_n: u64,
    /// Closed bins, oldest first: `[mid operating time (s), mean ratio, mean variance]`.
    bins: VecDeque<[f64; 3]>,
    /// The fit at the last closed bin.
    estimate: Option<TrendEstimate>,
}

impl DegradationTrend {
    /// An empty history; projections are to `threshold` (health ratio: the alarm's
    /// `degraded_below_ratio`).
    pub fn new(threshold: f64) -> Self {
        DegradationTrend {
            threshold,
            operating_s: 0.0,
            open_s: 0.0,
            open_ratio_sum: 0.0,
            open_var_sum: 0.0,
            open_n: 0,
            bins: VecDeque::with_capacity(TREND_WINDOW_BINS),
            estimate: None,
        }
    }

    /// One learning sample `dt_s` of operating time long: the posterior mean's health ratio and
    /// its 5 % and 95 % quantiles (over nominal). A non-finite figure is not taken.
    pub fn update(&mut self, dt_s: f64, health_ratio: f64, q05_ratio: f64, q95_ratio: f64) {
        let std = (q95_ratio - q05_ratio) / (2.0 * Z_95);
        if !(health_ratio.is_finite() && std.is_finite() && dt_s > 0.0) {
            return;
        }
        self.operating_s += dt_s;
        self.open_s += dt_s;
        self.open_ratio_sum += health_ratio;
        // A collapsed posterior (zero width) would take all the weight: floor it at 1e-4
        // of nominal, far below any posterior the filter publishes.
        self.open_var_sum += std.max(1e-4).powi(2);
        self.open_n += 1;
        if self.open_s + 1e-9 >= TREND_BIN_S {
            let n = self.open_n as f64;
            self.bins.push_back([
                self.operating_s - 0.5 * self.open_s,
                self.open_ratio_sum / n,
                self.open_var_sum / n,
            ]);
            while self.bins.len() > TREND_WINDOW_BINS {
                self.bins.pop_front();
            }
            (
                self.open_s,
                self.open_ratio_sum,
                self.open_var_sum,
                self.open_n,
            ) = (0.0, 0.0, 0.0, 0);
            self.estimate = self.fit();
        }
    }

    /// The trend at the last closed bin (`None` before [`TREND_MIN_BINS`] bins).
    pub fn estimate(&self) -> Option<TrendEstimate> {
        self.estimate
    }

    /// Operating time seen so far (s).
    pub fn operating_s(&self) -> f64 {
        self.operating_s
    }

    /// The weighted least-squares line of the module's documentation over the bins.
    fn fit(&self) -> Option<TrendEstimate> {
        let n = self.bins.len();
        if n < TREND_MIN_BINS {
            return None;
        }
        let hours = |s: f64| s / 3600.0;
        let (mut sw, mut st, mut sr) = (0.0, 0.0, 0.0);
        for [t, r, v] in &self.bins {
            let w = 1.0 / v;
            sw += w;
            st += w * hours(*t);
            sr += w * r;
        }
        let (t_w, r_w) = (st / sw, sr / sw);
        let (mut stt, mut str_) = (0.0, 0.0);
        for [t, r, v] in &self.bins {
            let w = 1.0 / v;
            stt += w * (hours(*t) - t_w).powi(2);
            str_ += w * (hours(*t) - t_w) * (r - r_w);
        }
        if stt <= 0.0 {
            return None;
        }
        let b = str_ / stt;
        let chi2: f64 = self
            .bins
            .iter()
            .map(|[t, r, v]| (r - r_w - b * (hours(*t) - t_w)).powi(2) / v)
            .sum();
        let dof = (n - 2) as f64;
        let s2 = (chi2 / dof).max(1.0);
        let half = student_t_95(dof) * (s2 / stt).sqrt();
        let (lo, hi) = (b - half, b + half);
        let newest_h = hours(self.bins[n - 1][0]);
        let level = r_w + b * (newest_h - t_w);
        let time_to_threshold = (hi < 0.0).then(|| {
            let above = (level - self.threshold).max(0.0);
            TimeToThreshold {
                hours: above / -b,
                earliest_hours: above / -lo,
                latest_hours: above / -hi,
            }
        });
        Some(TrendEstimate {
            health_ratio: level,
            rate_per_h: b,
            rate_q05_per_h: lo,
            rate_q95_per_h: hi,
            window_h: hours(self.bins[n - 1][0] - self.bins[0][0] + TREND_BIN_S),
            bins: n,
            time_to_threshold,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// A synthetic posterior at 1 kHz: the ratio `truth(t)` plus an error that stays for about a
    /// second (an AR(1) of time constant 0.5 s, as a filter's posterior mean wanders), with a
    /// 90 % interval of +- 1.2 % (standard deviation 0.0073) around it.
    fn feed(trend: &mut DegradationTrend, seconds: f64, truth: impl Fn(f64) -> f64, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let dt = 1e-3;
        let std = 0.0073;
        let phi: f64 = (-dt / 0.5f64).exp();
        let mut err = 0.0;
        for k in 0..(seconds / dt).round() as usize {
            let t = k as f64 * dt;
            err = phi * err + std * (1.0 - phi * phi).sqrt() * rng.sample::<f64, _>(StandardNormal);
            let m = truth(t) + err;
            trend.update(dt, m, m - Z_95 * std, m + Z_95 * std);
        }
    }

    /// A ratio falling 6 % of nominal per operating hour (from 0.95), over 40 minutes: the
    /// fitted rate's interval holds -0.06 /h and excludes 0, the level is the truth's, and the
    /// projection to 0.7 is (0.95 - 0.04 - 0.7) / 0.06 = 3.5 h, inside its interval.
    #[test]
    fn a_synthetic_ramp_gives_its_rate_and_its_time_to_the_threshold() {
        let mut trend = DegradationTrend::new(0.7);
        let rate_per_h = -0.06;
        let truth = |t: f64| 0.95 + rate_per_h * t / 3600.0;
        feed(&mut trend, 2400.0, truth, 1);
        let e = trend.estimate().unwrap();
        assert_eq!(e.bins, 240);
        assert!((e.window_h - 2400.0 / 3600.0).abs() < 1e-9);
        assert!(
            e.rate_q05_per_h < rate_per_h && rate_per_h < e.rate_q95_per_h,
            "{e:?}"
        );
        assert!(e.rate_q95_per_h < 0.0, "{e:?}");
        assert!((e.rate_per_h - rate_per_h).abs() < 0.01, "{e:?}");
        assert!((e.health_ratio - truth(2395.0)).abs() < 0.003, "{e:?}");
        let p = e.time_to_threshold.unwrap();
        let expected = (truth(2395.0) - 0.7) / -rate_per_h;
        assert!(
            p.earliest_hours < expected && expected < p.latest_hours,
            "{p:?} {expected}"
        );
        assert!((p.hours - expected).abs() < 0.2 * expected, "{p:?}");
    }

    /// A healthy damper: the rate's interval holds 0, so no projection; on a few seeds.
    #[test]
    fn a_flat_ratio_projects_nothing() {
        for seed in 0..4 {
            let mut trend = DegradationTrend::new(0.7);
            feed(&mut trend, 1200.0, |_| 1.0, seed);
            let e = trend.estimate().unwrap();
            assert!(e.rate_q05_per_h < 0.0 && 0.0 < e.rate_q95_per_h, "{e:?}");
            assert_eq!(e.time_to_threshold, None);
        }
    }

    /// Nothing before two operating minutes; the window keeps the last hour; a ratio already
    /// below the threshold projects 0; non-finite samples are not taken.
    #[test]
    fn the_window_and_its_edges() {
        let mut trend = DegradationTrend::new(0.7);
        feed(&mut trend, 119.0, |_| 1.0, 1);
        assert_eq!(trend.estimate(), None);
        trend.update(1e-3, f64::NAN, 0.9, 1.1);
        assert!((trend.operating_s() - 119.0).abs() < 1e-6);
        feed(&mut trend, 3700.0, |t| 0.69 - 0.1 * t / 3600.0, 2);
        let e = trend.estimate().unwrap();
        assert_eq!(e.bins, TREND_WINDOW_BINS);
        assert!((e.window_h - 1.0).abs() < 1e-9);
        assert_eq!(e.time_to_threshold.unwrap().hours, 0.0);
    }

    #[test]
    fn student_t_quantile() {
        assert!((student_t_95(4.0) - 2.132).abs() < 0.02);
        assert!((student_t_95(10.0) - 1.812).abs() < 0.002);
        assert!((student_t_95(1e9) - Z_95).abs() < 1e-6);
    }
}
