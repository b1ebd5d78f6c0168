//! Systematic resampling (one uniform draw, `n` evenly spaced pointers).
//!
//! Lower variance than multinomial resampling and O(n); the draw comes from the caller's
//! seeded generator, so a run repeats exactly.

use rand::Rng;

/// Fills `indices` with `indices.len()` ancestor indices drawn systematically from the
/// *normalised* log-weights `normalized_log_w`.
pub fn systematic_resample<R: Rng + ?Sized>(
    normalized_log_w: &[f64],
    indices: &mut [usize],
    rng: &mut R,
) {
    let n_out = indices.len();
    if n_out == 0 || normalized_log_w.is_empty() {
        return;
    }
    let step = 1.0 / n_out as f64;
    let mut pointer = rng.random::<f64>() * step;
    let mut cumulative = normalized_log_w[0].exp();
    let mut i = 0;
    let last = normalized_log_w.len() - 1;
    for slot in indices.iter_mut() {
        while pointer > cumulative && i < last {
            i += 1;
            cumulative += normalized_log_w[i].exp();
        }
        *slot = i;
        pointer += step;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn counts_are_within_one_of_expected() {
        let w = [0.1f64, 0.2, 0.3, 0.4];
        let log_w: Vec<f64> = w.iter().map(|v| v.ln()).collect();
        let mut idx = vec![0; 1000];
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        systematic_resample(&log_w, &mut idx, &mut rng);
        for (k, wk) in w.iter().enumerate() {
            let count = idx.iter().filter(|&&i| i == k).count() as f64;
            assert!((count - wk * 1000.0).abs() <= 1.0, "{k}: {count}");
        }
        assert!(idx.windows(2).all(|p| p[0] <= p[1]));
    }
}
