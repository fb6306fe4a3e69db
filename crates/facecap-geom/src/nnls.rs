//! Non-negative quadratic programming by sequential coordinate-wise descent
//! (Franc, Hlavac & Navara 2005, "Sequential coordinate-wise algorithm for the
//! non-negative least squares problem").
//!
//! Solves `min_x 1/2 x^T H x + f^T x` subject to `x >= 0` for symmetric positive
//! (semi-)definite `H` (`n x n`, row-major slice). For least squares `||A x - b||^2`,
//! `H = A^T A`, `f = -A^T b`. Each coordinate update is the exact minimiser along that
//! coordinate clipped at 0:
//!
//! `x_k <- max(0, x_k - g_k / H_kk)`, `g <- g + (x_k_new - x_k_old) H[:, k]`
//!
//! so the objective never increases. It stops when the KKT conditions hold to
//! `tol` (`g_k >= -tol` for `x_k = 0`, `|g_k| <= tol` for `x_k > 0`) or after
//! `max_iter` full passes. Allocation-free: the caller passes the gradient buffer.

/// Why [`solve_into`] stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NnlsStop {
    /// KKT conditions met within the tolerance.
    Converged,
    /// `max_iter` passes done.
    MaxIterations,
}

/// Outcome of [`solve_into`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NnlsReport {
    /// Full passes over the coordinates.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: NnlsStop,
}

/// Objective `1/2 x^T H x + f^T x`.
pub fn objective(h: &[f64], f: &[f64], x: &[f64]) -> f64 {
    let n = x.len();
    let mut q = 0.0;
    for r in 0..n {
        let mut hx = 0.0;
        for c in 0..n {
            hx += h[r * n + c] * x[c];
        }
        q += x[r] * (0.5 * hx + f[r]);
    }
    q
}

/// Sequential coordinate-wise NNLS, warm-started from `x` (negative entries are set to 0).
/// `grad` is scratch of length `n`. Coordinates with `H_kk <= 0` are left at 0.
pub fn solve_into(h: &[f64], f: &[f64], x: &mut [f64], grad: &mut [f64], max_iter: usize, tol: f64) -> NnlsReport {
    // Compiled for the CPU found at run time (AVX2 + FMA where available): the gradient
    // updates are axpys over rows of `h`.
    pulp::Arch::new().dispatch(Scd {
        h,
        f,
        x,
        grad,
        scratch: None,
        max_iter,
        tol,
    })
}

/// Scratch length of [`solve_polished_into`] for `n` variables.
pub fn polish_scratch_len(n: usize) -> usize {
    n * n + 2 * n
}

/// [`solve_into`] with a support polish: after every pass of the sequential
/// coordinate-wise algorithm that left the support `F = {k : x_k > 0}` unchanged,
/// the exact minimiser `z` of the objective on that face (`H_FF z = -f_F`, Cholesky)
/// is tried: the step `x <- x + t (z - x)` with the largest `t <= 1` that keeps
/// `x >= 0` (the objective decreases monotonically along the segment, `z` being the
/// minimiser on the face that contains `x`); the step is kept only if the objective
/// did not increase (checked), then the gradient is recomputed and the KKT test run.
/// The coordinate passes stay those of Franc et al.; the polish only lets the passes
/// stop after a handful instead of hundreds on ill-conditioned `H` (the 56-identity
/// block of the tensor fit). Same solution as [`solve_into`] (unique for `H > 0`).
/// `scratch` must hold at least [`polish_scratch_len`]`(n)` values.
pub fn solve_polished_into(
    h: &[f64],
    f: &[f64],
    x: &mut [f64],
    grad: &mut [f64],
    scratch: &mut [f64],
    max_iter: usize,
    tol: f64,
) -> NnlsReport {
    pulp::Arch::new().dispatch(Scd {
        h,
        f,
        x,
        grad,
        scratch: Some(scratch),
        max_iter,
        tol,
    })
}

struct Scd<'a> {
    h: &'a [f64],
    f: &'a [f64],
    x: &'a mut [f64],
    grad: &'a mut [f64],
    scratch: Option<&'a mut [f64]>,
    max_iter: usize,
    tol: f64,
}

