//! The forecast's small dense kernels (`crate::forecast`'s IMM recursion), written once for a
//! size known at compile time or at run time ([`Size`]): the sizes are configuration (the
//! regressor's uncertain part is 5 in the paper's setting, 10 with regression memory 2), and a
//! loop of 5 whose bound the compiler knows is unrolled, without bounds checks, where the
//! same loop over a run-time bound spends more on its control than on its arithmetic.
//! [`with_size!`] calls a kernel with a compile-time size for 1 to 12 and the run-time size
//! beyond.
//!
//! Also nalgebra's own dense operations on flat storage, each with nalgebra's operations in
//! nalgebra's order (its dynamic-size dot product, Cholesky factor and solve, small product):
//! the mixture's step must keep its rounding (docs/fuel.md, "Benchmark": `V_psi` is badly
//! conditioned and the recursion carries any difference on), and on flat storage with
//! compile-time sizes the same operations cost less than nalgebra's generic dynamic code.

/// A dimension: [`Fixed`] (known at compile time) or `usize` (at run time).
pub(crate) trait Size: Copy {
    fn get(self) -> usize;
}

/// A dimension known at compile time.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Fixed<const N: usize>;

impl<const N: usize> Size for Fixed<N> {
    #[inline(always)]
    fn get(self) -> usize {
        N
    }
}

impl Size for usize {
    #[inline(always)]
    fn get(self) -> usize {
        self
    }
}

/// `$body` with `$s` bound to the [`Size`] `$n`: a [`Fixed`] for 1 to 12, else the `usize`.
macro_rules! with_size {
    ($n:expr, |$s:ident| $body:expr) => {{
        use $crate::kernel::Fixed;
        match $n {
            1 => {
                let $s = Fixed::<1>;
                $body
            }
            2 => {
                let $s = Fixed::<2>;
                $body
            }
            3 => {
                let $s = Fixed::<3>;
                $body
            }
            4 => {
                let $s = Fixed::<4>;
                $body
            }
            5 => {
                let $s = Fixed::<5>;
                $body
            }
            6 => {
                let $s = Fixed::<6>;
                $body
            }
            7 => {
                let $s = Fixed::<7>;
                $body
            }
            8 => {
                let $s = Fixed::<8>;
                $body
            }
            9 => {
                let $s = Fixed::<9>;
                $body
            }
            10 => {
                let $s = Fixed::<10>;
                $body
            }
            11 => {
                let $s = Fixed::<11>;
                $body
            }
            12 => {
                let $s = Fixed::<12>;
                $body
            }
            n => {
                let $s: usize = n;
                $body
            }
        }
    }};
}
pub(crate) use with_size;

/// `|L x|^2` for a lower-triangular `n x n` `l` (column-major, only the lower triangle read),
/// `L x` written into `work` (length at least `n`).
#[inline(always)]
pub(crate) fn lower_times_norm_squared(
    n: impl Size,
    l: &[f64],
    x: &[f64],
    work: &mut [f64],
) -> f64 {
    let n = n.get();
    let (l, x, work) = (&l[..n * n], &x[..n], &mut work[..n]);
    work.fill(0.0);
    for b in 0..n {
        let x_b = x[b];
        for a in b..n {
            work[a] += l[b * n + a] * x_b;
        }
    }
    work.iter().map(|w| w * w).sum()
}

/// `Sigma theta` at the columns `read` into `sigma_theta` (`n x k_y`, column-major), and
/// `theta' Sigma theta` at `(u, v)`, `u, v` in `read`, into `propagated` (`k_y x k_y`,
/// column-major; `Sigma` symmetric: computed for `u <= v`, mirrored). `Sigma` is `n x n` (the
/// regressor's uncertain part), `theta` `k_psi x k_y` (column-major, `k_y` from its length)
/// with its first `n` rows read. Each column of `Sigma theta` is a sum of `Sigma`'s columns.
#[inline(always)]
pub(crate) fn propagate_covariance(
    n: impl Size,
    theta: &[f64],
    k_psi: usize,
    sigma: &[f64],
    read: &[usize],
    sigma_theta: &mut [f64],
    propagated: &mut [f64],
) {
    let n = n.get();
    let k_y = theta.len() / k_psi;
    let sigma = &sigma[..n * n];
    let theta_column = |u: usize| &theta[u * k_psi..u * k_psi + n];
    for &v in read {
        let out = &mut sigma_theta[v * n..(v + 1) * n];
        let theta_v = theta_column(v);
        out.fill(0.0);
        for b in 0..n {
            let t = theta_v[b];
            let sigma_b = &sigma[b * n..(b + 1) * n];
            for a in 0..n {
                out[a] += sigma_b[a] * t;
            }
        }
    }
    for (index, &u) in read.iter().enumerate() {
        let theta_u = theta_column(u);
        for &v in &read[index..] {
            let sigma_theta_v = &sigma_theta[v * n..(v + 1) * n];
            let mut x = 0.0;
            for a in 0..n {
                x += theta_u[a] * sigma_theta_v[a];
            }
            propagated[v * k_y + u] = x;
            propagated[u * k_y + v] = x;
        }
    }
}

