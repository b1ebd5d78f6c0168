//! `Phi(theta) x` of many particles at once: the Taylor series of the sparse `A(theta)`,
//! structure-of-arrays in blocks that the compiler vectorises.

use crate::model::{
    state, BogieModel, Matrix17x2, Vector5, MASS_ENTRIES, N_OUTPUTS, N_STATES, OUTPUT_ROWS,
    SPEED_ENTRIES,
};
use crate::params::Dampers;
use crate::DamperError;

/// `A(theta) x` with `A` sparse, plus `H x`: the structure the fast filter exploits.
#[derive(Debug, Clone)]
pub struct SparsePropagator {
    /// Non-zeros of the plant `A` without its damper terms and without the drift leak.
    entries: Vec<(usize, usize, f64)>,
    /// Non-zeros of `H` as `(output, state, value)`.
    h_entries: Vec<(usize, usize, f64)>,
    dt_s: f64,
    order: usize,
    /// `exp(-eps T) - 1`: the leak as a projector update (model docs).
    leak: f64,
    drift_basis: Matrix17x2,
    /// Rows where the drift basis is non-zero.
    drift_rows: Vec<usize>,
    /// Where the speed- and mass-dependent entries (`model::SPEED_ENTRIES`,
    /// `model::MASS_ENTRIES`) sit in `entries` and `h_entries`, so that
    /// [`SparsePropagator::set_speed`] rewrites them in place.
    speed_slots: Vec<usize>,
    h_speed_slots: Vec<usize>,
    /// `RbpfConfig::taylor_truncation`: the Taylor order is the least whose first omitted
    /// term of the stiffest creep mode is below it.
    truncation: f64,
    /// `entries` grouped by row as `(column, value)`: row `r` is
    /// `rows[row_start[r]..row_start[r + 1]]` (kept in step by `set_speed`).
    rows: Vec<(usize, f64)>,
    row_start: [usize; N_STATES + 1],
}

impl SparsePropagator {
    /// The propagator of `model`'s plant at time step `dt_s`, its Taylor series truncated
    /// at `truncation` (`RbpfConfig::taylor_truncation`).
    pub fn new(model: &BogieModel, dt_s: f64, truncation: f64) -> Result<Self, DamperError> {
        let plant = BogieModel::new(model.params(), 0.0)?;
        let mut a = plant.a_matrix(&Dampers::NOMINAL);
        a[(state::PSIB_DOT, state::PSIB_DOT)] = 0.0;
        a[(state::YSR, state::YB)] = 0.0;
        a[(state::YSR, state::YSR)] = 0.0;
        let sparse = |m: &[(usize, usize)], get: &dyn Fn(usize, usize) -> f64| {
            m.iter()
                .map(|&(r, c)| (r, c, get(r, c)))
                .filter(|e| e.2 != 0.0)
                .collect::<Vec<_>>()
        };
        let all: Vec<(usize, usize)> = (0..N_STATES)
            .flat_map(|r| (0..N_STATES).map(move |c| (r, c)))
            .collect();
        let h = model.h_matrix();
        let h_all: Vec<(usize, usize)> = (0..N_OUTPUTS)
            .flat_map(|r| (0..N_STATES).map(move |c| (r, c)))
            .collect();
        let drift_basis = *model.drift_basis();
        let entries = sparse(&all, &|r, c| a[(r, c)]);
        let h_entries = sparse(&h_all, &|r, c| h[(r, c)]);
        let scheduled =
            |rc: (usize, usize)| SPEED_ENTRIES.contains(&rc) || MASS_ENTRIES.contains(&rc);
        let speed_slots = entries
            .iter()
            .enumerate()
            .filter(|(_, e)| scheduled((e.0, e.1)))
            .map(|(k, _)| k)
            .collect();
        let h_speed_slots = h_entries
            .iter()
            .enumerate()
            .filter(|(_, e)| scheduled((OUTPUT_ROWS[e.0], e.1)))
            .map(|(k, _)| k)
            .collect();
        let mut prop = SparsePropagator {
            entries,
            h_entries,
            dt_s,
            order: 1,
            leak: (-model.drift_leak_per_s() * dt_s).exp_m1(),
            drift_rows: (0..N_STATES)
                .filter(|&r| drift_basis.row(r).amax() > 0.0)
                .collect(),
            drift_basis,
            speed_slots,
            h_speed_slots,
            truncation,
            rows: vec![],
            row_start: [0; N_STATES + 1],
        };
        prop.set_speed(model);
        Ok(prop)
    }

