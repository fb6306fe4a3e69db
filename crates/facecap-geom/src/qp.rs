//! Exact solver for small dense box-constrained convex quadratic programs.
//!
//! Problem (all vectors of length `n`, `H` dense row-major `n x n`, symmetric positive
//! semi-definite):
//!
//! ```text
//! minimise  q(x) = 1/2 x^T H x - g^T x     subject to  lo <= x <= hi
//! ```
//!
//! `lo`/`hi` may hold `-inf`/`+inf` (unbounded variables, e.g. pose increments in the 3D solve).
//!
//! # Method
//! [`solve_box_qp`] runs the primal active-set method [`active_set`] (Nocedal & Wright 2006,
//! "Numerical Optimization", Algorithm 16.3, specialised to bounds as Stark & Parker 1995's
//! BVLS): the working set starts as the bounds active at the warm start (at a vertex, e.g. the
//! cold start `x = 0`, every bound whose multiplier has the wrong sign is released at once and
//! the method starts from the clamped subspace minimiser of that free set, repeated while it
//! clamps; any feasible start with its active bounds as working set keeps the method exact); each
//! iteration solves the equality-constrained problem on the free set `F` with the Cholesky factor
//! of `H_FF`, updated by one-row appends and Givens deletions (`O(m^2)`, no refactorisation),
//! steps to the first blocking bound (added to the working set) or, at a subspace minimiser,
//! releases the bound with the most wrongly signed multiplier. Finite termination for positive
//! definite `H`; the KKT conditions (`grad_i >= 0` at a lower bound, `<= 0` at an upper bound,
//! `= 0` otherwise, to `kkt_tol`) certify the result. [`solve_box_qp_reuse`] also keeps the
//! factor and working set from one call to the next when the caller knows `H = c H_prev`.
//!
//! Fallback, when the active-set method stops uncertified (numerically singular `H_FF`,
//! iteration cap): projected Newton with a free-set reduced Hessian from its (feasible, never
//! worse) point (Bertsekas 1982, "Projected Newton methods for optimization problems with simple
//! constraints", SIAM J. Control Optim. 20(2)), [`projected_newton`]:
//! 1. `grad = H x - g`; stop when the KKT conditions hold to `kkt_tol`.
//! 2. Free set `F` = variables strictly inside, or at a bound with the gradient pointing inside.
//! 3. Newton direction on `F`: `H_FF d_F = -grad_F` (Cholesky), `d = 0` elsewhere.
//! 4. Projected Armijo search `x(a) = P(x + a d)`, `a = 1, 1/2, ...`; should the Newton step
//!    fail one exact coordinate-descent sweep is taken instead, which never increases `q`.
//!
//! Departure from the paper: no epsilon-active set; bounds are hit exactly because every trial
//! point is clamped, and the coordinate-descent fallback guarantees descent.
//!
//! All buffers live in [`QpWorkspace`]; [`solve_box_qp`] does not allocate once the workspace has
//! been sized for `n`.

/// Options of [`solve_box_qp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpOptions {
    /// Maximum projected-Newton iterations (the active-set method allows `4x + 2n` working-set
    /// changes).
    pub max_iterations: usize,
    /// KKT tolerance, relative to `max(1, max_i |g_i|, max_i H_ii)`.
    pub kkt_tol: f64,
}

impl Default for QpOptions {
    fn default() -> Self {
        QpOptions {
            max_iterations: 100,
            kkt_tol: 1e-10,
        }
    }
}

/// Outcome of [`solve_box_qp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpOutcome {
    /// Iterations taken.
    pub iterations: usize,
    /// Final `q(x)`.
    pub cost: f64,
    /// True when the KKT conditions hold to the tolerance.
    pub converged: bool,
    /// Largest KKT violation at the returned point (absolute).
    pub kkt_violation: f64,
}