/// `a . b` summed as nalgebra sums the dot product of two dynamic-size vectors (the same
/// bits): in order from 0, except that from 8 elements on, blocks of 8 go to 8 partial sums
/// first (nalgebra's `dotx`).
#[inline(always)]
pub(crate) fn nalgebra_dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut res = 0.0;
    let mut acc = [0.0; 8];
    let mut i = 0;
    while n - i >= 8 {
        for (l, acc) in acc.iter_mut().enumerate() {
            *acc += a[i + l] * b[i + l];
        }
        i += 8;
    }
    res += acc[0] + acc[4];
    res += acc[1] + acc[5];
    res += acc[2] + acc[6];
    res += acc[3] + acc[7];
    for k in i..n {
        res += a[k] * b[k];
    }
    res
}

/// `cov += (c + d d') mu` on the lower triangle of the `n x n` column-major `cov` (`c`
/// symmetric, its lower triangle read; `d` of length at least `n`).
#[inline(always)]
pub(crate) fn add_spread_lower(n: impl Size, cov: &mut [f64], c: &[f64], d: &[f64], mu: f64) {
    let n = n.get();
    let (cov, c, d) = (&mut cov[..n * n], &c[..n * n], &d[..n]);
    for b in 0..n {
        let d_b = d[b];
        for a in b..n {
            cov[b * n + a] += (c[b * n + a] + d[a] * d_b) * mu;
        }
    }
}

/// `m[(b, a)] = m[(a, b)]` for `a > b`: the lower triangle of the column-major `n x n` `m`
/// copied to the upper.
#[inline(always)]
pub(crate) fn mirror_lower(n: impl Size, m: &mut [f64]) {
    let n = n.get();
    let m = &mut m[..n * n];
    for b in 0..n {
        for a in b + 1..n {
            m[a * n + b] = m[b * n + a];
        }
    }
}

/// `L^-1` of the lower-triangular `n x n` `l` (column-major, only the lower triangle read,
/// its diagonal nonzero) into `out` (zero above the diagonal): forward substitution of each
/// unit vector, the columns independent of each other.
#[inline(always)]
pub(crate) fn lower_inverse(n: impl Size, l: &[f64], out: &mut [f64]) {
    let n = n.get();
    let (l, out) = (&l[..n * n], &mut out[..n * n]);
    out.fill(0.0);
    for j in 0..n {
        let x = &mut out[j * n..(j + 1) * n];
        x[j] = 1.0;
        for k in j..n {
            x[k] /= l[k * n + k];
            let x_k = x[k];
            for i in k + 1..n {
                x[i] -= l[k * n + i] * x_k;
            }
        }
    }
}

/// nalgebra's `Cholesky::new` of the column-major `n x n` `a` in place, the same operations
/// in the same order (so the same bits): the lower triangle becomes `L` (`a = L L'`), the
/// upper is left as it was. `false` (and `a` part-way) where a pivot is zero, negative or
/// not a number, where nalgebra answers `None`.
#[inline(always)]
pub(crate) fn cholesky_in_place(n: impl Size, a: &mut [f64]) -> bool {
    let n = n.get();
    let a = &mut a[..n * n];
    for j in 0..n {
        let (done, rest) = a.split_at_mut(j * n);
        let column = &mut rest[..n];
        for k in 0..j {
            // nalgebra's axpy: `y = (a x) 1 + 1 y` with `a = -L_jk`, the same as `y + a x`.
            let source = &done[k * n..(k + 1) * n];
            let factor = -source[j];
            for i in j..n {
                column[i] += factor * source[i];
            }
        }
        // nalgebra takes the root of a pivot that is not zero and `>= 0`: of one `> 0`.
        let diagonal = column[j];
        let root = match diagonal > 0.0 {
            true => diagonal.sqrt(),
            false => return false,
        };
        column[j] = root;
        for x in &mut column[j + 1..] {
            *x /= root;
        }
    }
    true
}

