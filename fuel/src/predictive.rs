//! Predictive distributions of the fuel: mixtures of Student-t densities and their central
//! intervals.
//!
//! A normal regression component with Gauss-inverse-Wishart statistics `(V, kappa)` predicts a
//! scalar channel with a Student-t density (Peterka 1981; Karny et al., *Optimized Bayesian
//! Dynamic Advising*, 2006, ch. 8): location `theta' psi`, squared scale `r (1 + zeta)` with
//! `zeta = psi' V_psi^-1 psi`, and `kappa - k_y + 1` degrees of freedom for one channel of a
//! `k_y`-variate component (the marginal of an inverse-Wishart). The mixture's predictive is the
//! sum of these weighted by the predicted pointer (Algorithm 3.4, step 2 one step ahead); its
//! quantiles have no closed form and are found by safeguarded Newton steps on the mixture's CDF.

use railmon_filter::normal::normal_cdf;
use railmon_filter::special::ln_gamma;
use serde::{Deserialize, Serialize};

/// One Student-t term of a predictive mixture.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudentT {
    /// Weight in the mixture (the terms' weights sum to 1).
    pub weight: f64,
    pub location: f64,
    /// Scale (not the standard deviation: that is `scale sqrt(dof / (dof - 2))`).
    pub scale: f64,
    /// Degrees of freedom, >= 1.
    pub dof: f64,
}

impl StudentT {
    /// `P(X <= x)`.
    pub fn cdf(&self, x: f64) -> f64 {
        student_t_cdf(
            (x - self.location) / self.scale.max(f64::MIN_POSITIVE),
            self.dof,
        )
    }
}

/// A central predictive interval, in the units of the channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    pub lower: f64,
    pub upper: f64,
}

impl Interval {
    pub fn contains(&self, x: f64) -> bool {
        self.lower <= x && x <= self.upper
    }
}

/// The central interval of probability `mass` (e.g. 0.9: from the 5 % to the 95 % quantile) of
/// the mixture `terms`. Terms with a non-positive or non-finite weight are ignored; without any
/// term the interval is NaN.
pub fn central_interval(terms: &[StudentT], mass: f64) -> Interval {
    let tail = 0.5 * (1.0 - mass);
    Interval {
        lower: quantile(terms, tail),
        upper: quantile(terms, 1.0 - tail),
    }
}