/// Reusable buffers for [`solve_box_qp`] (sized for the largest `n` seen).
#[derive(Debug, Clone, Default)]
pub struct QpWorkspace {
    grad: Vec<f64>,
    dir: Vec<f64>,
    trial: Vec<f64>,
    delta: Vec<f64>,
    free: Vec<usize>,
    chol: Vec<f64>,
    rhs: Vec<f64>,
    mark: Vec<bool>,
    /// `chol` holds the factor of `H_FF` for `free` of the last [`active_set`] call on `n`
    /// variables (`factor_n`), reusable by [`solve_box_qp_reuse`].
    factor_valid: bool,
    factor_n: usize,
    reuses: usize,
}

impl QpWorkspace {
    /// A workspace pre-sized for problems of `n` variables.
    pub fn new(n: usize) -> Self {
        let mut ws = QpWorkspace::default();
        ws.reserve(n);
        ws
    }

    fn reserve(&mut self, n: usize) {
        for v in [
            &mut self.grad,
            &mut self.dir,
            &mut self.trial,
            &mut self.delta,
            &mut self.rhs,
        ] {
            if v.len() != n {
                v.resize(n, 0.0);
            }
        }
        if self.mark.len() != n {
            self.mark.resize(n, false);
        }
        if self.free.capacity() < n {
            self.free.reserve(n - self.free.len());
        }
        if self.chol.len() < n * n {
            self.chol.resize(n * n, 0.0);
        }
    }
}

/// `q(x) = 1/2 x^T H x - g^T x`.
pub fn qp_cost(h: &[f64], g: &[f64], x: &[f64]) -> f64 {
    let n = x.len();
    let mut c = 0.0;
    for i in 0..n {
        let row = &h[i * n..(i + 1) * n];
        let hx: f64 = row.iter().zip(x).map(|(a, b)| a * b).sum();
        c += x[i] * (0.5 * hx - g[i]);
    }
    c
}

fn kkt_violation(x: &[f64], grad: &[f64], lo: &[f64], hi: &[f64]) -> f64 {
    let mut v = 0.0f64;
    for i in 0..x.len() {
        // a fixed variable (lo == hi) has no feasible direction: any gradient is optimal there
        let vi = if lo[i] >= hi[i] {
            0.0
        } else if x[i] <= lo[i] {
            (-grad[i]).max(0.0)
        } else if x[i] >= hi[i] {
            grad[i].max(0.0)
        } else {
            grad[i].abs()
        };
        v = v.max(vi);
    }
    v
}

/// `grad = H x - g` (`H` symmetric: accumulated over the rows of the non-zero `x_j`).
fn gradient(h: &[f64], g: &[f64], x: &[f64], grad: &mut [f64]) {
    let n = x.len();
    for (gi, b) in grad.iter_mut().zip(g) {
        *gi = -b;
    }
    for j in 0..n {
        if x[j] != 0.0 {
            axpy(x[j], &h[j * n..(j + 1) * n], grad);
        }
    }
}

/// One exact coordinate-descent sweep (never increases `q`); keeps `grad` current.
fn coordinate_sweep(h: &[f64], x: &mut [f64], grad: &mut [f64], lo: &[f64], hi: &[f64]) {
    let n = x.len();
    for i in 0..n {
        let hii = h[i * n + i];
        if hii <= 0.0 {
            continue;
        }
        let xi = (x[i] - grad[i] / hii).clamp(lo[i], hi[i]);
        let d = xi - x[i];
        if d != 0.0 {
            x[i] = xi;
            for (k, gk) in grad.iter_mut().enumerate() {
                *gk += h[k * n + i] * d;
            }
        }
    }
}

