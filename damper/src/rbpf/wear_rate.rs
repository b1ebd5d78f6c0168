//! A wear rate per particle, walking only as far as the data identify it (issue 24 item 3).
//!
//! Each particle carries `r = d ln C / dt` per damper beside `ln C` (a local linear trend
//! per particle: Harvey 1989, section 2.3.2, `mu_t = mu_{t-1} + beta_{t-1}`), so a ramp's
//! slope is a hypothesis the weights test rather than a velocity read off the mean
//! (`super::wear_evolution`). A rate is a belief that the data must keep confirming, so:
//!
//! 1. **Its walk is sized by the data's information about `ln C` now** ([`Information`]).
//!    For a local linear trend with level observed at information `I` per second and slope
//!    walk `q_s`, the continuous steady state is `P_11 = sqrt(2) q_s^(1/4) I^(-3/4)`,
//!    `P_22 = sqrt(2) q_s^(3/4) I^(-1/4)` (the integrated random walk's Riccati solution,
//!    e.g. Jazwinski 1970, example 7.14). With `q_s = kappa I` the level's spread from the
//!    slope is `sqrt(2) kappa^(1/4) I^(-1/2)`: the same law in `I` as the fixed level walk's
//!    `sqrt(q0 / I)`, so where the data are weak (low speed, right after a stop) the rate
//!    adds proportionally no more width than today's walk, and where they are absent it does
//!    not walk at all.
//! 2. **It reverts to 0** (Ornstein-Uhlenbeck, `dr = -r / T_r dt + sqrt(q_s) dW`), memory
//!    [`RATE_MEMORY_S`]: without fresh evidence a rate decays, so a healthy damper's mean
//!    cannot run away on a rate it learned from a transient (the false alarm of the rejected
//!    v5, damper-log "Slope per particle").
//! 3. **Liu-West on the rate too** (eq. 24, per damper: shrink to the cloud's mean rate by
//!    `a`, jitter by `h^2` of its variance) so that resampling's copies spread again.
//!
//! Measured and not kept (docs/notes/damper-log.md, "Slope per particle, its walk sized by the
//! data"): tuned with `RAILMON_RATE_KAPPA` (`kappa`), `RAILMON_RATE_MEMORY_S` (`T_r`) and
//! `RAILMON_RATE_OFF` (the kept filter, bit for bit), read here for the experiment only.

/// The memory of a wear rate without fresh evidence (s): the shortest ramp the issue asks to
/// follow (`sampler::RAMP_S`, one minute). A rate held longer must be confirmed by the data.
pub const RATE_MEMORY_S: f64 = 60.0;

/// The rate walk per unit of information, `kappa` in `q_s = kappa I` ((ln C / s)^2 per s
/// per (1 / (ln C)^2 per s)).
pub const RATE_WALK_PER_INFORMATION: f64 = 1e-9;

/// The memory of the information estimate (s): a few kernel moves, short beside a ramp.
pub const INFORMATION_MEMORY_S: f64 = 10.0;

/// The data's information about `ln C` per damper and second (Fisher information of the
/// Kalman-marginal likelihood), estimated at each resampling from the cloud that the weights
/// judged since the last kernel move: the particles were fixed over that interval, so their
/// weights are the interval's likelihood, and for a Gaussian cloud of variance `V_u` weighted
/// by a Gaussian likelihood of precision `J` the weighted variance is `V_w = 1 / (1 / V_u +
/// J)` (conjugate update), hence `J = 1 / V_w - 1 / V_u` (marginal per damper; the same
/// particles in both, so the resampling noise is common). Averaged over
/// [`INFORMATION_MEMORY_S`] as `sum J / sum dt`. Zero at the start and after a pause
/// ([`Information::reset`]): no rate walks until the data have spoken.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Information {
    /// Discounted sum of `J` per damper (1 / (ln C)^2).
    sum_j: [f64; 2],
    /// Discounted sum of the intervals (s).
    sum_s: f64,
}

impl Information {
    /// Information per second per damper (0 before any).
    pub fn per_s(&self) -> [f64; 2] {
        if self.sum_s > 0.0 {
            self.sum_j.map(|j| j / self.sum_s)
        } else {
            [0.0; 2]
        }
    }

    pub fn reset(&mut self) {
        *self = Information::default();
    }

