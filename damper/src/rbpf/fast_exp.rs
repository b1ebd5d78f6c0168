//! `exp` over a slice, written for the weights (issue 28): branch-free so that it vectorises.
//!
//! Textbook method: `x = k ln 2 + r` with `k = round(x / ln 2)` and `|r| <= ln 2 / 2`
//! (Cody-Waite: `ln 2` split in a high part with trailing zero bits, so `k * LN2_HI` is exact
//! for `|k| < 2^11`, and a low part), `exp(r)` by its Taylor series to `r^13 / 13!` (the
//! first term left out is `(ln 2 / 2)^14 / 14! = 4.5e-18`, below half an ulp), and `2^k`
//! built from the exponent bits, in two factors so that results down to the subnormals are
//! reached without an out-of-range exponent.

/// `ln 2` to 32 bits (its trailing 21 bits zero: `k * LN2_HI` is exact for `|k| <= 2^11`).
const LN2_HI: f64 = 0.693_147_180_369_123_8;
/// `ln 2 - LN2_HI`.
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
const INV_LN2: f64 = std::f64::consts::LOG2_E;
/// `1.5 * 2^52`: adding it rounds a number of magnitude below `2^51` to an integer.
const ROUND: f64 = 6_755_399_441_055_744.0;
/// Above, `exp` overflows; below, it is under half the least subnormal.
const X_MAX: f64 = 709.782_712_893_384;
const X_MIN: f64 = -745.133_219_101_941_1;

/// `1 / n!`, `n = 2..=13`, for the Taylor series of `exp(r)`.
const INV_FACT: [f64; 12] = [
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5040.0,
    1.0 / 40320.0,
    1.0 / 362_880.0,
    1.0 / 3_628_800.0,
    1.0 / 39_916_800.0,
    1.0 / 479_001_600.0,
    1.0 / 6_227_020_800.0,
];

/// `exp(x)`, branch-free: 0 below `X_MIN` (and at `-inf`), `inf` above `X_MAX`, NaN for NaN.
#[inline(always)]
pub(super) fn exp(x: f64) -> f64 {
    let xc = x.clamp(X_MIN - 1.0, X_MAX + 1.0);
    let t = xc * INV_LN2 + ROUND;
    let kf = t - ROUND;
    let r = (xc - kf * LN2_HI) - kf * LN2_LO;
    // Horner from r^13 / 13! down to 1 + r.
    let mut p = INV_FACT[11];
    for c in INV_FACT[..11].iter().rev() {
        p = p.mul_add(r, *c);
    }
    p = p.mul_add(r, 1.0);
    p = p.mul_add(r, 1.0);
    // 2^k = 2^k1 * 2^k2 with k1 = floor(k / 2): both factors normal for k in [-1076, 1025].
    // k from the bits of `t = 1.5 * 2^52 + k` (its ulp is 1), not by `kf as i64`: that
    // saturating conversion has no vector form before AVX-512DQ and made the loop scalar.
    let k = t.to_bits() as i64 - ROUND.to_bits() as i64;
    let k1 = k >> 1;
    let k2 = k - k1;
    let s1 = f64::from_bits(((k1 + 1023) as u64) << 52);
    let s2 = f64::from_bits(((k2 + 1023) as u64) << 52);
    let y = p * s1 * s2;
    let y = if x < X_MIN { 0.0 } else { y };
    let y = if x > X_MAX { f64::INFINITY } else { y };
    if x.is_nan() {
        x
    } else {
        y
    }
}

/// `v[i] = exp(v[i] + shift)`, in place.
pub(super) fn exp_shifted_in_place(v: &mut [f64], shift: f64) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            return unsafe { exp_avx512(v, shift) };
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            return unsafe { exp_avx2(v, shift) };
        }
    }
    exp_plain(v, shift)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn exp_avx512(v: &mut [f64], shift: f64) {
    exp_plain(v, shift)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn exp_avx2(v: &mut [f64], shift: f64) {
    exp_plain(v, shift)
}

#[inline(always)]
fn exp_plain(v: &mut [f64], shift: f64) {
    for x in v.iter_mut() {
        *x = exp(*x + shift);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in ulps between two positive finite numbers.
    fn ulps(a: f64, b: f64) -> u64 {
        a.to_bits().abs_diff(b.to_bits())
    }

    /// Within 2 ulp of `f64::exp` over a dense grid of the normal range, and the edges.
    #[test]
    fn exp_is_within_two_ulp_of_std() {
        let n = 2_000_000;
        let (lo, hi) = (-708.0, 709.0);
        let xs: Vec<f64> = (0..=n)
            .map(|i| lo + (hi - lo) * i as f64 / n as f64)
            .chain((0..=200_000).map(|i| -1.0 + 2.0 * i as f64 / 200_000.0))
            .collect();
        let mut ys = xs.clone();
        exp_shifted_in_place(&mut ys, 0.0);
        let mut worst = 0;
        for (x, y) in xs.iter().zip(&ys) {
            let d = ulps(*y, x.exp());
            worst = worst.max(d);
            assert!(d <= 2, "exp({x}) = {y} vs {}", x.exp());
        }
        println!("worst {worst} ulp");
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp(-800.0), 0.0);
        assert_eq!(exp(f64::INFINITY), f64::INFINITY);
        assert_eq!(exp(710.0), f64::INFINITY);
        assert!(exp(f64::NAN).is_nan());
        // Subnormal results: close in absolute terms (the last bits of a subnormal are coarse).
        for x in [-709.0, -720.0, -740.0, -745.0] {
            assert!((exp(x) - x.exp()).abs() <= 2.0 * f64::from_bits(1), "{x}");
        }
    }
}