/// Whether the CDF of the mixture `terms` at `x`, `sum w_i F_i(x) / total` (`total` the sum
/// of the weights), computed as [`StudentT::cdf`] computes each `F_i`, lies in `[lo, hi]`: the
/// same answer, to the bit, as evaluating it, which this does only as far as bounds do not
/// settle it. The calibration asks this of 11 predictives at every step, and most targets lie
/// well inside their interval, where the continued fraction of each term's CDF (or its erfc)
/// is not needed to know it.
///
/// The bound: a Student-t density (any degrees of freedom) is largest at its centre and at
/// most `1 / sqrt(2 pi)` there (the normal's), so `F(z)` lies in `[1/2, 1/2 + z / sqrt(2 pi)]`
/// for `z >= 0` and symmetrically below; so does the normal approximation used above 100
/// degrees of freedom (its argument is `z` shrunk towards 0). The computed values differ from
/// these by the erfc fit (below 1.2e-7) and rounding, far below the margin `1e-6` by which the
/// bounds must clear `lo` and `hi`. Where all terms' bounds do not settle it, the terms are
/// evaluated one at a time, the heaviest first, each evaluated value replacing its bounds,
/// until the bounds of the rest settle it (either way: inside, or outside by the margin): a
/// term of small weight (a rarely active component, whose few degrees of freedom need the
/// continued fraction) then seldom needs its CDF. Where every term is evaluated, the answer
/// is the evaluation's, summed in the terms' order. Anything not finite, a negative weight or
/// fewer than one degree of freedom leaves the answer to the evaluation.
pub fn cdf_within(terms: &[StudentT], total: f64, x: f64, lo: f64, hi: f64) -> bool {
    const MARGIN: f64 = 1e-6;
    const MAX_DENSITY: f64 = 0.398_942_280_401_432_7;
    let evaluate = || {
        let cdf = terms.iter().map(|t| t.weight * t.cdf(x)).sum::<f64>() / total;
        (lo..=hi).contains(&cdf)
    };
    // Per term its weighted bounds, and whether they are its evaluated value (a step's
    // predictive has one term per component, two mixtures' with the blend).
    const MOST: usize = 16;
    let mut bounds = [(0.0, 0.0); MOST];
    let mut done = [false; MOST];
    for (t, b) in terms.iter().zip(bounds.iter_mut()) {
        let z = (x - t.location) / t.scale.max(f64::MIN_POSITIVE);
        if !(z.is_finite() && t.weight.is_finite() && t.weight >= 0.0 && t.dof >= 1.0) {
            return evaluate();
        }
        let reach = MAX_DENSITY * z.abs();
        let (f_lo, f_hi) = if z >= 0.0 {
            (0.5, (0.5 + reach).min(1.0))
        } else {
            ((0.5 - reach).max(0.0), 0.5)
        };
        *b = (t.weight * f_lo, t.weight * f_hi);
    }
    if terms.len() > MOST || !(total > 0.0 && total.is_finite()) {
        return evaluate();
    }
    let bounds = &mut bounds[..terms.len()];
    loop {
        let (l, u) = bounds
            .iter()
            .fold((0.0, 0.0), |(l, u), (b_lo, b_hi)| (l + b_lo, u + b_hi));
        let (l, u) = (l / total, u / total);
        if l > lo + MARGIN && u < hi - MARGIN {
            return true;
        }
        if u < lo - MARGIN || l > hi + MARGIN {
            return false;
        }
        // The heaviest term not evaluated yet; once all are, the evaluation's own sum.
        let Some(next) = (0..terms.len())
            .filter(|&i| !done[i])
            .max_by(|&a, &b| terms[a].weight.total_cmp(&terms[b].weight))
        else {
            return evaluate();
        };
        let value = terms[next].weight * terms[next].cdf(x);
        bounds[next] = (value, value);
        done[next] = true;
    }
}

/// The `p`-quantile of the mixture: Newton's method on its CDF with its density as the slope,
/// kept inside a bracket that shrinks at every step and taking the bisection step whenever
/// Newton's would leave it (safeguarded Newton, Numerical Recipes 3rd ed. 9.4 `rtsafe`); to
/// 1e-7 of the first bracket. Plain bisection needed ~24 CDF evaluations of every term per
/// quantile and made the monitor's step 12x slower; Newton converges in a handful.
pub fn quantile(terms: &[StudentT], p: f64) -> f64 {
    // Per term, what does not depend on `x` is computed once (the profile of the monitor's
    // step put ~15 % of it in `ln_gamma` calls that repeated these per CDF evaluation); the
    // values are the same to the bit as computing them inside every evaluation.
    let live: Vec<(StudentT, f64, TConstants)> = terms
        .iter()
        .filter(|t| t.weight > 0.0 && t.weight.is_finite())
        .map(|t| (*t, ln_t_density_norm(t.dof), TConstants::new(t.dof)))
        .collect();
    let total: f64 = live.iter().map(|(t, _, _)| t.weight).sum();
    if total <= 0.0 || !total.is_finite() {
        return f64::NAN;
    }
    // The mixture's CDF at `x` and its density (the CDF's slope).
    let cdf_and_density = |x: f64| {
        live.iter()
            .fold((0.0, 0.0), |(f, d), (t, ln_norm, constants)| {
                let scale = t.scale.max(f64::MIN_POSITIVE);
                let z = (x - t.location) / scale;
                let density =
                    (ln_norm - 0.5 * (t.dof + 1.0) * (z * z / t.dof).ln_1p()).exp() / scale;
                (
                    f + t.weight * constants.cdf(z, t.dof),
                    d + t.weight * density,
                )
            })
    };
    // A bracket: every term's own p-quantile lies between the extremes of the terms' quantiles,
    // and so does the mixture's. A term's quantile is within `location +- scale k`, with `k`
    // the quantile of a t with that term's dof, bounded here by a generous multiple.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (t, _, constants) in &live {
        let reach = t.scale * constants.reach(p.min(1.0 - p), t.dof);
        lo = lo.min(t.location - reach);
        hi = hi.max(t.location + reach);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return f64::NAN;
    }
    let tolerance = 1e-7 * (hi - lo).max(1e-12);
    let mut x = 0.5 * (lo + hi);
    // Bisection alone ends within ~60 steps; Newton's steps only shorten that.
    for _ in 0..200 {
        let (f, density) = cdf_and_density(x);
        let miss = f / total - p;
        if miss < 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let newton = x - miss * total / density;
        let next = match density > 0.0 && newton > lo && newton < hi {
            true => newton,
            false => 0.5 * (lo + hi),
        };
        let step = (next - x).abs();
        x = next;
        if step <= tolerance || hi - lo <= tolerance {
            break;
        }
    }
    x
}