/// Solves the box QP in the module docs exactly, starting from `x` (warm start; clamped into the
/// box first) and overwriting it with the solution.
///
/// Runs the primal active-set method ([`active_set`], warm-started from the bounds active at
/// `x`); should it stop without a certificate (singular reduced Hessian, iteration cap) the
/// projected-Newton method continues from its (feasible, never worse) point.
///
/// Inputs are trusted (checked with `debug_assert!`): `h.len() == n*n`, `g`, `lo`, `hi` of length
/// `n`, `lo <= hi`, `H` symmetric PSD. Callers in this crate build them from validated models.
pub fn solve_box_qp(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &mut [f64],
    opts: &QpOptions,
    ws: &mut QpWorkspace,
) -> QpOutcome {
    solve_box_qp_reuse(h, g, lo, hi, x, opts, ws, None)
}

/// Refactorise from scratch after this many consecutive factor reuses (bounds the drift of the
/// updated factor).
const MAX_REUSES: usize = 64;

/// [`solve_box_qp`] that may keep the previous call's Cholesky factor and working set.
///
/// `reuse = Some(c)` is the caller's promise that `H = c * H_prev`, with `H_prev` the Hessian of
/// the previous call on this workspace (same `n`) and `c > 0`; the factor of the previous final
/// free set is then scaled by `sqrt(c)` (`O(m^2)`) instead of recomputed (`O(m^3)`), and the
/// previous free set is the starting working set. It is ignored (full refactorisation) when the
/// workspace holds no such factor, when a variable outside the previous free set is not at a
/// bound of `x`, and after 64 consecutive reuses. The result is the same exact solution.
#[allow(clippy::too_many_arguments)]
pub fn solve_box_qp_reuse(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &mut [f64],
    opts: &QpOptions,
    ws: &mut QpWorkspace,
    reuse: Option<f64>,
) -> QpOutcome {
    let o = active_set_reuse(h, g, lo, hi, x, opts, ws, reuse);
    if o.converged {
        return o;
    }
    ws.factor_valid = false;
    let mut p = projected_newton(h, g, lo, hi, x, opts, ws);
    p.iterations += o.iterations;
    p
}

/// Appends variable `i` as the last free variable: extends the Cholesky factor `L` of `H_FF`
/// (row-major, stride `n`) by one row, `O(m^2)`. False when `H_FF` would not be numerically
/// positive definite (nothing is changed then).
fn chol_append(h: &[f64], n: usize, free: &mut Vec<usize>, l: &mut [f64], i: usize) -> bool {
    let m = free.len();
    let mut d2 = h[i * n + i];
    for a in 0..m {
        let row = &l[a * n..a * n + a];
        let mut s = h[free[a] * n + i];
        for (b, lab) in row.iter().enumerate() {
            s -= lab * l[m * n + b];
        }
        let v = s / l[a * n + a];
        l[m * n + a] = v;
        d2 -= v * v;
    }
    if !d2.is_finite() || d2 <= 1e-14 * h[i * n + i].abs() {
        return false;
    }
    l[m * n + m] = d2.sqrt();
    free.push(i);
    true
}

/// Removes the free variable at position `k` from the factor (row deletion followed by Givens
/// rotations that restore the triangle), `O(m^2)`.
fn chol_delete(n: usize, free: &mut Vec<usize>, l: &mut [f64], k: usize) {
    let m = free.len();
    for a in k + 1..m {
        for b in 0..=a {
            l[(a - 1) * n + b] = l[a * n + b];
        }
    }
    // rows k..m-1 (new numbering) now reach one column past the diagonal
    for j in k..m - 1 {
        let (a, b) = (l[j * n + j], l[j * n + j + 1]);
        let r = a.hypot(b);
        if r == 0.0 {
            continue;
        }
        let (c, s) = (a / r, b / r);
        l[j * n + j] = r;
        l[j * n + j + 1] = 0.0;
        for i in j + 1..m - 1 {
            let (u, v) = (l[i * n + j], l[i * n + j + 1]);
            l[i * n + j] = c * u + s * v;
            l[i * n + j + 1] = c * v - s * u;
        }
    }
    free.remove(k);
}