    /// Takes the speed- and mass-dependent entries of `A` and `H` from `model` (the filter's
    /// model at the measured speed and body mass, `BogieModel::set_speed`,
    /// `BogieModel::set_half_body_mass_kg`), and the least Taylor order that keeps the
    /// first omitted term of the stiffest creep mode below `truncation`: the creep damping
    /// grows as `1 / v`, so low speeds need more terms. Only that stiff mode is bounded: the
    /// series damper's node of a particle at 0.1 x `C_sy` (`K_sry T / C_sy` = 1.5) is stiffer
    /// still, and measured, its likelihood moved by 0.003 nats over 20 s at 1e-5 (0.035
    /// at 1e-4; `benches/accuracy.rs -- --csy-ratio 0.1`): a fast mode driven by the slow ones, whose
    /// error the data do not resolve.
    pub fn set_speed(&mut self, model: &BogieModel) {
        let a = model.a_matrix(&Dampers::NOMINAL);
        let h = model.h_matrix();
        for &k in &self.speed_slots {
            let (r, c, _) = self.entries[k];
            self.entries[k].2 = a[(r, c)];
        }
        for &k in &self.h_speed_slots {
            let (m, c, _) = self.h_entries[k];
            self.h_entries[k].2 = h[(m, c)];
        }
        // `entries` is in row-major order (built so): a row's non-zeros keep their order.
        self.rows.clear();
        let mut next_row = 0;
        for &(r, c, v) in &self.entries {
            while next_row <= r {
                self.row_start[next_row] = self.rows.len();
                next_row += 1;
            }
            self.rows.push((c, v));
        }
        self.row_start[next_row..].fill(self.rows.len());
        let stiffest = SPEED_ENTRIES
            .iter()
            .map(|&(r, c)| (a[(r, c)] * self.dt_s).abs())
            .fold(0.0, f64::max);
        let mut order = 1;
        let mut term = stiffest * stiffest / 2.0;
        // At most 60 terms: beyond that the series is no way to integrate (v -> 0).
        while term > self.truncation && order < 60 {
            order += 1;
            term *= stiffest / (order + 1) as f64;
        }
        self.order = order;
    }

    /// The Taylor order in use (see [`SparsePropagator::set_speed`]).
    pub fn order(&self) -> usize {
        self.order
    }

    /// `out = Phi_f(theta_i) x` for all `n` particles (structure-of-arrays, `x[s * n + i]`),
    /// where `yaw[i]`, `series[i]` are the damper entries of particle `i`
    /// (`DamperEntries`); in blocks of [`BLOCK`] particles.
    pub fn propagate(&self, n: usize, x: &[f64], yaw: &[f64], series: &[f64], out: &mut [f64]) {
        let mut blk = Block::new();
        let mut x_blk = [Row::ZERO; N_STATES];
        let mut acc = [Row::ZERO; N_STATES];
        for i0 in (0..n).step_by(BLOCK) {
            let len = BLOCK.min(n - i0);
            for (s, row) in x_blk.iter_mut().enumerate() {
                *row = Row::ZERO;
                row[..len].copy_from_slice(&x[s * n + i0..s * n + i0 + len]);
            }
            let (mut yaw_blk, mut series_blk) = (Row::ZERO, Row::ZERO);
            yaw_blk[..len].copy_from_slice(&yaw[i0..i0 + len]);
            series_blk[..len].copy_from_slice(&series[i0..i0 + len]);
            self.propagate_block(&x_blk, &yaw_blk, &series_blk, &Row::ONE, &mut acc, &mut blk);
            for (s, row) in acc.iter().enumerate() {
                out[s * n + i0..s * n + i0 + len].copy_from_slice(&row[..len]);
            }
        }
    }