/// `ln` of the standard Student-t density's constant, `Gamma((dof + 1) / 2) / (Gamma(dof / 2)
/// sqrt(dof pi))`.
fn ln_t_density_norm(dof: f64) -> f64 {
    ln_gamma(0.5 * (dof + 1.0)) - ln_gamma(0.5 * dof) - 0.5 * (dof * std::f64::consts::PI).ln()
}

/// What a Student-t CDF needs of its degrees of freedom alone: `ln B(dof / 2, 1 / 2)` in the
/// form `regularized_incomplete_beta` uses (`None` where the CDF takes the normal shortcut).
#[derive(Clone, Copy, Debug)]
struct TConstants {
    ln_beta: Option<f64>,
}

impl TConstants {
    fn new(dof: f64) -> Self {
        TConstants {
            ln_beta: (dof <= 100.0).then(|| ln_beta_inverse(0.5 * dof, 0.5)),
        }
    }

    /// [`student_t_cdf`] of `t` (`dof` the one these constants were made for).
    fn cdf(&self, t: f64, dof: f64) -> f64 {
        student_t_cdf_with(t, dof, self.ln_beta)
    }

    /// A number `k` with `P(|T_dof| > k) <= 2 tail`: doubles from 1 until the tail is small
    /// enough.
    fn reach(&self, tail: f64, dof: f64) -> f64 {
        let mut k = 1.0;
        while k < 1e12 && 1.0 - self.cdf(k, dof) > tail {
            k *= 2.0;
        }
        k
    }
}

/// `ln Gamma(a + b) - ln Gamma(a) - ln Gamma(b)`, evaluated in that order.
fn ln_beta_inverse(a: f64, b: f64) -> f64 {
    ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b)
}

/// CDF of the standard Student-t with `dof` degrees of freedom:
/// `1 - I_{dof / (dof + t^2)}(dof / 2, 1/2) / 2` for `t >= 0` (Abramowitz & Stegun 26.7.1,
/// 26.5.27), symmetric for `t < 0`. Above 10^7 degrees of freedom the normal CDF.
pub fn student_t_cdf(t: f64, dof: f64) -> f64 {
    student_t_cdf_with(t, dof, None)
}

/// [`student_t_cdf`] with `ln_beta = ln_beta_inverse(dof / 2, 1 / 2)` given or computed here.
fn student_t_cdf_with(t: f64, dof: f64, ln_beta: Option<f64>) -> f64 {
    if t.is_nan() || dof.is_nan() {
        return f64::NAN;
    }
    if dof > 100.0 {
        // Abramowitz & Stegun 26.7.8: z = t (1 - 1/(4 dof)) / sqrt(1 + t^2 / (2 dof)) is close
        // to normal (error in the CDF ~1e-5 at 100 degrees of freedom), and costs one erfc
        // instead of a continued fraction: the monitor evaluates this ~10^3 times a step.
        let z = t * (1.0 - 0.25 / dof) / (1.0 + t * t / (2.0 * dof)).sqrt();
        return normal_cdf(z);
    }
    let x = dof / (dof + t * t);
    let (a, b) = (0.5 * dof, 0.5);
    let ln_beta = ln_beta.unwrap_or_else(|| ln_beta_inverse(a, b));
    let tail = 0.5 * incomplete_beta_with(a, b, x, ln_beta);
    if t >= 0.0 {
        1.0 - tail
    } else {
        tail
    }
}