/// Solves `L L^T y = b` in place for the leading `m x m` block of a stride-`n` factor.
fn chol_solve_strided(l: &[f64], n: usize, m: usize, b: &mut [f64]) {
    for i in 0..m {
        let row = &l[i * n..i * n + i];
        let s: f64 = row.iter().zip(&b[..i]).map(|(a, c)| a * c).sum();
        b[i] = (b[i] - s) / l[i * n + i];
    }
    // L^T y = b by rows of L (contiguous): y_i = b_i / L_ii, then b_k -= L_ik y_i for k < i
    for i in (0..m).rev() {
        let yi = b[i] / l[i * n + i];
        b[i] = yi;
        for (bk, lik) in b[..i].iter_mut().zip(&l[i * n..i * n + i]) {
            *bk -= lik * yi;
        }
    }
}

/// Primal active-set method for the box QP (Nocedal & Wright 2006, Algorithm 16.3, specialised
/// to bounds; the bounded-variable least-squares scheme of Stark & Parker 1995).
///
/// The working set starts as the bounds active at the (clamped) warm start `x`, so a warm start
/// from the previous frame's solution usually needs no or very few working-set changes. Each
/// iteration solves the equality-constrained problem on the free set `F` with the Cholesky factor
/// of `H_FF`, kept up to date by one-row appends and Givens deletions (`O(m^2)` per change
/// instead of refactorising). A step that would leave the box stops at the first bound, which is
/// added to the working set; at a subspace minimiser the bound with the most wrongly signed
/// multiplier is released, one at a time. Terminates in finitely many steps for positive definite
/// `H`; the returned point satisfies the KKT conditions to rounding. Returns `converged = false`
/// (with a feasible `x` no worse than the start) when the reduced Hessian is numerically singular
/// or `4 * max_iterations + 2 n` working-set changes did not suffice.
pub fn active_set(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &mut [f64],
    opts: &QpOptions,
    ws: &mut QpWorkspace,
) -> QpOutcome {
    active_set_reuse(h, g, lo, hi, x, opts, ws, None)
}