impl pulp::WithSimd for Scd<'_> {
    type Output = NnlsReport;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> NnlsReport {
        let Scd {
            h,
            f,
            x,
            grad,
            mut scratch,
            max_iter,
            tol,
        } = self;
        let n = x.len();
        debug_assert_eq!(h.len(), n * n);
        debug_assert_eq!(f.len(), n);
        debug_assert_eq!(grad.len(), n);
        for v in x.iter_mut() {
            if v.is_nan() || *v <= 0.0 {
                *v = 0.0;
            }
        }
        gradient(h, f, x, grad);
        for it in 0..max_iter {
            let mut support_changed = false;
            for k in 0..n {
                let hkk = h[k * n + k];
                if hkk <= 0.0 {
                    continue;
                }
                let old = x[k];
                let new = (old - grad[k] / hkk).max(0.0);
                let d = new - old;
                if d != 0.0 {
                    support_changed |= (old > 0.0) != (new > 0.0);
                    x[k] = new;
                    let col = &h[k * n..(k + 1) * n]; // symmetric: row k = column k
                    for (g, hc) in grad.iter_mut().zip(col) {
                        *g += d * hc;
                    }
                }
            }
            if kkt(x, grad, tol) {
                return NnlsReport {
                    iterations: it + 1,
                    stop: NnlsStop::Converged,
                };
            }
            if let Some(sc) = scratch.as_deref_mut() {
                if !support_changed && polish(h, f, x, sc) {
                    gradient(h, f, x, grad);
                    if kkt(x, grad, tol) {
                        return NnlsReport {
                            iterations: it + 1,
                            stop: NnlsStop::Converged,
                        };
                    }
                }
            }
        }
        NnlsReport {
            iterations: max_iter,
            stop: NnlsStop::MaxIterations,
        }
    }
}

/// `grad = H x + f`.
#[inline(always)]
fn gradient(h: &[f64], f: &[f64], x: &[f64], grad: &mut [f64]) {
    let n = x.len();
    for (r, g) in grad.iter_mut().enumerate() {
        let mut acc = f[r];
        for (hv, xv) in h[r * n..(r + 1) * n].iter().zip(x.iter()) {
            acc += hv * xv;
        }
        *g = acc;
    }
}

#[inline(always)]
fn kkt(x: &[f64], grad: &[f64], tol: f64) -> bool {
    x.iter()
        .zip(grad)
        .all(|(&xv, &g)| if xv > 0.0 { g.abs() <= tol } else { g >= -tol })
}

/// The face step of [`solve_polished_into`]; returns whether `x` changed.
#[inline(always)]
fn polish(h: &[f64], f: &[f64], x: &mut [f64], scratch: &mut [f64]) -> bool {
    let n = x.len();
    let nf = x.iter().filter(|&&v| v > 0.0).count();
    if nf == 0 || scratch.len() < polish_scratch_len(n) {
        return false;
    }
    let (a, rest) = scratch.split_at_mut(nf * nf);
    let (z, rest) = rest.split_at_mut(nf);
    let backup = &mut rest[..n];
    let free = || x.iter().enumerate().filter(|(_, v)| **v > 0.0).map(|(i, _)| i);
    for (ai, i) in free().enumerate() {
        for (bj, j) in free().enumerate() {
            a[ai * nf + bj] = h[i * n + j];
        }
        z[ai] = -f[i];
    }
    if crate::cholesky::solve(a, nf, z).is_err() {
        return false;
    }
    // Largest t <= 1 keeping x + t (z - x) >= 0 on the support.
    let mut t = 1.0f64;
    let mut block = usize::MAX;
    for (ai, i) in free().enumerate() {
        if z[ai] <= 0.0 {
            let ti = x[i] / (x[i] - z[ai]);
            if ti < t {
                t = ti;
                block = ai;
            }
        }
    }
    if t.is_nan() || t <= 0.0 {
        return false;
    }
    let before = objective(h, f, x);
    backup.copy_from_slice(x);
    let mut ai = 0;
    for (i, xv) in x.iter_mut().enumerate() {
        if backup[i] > 0.0 {
            let v = if ai == block {
                0.0
            } else {
                backup[i] + t * (z[ai] - backup[i])
            };
            *xv = v.max(0.0);
            ai += 1;
        }
    }
    if objective(h, f, x) > before {
        x.copy_from_slice(backup);
        return false;
    }
    true
}

/// Slow reference: exhaustive search over active sets (only for small `n`, tests).
/// Returns the minimiser of `1/2 x^T H x + f^T x` over `x >= 0` for positive definite `H`.
pub fn reference_active_sets(h: &[f64], f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let mut best = vec![0.0; n];
    let mut best_obj = 0.0;
    for mask in 1u32..(1u32 << n) {
        let idx: Vec<usize> = (0..n).filter(|k| mask & (1 << k) != 0).collect();
        let m = idx.len();
        let hs = nalgebra::DMatrix::from_fn(m, m, |r, c| h[idx[r] * n + idx[c]]);
        let fs = nalgebra::DVector::from_fn(m, |r, _| -f[idx[r]]);
        let Some(sol) = hs.lu().solve(&fs) else { continue };
        if sol.iter().any(|&v| v < 0.0) {
            continue;
        }
        let mut x = vec![0.0; n];
        for (k, &i) in idx.iter().enumerate() {
            x[i] = sol[k];
        }
        let o = objective(h, f, &x);
        if o < best_obj {
            best_obj = o;
            best = x;
        }
    }
    best
}