    /// `acc = Phi_f(theta_j) x` for the particles of one block (`yaw`, `series`: their damper
    /// entries; `body`: the scale of the body's acceleration row, `m_model / m_j`, 1 when
    /// every particle runs at the model's body mass: `model::MASS_ENTRIES` are the whole row,
    /// all `~ 1 / m_bd`), by the Taylor series `sum_k (A T)^k / k!` of the sparse `A(theta_j)`. Works on
    /// whole rows of [`BLOCK`] (padding columns hold zeros), the block's partial sums held in
    /// registers: each row of a term is summed over its non-zeros (in the order of `entries`,
    /// then the damper entry) and added to the sum in one pass; the first term is read from
    /// `x`, the next ones alternate between the two buffers of `blk`.
    #[inline(always)]
    pub(super) fn propagate_block(
        &self,
        x: &[Row; N_STATES],
        yaw: &Row,
        series: &Row,
        body: &Row,
        acc: &mut [Row; N_STATES],
        blk: &mut Block,
    ) {
        *acc = *x;
        for k in 1..=self.order {
            let s = self.dt_s / k as f64;
            let (first, second) = blk.term.split_at_mut(1);
            let (src, dst) = match k {
                1 => (x, &mut first[0]),
                _ if k % 2 == 0 => (&first[0], &mut second[0]),
                _ => (&second[0], &mut first[0]),
            };
            for r in 0..N_STATES {
                let row = &self.rows[self.row_start[r]..self.row_start[r + 1]];
                let (acc, out) = (&mut acc[r], &mut dst[r]);
                match r {
                    // The two damper rows, per particle.
                    state::PSIB_DOT => term_row(s, row, src, acc, out, |j| {
                        s * yaw[j] * src[state::PSIB_DOT][j]
                    }),
                    state::YSR => term_row(s, row, src, acc, out, |j| {
                        s * series[j] * (src[state::YB][j] - src[state::YSR][j])
                    }),
                    // x 1 is exact: at the model's mass the sum is bit for bit what it was.
                    state::YBD_DOT => term_row_scaled(s, row, src, acc, out, body),
                    _ => term_row(s, row, src, acc, out, |_| 0.0),
                }
            }
        }
        // Drift leak: acc += (exp(-eps T) - 1) V W acc (A and V W commute).
        let mut w0 = [0.0; BLOCK];
        let mut w1 = [0.0; BLOCK];
        for j in 0..BLOCK {
            w0[j] = self.leak * (acc[state::YW1][j] - acc[state::D1][j]);
            w1[j] = self.leak * (acc[state::YW2][j] - acc[state::D2][j]);
        }
        for &r in &self.drift_rows {
            let (v0, v1) = (self.drift_basis[(r, 0)], self.drift_basis[(r, 1)]);
            for ((a, p), q) in acc[r].iter_mut().zip(&w0).zip(&w1) {
                *a += v0 * p + v1 * q;
            }
        }
    }

    /// `e = y - H x` for one block, the body accelerometer's row scaled by `body` (as in
    /// [`SparsePropagator::propagate_block`]: `H`'s rows are rows of `A`).
    #[inline(always)]
    pub(super) fn innovation_block(
        &self,
        x: &[Row; N_STATES],
        body: &Row,
        e: &mut [Row; N_OUTPUTS],
        y: &Vector5,
    ) {
        for (m, row) in e.iter_mut().enumerate() {
            *row = Row([y[m]; BLOCK]);
        }
        for &(m, c, v) in &self.h_entries {
            if m == BODY_OUTPUT {
                for ((e, a), b) in e[m].iter_mut().zip(x[c].iter()).zip(body.iter()) {
                    *e -= v * a * b;
                }
            } else {
                for (e, a) in e[m].iter_mut().zip(x[c].iter()) {
                    *e -= v * a;
                }
            }
        }
    }
}