/// [`active_set`] with the factor reuse of [`solve_box_qp_reuse`].
#[allow(clippy::too_many_arguments)]
pub fn active_set_reuse(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &mut [f64],
    opts: &QpOptions,
    ws: &mut QpWorkspace,
    reuse: Option<f64>,
) -> QpOutcome {
    let n = x.len();
    debug_assert_eq!(h.len(), n * n);
    debug_assert_eq!(g.len(), n);
    debug_assert!(lo.len() == n && hi.len() == n);
    ws.reserve(n);
    let mut scale = 1.0f64;
    for i in 0..n {
        x[i] = x[i].clamp(lo[i], hi[i]);
        scale = scale.max(g[i].abs()).max(h[i * n + i].abs());
    }
    let tol = opts.kkt_tol * scale;
    let mut reuse = reuse.filter(|c| c.is_finite() && *c > 0.0);
    if !(ws.factor_valid && ws.factor_n == n && ws.reuses < MAX_REUSES) {
        reuse = None;
    }
    ws.factor_valid = false;
    let QpWorkspace {
        grad,
        dir: u,
        rhs,
        free,
        chol: l,
        mark,
        factor_valid,
        factor_n,
        reuses,
        ..
    } = ws;
    let (grad, u, rhs, mark) = (&mut grad[..n], &mut u[..n], &mut rhs[..n], &mut mark[..n]);
    if reuse.is_some() {
        mark.fill(false);
        for &i in free.iter() {
            mark[i] = true;
        }
        if (0..n).any(|j| !mark[j] && x[j] > lo[j] && x[j] < hi[j]) {
            reuse = None;
        }
    }
    if let Some(c) = reuse {
        let r = c.sqrt();
        for a in 0..free.len() {
            for v in &mut l[a * n..a * n + a + 1] {
                *v *= r;
            }
        }
        *reuses += 1;
    } else {
        *reuses = 0;
        // starting working set: the bounds active at x (warm start: the previous solution's)
        free.clear();
        for i in 0..n {
            if x[i] > lo[i] && x[i] < hi[i] && !chol_append(h, n, free, l, i) {
                return finish(h, g, lo, hi, x, grad, 0, tol, false);
            }
        }
        if free.is_empty() {
            // a vertex (cold start at 0): release every bound whose multiplier has the wrong
            // sign at once (the projected-gradient guess); the excess then leaves again through
            // cheap blocking steps instead of one release, each with a gradient, per variable
            gradient(h, g, x, grad);
            for i in 0..n {
                let (at_lo, at_hi) = (x[i] <= lo[i], x[i] >= hi[i]);
                let release = !(at_lo && at_hi) && ((at_lo && -grad[i] > tol) || (at_hi && grad[i] > tol));
                if release && !chol_append(h, n, free, l, i) {
                    return finish(h, g, lo, hi, x, grad, 0, tol, false);
                }
            }
            // start from the clamped subspace minimiser instead of the vertex: a feasible point
            // whose working set (the clamped variables, dropped from the factor) is usually
            // close to the optimal one; any feasible start keeps the method exact
            for _round in 0..4 {
                let m = free.len();
                if m == 0 {
                    break;
                }
                u.fill(0.0);
                for j in 0..n {
                    if x[j] != 0.0 {
                        axpy(x[j], &h[j * n..(j + 1) * n], u);
                    }
                }
                for (a, &i) in free.iter().enumerate() {
                    // x_F is at its bounds here; rhs = g_F - H_FB x_B = g_F - (H x)_F + H_FF x_F
                    let mut hff = 0.0;
                    for &j in free.iter() {
                        hff += h[i * n + j] * x[j];
                    }
                    rhs[a] = g[i] - u[i] + hff;
                }
                chol_solve_strided(l, n, m, &mut rhs[..m]);
                for (a, &i) in free.iter().enumerate() {
                    x[i] = rhs[a].clamp(lo[i], hi[i]);
                }
                let mut k = free.len();
                let mut dropped = false;
                while k > 0 {
                    k -= 1;
                    let i = free[k];
                    if x[i] <= lo[i] || x[i] >= hi[i] {
                        chol_delete(n, free, l, k);
                        dropped = true;
                    }
                }
                if !dropped {
                    break;
                }
            }
        }
    }
    let cap = 4 * opts.max_iterations + 2 * n;
    let mut changes = 0;
    // u = H x_B over the fixed variables that are not zero (usually few: those at 1), kept up
    // to date as variables enter and leave the working set
    mark.fill(false);
    for &i in free.iter() {
        mark[i] = true;
    }
    u.fill(0.0);
    for j in 0..n {
        if !mark[j] && x[j] != 0.0 {
            axpy(x[j], &h[j * n..(j + 1) * n], u);
        }
    }
    loop {
        let m = free.len();
        if m > 0 {
            for (a, &i) in free.iter().enumerate() {
                rhs[a] = g[i] - u[i];
            }
            chol_solve_strided(l, n, m, &mut rhs[..m]);
            let mut alpha = 1.0f64;
            let mut block: Option<(usize, f64)> = None;
            for (a, &i) in free.iter().enumerate() {
                let (y, xi) = (rhs[a], x[i]);
                if y < lo[i] {
                    let t = (lo[i] - xi) / (y - xi);
                    if t < alpha {
                        alpha = t;
                        block = Some((a, lo[i]));
                    }
                } else if y > hi[i] {
                    let t = (hi[i] - xi) / (y - xi);
                    if t < alpha {
                        alpha = t;
                        block = Some((a, hi[i]));
                    }
                }
            }
            if let Some((k, bound)) = block {
                let alpha = alpha.max(0.0);
                for (a, &i) in free.iter().enumerate() {
                    x[i] = (x[i] + alpha * (rhs[a] - x[i])).clamp(lo[i], hi[i]);
                }
                let fixed = free[k];
                x[fixed] = bound;
                mark[fixed] = false;
                if bound != 0.0 {
                    axpy(bound, &h[fixed * n..(fixed + 1) * n], u);
                }
                chol_delete(n, free, l, k);
                changes += 1;
                if changes > cap {
                    return finish(h, g, lo, hi, x, grad, changes, tol, false);
                }
                continue;
            }
            for (a, &i) in free.iter().enumerate() {
                x[i] = rhs[a];
            }
        }
        // gradient = H x - g = u + H_{.F} x_F - g, then release the most wrongly signed bound
        grad.copy_from_slice(u);
        for &i in free.iter() {
            if x[i] != 0.0 {
                axpy(x[i], &h[i * n..(i + 1) * n], grad);
            }
        }
        for (gj, b) in grad.iter_mut().zip(g) {
            *gj -= b;
        }
        let mut worst = tol;
        let mut release = None;
        for j in 0..n {
            if mark[j] {
                continue;
            }
            let (at_lo, at_hi) = (x[j] <= lo[j], x[j] >= hi[j]);
            if at_lo && at_hi {
                continue;
            }
            let v = if at_lo { -grad[j] } else { grad[j] };
            if v > worst {
                worst = v;
                release = Some(j);
            }
        }
        let Some(j) = release else {
            break;
        };
        if !chol_append(h, n, free, l, j) {
            return finish(h, g, lo, hi, x, grad, changes, tol, false);
        }
        mark[j] = true;
        if x[j] != 0.0 {
            axpy(-x[j], &h[j * n..(j + 1) * n], u);
        }
        changes += 1;
        if changes > cap {
            return finish(h, g, lo, hi, x, grad, changes, tol, false);
        }
    }
    *factor_valid = true;
    *factor_n = n;
    // grad was computed at this x in the last pass of the loop (u is rebuilt from scratch at
    // every call and only updated a few times within it, so its rounding stays at the level of
    // one product)
    finish(h, g, lo, hi, x, grad, changes, tol, true)
}

