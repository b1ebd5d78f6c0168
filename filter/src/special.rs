//! Special functions shared by the estimators: `ln Gamma`, used by the slip detector's
//! variational bounds (Beta and Gamma normalisers) and by the fuel predictive's Student-t
//! density and CDF constants.

use std::f64::consts::PI;

/// `ln Gamma(x)` for `x > 0`: recurrence up to `x >= 15`, then Stirling's series
/// (truncation error < 3e-14 there). The recurrence multiplies and takes one logarithm.
pub fn ln_gamma(mut x: f64) -> f64 {
    let mut product = 1.0;
    while x < 15.0 {
        product *= x;
        x += 1.0;
    }
    let acc = -product.ln();
    let inv = 1.0 / x;
    let inv2 = inv * inv;
    acc + (x - 0.5) * x.ln() - x
        + 0.5 * (2.0 * PI).ln()
        + inv * (1.0 / 12.0 - inv2 * (1.0 / 360.0 - inv2 * (1.0 / 1260.0 - inv2 / 1680.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `Gamma(n) = (n - 1)!` across the recurrence's end (15) and far into the series.
    #[test]
    fn ln_gamma_matches_factorials() {
        let mut ln_factorial = 0.0f64; // ln (n - 1)!
        for n in 1..=170u32 {
            let got = ln_gamma(f64::from(n));
            assert!(
                (got - ln_factorial).abs() <= 1e-13 * ln_factorial.abs().max(1.0),
                "n {n}: {got} vs {ln_factorial}"
            );
            ln_factorial += f64::from(n).ln();
        }
    }

    /// `Gamma(n + 1/2) = (2n)! sqrt(pi) / (4^n n!)`, built as `Gamma(1/2) = sqrt(pi)` times
    /// `(k - 1/2)` for `k = 1..n`: the half-integers are where the Student-t constants sit
    /// (`dof / 2` for odd `dof`).
    #[test]
    fn ln_gamma_matches_half_integers() {
        let mut want = 0.5 * PI.ln(); // ln Gamma(1/2)
        for n in 0..=150u32 {
            let x = f64::from(n) + 0.5;
            let got = ln_gamma(x);
            assert!(
                (got - want).abs() <= 1e-13 * want.abs().max(1.0),
                "x {x}: {got} vs {want}"
            );
            want += x.ln();
        }
        // Small arguments (the recurrence's many steps): Gamma(0.1) = 9.513507698668732.
        assert!((ln_gamma(0.1) - 9.513_507_698_668_732f64.ln()).abs() < 1e-13);
    }
}