/// One row of the next Taylor term, `out = sum_c (s A_rc) src_c + extra`, summed from 0 in the
/// order of `row` (bit for bit the accumulation into a zeroed row it replaces), and
/// `acc += out`. The partial sums of the whole block stay in registers (eight AVX-512
/// vectors: eight independent dependency chains; measured, chunks of 16 particles, two
/// chains, ran at half the speed).
#[inline(always)]
fn term_row(
    s: f64,
    row: &[(usize, f64)],
    src: &[Row; N_STATES],
    acc: &mut Row,
    out: &mut Row,
    extra: impl Fn(usize) -> f64,
) {
    let mut t = [0.0; BLOCK];
    for &(c, v) in row {
        let sv = s * v;
        for (tj, x) in t.iter_mut().zip(src[c].iter()) {
            *tj += sv * x;
        }
    }
    for (j, tj) in t.iter_mut().enumerate() {
        *tj += extra(j);
    }
    out.0 = t;
    for (a, tj) in acc.iter_mut().zip(&t) {
        *a += tj;
    }
}

/// [`term_row`] with the row's sum scaled per particle by `scale` before it is stored and
/// added (the body's acceleration row at each particle's own mass).
#[inline(always)]
fn term_row_scaled(
    s: f64,
    row: &[(usize, f64)],
    src: &[Row; N_STATES],
    acc: &mut Row,
    out: &mut Row,
    scale: &Row,
) {
    let mut t = [0.0; BLOCK];
    for &(c, v) in row {
        let sv = s * v;
        for (tj, x) in t.iter_mut().zip(src[c].iter()) {
            *tj += sv * x;
        }
    }
    for (tj, k) in t.iter_mut().zip(scale.iter()) {
        *tj *= k;
    }
    out.0 = t;
    for (a, tj) in acc.iter_mut().zip(&t) {
        *a += tj;
    }
}

/// The body accelerometer's place among the outputs (the `y_bd''` row of `A`).
const BODY_OUTPUT: usize = 4;
const _: () = assert!(OUTPUT_ROWS[BODY_OUTPUT] == state::YBD_DOT);

/// Particles processed together: small enough for the level-1 cache (about 35 kB), long
/// enough for the inner loops to vectorise.
pub const BLOCK: usize = 64;

/// One value of a block's particles, aligned to cache lines (a 512-byte row is then eight
/// whole lines): an unaligned vector load straddles two lines, and measured, a block kernel
/// on 16-byte-aligned rows ran 20-30 % slower than the same kernel on aligned ones.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub(super) struct Row(pub(super) [f64; BLOCK]);

impl Row {
    pub(super) const ZERO: Row = Row([0.0; BLOCK]);
    pub(super) const ONE: Row = Row([1.0; BLOCK]);
}

impl std::ops::Deref for Row {
    type Target = [f64; BLOCK];
    #[inline(always)]
    fn deref(&self) -> &[f64; BLOCK] {
        &self.0
    }
}

impl std::ops::DerefMut for Row {
    #[inline(always)]
    fn deref_mut(&mut self) -> &mut [f64; BLOCK] {
        &mut self.0
    }
}

/// Block-local working arrays, one row of [`BLOCK`] particles per state or output.
#[derive(Debug, Clone)]
pub(super) struct Block {
    /// Two Taylor terms, alternating (the last and the next).
    term: [[Row; N_STATES]; 2],
    /// The innovations.
    pub(super) e: [Row; N_OUTPUTS],
}