/// `y += a x`.
#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// The outcome at `x`; `grad_current` says whether `grad` already holds `H x - g`.
#[allow(clippy::too_many_arguments)]
fn finish(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &[f64],
    grad: &mut [f64],
    iterations: usize,
    tol: f64,
    grad_current: bool,
) -> QpOutcome {
    if !grad_current {
        gradient(h, g, x, grad);
    }
    let viol = kkt_violation(x, grad, lo, hi);
    let (mut xg, mut xb) = (0.0, 0.0);
    for i in 0..x.len() {
        xg += x[i] * grad[i];
        xb += x[i] * g[i];
    }
    QpOutcome {
        iterations,
        // q = 1/2 x^T H x - g^T x = 1/2 x^T (H x - g) - 1/2 g^T x
        cost: 0.5 * xg - 0.5 * xb,
        converged: viol <= tol,
        kkt_violation: viol,
    }
}

/// Projected Newton (module docs): the fallback of [`solve_box_qp`].
pub fn projected_newton(
    h: &[f64],
    g: &[f64],
    lo: &[f64],
    hi: &[f64],
    x: &mut [f64],
    opts: &QpOptions,
    ws: &mut QpWorkspace,
) -> QpOutcome {
    let n = x.len();
    debug_assert_eq!(h.len(), n * n);
    debug_assert_eq!(g.len(), n);
    debug_assert!(lo.len() == n && hi.len() == n);
    ws.reserve(n);
    for i in 0..n {
        x[i] = x[i].clamp(lo[i], hi[i]);
    }
    let mut scale = 1.0f64;
    for i in 0..n {
        scale = scale.max(g[i].abs()).max(h[i * n + i].abs());
    }
    let tol = opts.kkt_tol * scale;
    const ARMIJO: f64 = 1e-4;
    const MAX_HALVINGS: usize = 40;
    ws.factor_valid = false;
    let QpWorkspace {
        grad,
        dir,
        trial,
        delta,
        free,
        chol,
        rhs,
        ..
    } = ws;
    let grad = &mut grad[..n];
    gradient(h, g, x, grad);
    let mut iterations = 0;
    let mut viol = kkt_violation(x, grad, lo, hi);
    while viol > tol && iterations < opts.max_iterations {
        iterations += 1;
        free.clear();
        for i in 0..n {
            let at_lo = x[i] <= lo[i] && grad[i] > 0.0;
            let at_hi = x[i] >= hi[i] && grad[i] < 0.0;
            if !(at_lo || at_hi) {
                free.push(i);
            }
        }
        let m = free.len();
        let mut stepped = false;
        if m > 0 {
            for (a, &i) in free.iter().enumerate() {
                for (b, &j) in free.iter().enumerate() {
                    chol[a * m + b] = h[i * n + j];
                }
                rhs[a] = -grad[i];
            }
            if crate::cholesky::factor(&mut chol[..m * m], m).is_ok() {
                crate::cholesky::solve_factored(&chol[..m * m], m, &mut rhs[..m]);
                dir[..n].fill(0.0);
                for (a, &i) in free.iter().enumerate() {
                    dir[i] = rhs[a];
                }
                let mut alpha = 1.0;
                for _ in 0..MAX_HALVINGS {
                    let mut gd = 0.0;
                    for i in 0..n {
                        trial[i] = (x[i] + alpha * dir[i]).clamp(lo[i], hi[i]);
                        delta[i] = trial[i] - x[i];
                        gd += grad[i] * delta[i];
                    }
                    if gd >= 0.0 {
                        alpha *= 0.5;
                        continue;
                    }
                    let mut dhd = 0.0;
                    for i in 0..n {
                        if delta[i] == 0.0 {
                            continue;
                        }
                        let row = &h[i * n..(i + 1) * n];
                        dhd += delta[i] * row.iter().zip(delta.iter()).map(|(a, b)| a * b).sum::<f64>();
                    }
                    if gd + 0.5 * dhd <= ARMIJO * gd {
                        x.copy_from_slice(&trial[..n]);
                        stepped = true;
                        break;
                    }
                    alpha *= 0.5;
                }
            }
        }
        if stepped {
            gradient(h, g, x, grad);
        } else {
            coordinate_sweep(h, x, grad, lo, hi);
        }
        viol = kkt_violation(x, grad, lo, hi);
    }
    QpOutcome {
        iterations,
        cost: qp_cost(h, g, x),
        converged: viol <= tol,
        kkt_violation: viol,
    }
}