    /// One interval of `since_s` seconds whose particles `ln_theta` earned the normalised
    /// log-weights `log_w`; `include[i]` false leaves a particle out (a regenerated or jump
    /// particle: not drawn from the cloud the others were).
    pub fn observe(
        &mut self,
        ln_theta: &[[f64; 2]],
        log_w: &[f64],
        include: impl Fn(usize) -> bool,
        since_s: f64,
    ) {
        if since_s <= 0.0 {
            return;
        }
        let (mut n, mut w_sum) = (0.0, 0.0);
        let (mut su, mut sw) = ([0.0; 2], [0.0; 2]);
        let origin = ln_theta[0];
        for (i, (th, lw)) in ln_theta.iter().zip(log_w).enumerate() {
            if !include(i) {
                continue;
            }
            let w = lw.exp();
            n += 1.0;
            w_sum += w;
            for k in 0..2 {
                su[k] += th[k] - origin[k];
                sw[k] += w * (th[k] - origin[k]);
            }
        }
        if n < 3.0 || w_sum <= 0.0 {
            return;
        }
        let (mu, mw) = (su.map(|s| s / n), sw.map(|s| s / w_sum));
        let (mut vu, mut vw) = ([0.0; 2], [0.0; 2]);
        for (i, (th, lw)) in ln_theta.iter().zip(log_w).enumerate() {
            if !include(i) {
                continue;
            }
            let w = lw.exp() / w_sum;
            for k in 0..2 {
                let d = th[k] - origin[k];
                vu[k] += (d - mu[k]).powi(2) / (n - 1.0);
                vw[k] += w * (d - mw[k]).powi(2);
            }
        }
        let decay = (-since_s / INFORMATION_MEMORY_S).exp();
        for k in 0..2 {
            let j = if vu[k] > 0.0 && vw[k] > 0.0 {
                (1.0 / vw[k] - 1.0 / vu[k]).max(0.0)
            } else {
                0.0
            };
            self.sum_j[k] = decay * self.sum_j[k] + j;
        }
        self.sum_s = decay * self.sum_s + since_s;
    }
}

/// The rate walk's standard deviation over `since_s` for information `info_per_s`.
pub fn rate_walk_std(info_per_s: f64, since_s: f64) -> f64 {
    // TUNING ONLY (removed before commit).
    let kappa = std::env::var("RAILMON_RATE_KAPPA")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(RATE_WALK_PER_INFORMATION);
    // TUNING ONLY: a constant walk q_s, no information gate (v5 with reversion).
    if let Some(q) = std::env::var("RAILMON_RATE_CONST_Q")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
    {
        return (q * since_s).sqrt();
    }
    (kappa * info_per_s.max(0.0) * since_s).sqrt()
}

/// The rate's reversion factor over `since_s`.
pub fn rate_reversion(since_s: f64) -> f64 {
    // TUNING ONLY (removed before commit).
    let memory_s = std::env::var("RAILMON_RATE_MEMORY_S")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(RATE_MEMORY_S);
    (-since_s / memory_s).exp()
}

/// The information per second at which a rate of a quarter of the fastest wear is seen at one
/// standard deviation within [`RATE_MEMORY_S`]: a line's slope fitted over `T` to a level
/// observed at information `I` per second has variance `12 / (I T^3)`.
pub fn information_to_see_a_rate() -> f64 {
    let r = super::MAX_WEAR_PER_S / 4.0;
    12.0 / (r * r * RATE_MEMORY_S.powi(3))
}

/// The rate's reversion over `since_s` where the data carry `info_per_s` about `ln C`: its
/// memory [`RATE_MEMORY_S`] where they can tell a rate within it, shorter in proportion where
/// they cannot (low speed, right after a pause: `I` = 0 wipes the rates at once). Experiment:
/// `RAILMON_RATE_INFORMED` (else the fixed memory).
pub fn rate_reversion_informed(info_per_s: f64, since_s: f64) -> f64 {
    if std::env::var_os("RAILMON_RATE_INFORMED").is_none() {
        return rate_reversion(since_s);
    }
    let scale: f64 = std::env::var("RAILMON_RATE_INFO_SCALE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1.0);
    let share = (info_per_s / (scale * information_to_see_a_rate())).clamp(0.0, 1.0);
    let memory_s = RATE_MEMORY_S * share;
    if memory_s <= 0.0 {
        0.0
    } else {
        (-since_s / memory_s).exp()
    }
}