/// nalgebra's `Cholesky::solve_mut` of every column of `b` (column-major, `n` rows) with the
/// factor `l` (column-major `n x n`, its lower triangle read), the same operations in the
/// same order: per column `L y = b` forward (`b_k <- b_k + (-y_i) L_ki`), then `L' x = y`
/// backward with nalgebra's dot product. The columns' operations are independent of each
/// other and interleaved row by row (the same bits as one column after the other): each
/// row's division waits for the previous row's, and the other columns fill that wait.
#[inline(always)]
pub(crate) fn cholesky_solve_in_place(n: impl Size, l: &[f64], b: &mut [f64]) {
    cholesky_solve_each(n, |_| l, b);
}

/// [`cholesky_solve_in_place`] with column `c` of `b` solved with the factor `factor(c)`
/// (several components' solves interleaved).
#[inline(always)]
pub(crate) fn cholesky_solve_each<'a>(
    n: impl Size,
    factor: impl Fn(usize) -> &'a [f64],
    b: &mut [f64],
) {
    let n = n.get();
    let columns = b.len() / n.max(1);
    let b = &mut b[..columns * n];
    lower_solve_each(n, &factor, b);
    for i in (0..n).rev() {
        for (c, b) in b.chunks_exact_mut(n).enumerate() {
            let l = &factor(c)[..n * n];
            let dot = nalgebra_dot(&l[i * n + i + 1..(i + 1) * n], &b[i + 1..]);
            b[i] = (b[i] - dot) / l[i * n + i];
        }
    }
}

/// nalgebra's `solve_lower_triangular_mut` (and the forward half of `Cholesky::solve_mut`) of
/// every column of `b` (column-major, `n` rows) with the lower triangle of `l` (column-major
/// `n x n`, its diagonal nonzero), the same operations in the same order, the columns
/// interleaved row by row: `b_k <- b_k + (-y_i) L_ki` with `y_i = b_i / L_ii`.
#[inline(always)]
pub(crate) fn lower_solve_in_place(n: impl Size, l: &[f64], b: &mut [f64]) {
    lower_solve_each(n, |_| l, b);
}

/// [`lower_solve_in_place`] with column `c` of `b` solved with the factor `factor(c)`.
#[inline(always)]
fn lower_solve_each<'a>(n: impl Size, factor: impl Fn(usize) -> &'a [f64], b: &mut [f64]) {
    let n = n.get();
    let columns = b.len() / n.max(1);
    let b = &mut b[..columns * n];
    for i in 0..n {
        for (c, b) in b.chunks_exact_mut(n).enumerate() {
            let column = &factor(c)[i * n..(i + 1) * n];
            let coeff = b[i] / column[i];
            b[i] = coeff;
            for k in i + 1..n {
                b[k] += -coeff * column[k];
            }
        }
    }
}

/// nalgebra's product `a b` of a `rows x inner` and an `inner x cols` matrix (`a_at(i, l)`,
/// `b_at(l, j)`) below the sizes where it calls `matrixmultiply` (see [`gemm_is_nalgebras`]),
/// written into `out` (column-major `rows x cols`): each element the products in order, the
/// first without an addition (nalgebra's `gemv` per column), so the same bits.
#[inline(always)]
pub(crate) fn small_product(
    rows: usize,
    inner: usize,
    cols: usize,
    a_at: impl Fn(usize, usize) -> f64,
    b_at: impl Fn(usize, usize) -> f64,
    out: &mut [f64],
) {
    for j in 0..cols {
        for i in 0..rows {
            let mut x = a_at(i, 0) * b_at(0, j);
            for l in 1..inner {
                x += a_at(i, l) * b_at(l, j);
            }
            out[j * rows + i] = x;
        }
    }
}