/// Slow, obvious reference for tests: enumerates every assignment of each variable to
/// {lower bound, upper bound, free} (`3^n`, so `n <= 8`), solves the free part by Gaussian
/// elimination, and returns the feasible KKT point of least cost. `None` if `n > 8` or no KKT
/// point was found (singular `H`).
pub fn reference_box_qp(h: &[f64], g: &[f64], lo: &[f64], hi: &[f64]) -> Option<Vec<f64>> {
    let n = g.len();
    if n > 8 {
        return None;
    }
    let mut best: Option<(f64, Vec<f64>)> = None;
    let total = 3usize.pow(n as u32);
    for code in 0..total {
        let mut c = code;
        let mut state = vec![0u8; n];
        for s in state.iter_mut() {
            *s = (c % 3) as u8;
            c /= 3;
        }
        let mut x = vec![0.0; n];
        let free: Vec<usize> = (0..n).filter(|&i| state[i] == 2).collect();
        for i in 0..n {
            match state[i] {
                0 => x[i] = lo[i],
                1 => x[i] = hi[i],
                _ => {}
            }
            if !x[i].is_finite() && state[i] != 2 {
                x[i] = f64::NAN;
            }
        }
        if x.iter().enumerate().any(|(i, v)| state[i] != 2 && !v.is_finite()) {
            continue;
        }
        let m = free.len();
        if m > 0 {
            // H_FF x_F = g_F - H_FB x_B
            let mut a = vec![0.0; m * (m + 1)];
            for (r, &i) in free.iter().enumerate() {
                for (cc, &j) in free.iter().enumerate() {
                    a[r * (m + 1) + cc] = h[i * n + j];
                }
                let mut rhs = g[i];
                for j in 0..n {
                    if state[j] != 2 {
                        rhs -= h[i * n + j] * x[j];
                    }
                }
                a[r * (m + 1) + m] = rhs;
            }
            // Gaussian elimination with partial pivoting
            let mut ok = true;
            for col in 0..m {
                let piv = (col..m).max_by(|&p, &q| a[p * (m + 1) + col].abs().total_cmp(&a[q * (m + 1) + col].abs()));
                let Some(p) = piv else {
                    ok = false;
                    break;
                };
                if a[p * (m + 1) + col].abs() < 1e-12 {
                    ok = false;
                    break;
                }
                for k in 0..=m {
                    a.swap(col * (m + 1) + k, p * (m + 1) + k);
                }
                for r in 0..m {
                    if r != col {
                        let f = a[r * (m + 1) + col] / a[col * (m + 1) + col];
                        for k in col..=m {
                            a[r * (m + 1) + k] -= f * a[col * (m + 1) + k];
                        }
                    }
                }
            }
            if !ok {
                continue;
            }
            for (r, &i) in free.iter().enumerate() {
                x[i] = a[r * (m + 1) + m] / a[r * (m + 1) + r];
            }
        }
        let eps = 1e-9;
        if (0..n).any(|i| x[i] < lo[i] - eps || x[i] > hi[i] + eps) {
            continue;
        }
        let mut grad = vec![0.0; n];
        gradient(h, g, &x, &mut grad);
        let scale = 1.0 + g.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let kkt_ok = (0..n).all(|i| match state[i] {
            0 => grad[i] >= -1e-8 * scale,
            1 => grad[i] <= 1e-8 * scale,
            _ => true,
        });
        if !kkt_ok {
            continue;
        }
        let c = qp_cost(h, g, &x);
        if best.as_ref().map_or(true, |(bc, _)| c < *bc) {
            best = Some((c, x));
        }
    }
    best.map(|(_, x)| x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simple_2d() {
        // min 1/2 (x^2 + y^2) - (2x - 3y) on [0,1]^2 -> x = 1, y = 0
        let h = [1.0, 0.0, 0.0, 1.0];
        let g = [2.0, -3.0];
        let mut x = [0.5, 0.5];
        let mut ws = QpWorkspace::new(2);
        let o = solve_box_qp(&h, &g, &[0.0; 2], &[1.0; 2], &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged);
        assert_eq!(x, [1.0, 0.0]);
    }

    #[test]
    fn unbounded_variables() {
        let h = [2.0, 1.0, 1.0, 2.0];
        let g = [1.0, 1.0];
        let mut x = [0.0, 0.0];
        let mut ws = QpWorkspace::new(2);
        let inf = f64::INFINITY;
        let o = solve_box_qp(&h, &g, &[-inf; 2], &[inf; 2], &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged);
        assert!((x[0] - 1.0 / 3.0).abs() < 1e-12 && (x[1] - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn fixed_variable_pulled_outwards_is_optimal() {
        // variable 1 is fixed at 0 (lo == hi) while the data pull it up: the active-set method
        // must report convergence (no feasible direction), not fall back to projected Newton
        let h = [2.0, 0.5, 0.5, 1.0];
        let g = [1.0, 4.0];
        let mut x = [0.0, 0.0];
        let mut ws = QpWorkspace::new(2);
        let o = active_set(&h, &g, &[0.0; 2], &[1.0, 0.0], &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged, "{o:?}");
        assert!(o.kkt_violation < 1e-12, "{o:?}");
        assert!((x[0] - 0.5).abs() < 1e-12 && x[1] == 0.0, "{x:?}");
    }
}