/// `I_x(a, b)`, the regularised incomplete beta function, by its continued fraction (modified
/// Lentz; Numerical Recipes 3rd ed., 6.4), using the symmetry `I_x(a, b) = 1 - I_{1-x}(b, a)`
/// where the fraction converges faster.
pub fn regularized_incomplete_beta(a: f64, b: f64, x: f64) -> f64 {
    incomplete_beta_with(a, b, x, ln_beta_inverse(a, b))
}

/// [`regularized_incomplete_beta`] with `ln_beta = ln_beta_inverse(a, b)` given.
fn incomplete_beta_with(a: f64, b: f64, x: f64, ln_beta: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = ln_beta + a * x.ln() + b * (1.0 - x).ln();
    if x < (a + 1.0) / (a + b + 2.0) {
        (ln_front.exp() * beta_fraction(a, b, x) / a).clamp(0.0, 1.0)
    } else {
        (1.0 - ln_front.exp() * beta_fraction(b, a, 1.0 - x) / b).clamp(0.0, 1.0)
    }
}

fn beta_fraction(a: f64, b: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..=300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        if d.abs() < TINY {
            d = TINY;
        }
        c = 1.0 + aa / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        if d.abs() < TINY {
            d = TINY;
        }
        c = 1.0 + aa / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        let delta = d * c;
        h *= delta;
        if (delta - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The per-term constants change no bit: the CDF with them equals the CDF computing them
    /// inside, and the bracket's reach equals the doubling search on that CDF.
    #[test]
    fn cached_constants_give_the_same_bits() {
        for dof in [1.0, 1.5, 2.0, 3.7, 10.0, 29.0, 64.5, 100.0, 100.5, 1e4] {
            let constants = TConstants::new(dof);
            for t in [-40.0, -3.1, -1.0, -0.2, 0.0, 1e-9, 0.7, 1.812_461, 6.3, 1e3] {
                assert_eq!(
                    constants.cdf(t, dof).to_bits(),
                    student_t_cdf(t, dof).to_bits(),
                    "dof {dof}, t {t}"
                );
            }
            for tail in [0.05, 0.05 + 1e-17, 0.01, 0.25] {
                let mut k = 1.0;
                while k < 1e12 && 1.0 - student_t_cdf(k, dof) > tail {
                    k *= 2.0;
                }
                assert_eq!(constants.reach(tail, dof), k, "dof {dof}, tail {tail}");
            }
        }
    }

    /// The bounds' answer is the evaluation's on mixtures of one to five terms (heavy tails,
    /// the normal approximation's range, far-apart terms, weights not summing to 1 or spread
    /// over 12 decades) at targets from deep in the tails to the centre, and at targets on the
    /// 5 % and 95 % quantiles themselves (seeded).
    #[test]
    fn cdf_within_answers_as_the_evaluation() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (lo, hi) = (0.05, 0.95);
        for case in 0..6000 {
            let n = 1 + case % 5;
            let terms: Vec<StudentT> = (0..n)
                .map(|_| StudentT {
                    // Weights over many decades too (a dominant component beside rare ones).
                    weight: match case % 3 {
                        0 => rng.random_range(0.0..2.0),
                        _ => 10f64.powf(rng.random_range(-12.0..0.0)),
                    },
                    location: rng.random_range(-5.0..5.0),
                    scale: 10f64.powf(rng.random_range(-3.0..1.0)),
                    dof: [1.0, 2.5, 7.0, 60.0, 100.0, 150.0, 1e6][rng.random_range(0..7)],
                })
                .collect();
            let total: f64 = terms.iter().map(|t| t.weight).sum();
            let exact = |x: f64| {
                let cdf = terms.iter().map(|t| t.weight * t.cdf(x)).sum::<f64>() / total;
                (lo..=hi).contains(&cdf)
            };
            let mut targets: Vec<f64> = (0..20).map(|_| rng.random_range(-12.0..12.0)).collect();
            let interval = central_interval(&terms, 0.9);
            targets.extend([interval.lower, interval.upper]);
            for x in targets {
                assert_eq!(
                    cdf_within(&terms, total, x, lo, hi),
                    exact(x),
                    "{terms:?} at {x}"
                );
            }
        }
        // Not finite: the evaluation's answer (NaN is outside any range).
        let t = StudentT {
            weight: 1.0,
            location: f64::NAN,
            scale: 1.0,
            dof: 5.0,
        };
        assert!(!cdf_within(&[t], 1.0, 0.0, lo, hi));
    }

    #[test]
    fn student_t_cdf_matches_tables() {
        // Two-sided 90 % points of the t distribution (any statistics table).
        for (dof, t95) in [
            (1.0, 6.313_752),
            (5.0, 2.015_048),
            (10.0, 1.812_461),
            (30.0, 1.697_261),
        ] {
            let p = student_t_cdf(t95, dof);
            assert!((p - 0.95).abs() < 1e-6, "dof {dof}: {p}");
            assert!((student_t_cdf(-t95, dof) - 0.05).abs() < 1e-6);
        }
        // Cauchy: CDF = 1/2 + atan(t) / pi.
        for t in [-3.0, -0.5, 0.0, 0.7, 4.0] {
            let want = 0.5 + f64::atan(t) / std::f64::consts::PI;
            assert!((student_t_cdf(t, 1.0) - want).abs() < 1e-10, "t {t}");
        }
        // Many degrees of freedom: the normal.
        assert!((student_t_cdf(1.644_854, 1e9) - 0.95).abs() < 1e-6);
        assert!((student_t_cdf(1.644_854, 1e5) - 0.95).abs() < 1e-5);
    }

    #[test]
    fn one_term_interval_is_the_t_quantiles_and_a_mixture_interval_covers_its_mass() {
        let t = StudentT {
            weight: 1.0,
            location: 2.0,
            scale: 0.5,
            dof: 5.0,
        };
        let i = central_interval(&[t], 0.9);
        assert!((i.lower - (2.0 - 0.5 * 2.015_048)).abs() < 1e-5, "{i:?}");
        assert!((i.upper - (2.0 + 0.5 * 2.015_048)).abs() < 1e-5, "{i:?}");
        // Two well separated terms: each tail holds 5 % of the total mass.
        let terms = [
            StudentT { weight: 0.3, ..t },
            StudentT {
                weight: 0.7,
                location: 10.0,
                scale: 1.0,
                dof: 50.0,
            },
        ];
        let i = central_interval(&terms, 0.9);
        let cdf = |x: f64| terms.iter().map(|t| t.weight * t.cdf(x)).sum::<f64>();
        assert!((cdf(i.lower) - 0.05).abs() < 1e-7 && (cdf(i.upper) - 0.95).abs() < 1e-7);
        assert!(central_interval(&[], 0.9).lower.is_nan());
    }

    /// The safeguarded Newton quantile equals a plain bisection on the same CDF, for heavy
    /// tails (1 degree of freedom), the normal approximation's range (> 100) and a mixture of
    /// far-apart terms where Newton's first steps leave the bracket.
    #[test]
    fn newton_quantile_equals_bisection() {
        let bisection = |terms: &[StudentT], p: f64| {
            let total: f64 = terms.iter().map(|t| t.weight).sum();
            let cdf = |x: f64| terms.iter().map(|t| t.weight * t.cdf(x)).sum::<f64>() / total;
            let (mut lo, mut hi) = (-1e4, 1e4);
            while hi - lo > 1e-10 {
                let mid = 0.5 * (lo + hi);
                if cdf(mid) < p {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        };
        let term = |weight, location, scale, dof| StudentT {
            weight,
            location,
            scale,
            dof,
        };
        let cases = [
            vec![term(1.0, 0.3, 2.0, 1.0)],
            vec![term(1.0, -4.0, 0.1, 500.0)],
            vec![term(0.2, 0.0, 0.5, 3.0), term(0.8, 40.0, 0.2, 200.0)],
            vec![
                term(0.5, 1.0, 1.0, 4.0),
                term(0.3, 1.5, 3.0, 12.0),
                term(0.2, -2.0, 0.3, 1e6),
            ],
        ];
        for terms in &cases {
            for p in [0.05, 0.5, 0.95, 0.999] {
                let (got, want) = (quantile(terms, p), bisection(terms, p));
                assert!(
                    (got - want).abs() < 1e-5 * (1.0 + want.abs()),
                    "{terms:?} p {p}: {got} vs {want}"
                );
            }
        }
    }
}