/// Whether nalgebra's dynamic-size product of a `rows x inner` and an `inner x cols` matrix
/// is its own `gemv` per column, which [`small_product`] replicates (else it calls
/// `matrixmultiply`, whose order is its own: all of `rows`, `cols`, `inner` above 5).
pub(crate) fn gemm_is_nalgebras(rows: usize, inner: usize, cols: usize) -> bool {
    !(rows > 5 && cols > 5 && inner > 5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// [`nalgebra_dot`] is nalgebra's dynamic-size dot product to the bit, below and above
    /// its 8-element blocks.
    #[test]
    fn dot_is_nalgebras_to_the_bit() {
        for n in 0..=20 {
            let a = nalgebra::DVector::from_fn(n, |i, _| ((i * 13) as f64 + 0.3).sin() * 1e3);
            let b = nalgebra::DVector::from_fn(n, |i, _| ((i * 7) as f64 + 1.1).cos() / 3.0);
            let got = nalgebra_dot(a.as_slice(), b.as_slice());
            assert_eq!(got.to_bits(), a.dot(&b).to_bits(), "{n}");
        }
    }

    /// [`cholesky_in_place`] and [`cholesky_solve_in_place`] are nalgebra's `Cholesky::new`
    /// and `solve_mut` to the bit (every size 1 to 13, so beyond nalgebra's 8-element dot
    /// blocks and the compile-time sizes), and fail where nalgebra fails.
    #[test]
    fn cholesky_is_nalgebras_to_the_bit() {
        for n in 1..=13 {
            let half = DMatrix::from_fn(n, n + 2, |i, j| ((i * 31 + j * 17) as f64 + 0.4).sin());
            let spd = &half * half.transpose() + DMatrix::from_diagonal_element(n, n, 1e-3);
            let want = nalgebra::Cholesky::new(spd.clone()).expect("SPD");
            let mut got = spd.clone();
            assert!(with_size!(n, |s| cholesky_in_place(s, got.as_mut_slice())));
            assert_eq!(&got, want.l_dirty(), "{n}");
            let b = DMatrix::from_fn(n, 1, |i, _| (i as f64 * 0.7).cos() * 1e2);
            let mut want_x = b.clone();
            want.solve_mut(&mut want_x);
            let mut x = b.clone();
            with_size!(n, |s| cholesky_solve_in_place(
                s,
                got.as_slice(),
                x.as_mut_slice()
            ));
            assert_eq!(x, want_x, "{n}");
            let b3 = DMatrix::from_fn(n, 3, |i, j| ((i + 5 * j) as f64 * 0.7).cos() * 1e2);
            let mut want_x3 = b3.clone();
            want.solve_mut(&mut want_x3);
            let mut x3 = b3.clone();
            cholesky_solve_in_place(n, got.as_slice(), x3.as_mut_slice());
            assert_eq!(x3, want_x3, "{n}");
            // Each column with its own factor (here the factor and its double's).
            let want2 = nalgebra::Cholesky::new(&spd * 2.0).expect("SPD");
            let mut want_second = b.clone();
            want2.solve_mut(&mut want_second);
            let mut both = DMatrix::from_columns(&[b.column(0), b.column(0)]);
            let factors = [want.l_dirty().as_slice(), want2.l_dirty().as_slice()];
            with_size!(n, |s| cholesky_solve_each(
                s,
                |c| factors[c],
                both.as_mut_slice()
            ));
            assert_eq!(both.column(0), want_x.column(0), "{n}");
            assert_eq!(both.column(1), want_second.column(0), "{n}");
            for (rows, inner, cols) in [(n, n, n), (n, n + 2, 1), (1, n, n), (n, 5, n)] {
                if !gemm_is_nalgebras(rows, inner, cols) {
                    continue;
                }
                let a = DMatrix::from_fn(rows, inner, |i, j| ((i * 3 + j) as f64).sin());
                let b = DMatrix::from_fn(inner, cols, |i, j| ((i + 7 * j) as f64).cos());
                let mut got = DMatrix::zeros(rows, cols);
                small_product(
                    rows,
                    inner,
                    cols,
                    |i, l| a[(i, l)],
                    |l, j| b[(l, j)],
                    got.as_mut_slice(),
                );
                assert_eq!(got, &a * &b, "{rows} {inner} {cols}");
            }
            let mut indefinite = spd.clone();
            indefinite[(n - 1, n - 1)] = -1.0;
            assert!(nalgebra::Cholesky::new(indefinite.clone()).is_none());
            assert!(!cholesky_in_place(n, indefinite.as_mut_slice()));
        }
    }

    /// The kernels at a compile-time size give the run-time size's numbers to the bit, and
    /// both nalgebra's products to rounding (every size 1 to 13, so the fallback too).
    #[test]
    fn kernels_are_the_products_at_every_size() {
        let fill = |r: usize, c: usize, seed: f64| {
            DMatrix::from_fn(r, c, |i, j| ((i * 31 + j * 17) as f64 + seed).sin() * 1e2)
        };
        let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-12 * scale.max(1.0);
        for n in 1..=13 {
            let l = fill(n, n, 0.7).lower_triangle();
            let x = fill(n, 1, 1.3);
            let want = (&l * &x).norm_squared();
            let mut work = vec![0.0; n];
            let got = with_size!(n, |s| lower_times_norm_squared(
                s,
                l.as_slice(),
                x.as_slice(),
                &mut work
            ));
            let dynamic = lower_times_norm_squared(n, l.as_slice(), x.as_slice(), &mut work);
            assert_eq!(got.to_bits(), dynamic.to_bits());
            assert!(close(got, want, want), "{n}: {got} {want}");

            let mut l_inv = vec![0.0; n * n];
            let diagonal = DMatrix::from_diagonal_element(n, n, 3e2);
            let l = &l + diagonal;
            with_size!(n, |s| lower_inverse(s, l.as_slice(), &mut l_inv));
            let product = &l * DMatrix::from_column_slice(n, n, &l_inv);
            assert!(
                (product - DMatrix::identity(n, n)).abs().max() < 1e-12,
                "{n}"
            );

            let half = fill(n, n, 0.1);
            let sigma = &half * half.transpose();
            let d = fill(n, 1, 2.3);
            let mut cov = fill(n, n, 4.1).lower_triangle();
            let mut dynamic = cov.clone();
            let mut want = &cov + (&sigma + &d * d.transpose()) * 0.3;
            with_size!(n, |s| {
                add_spread_lower(s, cov.as_mut_slice(), sigma.as_slice(), d.as_slice(), 0.3);
                mirror_lower(s, cov.as_mut_slice());
            });
            add_spread_lower(
                n,
                dynamic.as_mut_slice(),
                sigma.as_slice(),
                d.as_slice(),
                0.3,
            );
            mirror_lower(n, dynamic.as_mut_slice());
            want.fill_upper_triangle_with_lower_triangle();
            assert_eq!(cov, dynamic);
            for (a, b) in cov.iter().zip(want.iter()) {
                assert!(close(*a, *b, want.abs().max()), "{n}: {a} {b}");
            }

            for k_y in 1..=6 {
                let theta = fill(n + 2, k_y, 2.9);
                let theta_u = theta.rows(0, n);
                let want_st = &sigma * theta_u;
                let want = theta_u.transpose() * &want_st;
                let read: Vec<usize> = (0..k_y).step_by(2).collect();
                let (mut st, mut got) = (vec![0.0; n * k_y], DMatrix::<f64>::zeros(k_y, k_y));
                let (mut st_dyn, mut got_dyn) = (st.clone(), got.clone());
                let t = theta.as_slice();
                with_size!(n, |s| propagate_covariance(
                    s,
                    t,
                    n + 2,
                    sigma.as_slice(),
                    &read,
                    &mut st,
                    got.as_mut_slice()
                ));
                propagate_covariance(
                    n,
                    t,
                    n + 2,
                    sigma.as_slice(),
                    &read,
                    &mut st_dyn,
                    got_dyn.as_mut_slice(),
                );
                assert_eq!((&st, &got), (&st_dyn, &got_dyn));
                for &u in &read {
                    for a in 0..n {
                        let scale = want_st.abs().max();
                        assert!(close(st[u * n + a], want_st[(a, u)], scale));
                    }
                    for &v in &read {
                        assert!(close(got[(u, v)], want[(u, v)], want.abs().max()));
                        assert_eq!(got[(u, v)].to_bits(), got[(v, u)].to_bits());
                    }
                }
            }
        }
    }
}
