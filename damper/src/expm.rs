//! Matrix exponential and the exact zero-order-hold discretisation.
//!
//! `expm` is Higham's scaling-and-squaring with the [13/13] Padé approximant (Higham, "The
//! scaling and squaring method for the matrix exponential revisited", SIAM J. Matrix Anal.
//! Appl. 26(4), 2005, algorithm 2.3 with the degree-13 branch only: always accurate to
//! roundoff, at most ~2 extra multiplies on small norms, which do not matter here).

use nalgebra::{Const, DimMin, SMatrix};

use crate::model::{Matrix17, Matrix17x2, N_INPUTS, N_STATES};
use crate::DamperError;

/// Padé [13/13] numerator coefficients `b_0..b_13` (Higham 2005, table 2.3 / eq. 2.4).
const PADE13: [f64; 14] = [
    64_764_752_532_480_000.0,
    32_382_376_266_240_000.0,
    7_771_770_303_897_600.0,
    1_187_353_796_428_800.0,
    129_060_195_264_000.0,
    10_559_470_521_600.0,
    670_442_572_800.0,
    33_522_128_640.0,
    1_323_241_920.0,
    40_840_800.0,
    960_960.0,
    16_380.0,
    182.0,
    1.0,
];
/// Largest 1-norm for which [13/13] Padé is accurate to unit roundoff (Higham 2005, table 2.3).
const THETA13: f64 = 5.371_920_351_148_152;

/// `exp(a)`. Errors only on non-finite input (then `V - U` cannot be factorised).
pub fn expm<const N: usize>(a: &SMatrix<f64, N, N>) -> Result<SMatrix<f64, N, N>, DamperError>
where
    Const<N>: DimMin<Const<N>, Output = Const<N>>,
{
    if a.iter().any(|v| !v.is_finite()) {
        return Err(DamperError::NonFinite { what: "expm input" });
    }
    let norm1 = (0..N)
        .map(|j| a.column(j).iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let squarings = if norm1 > THETA13 {
        (norm1 / THETA13).log2().ceil() as i32
    } else {
        0
    };
    let a = a * 2f64.powi(-squarings);
    let b = &PADE13;
    let id = SMatrix::<f64, N, N>::identity();
    let a2 = a * a;
    let a4 = a2 * a2;
    let a6 = a4 * a2;
    let u_inner =
        a6 * (a6 * b[13] + a4 * b[11] + a2 * b[9]) + a6 * b[7] + a4 * b[5] + a2 * b[3] + id * b[1];
    let u = a * u_inner;
    let v =
        a6 * (a6 * b[12] + a4 * b[10] + a2 * b[8]) + a6 * b[6] + a4 * b[4] + a2 * b[2] + id * b[0];
    let mut r = (v - u).lu().solve(&(v + u)).ok_or(DamperError::NonFinite {
        what: "expm Padé solve",
    })?;
    for _ in 0..squarings {
        r = r * r;
    }
    Ok(r)
}

/// The exact discretisation of `x' = A x + G beta` with `beta` held over each step:
/// `Phi = expm(A T)`, `Gamma = int_0^T expm(A s) ds G` (paper, eq. 10 and 20).
#[derive(Debug, Clone, PartialEq)]
pub struct Discrete {
    pub phi: Matrix17,
    pub gamma: Matrix17x2,
}

/// Augmented size of `[[A, G], [0, 0]]`.
const N_AUG: usize = N_STATES + N_INPUTS;

/// `Phi` and `Gamma` from one exponential of the augmented matrix `[[A, G], [0, 0]] T`, whose
/// top blocks are `[Phi, Gamma]` (Van Loan, "Computing integrals involving the matrix
/// exponential", IEEE TAC 23(3), 1978).
pub fn discretize(a: &Matrix17, g: &Matrix17x2, dt_s: f64) -> Result<Discrete, DamperError> {
    let mut m = SMatrix::<f64, N_AUG, N_AUG>::zeros();
    m.fixed_view_mut::<N_STATES, N_STATES>(0, 0)
        .copy_from(&(a * dt_s));
    m.fixed_view_mut::<N_STATES, N_INPUTS>(0, N_STATES)
        .copy_from(&(g * dt_s));
    let e = expm(&m)?;
    Ok(Discrete {
        phi: e.fixed_view::<N_STATES, N_STATES>(0, 0).into_owned(),
        gamma: e.fixed_view::<N_STATES, N_INPUTS>(0, N_STATES).into_owned(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Matrix3};

    #[test]
    fn expm_of_a_rotation_generator_is_a_rotation() {
        // exp([[0, -w], [w, 0]] t) = [[cos, -sin], [sin, cos]], here with a norm that needs
        // squaring (w t = 40 > theta_13).
        let wt = 40.0;
        let e = expm(&Matrix2::new(0.0, -wt, wt, 0.0)).unwrap();
        let expected = Matrix2::new(wt.cos(), -wt.sin(), wt.sin(), wt.cos());
        assert!((e - expected).amax() < 1e-12, "{e}");
    }

    #[test]
    fn expm_of_a_jordan_block_is_analytic() {
        // exp([[l, 1, 0], [0, l, 1], [0, 0, l]]) = e^l [[1, 1, 1/2], [0, 1, 1], [0, 0, 1]].
        let l = -0.7;
        let a = Matrix3::new(l, 1.0, 0.0, 0.0, l, 1.0, 0.0, 0.0, l);
        let el = f64::exp(l);
        let expected = Matrix3::new(1.0, 1.0, 0.5, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0) * el;
        assert!((expm(&a).unwrap() - expected).amax() < 1e-14);
    }

    #[test]
    fn expm_rejects_nan() {
        assert!(expm(&Matrix2::new(f64::NAN, 0.0, 0.0, 0.0)).is_err());
    }
}