impl Block {
    pub(super) fn new() -> Box<Self> {
        Box::new(Block {
            term: [[Row::ZERO; N_STATES]; 2],
            e: [Row::ZERO; N_OUTPUTS],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expm::expm;
    use crate::model::Vector17;
    use crate::params::BogieParams;

    /// The sparse Taylor propagation with the leak projector equals `expm(A_f T) x`.
    #[test]
    fn sparse_propagation_equals_the_matrix_exponential() {
        let model = BogieModel::new(&BogieParams::default(), 0.1).unwrap();
        let dt = 1e-3;
        let thetas = [
            Dampers::NOMINAL,
            Dampers {
                csy_ns_per_m: 3e3,
                csay_ns_per_m: 400e3,
            },
            Dampers {
                csy_ns_per_m: 40e3,
                csay_ns_per_m: 20e3,
            },
        ];
        let n = thetas.len();
        let xs: Vec<Vector17> = (0..n)
            .map(|i| Vector17::from_fn(|s, _| ((s * 5 + i * 3) % 7) as f64 * 1e-3 - 3e-3))
            .collect();
        let mut soa = vec![0.0; N_STATES * n];
        for (i, x) in xs.iter().enumerate() {
            for s in 0..N_STATES {
                soa[s * n + i] = x[s];
            }
        }
        let unit = model.damper_entries(&Dampers {
            csy_ns_per_m: 1.0,
            csay_ns_per_m: 1.0,
        });
        let yaw: Vec<f64> = thetas
            .iter()
            .map(|d| unit.yaw_damping_per_s * d.csay_ns_per_m)
            .collect();
        let series: Vec<f64> = thetas
            .iter()
            .map(|d| unit.series_rate_per_s / d.csy_ns_per_m)
            .collect();
        let exact: Vec<Vector17> = thetas
            .iter()
            .zip(&xs)
            .map(|(d, x)| expm(&(model.a_matrix(d) * dt)).unwrap() * x)
            .collect();
        // Truncation error (relative, worst particle) falls with the order as (rho T)^k / k!.
        let mut errors = vec![];
        // The order the creep terms need (`set_speed`): at the default truncation (1e-9) 8 at
        // 45.3 m/s (`|A_ii| T` = 0.35) and 20 at 5 m/s (3.2); at 1e-5, 5 and 15.
        let order_at = |v: f64, truncation: f64| {
            let mut m = model.clone();
            m.set_speed(v).unwrap();
            SparsePropagator::new(&m, dt, truncation).unwrap().order()
        };
        assert_eq!(order_at(45.3, 1e-5), 5);
        assert_eq!(order_at(5.0, 1e-5), 15);
        assert_eq!(order_at(45.3, 1e-9), 8);
        assert_eq!(order_at(5.0, 1e-9), 20);
        for order in [8, 10, 12] {
            let mut prop = SparsePropagator::new(&model, dt, 1e-9).unwrap();
            prop.order = order;
            let mut out = soa.clone();
            prop.propagate(n, &soa, &yaw, &series, &mut out);
            let err = (0..n)
                .map(|i| {
                    let got = Vector17::from_fn(|s, _| out[s * n + i]);
                    (got - exact[i]).amax() / exact[i].amax()
                })
                .fold(0.0, f64::max);
            errors.push(err);
        }
        assert!(errors.windows(2).all(|w| w[1] < w[0] * 0.1), "{errors:?}");
        // Measured: [5e-8, 3e-10, 1.2e-12] (orders 4 and 6: 3e-4, 5e-6); the worst case is
        // the stiff series node of C_sy = 3 kN s/m (K_sry T / C_sy = 0.8), a fast mode whose
        // error the likelihood does not resolve (`SparsePropagator::set_speed`).
        assert!(errors[1] < 1e-9, "order 10: {errors:?}");
        assert!(errors[2] < 1e-11, "order 12: {errors:?}");
    }
}
