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
    let n = x.len();
    debug_assert_eq!(h.len(), n * n);
    debug_assert_eq!(f.len(), n);
    debug_assert_eq!(grad.len(), n);
    for v in x.iter_mut() {
        if v.is_nan() || *v <= 0.0 {
            *v = 0.0;
        }
    }
    for r in 0..n {
        let mut g = f[r];
        for c in 0..n {
            g += h[r * n + c] * x[c];
        }
        grad[r] = g;
    }
    for it in 0..max_iter {
        for k in 0..n {
            let hkk = h[k * n + k];
            if hkk <= 0.0 {
                continue;
            }
            let old = x[k];
            let new = (old - grad[k] / hkk).max(0.0);
            let d = new - old;
            if d != 0.0 {
                x[k] = new;
                let col = &h[k * n..(k + 1) * n]; // symmetric: row k = column k
                for (g, hc) in grad.iter_mut().zip(col) {
                    *g += d * hc;
                }
            }
        }
        let kkt = x
            .iter()
            .zip(grad.iter())
            .all(|(&xv, &g)| if xv > 0.0 { g.abs() <= tol } else { g >= -tol });
        if kkt {
            return NnlsReport {
                iterations: it + 1,
                stop: NnlsStop::Converged,
            };
        }
    }
    NnlsReport {
        iterations: max_iter,
        stop: NnlsStop::MaxIterations,
    }
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
