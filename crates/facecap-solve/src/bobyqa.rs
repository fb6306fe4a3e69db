//! Our BOBYQA: bound-constrained derivative-free minimisation by quadratic interpolation
//! (Powell 2009, "The BOBYQA algorithm for bound constrained optimization without
//! derivatives", Cambridge DAMTP report NA2009/06).
//!
//! # Method
//! Minimises `f(x)` over the box `lo <= x <= hi` without derivatives. A quadratic model
//! `Q(x) = c + g^T (x - x_opt) + 1/2 (x - x_opt)^T H (x - x_opt)` interpolates `f` at `npt`
//! points (`n + 2 <= npt <= (n+1)(n+2)/2`; `2n + 1` recommended). The freedom left by the
//! interpolation conditions is taken up by minimising the Frobenius norm of the *change* of
//! `H` (the symmetric Broyden idea), so each new point changes the model by a multiple of one
//! Lagrange function. `H` is held as an explicit part `HQ` plus an implicit part
//! `sum_k PQ_k y_k y_k^T` over the interpolation points `y_k` (shifted by `XBASE`).
//!
//! The inverse of the KKT matrix of the interpolation problem, `W^-1 = [[Omega, Xi^T],
//! [Xi, Upsilon]]`, is held in factored form: `Omega = Z Z^T` with `Z` (`ZMAT`, `npt x (npt-n-1)`)
//! and the last `n` columns (`BMAT`, `(npt+n) x n`). Moving one interpolation point is a rank-2
//! update of this inverse (UPDATE, eq. (4.9)-(4.14) of the paper): `O((npt + n) n + npt (npt-n-1))`
//! work, a Givens rotation sweep of one row of `Z` and a rank-2 change of `BMAT`.
//!
//! Each iteration either
//! * takes a trust-region step: TRSBOX, a truncated conjugate-gradient method in the
//!   intersection of the ball `||d|| <= delta` and the box, with restarts when a bound becomes
//!   active and 2D "alternative" iterations on the ball boundary (paper section 3); or
//! * a geometry step ("alternative iteration") when an interpolation point is far from the
//!   trust-region centre: ALTMOV picks a point on lines through `x_opt` and other
//!   interpolation points, or a constrained Cauchy step of the Lagrange function, maximising
//!   the UPDATE denominator (paper section 4).
//!
//! `rho` (the resolution) decreases from `rho_begin` to `rho_end`: `rho <- rho/10`, or
//! `sqrt(rho rho_end)` / `rho_end` near the end, exactly as Powell's code.
//!
//! # Differences from Powell's Fortran
//! * **RESCUE is not implemented.** Powell calls it when rounding errors have damaged the
//!   UPDATE denominator (`denom <= 1/2 vlag_knew^2`, "not invoked in most applications"). Here
//!   that condition ends the run with [`BobyqaStop::Cancellation`] and the best point so far
//!   (what Powell's code does when RESCUE has just been called without progress).
//! * The explicit Hessian `HQ` is stored as a full symmetric `n x n` row-major matrix instead
//!   of packed, so Hessian-vector products are plain dense loops; `BMAT` is row-major
//!   (`(npt+n) x n`), `XPT` is row-major (`npt x n`), `ZMAT` is column-major. All arrays are
//!   allocated once in [`Bobyqa::new`] and reused for every [`Bobyqa::minimize`] call (no
//!   allocation per solve).
//! * TRSBOX works on the full model Hessian `H = HQ + sum_k PQ_k y_k y_k^T`, formed once per
//!   TRSBOX call (`npt n^2` multiply-adds in register tiles, skipped when the model has not
//!   changed since the last call); each of its Hessian-vector products then costs `n^2`
//!   instead of Powell's `n^2 + 2 npt n` (TRSBOX takes ~7 products per call at `n = 16`).
//!   The products elsewhere (gradient update after a step) stay implicit.
//! * `y_k . x_opt` (used by VLAG/BETA, the model update, ALTMOV and the Frobenius test) is
//!   cached and refreshed only when `x_opt` or the points move (the same values as Powell
//!   recomputes each time).
//! * UPDATE changes all `n` rows of the symmetric block of `BMAT` by the (symmetric) rank-2
//!   term instead of the upper triangle plus a mirror copy, so that block is symmetric up to
//!   rounding only.
//! * The whole run is one `pulp` dispatch (AVX2 + FMA where the CPU has them, portable scalar
//!   code otherwise): every loop is inlined into the dispatched function, dot products and
//!   `axpy`s run in SIMD registers with fused multiply-adds. Results therefore differ from a
//!   scalar build in the last bits, and BOBYQA's iterates (hence the evaluation count and the
//!   final point) differ by rounding from Powell's order of operations; the kernels are
//!   checked against scalar references in the tests.
//! * A NaN or infinite objective value is an error ([`Error::Numerical`]), not a silent
//!   continuation; `x` then holds the best point evaluated so far.
//!
//! # Parameters (of [`Bobyqa::minimize`])
//! | param | meaning | range |
//! |---|---|---|
//! | `n` | number of variables | `>= 2` |
//! | `npt` | interpolation points | `n + 2 ..= (n+1)(n+2)/2` |
//! | `rho_begin` | initial trust radius (units of `x`) | `> 0`, `hi - lo >= 2 rho_begin` |
//! | `rho_end` | final trust radius | `(0, rho_begin]` |
//! | `max_evals` | evaluation cap | `> npt` |

// Index loops mirror Powell's Fortran (several arrays indexed together); kept for traceability.
#![allow(clippy::needless_range_loop)]

use pulp::Simd;

use crate::error::{Error, Result};

/// Why [`Bobyqa::minimize`] stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BobyqaStop {
    /// The trust region reached `rho_end` (normal termination).
    RhoEnd,
    /// `max_evals` evaluations were used.
    MaxEvals,
    /// Rounding errors damaged the denominator of the H update (Powell would call RESCUE).
    Cancellation,
    /// A trust-region step failed to reduce the model (rounding errors).
    ModelStepFailed,
}

/// Result of [`Bobyqa::minimize`] (the minimiser itself is written into `x`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BobyqaOutcome {
    /// Objective at the returned `x`.
    pub f: f64,
    /// Number of objective evaluations.
    pub evaluations: usize,
    /// Stop reason.
    pub stop: BobyqaStop,
}

/// Settings of one [`Bobyqa::minimize`] run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BobyqaRun {
    /// Initial trust-region radius.
    pub rho_begin: f64,
    /// Final trust-region radius.
    pub rho_end: f64,
    /// Evaluation cap.
    pub max_evals: usize,
}

/// BOBYQA engine and workspace for a fixed `(n, npt)`: every array of the method, allocated
/// once and reused across [`Bobyqa::minimize`] calls.
#[derive(Debug, Clone)]
pub struct Bobyqa {
    n: usize,
    npt: usize,
    xbase: Vec<f64>,
    /// `npt x n`, row-major.
    xpt: Vec<f64>,
    fval: Vec<f64>,
    xopt: Vec<f64>,
    gopt: Vec<f64>,
    /// `n x n`, full symmetric, row-major.
    hq: Vec<f64>,
    pq: Vec<f64>,
    /// The full model Hessian `HQ + sum_k pq_k y_k y_k^T` (`n x n`, row-major), built at the
    /// start of TRSBOX so that its Hessian-vector products cost `n^2` instead of
    /// `n^2 + 2 npt n`; valid while `hfull_fresh`.
    hfull: Vec<f64>,
    hfull_fresh: bool,
    /// `npt x n` scratch of the Hessian build: `pq_k y_k`.
    hw: Vec<f64>,
    /// `y_k . xopt` for every interpolation point (used by VLAG, the model update, ALTMOV
    /// and the Frobenius test); valid while `yx_fresh`.
    yx: Vec<f64>,
    yx_fresh: bool,
    /// Diagonal of `Omega = Z Z^T` (used by the KNEW choice); valid while `hdiag_fresh`
    /// (ZMAT unchanged since it was formed).
    hdiag: Vec<f64>,
    hdiag_fresh: bool,
    /// `(npt + n) x n`, row-major.
    bmat: Vec<f64>,
    /// `npt x (npt - n - 1)`, column-major (column `jj` is `zmat[jj*npt..(jj+1)*npt]`).
    zmat: Vec<f64>,
    sl: Vec<f64>,
    su: Vec<f64>,
    xnew: Vec<f64>,
    xalt: Vec<f64>,
    d: Vec<f64>,
    vlag: Vec<f64>,
    xeval: Vec<f64>,
    // scratch
    gnew: Vec<f64>,
    xbdi: Vec<f64>,
    s: Vec<f64>,
    hs: Vec<f64>,
    hred: Vec<f64>,
    glag: Vec<f64>,
    hcol: Vec<f64>,
    wa: Vec<f64>,
    wb: Vec<f64>,
    wn: Vec<f64>,
    wn2: Vec<f64>,
    /// `npt` scratch vectors.
    wk1: Vec<f64>,
    wk2: Vec<f64>,
    wk3: Vec<f64>,
    /// `npt + n` scratch (UPDATE).
    wu: Vec<f64>,
}

/// `a . b` (equal lengths) in SIMD registers: `S::F64_LANES` partial sums (lane `i mod L`)
/// with fused multiply-adds where the CPU has them, then the scalar tail.
#[inline(always)]
fn dot<S: Simd>(simd: S, a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    let (ah, at) = S::as_simd_f64s(a);
    let (bh, bt) = S::as_simd_f64s(b);
    let mut acc = simd.splat_f64s(0.0);
    for (x, y) in ah.iter().zip(bh) {
        acc = simd.mul_add_e_f64s(*x, *y, acc);
    }
    let mut s = simd.reduce_sum_f64s(acc);
    for (x, y) in at.iter().zip(bt) {
        s += x * y;
    }
    s
}

/// `y += alpha x` (equal lengths) in SIMD registers.
#[inline(always)]
fn axpy<S: Simd>(simd: S, alpha: f64, x: &[f64], y: &mut [f64]) {
    debug_assert_eq!(x.len(), y.len());
    let (xh, xt) = S::as_simd_f64s(x);
    let (yh, yt) = S::as_mut_simd_f64s(y);
    let av = simd.splat_f64s(alpha);
    for (yv, xv) in yh.iter_mut().zip(xh) {
        *yv = simd.mul_add_e_f64s(av, *xv, *yv);
    }
    for (yi, xi) in yt.iter_mut().zip(xt) {
        *yi += alpha * xi;
    }
}

/// `(a . v, b . v)` (equal lengths) in one pass.
#[inline(always)]
fn dot2<S: Simd>(simd: S, a: &[f64], b: &[f64], v: &[f64]) -> (f64, f64) {
    debug_assert!(a.len() == v.len() && b.len() == v.len());
    let (ah, at) = S::as_simd_f64s(a);
    let (bh, bt) = S::as_simd_f64s(b);
    let (vh, vt) = S::as_simd_f64s(v);
    let mut acc_a = simd.splat_f64s(0.0);
    let mut acc_b = simd.splat_f64s(0.0);
    for ((x, y), z) in ah.iter().zip(bh).zip(vh) {
        acc_a = simd.mul_add_e_f64s(*x, *z, acc_a);
        acc_b = simd.mul_add_e_f64s(*y, *z, acc_b);
    }
    let (mut sa, mut sb) = (simd.reduce_sum_f64s(acc_a), simd.reduce_sum_f64s(acc_b));
    for ((x, y), z) in at.iter().zip(bt).zip(vt) {
        sa += x * z;
        sb += y * z;
    }
    (sa, sb)
}

/// `z += alpha x + beta y` (equal lengths) in one pass.
#[inline(always)]
fn axpy2<S: Simd>(simd: S, alpha: f64, x: &[f64], beta: f64, y: &[f64], z: &mut [f64]) {
    debug_assert!(x.len() == z.len() && y.len() == z.len());
    let (xh, xt) = S::as_simd_f64s(x);
    let (yh, yt) = S::as_simd_f64s(y);
    let (zh, zt) = S::as_mut_simd_f64s(z);
    let (av, bv) = (simd.splat_f64s(alpha), simd.splat_f64s(beta));
    for ((zv, xv), yv) in zh.iter_mut().zip(xh).zip(yh) {
        *zv = simd.mul_add_e_f64s(bv, *yv, simd.mul_add_e_f64s(av, *xv, *zv));
    }
    for ((zi, xi), yi) in zt.iter_mut().zip(xt).zip(yt) {
        *zi += alpha * xi + beta * yi;
    }
}

/// `|a - b|^2` (equal lengths) in SIMD registers.
#[inline(always)]
fn dist_sq<S: Simd>(simd: S, a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    let (ah, at) = S::as_simd_f64s(a);
    let (bh, bt) = S::as_simd_f64s(b);
    let mut acc = simd.splat_f64s(0.0);
    for (x, y) in ah.iter().zip(bh) {
        let d = simd.sub_f64s(*x, *y);
        acc = simd.mul_add_e_f64s(d, d, acc);
    }
    let mut s = simd.reduce_sum_f64s(acc);
    for (x, y) in at.iter().zip(bt) {
        s += (x - y) * (x - y);
    }
    s
}

/// `(g . (a - b), |a - b|^2)` (equal lengths) in SIMD registers; writes `a - b` into `out`.
#[inline(always)]
fn dderiv_dist<S: Simd>(simd: S, a: &[f64], b: &[f64], g: &[f64], out: &mut [f64]) -> (f64, f64) {
    debug_assert!(a.len() == b.len() && a.len() == g.len() && a.len() == out.len());
    let (ah, at) = S::as_simd_f64s(a);
    let (bh, bt) = S::as_simd_f64s(b);
    let (gh, gt) = S::as_simd_f64s(g);
    let (oh, ot) = S::as_mut_simd_f64s(out);
    let mut acc_g = simd.splat_f64s(0.0);
    let mut acc_d = simd.splat_f64s(0.0);
    for (((x, y), w), o) in ah.iter().zip(bh).zip(gh).zip(oh.iter_mut()) {
        let d = simd.sub_f64s(*x, *y);
        *o = d;
        acc_g = simd.mul_add_e_f64s(*w, d, acc_g);
        acc_d = simd.mul_add_e_f64s(d, d, acc_d);
    }
    let (mut sg, mut sd) = (simd.reduce_sum_f64s(acc_g), simd.reduce_sum_f64s(acc_d));
    for (((x, y), w), o) in at.iter().zip(bt).zip(gt).zip(ot.iter_mut()) {
        let d = x - y;
        *o = d;
        sg += w * d;
        sd += d * d;
    }
    (sg, sd)
}

/// `max_i |a_i|` in SIMD registers (0 for an empty slice).
#[inline(always)]
fn abs_max<S: Simd>(simd: S, a: &[f64]) -> f64 {
    let (ah, at) = S::as_simd_f64s(a);
    let mut acc = simd.splat_f64s(0.0);
    for x in ah {
        acc = simd.max_f64s(acc, simd.abs_f64s(*x));
    }
    at.iter().fold(simd.reduce_max_f64s(acc), |m, v| m.max(v.abs()))
}

/// Plane rotation of two equal-length vectors: `(x, y) <- (ta x + tb y, ta y - tb x)`.
#[inline(always)]
fn givens<S: Simd>(simd: S, ta: f64, tb: f64, x: &mut [f64], y: &mut [f64]) {
    debug_assert_eq!(x.len(), y.len());
    let (xh, xt) = S::as_mut_simd_f64s(x);
    let (yh, yt) = S::as_mut_simd_f64s(y);
    let (a, b) = (simd.splat_f64s(ta), simd.splat_f64s(tb));
    for (xv, yv) in xh.iter_mut().zip(yh.iter_mut()) {
        let t = simd.mul_add_e_f64s(a, *xv, simd.mul_f64s(b, *yv));
        *yv = simd.sub_f64s(simd.mul_f64s(a, *yv), simd.mul_f64s(b, *xv));
        *xv = t;
    }
    for (xi, yi) in xt.iter_mut().zip(yt.iter_mut()) {
        let t = ta * *xi + tb * *yi;
        *yi = ta * *yi - tb * *xi;
        *xi = t;
    }
}

/// The full model Hessian `H = HQ + sum_k pq_k y_k y_k^T` (`n x n`, row-major) into `h`:
/// `h_ij = HQ_ij + sum_k w_ki y_kj` with `w_k = pq_k y_k` (in `w`, `npt x n`), summed over `k`
/// in order. Two rows at a time in register tiles of four SIMD vectors (16 columns with
/// AVX2) while the interpolation points stream past; the rest one row / vector / column at
/// a time (same order of operations).
#[inline(always)]
fn build_hessian<S: Simd>(simd: S, n: usize, hq: &[f64], pq: &[f64], xpt: &[f64], w: &mut [f64], h: &mut [f64]) {
    const TILE: usize = 4;
    let lanes = S::F64_LANES;
    let nv = n / lanes; // full vectors per row
    let nt = nv * lanes; // start of the scalar tail
    let npt = pq.len();
    let (xpt, w, h) = (&xpt[..npt * n], &mut w[..npt * n], &mut h[..n * n]);
    for ((wr, y), &p) in w.chunks_exact_mut(n).zip(xpt.chunks_exact(n)).zip(pq) {
        for (a, b) in wr.iter_mut().zip(y) {
            *a = p * b;
        }
    }
    let w: &[f64] = w;
    h.copy_from_slice(&hq[..n * n]);
    let zero = simd.splat_f64s(0.0);
    let mut i = 0;
    while i < n {
        let rows = if i + 1 < n { 2 } else { 1 };
        let mut v0 = 0;
        while v0 < nv {
            let wd = TILE.min(nv - v0);
            let (c0, c1) = (v0 * lanes, (v0 + wd) * lanes);
            if rows == 2 && wd == TILE {
                let (r0, r1) = h[i * n..(i + 2) * n].split_at_mut(n);
                let h0 = S::as_mut_simd_f64s(&mut r0[c0..c1]).0;
                let h1 = S::as_mut_simd_f64s(&mut r1[c0..c1]).0;
                let mut a0 = [zero; TILE];
                let mut a1 = [zero; TILE];
                for ((a, b), (x, y)) in a0.iter_mut().zip(a1.iter_mut()).zip(h0.iter().zip(h1.iter())) {
                    *a = *x;
                    *b = *y;
                }
                for (y, wr) in xpt.chunks_exact(n).zip(w.chunks_exact(n)) {
                    let yv = S::as_simd_f64s(&y[c0..c1]).0;
                    let (b0, b1) = (simd.splat_f64s(wr[i]), simd.splat_f64s(wr[i + 1]));
                    if let Ok(yv) = <&[S::f64s; TILE]>::try_from(yv) {
                        for t in 0..TILE {
                            a0[t] = simd.mul_add_e_f64s(b0, yv[t], a0[t]);
                            a1[t] = simd.mul_add_e_f64s(b1, yv[t], a1[t]);
                        }
                    }
                }
                for ((x, y), (a, b)) in h0.iter_mut().zip(h1.iter_mut()).zip(a0.iter().zip(a1.iter())) {
                    *x = *a;
                    *y = *b;
                }
            } else {
                for r in i..i + rows {
                    let hv = S::as_mut_simd_f64s(&mut h[r * n + c0..r * n + c1]).0;
                    for (y, wr) in xpt.chunks_exact(n).zip(w.chunks_exact(n)) {
                        let yv = S::as_simd_f64s(&y[c0..c1]).0;
                        let b = simd.splat_f64s(wr[r]);
                        for (a, &yy) in hv.iter_mut().zip(yv) {
                            *a = simd.mul_add_e_f64s(b, yy, *a);
                        }
                    }
                }
            }
            v0 += wd;
        }
        for r in i..i + rows {
            for j in nt..n {
                let mut v = h[r * n + j];
                for (y, wr) in xpt.chunks_exact(n).zip(w.chunks_exact(n)) {
                    v = wr[r].mul_add(y[j], v);
                }
                h[r * n + j] = v;
            }
        }
        i += rows;
    }
}

/// `hs = H s` for the symmetric `n x n` row-major `h`, as `sum_j s_j h_j` (rows `j` with
/// `s_j = 0`, the fixed variables of TRSBOX, are skipped) with `hs` held in register tiles of
/// four SIMD vectors.
#[inline(always)]
fn sym_mul<S: Simd>(simd: S, n: usize, h: &[f64], s: &[f64], hs: &mut [f64]) {
    const TILE: usize = 4;
    let lanes = S::F64_LANES;
    let nv = n / lanes;
    let nt = nv * lanes;
    let (h, s, hs) = (&h[..n * n], &s[..n], &mut hs[..n]);
    let zero = simd.splat_f64s(0.0);
    let mut v0 = 0;
    while v0 < nv {
        let wd = TILE.min(nv - v0);
        let (c0, c1) = (v0 * lanes, (v0 + wd) * lanes);
        let mut acc = [zero; TILE];
        for (hrow, &sj) in h.chunks_exact(n).zip(s) {
            if sj != 0.0 {
                let b = simd.splat_f64s(sj);
                let hv = S::as_simd_f64s(&hrow[c0..c1]).0;
                if let Ok(hv) = <&[S::f64s; TILE]>::try_from(hv) {
                    for t in 0..TILE {
                        acc[t] = simd.mul_add_e_f64s(b, hv[t], acc[t]);
                    }
                } else {
                    for (a, &x) in acc.iter_mut().zip(hv) {
                        *a = simd.mul_add_e_f64s(b, x, *a);
                    }
                }
            }
        }
        let out = S::as_mut_simd_f64s(&mut hs[c0..c1]).0;
        for (o, a) in out.iter_mut().zip(&acc) {
            *o = *a;
        }
        v0 += wd;
    }
    for j in nt..n {
        let mut v = 0.0;
        for (hrow, &sj) in h.chunks_exact(n).zip(s) {
            v += sj * hrow[j];
        }
        hs[j] = v;
    }
}

/// `hs = (HQ + sum_k pq_k y_k y_k^T) s`.
#[inline(always)]
fn hess_mul<S: Simd>(simd: S, n: usize, hq: &[f64], pq: &[f64], xpt: &[f64], s: &[f64], hs: &mut [f64]) {
    for (h, hrow) in hs.iter_mut().zip(hq.chunks_exact(n)) {
        *h = dot(simd, hrow, s);
    }
    for (row, &p) in xpt.chunks_exact(n).zip(pq) {
        if p != 0.0 {
            let t = p * dot(simd, row, s);
            axpy(simd, t, row, hs);
        }
    }
}

// TRSBOX kernels. `xbdi` marks the variables fixed at a bound (`xbdi_i != 0`); sums run over
// the free variables only (a fixed lane contributes +0).

/// `(sum_{free} a_i b_i, sum_{free} a_i c_i, sum_{free} d_i c_i)` in one pass.
#[inline(always)]
fn free_dots3<S: Simd>(simd: S, xbdi: &[f64], a: &[f64], b: &[f64], c: &[f64], d: &[f64]) -> (f64, f64, f64) {
    let m = xbdi.len();
    debug_assert!(a.len() == m && b.len() == m && c.len() == m && d.len() == m);
    let (xh, xt) = S::as_simd_f64s(xbdi);
    let (ah, at) = S::as_simd_f64s(a);
    let (bh, bt) = S::as_simd_f64s(b);
    let (ch, ct) = S::as_simd_f64s(c);
    let (dh, dt) = S::as_simd_f64s(d);
    let zero = simd.splat_f64s(0.0);
    let (mut s0, mut s1, mut s2) = (zero, zero, zero);
    for ((((x, a), b), c), d) in xh.iter().zip(ah).zip(bh).zip(ch).zip(dh) {
        let free = simd.equal_f64s(*x, zero);
        let a = simd.select_f64s(free, *a, zero);
        let d = simd.select_f64s(free, *d, zero);
        s0 = simd.mul_add_e_f64s(a, *b, s0);
        s1 = simd.mul_add_e_f64s(a, *c, s1);
        s2 = simd.mul_add_e_f64s(d, *c, s2);
    }
    let (mut r0, mut r1, mut r2) = (
        simd.reduce_sum_f64s(s0),
        simd.reduce_sum_f64s(s1),
        simd.reduce_sum_f64s(s2),
    );
    for ((((x, a), b), c), d) in xt.iter().zip(at).zip(bt).zip(ct).zip(dt) {
        if *x == 0.0 {
            r0 += a * b;
            r1 += a * c;
            r2 += d * c;
        }
    }
    (r0, r1, r2)
}

/// Conjugate-gradient direction: `s_i = beta s_i - g_i` for the free variables, 0 for the
/// fixed ones; returns `|s|^2`.
#[inline(always)]
fn cg_direction<S: Simd>(simd: S, xbdi: &[f64], beta: f64, g: &[f64], s: &mut [f64]) -> f64 {
    debug_assert!(g.len() == xbdi.len() && s.len() == xbdi.len());
    let (xh, xt) = S::as_simd_f64s(xbdi);
    let (gh, gt) = S::as_simd_f64s(g);
    let (sh, st) = S::as_mut_simd_f64s(s);
    let zero = simd.splat_f64s(0.0);
    let bv = simd.splat_f64s(beta);
    let mut acc = zero;
    for ((x, g), sv) in xh.iter().zip(gh).zip(sh.iter_mut()) {
        let v = simd.sub_f64s(simd.mul_f64s(bv, *sv), *g);
        let v = simd.select_f64s(simd.equal_f64s(*x, zero), v, zero);
        *sv = v;
        acc = simd.mul_add_e_f64s(v, v, acc);
    }
    let mut sq = simd.reduce_sum_f64s(acc);
    for ((x, g), sv) in xt.iter().zip(gt).zip(st.iter_mut()) {
        *sv = if *x == 0.0 { beta * *sv - g } else { 0.0 };
        sq += *sv * *sv;
    }
    sq
}

/// Step of length `a` along `s`: `g += a hs`, `d += a s`; returns `sum_{free} g_i^2`.
#[inline(always)]
fn cg_step<S: Simd>(simd: S, xbdi: &[f64], a: f64, hs: &[f64], s: &[f64], g: &mut [f64], d: &mut [f64]) -> f64 {
    let m = xbdi.len();
    debug_assert!(hs.len() == m && s.len() == m && g.len() == m && d.len() == m);
    let (xh, xt) = S::as_simd_f64s(xbdi);
    let (hh, ht) = S::as_simd_f64s(hs);
    let (sh, st) = S::as_simd_f64s(s);
    let (gh, gt) = S::as_mut_simd_f64s(g);
    let (dh, dt) = S::as_mut_simd_f64s(d);
    let zero = simd.splat_f64s(0.0);
    let av = simd.splat_f64s(a);
    let mut acc = zero;
    for ((((x, h), sv), gv), dv) in xh.iter().zip(hh).zip(sh).zip(gh.iter_mut()).zip(dh.iter_mut()) {
        *gv = simd.mul_add_e_f64s(av, *h, *gv);
        *dv = simd.mul_add_e_f64s(av, *sv, *dv);
        let gf = simd.select_f64s(simd.equal_f64s(*x, zero), *gv, zero);
        acc = simd.mul_add_e_f64s(gf, gf, acc);
    }
    let mut sq = simd.reduce_sum_f64s(acc);
    for ((((x, h), sv), gv), dv) in xt.iter().zip(ht).zip(st).zip(gt.iter_mut()).zip(dt.iter_mut()) {
        *gv += a * h;
        *dv += a * sv;
        if *x == 0.0 {
            sq += *gv * *gv;
        }
    }
    sq
}

/// Rotation of TRSBOX's alternative iteration by the angle with cosine `c` and sine `t`:
/// `g += (c - 1) hred + t hs`, `hred <- c hred + t hs`, and for the free variables
/// `d <- c d + t s`; returns `(sum_{free} d_i g_i, sum_{free} g_i^2)` after the change.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn cg_rotate<S: Simd>(
    simd: S,
    xbdi: &[f64],
    c: f64,
    t: f64,
    hs: &[f64],
    s: &[f64],
    hred: &mut [f64],
    g: &mut [f64],
    d: &mut [f64],
) -> (f64, f64) {
    let m = xbdi.len();
    debug_assert!(hs.len() == m && s.len() == m && hred.len() == m && g.len() == m && d.len() == m);
    let (xh, xt) = S::as_simd_f64s(xbdi);
    let (hh, ht) = S::as_simd_f64s(hs);
    let (sh, st) = S::as_simd_f64s(s);
    let (rh, rt) = S::as_mut_simd_f64s(hred);
    let (gh, gt) = S::as_mut_simd_f64s(g);
    let (dh, dt) = S::as_mut_simd_f64s(d);
    let zero = simd.splat_f64s(0.0);
    let (cm1, cv, tv) = (simd.splat_f64s(c - 1.0), simd.splat_f64s(c), simd.splat_f64s(t));
    let (mut a0, mut a1) = (zero, zero);
    for (((((x, h), sv), rv), gv), dv) in xh
        .iter()
        .zip(hh)
        .zip(sh)
        .zip(rh.iter_mut())
        .zip(gh.iter_mut())
        .zip(dh.iter_mut())
    {
        *gv = simd.mul_add_e_f64s(cm1, *rv, simd.mul_add_e_f64s(tv, *h, *gv));
        let free = simd.equal_f64s(*x, zero);
        let dn = simd.mul_add_e_f64s(cv, *dv, simd.mul_f64s(tv, *sv));
        *dv = simd.select_f64s(free, dn, *dv);
        let gf = simd.select_f64s(free, *gv, zero);
        a0 = simd.mul_add_e_f64s(*dv, gf, a0);
        a1 = simd.mul_add_e_f64s(gf, gf, a1);
        *rv = simd.mul_add_e_f64s(cv, *rv, simd.mul_f64s(tv, *h));
    }
    let (mut dg, mut gg) = (simd.reduce_sum_f64s(a0), simd.reduce_sum_f64s(a1));
    for (((((x, h), sv), rv), gv), dv) in xt
        .iter()
        .zip(ht)
        .zip(st)
        .zip(rt.iter_mut())
        .zip(gt.iter_mut())
        .zip(dt.iter_mut())
    {
        *gv += (c - 1.0) * *rv + t * h;
        if *x == 0.0 {
            *dv = c * *dv + t * sv;
            dg += *dv * *gv;
            gg += *gv * *gv;
        }
        *rv = c * *rv + t * h;
    }
    (dg, gg)
}

/// Objective evaluation with the NaN check.
fn evaluate(f: &mut impl FnMut(&[f64]) -> f64, x: &[f64], nf: usize) -> Result<f64> {
    let v = f(x);
    if v.is_nan() || v == f64::INFINITY {
        return Err(Error::Numerical {
            operation: "bobyqa",
            reason: format!("the objective returned {v} at evaluation {nf}"),
        });
    }
    Ok(v)
}

const NONE: usize = usize::MAX;

#[derive(Clone, Copy)]
enum Lbl {
    L20,
    L60,
    L90,
    L210,
    L230,
    L360,
    L650,
    L680,
    L720,
}

/// One [`Bobyqa::minimize`] run as a `pulp` operation (see there).
struct Run<'a, F: FnMut(&[f64]) -> f64> {
    engine: &'a mut Bobyqa,
    f: &'a mut F,
    x: &'a mut [f64],
    lo: &'a [f64],
    hi: &'a [f64],
    run: &'a BobyqaRun,
    nf: &'a mut usize,
}

impl<F: FnMut(&[f64]) -> f64> pulp::WithSimd for Run<'_, F> {
    type Output = Result<BobyqaOutcome>;
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
        let Run {
            engine,
            f,
            x,
            lo,
            hi,
            run,
            nf,
        } = self;
        engine.bobyqb(simd, f, x, lo, hi, run, nf)
    }
}

impl Bobyqa {
    /// Allocates the engine for `n` variables and `npt` interpolation points.
    ///
    /// # Errors
    /// `n < 2` or `npt` outside `n + 2 ..= (n+1)(n+2)/2`.
    pub fn new(n: usize, npt: usize) -> Result<Self> {
        if n < 2 {
            return Err(Error::invalid("n", n, "at least 2 variables"));
        }
        if npt < n + 2 || npt > (n + 1) * (n + 2) / 2 {
            return Err(Error::invalid(
                "npt",
                npt,
                format!("an integer in [{}, {}]", n + 2, (n + 1) * (n + 2) / 2),
            ));
        }
        let nptm = npt - n - 1;
        let ndim = npt + n;
        let z = |m: usize| vec![0.0; m];
        Ok(Bobyqa {
            n,
            npt,
            xbase: z(n),
            xpt: z(npt * n),
            fval: z(npt),
            xopt: z(n),
            gopt: z(n),
            hq: z(n * n),
            pq: z(npt),
            hfull: z(n * n),
            hfull_fresh: false,
            hw: z(npt * n),
            yx: z(npt),
            yx_fresh: false,
            hdiag: z(npt),
            hdiag_fresh: false,
            bmat: z(ndim * n),
            zmat: z(npt * nptm),
            sl: z(n),
            su: z(n),
            xnew: z(n),
            xalt: z(n),
            d: z(n),
            vlag: z(ndim),
            xeval: z(n),
            gnew: z(n),
            xbdi: z(n),
            s: z(n),
            hs: z(n),
            hred: z(n),
            glag: z(n),
            hcol: z(npt),
            wa: z(n),
            wb: z(n),
            wn: z(n),
            wn2: z(n),
            wk1: z(npt),
            wk2: z(npt),
            wk3: z(npt),
            wu: z(ndim),
        })
    }

    /// Number of variables.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Number of interpolation points.
    pub fn npt(&self) -> usize {
        self.npt
    }

    fn validate(&self, x: &[f64], lo: &[f64], hi: &[f64], run: &BobyqaRun) -> Result<()> {
        let n = self.n;
        for (what, len) in [("x", x.len()), ("lower bounds", lo.len()), ("upper bounds", hi.len())] {
            if len != n {
                return Err(Error::DimensionMismatch {
                    what: what.into(),
                    expected: n,
                    got: len,
                });
            }
        }
        if !(run.rho_begin.is_finite() && run.rho_begin > 0.0) {
            return Err(Error::invalid("rho_begin", run.rho_begin, "a finite number > 0"));
        }
        if !(run.rho_end.is_finite() && run.rho_end > 0.0 && run.rho_end <= run.rho_begin) {
            return Err(Error::invalid(
                "rho_end",
                run.rho_end,
                "a finite number in (0, rho_begin]",
            ));
        }
        if run.max_evals <= self.npt {
            return Err(Error::invalid(
                "max_evals",
                run.max_evals,
                format!("more than npt = {}", self.npt),
            ));
        }
        for i in 0..n {
            if !x[i].is_finite() {
                return Err(Error::invalid("x0", x[i], format!("finite (component {i})")));
            }
            if lo[i].is_nan() || hi[i].is_nan() || hi[i] - lo[i] < 2.0 * run.rho_begin {
                return Err(Error::invalid(
                    "bounds",
                    format!("[{}, {}] for variable {i}", lo[i], hi[i]),
                    "hi - lo >= 2 rho_begin",
                ));
            }
        }
        Ok(())
    }

    /// Minimises `f` over `[lo, hi]` starting from `x` (overwritten with the best point).
    ///
    /// # Errors
    /// Invalid sizes/parameters/bounds (see the module table), or a NaN objective value.
    pub fn minimize(
        &mut self,
        mut f: impl FnMut(&[f64]) -> f64,
        x: &mut [f64],
        lo: &[f64],
        hi: &[f64],
        run: &BobyqaRun,
    ) -> Result<BobyqaOutcome> {
        self.validate(x, lo, hi, run)?;
        let n = self.n;
        let rhobeg = run.rho_begin;
        // Driver: move x0 away from the bounds where needed, set SL/SU.
        for j in 0..n {
            let temp = hi[j] - lo[j];
            self.sl[j] = lo[j] - x[j];
            self.su[j] = hi[j] - x[j];
            if self.sl[j] >= -rhobeg {
                if self.sl[j] >= 0.0 {
                    x[j] = lo[j];
                    self.sl[j] = 0.0;
                    self.su[j] = temp;
                } else {
                    x[j] = lo[j] + rhobeg;
                    self.sl[j] = -rhobeg;
                    self.su[j] = (hi[j] - x[j]).max(rhobeg);
                }
            } else if self.su[j] <= rhobeg {
                if self.su[j] <= 0.0 {
                    x[j] = hi[j];
                    self.sl[j] = -temp;
                    self.su[j] = 0.0;
                } else {
                    x[j] = hi[j] - rhobeg;
                    self.sl[j] = (lo[j] - x[j]).min(-rhobeg);
                    self.su[j] = rhobeg;
                }
            }
        }
        let mut nf = 0usize;
        // The whole run is compiled for the CPU found at run time (AVX2 where available:
        // every loop below is inlined into the dispatched function and vectorised there).
        let r = pulp::Arch::new().dispatch(Run {
            engine: self,
            f: &mut f,
            x,
            lo,
            hi,
            run,
            nf: &mut nf,
        });
        if r.is_err() {
            // best point so far (if any point was evaluated)
            if nf > 1 {
                let kopt = (0..self.npt.min(nf - 1))
                    .min_by(|&a, &b| self.fval[a].total_cmp(&self.fval[b]))
                    .unwrap_or(0);
                for i in 0..n {
                    x[i] = (self.xbase[i] + self.xpt[kopt * n + i]).clamp(lo[i], hi[i]);
                }
            }
        }
        r
    }

    #[inline(always)]
    fn prelim(
        &mut self,
        f: &mut impl FnMut(&[f64]) -> f64,
        x: &[f64],
        lo: &[f64],
        hi: &[f64],
        rhobeg: f64,
        nf: &mut usize,
    ) -> Result<usize> {
        let (n, npt) = (self.n, self.npt);
        let rhosq = rhobeg * rhobeg;
        let recip = 1.0 / rhosq;
        let np = n + 1;
        self.xbase.copy_from_slice(x);
        self.xpt.fill(0.0);
        self.bmat.fill(0.0);
        self.hq.fill(0.0);
        self.pq.fill(0.0);
        self.hfull_fresh = false;
        self.zmat.fill(0.0);
        self.hdiag_fresh = false;
        self.gopt.fill(0.0);
        let mut kopt = 0usize;
        let mut fbeg = 0.0;
        let (mut stepa, mut stepb) = (0.0f64, 0.0f64);
        let (mut ipt, mut jpt) = (0usize, 0usize);
        // 1-based point counter as in Powell's code; row of point nf is nf - 1.
        let mut cnt = 0usize;
        loop {
            let nfm = cnt;
            cnt += 1;
            let row = cnt - 1;
            if nfm <= 2 * n {
                if nfm >= 1 && nfm <= n {
                    stepa = rhobeg;
                    if self.su[nfm - 1] == 0.0 {
                        stepa = -stepa;
                    }
                    self.xpt[row * n + nfm - 1] = stepa;
                } else if nfm > n {
                    let nfx = nfm - n;
                    stepa = self.xpt[(cnt - n - 1) * n + nfx - 1];
                    stepb = -rhobeg;
                    if self.sl[nfx - 1] == 0.0 {
                        stepb = (2.0 * rhobeg).min(self.su[nfx - 1]);
                    }
                    if self.su[nfx - 1] == 0.0 {
                        stepb = (-2.0 * rhobeg).max(self.sl[nfx - 1]);
                    }
                    self.xpt[row * n + nfx - 1] = stepb;
                }
            } else {
                let itemp = (nfm - np) / n;
                jpt = nfm - itemp * n - n;
                ipt = jpt + itemp;
                if ipt > n {
                    let t = jpt;
                    jpt = ipt - n;
                    ipt = t;
                }
                self.xpt[row * n + ipt - 1] = self.xpt[ipt * n + ipt - 1];
                self.xpt[row * n + jpt - 1] = self.xpt[jpt * n + jpt - 1];
            }
            for j in 0..n {
                let p = self.xpt[row * n + j];
                let mut v = (self.xbase[j] + p).clamp(lo[j], hi[j]);
                if p == self.sl[j] {
                    v = lo[j];
                }
                if p == self.su[j] {
                    v = hi[j];
                }
                self.xeval[j] = v;
            }
            *nf += 1;
            let fv = evaluate(f, &self.xeval, *nf)?;
            self.fval[row] = fv;
            if cnt == 1 {
                fbeg = fv;
                kopt = 0;
            } else if fv < self.fval[kopt] {
                kopt = row;
            }
            if cnt <= 2 * n + 1 {
                if cnt >= 2 && cnt <= n + 1 {
                    let c = nfm - 1;
                    self.gopt[c] = (fv - fbeg) / stepa;
                    if npt < cnt + n {
                        self.bmat[c] = -1.0 / stepa;
                        self.bmat[(cnt - 1) * n + c] = 1.0 / stepa;
                        self.bmat[(npt + c) * n + c] = -0.5 * rhosq;
                    }
                } else if cnt >= n + 2 {
                    let c = nfm - n - 1; // 0-based variable index
                    let other = cnt - n - 1; // 0-based row of the +stepa point
                    let temp = (fv - fbeg) / stepb;
                    let diff = stepb - stepa;
                    self.hq[c * n + c] = 2.0 * (temp - self.gopt[c]) / diff;
                    self.gopt[c] = (self.gopt[c] * stepb - temp * stepa) / diff;
                    if stepa * stepb < 0.0 && fv < self.fval[other] {
                        self.fval[row] = self.fval[other];
                        self.fval[other] = fv;
                        if kopt == row {
                            kopt = other;
                        }
                        self.xpt[other * n + c] = stepb;
                        self.xpt[row * n + c] = stepa;
                    }
                    let b0 = -(stepa + stepb) / (stepa * stepb);
                    let bn = -0.5 / self.xpt[other * n + c];
                    self.bmat[c] = b0;
                    self.bmat[row * n + c] = bn;
                    self.bmat[other * n + c] = -b0 - bn;
                    let zc = &mut self.zmat[c * npt..(c + 1) * npt];
                    zc[0] = std::f64::consts::SQRT_2 / (stepa * stepb);
                    zc[row] = (0.5f64).sqrt() / rhosq;
                    zc[other] = -zc[0] - zc[row];
                }
            } else {
                let c = nfm - n - 1; // zmat column
                let zc = &mut self.zmat[c * npt..(c + 1) * npt];
                zc[0] = recip;
                zc[row] = recip;
                zc[ipt] = -recip;
                zc[jpt] = -recip;
                let temp = self.xpt[row * n + ipt - 1] * self.xpt[row * n + jpt - 1];
                let h = (fbeg - self.fval[ipt] - self.fval[jpt] + fv) / temp;
                self.hq[(ipt - 1) * n + jpt - 1] = h;
                self.hq[(jpt - 1) * n + ipt - 1] = h;
            }
            if cnt >= npt {
                break;
            }
        }
        Ok(kopt)
    }

    #[allow(clippy::too_many_lines, clippy::too_many_arguments)]
    #[inline(always)]
    fn bobyqb<S: Simd>(
        &mut self,
        simd: S,
        f: &mut impl FnMut(&[f64]) -> f64,
        x: &mut [f64],
        lo: &[f64],
        hi: &[f64],
        run: &BobyqaRun,
        nf: &mut usize,
    ) -> Result<BobyqaOutcome> {
        let (n, npt) = (self.n, self.npt);
        let maxfun = run.max_evals;
        let rhoend = run.rho_end;
        let mut kopt = self.prelim(f, x, lo, hi, run.rho_begin, nf)?;
        let mut xoptsq = 0.0;
        self.yx_fresh = false;
        for i in 0..n {
            self.xopt[i] = self.xpt[kopt * n + i];
            xoptsq += self.xopt[i] * self.xopt[i];
        }
        let mut fsave = self.fval[0];
        let kbase = 0usize;
        let mut rho = run.rho_begin;
        let mut delta = rho;
        let mut ntrits: i32 = 0;
        let (mut diffa, mut diffb, mut diffc) = (0.0f64, 0.0f64, 0.0f64);
        let mut itest = 0;
        let mut nfsav = *nf;
        let mut stop = BobyqaStop::RhoEnd;
        let mut dsq = 0.0;
        let mut crvmin;
        let mut dnorm = 0.0;
        let mut distsq = 0.0;
        let mut knew = NONE;
        let mut adelt = 0.0;
        let mut alpha = 0.0;
        let mut cauchy = 0.0;
        let mut beta = 0.0;
        let mut denom = 0.0;
        let mut ratio = 0.0;
        let mut fval_last = f64::NAN;
        let mut lbl = Lbl::L20;
        loop {
            match lbl {
                Lbl::L20 => {
                    if kopt != kbase {
                        for i in 0..n {
                            self.gopt[i] += dot(simd, &self.hq[i * n..(i + 1) * n], &self.xopt);
                        }
                        if *nf > npt {
                            self.refresh_yx(simd);
                            for k in 0..npt {
                                let row = &self.xpt[k * n..(k + 1) * n];
                                let t = self.pq[k] * self.yx[k];
                                axpy(simd, t, row, &mut self.gopt);
                            }
                        }
                    }
                    lbl = Lbl::L60;
                }
                Lbl::L60 => {
                    let (dq, cm) = self.trsbox(simd, delta);
                    dsq = dq;
                    crvmin = cm;
                    dnorm = delta.min(dsq.sqrt());
                    if dnorm < 0.5 * rho {
                        ntrits = -1;
                        distsq = (10.0 * rho) * (10.0 * rho);
                        if *nf <= nfsav + 2 {
                            lbl = Lbl::L650;
                            continue;
                        }
                        let errbig = diffa.max(diffb).max(diffc);
                        let frhosq = 0.125 * rho * rho;
                        if crvmin > 0.0 && errbig > frhosq * crvmin {
                            lbl = Lbl::L650;
                            continue;
                        }
                        let bdtol = errbig / rho;
                        let mut go650 = false;
                        for j in 0..n {
                            let mut bdtest = bdtol;
                            if self.xnew[j] == self.sl[j] {
                                bdtest = self.gnew[j];
                            }
                            if self.xnew[j] == self.su[j] {
                                bdtest = -self.gnew[j];
                            }
                            if bdtest < bdtol {
                                let mut curv = self.hq[j * n + j];
                                for k in 0..npt {
                                    let v = self.xpt[k * n + j];
                                    curv += self.pq[k] * v * v;
                                }
                                bdtest += 0.5 * curv * rho;
                                if bdtest < bdtol {
                                    go650 = true;
                                    break;
                                }
                            }
                        }
                        lbl = if go650 { Lbl::L650 } else { Lbl::L680 };
                        continue;
                    }
                    ntrits += 1;
                    lbl = Lbl::L90;
                }
                Lbl::L90 => {
                    if dsq <= 1.0e-3 * xoptsq {
                        self.shift_base(simd, xoptsq);
                        xoptsq = 0.0;
                    }
                    lbl = if ntrits == 0 { Lbl::L210 } else { Lbl::L230 };
                }
                Lbl::L210 => {
                    let (a, c) = self.altmov(simd, kopt, knew, adelt);
                    alpha = a;
                    cauchy = c;
                    for i in 0..n {
                        self.d[i] = self.xnew[i] - self.xopt[i];
                    }
                    lbl = Lbl::L230;
                }
                Lbl::L230 => {
                    beta = self.vlag_beta(simd, kopt, xoptsq);
                    if ntrits == 0 {
                        let vk = self.vlag[knew];
                        denom = vk * vk + alpha * beta;
                        if denom < cauchy && cauchy > 0.0 {
                            for i in 0..n {
                                self.xnew[i] = self.xalt[i];
                                self.d[i] = self.xnew[i] - self.xopt[i];
                            }
                            cauchy = 0.0;
                            continue; // L230 again
                        }
                        if denom <= 0.5 * vk * vk {
                            stop = BobyqaStop::Cancellation;
                            lbl = Lbl::L720;
                            continue;
                        }
                    } else {
                        let (k, den, ok) = self.choose_knew(simd, kopt, beta, delta, false);
                        if !ok || k == NONE {
                            stop = BobyqaStop::Cancellation;
                            lbl = Lbl::L720;
                            continue;
                        }
                        knew = k;
                        denom = den;
                    }
                    lbl = Lbl::L360;
                }
                Lbl::L360 => {
                    for i in 0..n {
                        let mut v = (self.xbase[i] + self.xnew[i]).clamp(lo[i], hi[i]);
                        if self.xnew[i] == self.sl[i] {
                            v = lo[i];
                        }
                        if self.xnew[i] == self.su[i] {
                            v = hi[i];
                        }
                        self.xeval[i] = v;
                    }
                    if *nf >= maxfun {
                        stop = BobyqaStop::MaxEvals;
                        lbl = Lbl::L720;
                        continue;
                    }
                    *nf += 1;
                    let fv = evaluate(f, &self.xeval, *nf)?;
                    fval_last = fv;
                    if ntrits == -1 {
                        fsave = fv;
                        x.copy_from_slice(&self.xeval);
                        lbl = Lbl::L720;
                        continue;
                    }
                    let fopt = self.fval[kopt];
                    // predicted change: d^T g + 1/2 d^T H d
                    let mut vquad = dot(simd, &self.d, &self.gopt);
                    let mut dhd = 0.0;
                    for i in 0..n {
                        dhd += self.d[i] * dot(simd, &self.hq[i * n..(i + 1) * n], &self.d);
                    }
                    vquad += 0.5 * dhd;
                    for k in 0..npt {
                        vquad += 0.5 * self.pq[k] * self.wk2[k] * self.wk2[k];
                    }
                    let diff = fv - fopt - vquad;
                    diffc = diffb;
                    diffb = diffa;
                    diffa = diff.abs();
                    if dnorm > rho {
                        nfsav = *nf;
                    }
                    if ntrits > 0 {
                        if vquad >= 0.0 {
                            stop = BobyqaStop::ModelStepFailed;
                            lbl = Lbl::L720;
                            continue;
                        }
                        ratio = (fv - fopt) / vquad;
                        if ratio <= 0.1 {
                            delta = (0.5 * delta).min(dnorm);
                        } else if ratio <= 0.7 {
                            delta = (0.5 * delta).max(dnorm);
                        } else {
                            delta = (0.5 * delta).max(dnorm + dnorm);
                        }
                        if delta <= 1.5 * rho {
                            delta = rho;
                        }
                        if fv < fopt {
                            let (k, den, ok) = self.choose_knew(simd, kopt, beta, delta, true);
                            if ok && k != NONE {
                                knew = k;
                                denom = den;
                            }
                        }
                    }
                    self.update(simd, beta, denom, knew);
                    self.model_update(simd, knew, diff, fv);
                    if fv < fopt {
                        kopt = knew;
                        xoptsq = 0.0;
                        self.yx_fresh = false;
                        for j in 0..n {
                            self.xopt[j] = self.xnew[j];
                            xoptsq += self.xopt[j] * self.xopt[j];
                        }
                        // gopt += H d
                        hess_mul(simd, n, &self.hq, &self.pq, &self.xpt, &self.d, &mut self.hs);
                        for i in 0..n {
                            self.gopt[i] += self.hs[i];
                        }
                    }
                    if ntrits > 0 {
                        itest = self.frobenius_test(simd, kopt, itest);
                    }
                    if ntrits == 0 || fv <= fopt + 0.1 * vquad {
                        lbl = Lbl::L60;
                        continue;
                    }
                    distsq = (4.0 * delta * delta).max(100.0 * rho * rho);
                    lbl = Lbl::L650;
                }
                Lbl::L650 => {
                    knew = NONE;
                    for k in 0..npt {
                        let sum = dist_sq(simd, &self.xpt[k * n..(k + 1) * n], &self.xopt);
                        if sum > distsq {
                            knew = k;
                            distsq = sum;
                        }
                    }
                    if knew != NONE {
                        let dist = distsq.sqrt();
                        if ntrits == -1 {
                            delta = (0.1 * delta).min(0.5 * dist);
                            if delta <= 1.5 * rho {
                                delta = rho;
                            }
                        }
                        ntrits = 0;
                        adelt = (0.1 * dist).min(delta).max(rho);
                        dsq = adelt * adelt;
                        lbl = Lbl::L90;
                        continue;
                    }
                    if ntrits == -1 {
                        lbl = Lbl::L680;
                    } else if ratio > 0.0 || delta.max(dnorm) > rho {
                        lbl = Lbl::L60;
                    } else {
                        lbl = Lbl::L680;
                    }
                }
                Lbl::L680 => {
                    if rho > rhoend {
                        delta = 0.5 * rho;
                        ratio = rho / rhoend;
                        if ratio <= 16.0 {
                            rho = rhoend;
                        } else if ratio <= 250.0 {
                            rho = ratio.sqrt() * rhoend;
                        } else {
                            rho *= 0.1;
                        }
                        delta = delta.max(rho);
                        ntrits = 0;
                        nfsav = *nf;
                        lbl = Lbl::L60;
                        continue;
                    }
                    lbl = if ntrits == -1 { Lbl::L360 } else { Lbl::L720 };
                }
                Lbl::L720 => {
                    let mut fret = fval_last;
                    if self.fval[kopt] <= fsave {
                        for i in 0..n {
                            let mut v = (self.xbase[i] + self.xopt[i]).clamp(lo[i], hi[i]);
                            if self.xopt[i] == self.sl[i] {
                                v = lo[i];
                            }
                            if self.xopt[i] == self.su[i] {
                                v = hi[i];
                            }
                            x[i] = v;
                        }
                        fret = self.fval[kopt];
                    }
                    return Ok(BobyqaOutcome {
                        f: fret,
                        evaluations: *nf,
                        stop,
                    });
                }
            }
        }
    }

    /// Recomputes the cached `y_k . xopt` unless still valid.
    #[inline(always)]
    fn refresh_yx<S: Simd>(&mut self, simd: S) {
        if !self.yx_fresh {
            let n = self.n;
            for (v, row) in self.yx.iter_mut().zip(self.xpt.chunks_exact(n)) {
                *v = dot(simd, row, &self.xopt);
            }
            self.yx_fresh = true;
        }
    }

    /// Shift of `XBASE` to `XOPT` (label 90 of BOBYQB): BMAT and the model's second
    /// derivatives are revised so that the model and the H matrix are unchanged.
    #[inline(always)]
    fn shift_base<S: Simd>(&mut self, simd: S, xoptsq: f64) {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        self.hfull_fresh = false;
        self.yx_fresh = false;
        let fracsq = 0.25 * xoptsq;
        let mut sumpq = 0.0;
        // wk1[k] = y_k . xopt - |xopt|^2/2
        for k in 0..npt {
            sumpq += self.pq[k];
            let row = &self.xpt[k * n..(k + 1) * n];
            let sum = dot(simd, row, &self.xopt) - 0.5 * xoptsq;
            self.wk1[k] = sum;
            let temp = fracsq - 0.5 * sum;
            for i in 0..n {
                self.wn[i] = self.bmat[k * n + i];
                self.wn2[i] = sum * row[i] + temp * self.xopt[i];
            }
            for i in 0..n {
                let b = &mut self.bmat[(npt + i) * n..(npt + i + 1) * n];
                let (wi, vi) = (self.wn[i], self.wn2[i]);
                axpy(simd, wi, &self.wn2[..=i], &mut b[..=i]);
                axpy(simd, vi, &self.wn[..=i], &mut b[..=i]);
            }
        }
        for jj in 0..nptm {
            let zc = &self.zmat[jj * npt..(jj + 1) * npt];
            let mut sumz = 0.0;
            let mut sumw = 0.0;
            for k in 0..npt {
                sumz += zc[k];
                self.wk3[k] = self.wk1[k] * zc[k];
                sumw += self.wk3[k];
            }
            let c = fracsq * sumz - 0.5 * sumw;
            for j in 0..n {
                self.wn[j] = c * self.xopt[j];
            }
            for k in 0..npt {
                axpy(simd, self.wk3[k], &self.xpt[k * n..(k + 1) * n], &mut self.wn);
            }
            for k in 0..npt {
                axpy(simd, zc[k], &self.wn, &mut self.bmat[k * n..(k + 1) * n]);
            }
            for i in 0..n {
                let b = &mut self.bmat[(npt + i) * n..(npt + i + 1) * n];
                let wi = self.wn[i];
                axpy(simd, wi, &self.wn[..=i], &mut b[..=i]);
            }
        }
        // complete the shift: HQ, the symmetric block of BMAT, XPT
        for j in 0..n {
            self.wn[j] = -0.5 * sumpq * self.xopt[j];
        }
        for k in 0..npt {
            axpy(simd, self.pq[k], &self.xpt[k * n..(k + 1) * n], &mut self.wn);
            for j in 0..n {
                self.xpt[k * n + j] -= self.xopt[j];
            }
        }
        for i in 0..n {
            for j in 0..n {
                self.hq[i * n + j] += self.wn[i] * self.xopt[j] + self.xopt[i] * self.wn[j];
            }
        }
        for i in 0..n {
            for j in (i + 1)..n {
                self.bmat[(npt + i) * n + j] = self.bmat[(npt + j) * n + i];
            }
        }
        for i in 0..n {
            self.xbase[i] += self.xopt[i];
            self.xnew[i] -= self.xopt[i];
            self.sl[i] -= self.xopt[i];
            self.su[i] -= self.xopt[i];
            self.xopt[i] = 0.0;
        }
    }

    /// VLAG (values of the Lagrange functions at `xopt + d`, and the last `n` components of
    /// `H w`) and BETA (label 230). Leaves `y_k . d` in `wk2` and
    /// `(y_k . d)(y_k . d / 2 + y_k . xopt)` in `wk1`.
    #[inline(always)]
    fn vlag_beta<S: Simd>(&mut self, simd: S, kopt: usize, xoptsq: f64) -> f64 {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        self.refresh_yx(simd);
        // one pass over the rows of XPT and BMAT: y_k . d, b_k . d, and wn = BMAT[:npt]^T wk1
        self.wn.fill(0.0);
        {
            let d = &self.d[..n];
            let rows = self.xpt[..npt * n]
                .chunks_exact(n)
                .zip(self.bmat[..npt * n].chunks_exact(n));
            let outs = self.wk1[..npt]
                .iter_mut()
                .zip(&mut self.wk2[..npt])
                .zip(&mut self.vlag[..npt]);
            for (((y, b), ((w1, w2), vl)), &yx) in rows.zip(outs).zip(&self.yx[..npt]) {
                let (suma, bd) = dot2(simd, y, b, d);
                let t = suma * (0.5 * suma + yx);
                *w1 = t;
                *w2 = suma;
                *vl = bd;
                axpy(simd, t, b, &mut self.wn);
            }
        }
        let mut beta = 0.0;
        for jj in 0..nptm {
            let zc = &self.zmat[jj * npt..(jj + 1) * npt];
            let sum = dot(simd, zc, &self.wk1);
            beta -= sum * sum;
            axpy(simd, sum, zc, &mut self.vlag[..npt]);
        }
        let mut dsq = 0.0;
        let mut bsum = 0.0;
        let mut dx = 0.0;
        for j in 0..n {
            let dj = self.d[j];
            dsq += dj * dj;
            let mut sum = self.wn[j];
            bsum += sum * dj;
            sum += dot(simd, &self.bmat[(npt + j) * n..(npt + j + 1) * n], &self.d);
            self.vlag[npt + j] = sum;
            bsum += sum * dj;
            dx += dj * self.xopt[j];
        }
        beta = dx * dx + dsq * (xoptsq + dx + dx + 0.5 * dsq) + beta - bsum;
        self.vlag[kopt] += 1.0;
        beta
    }

    /// Index of the interpolation point to replace by a trust-region step: the largest
    /// `max(1, (dist/delta)^4) * (beta H_kk + vlag_k^2)`. Distances from `xopt` (skipping
    /// `kopt`) or, with `from_new`, from `xnew` (all points). Returns (knew, denom, ok) where
    /// `ok` is false when the denominator suffers from cancellation.
    #[inline(always)]
    fn choose_knew<S: Simd>(
        &mut self,
        simd: S,
        kopt: usize,
        beta: f64,
        delta: f64,
        from_new: bool,
    ) -> (usize, f64, bool) {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        if !self.hdiag_fresh {
            let hdiag = &mut self.hdiag[..npt];
            hdiag.fill(0.0);
            for zc in self.zmat[..npt * nptm].chunks_exact(npt) {
                for (h, z) in hdiag.iter_mut().zip(zc) {
                    *h += z * z;
                }
            }
            self.hdiag_fresh = true;
        }
        let delsq = delta * delta;
        let mut scaden = 0.0;
        let mut biglsq: f64 = 0.0;
        let mut knew = NONE;
        let mut denom = 0.0;
        let centre: &[f64] = if from_new { &self.xnew } else { &self.xopt };
        let (hdiag, vlag) = (&self.hdiag[..npt], &self.vlag[..npt]);
        for (k, row) in self.xpt[..npt * n].chunks_exact(n).enumerate() {
            if !from_new && k == kopt {
                continue;
            }
            let den = beta * hdiag[k] + vlag[k] * vlag[k];
            let distsq = dist_sq(simd, row, centre);
            let q = distsq / delsq;
            let temp = (q * q).max(1.0);
            if temp * den > scaden {
                scaden = temp * den;
                knew = k;
                denom = den;
            }
            biglsq = biglsq.max(temp * vlag[k] * vlag[k]);
        }
        (knew, denom, scaden > 0.5 * biglsq)
    }

    /// Model update after the new point replaced point `knew` (after UPDATE): second
    /// derivatives (PQ, HQ), the point itself, and the gradient at the old `xopt`.
    #[inline(always)]
    fn model_update<S: Simd>(&mut self, simd: S, knew: usize, diff: f64, fv: f64) {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        self.hfull_fresh = false;
        let pqold = self.pq[knew];
        self.pq[knew] = 0.0;
        if pqold != 0.0 {
            let xk = &self.xpt[knew * n..(knew + 1) * n];
            for (hrow, &xi) in self.hq.chunks_exact_mut(n).zip(xk) {
                axpy(simd, pqold * xi, xk, hrow);
            }
        }
        // hcol = Z Z^T e_knew  (the knew-th column of Omega)
        self.wk3.fill(0.0);
        for jj in 0..nptm {
            let zc = &self.zmat[jj * npt..(jj + 1) * npt];
            let zk = zc[knew];
            if zk != 0.0 {
                axpy(simd, zk, zc, &mut self.wk3);
            }
        }
        for k in 0..npt {
            self.pq[k] += diff * self.wk3[k];
        }
        self.fval[knew] = fv;
        self.refresh_yx(simd);
        self.xpt[knew * n..(knew + 1) * n].copy_from_slice(&self.xnew);
        self.yx[knew] = dot(simd, &self.xnew, &self.xopt);
        self.wn.copy_from_slice(&self.bmat[knew * n..(knew + 1) * n]);
        for k in 0..npt {
            let row = &self.xpt[k * n..(k + 1) * n];
            let t = self.wk3[k] * self.yx[k];
            axpy(simd, t, row, &mut self.wn);
        }
        axpy(simd, diff, &self.wn, &mut self.gopt);
    }

    /// Replaces the model by the least-Frobenius-norm interpolant when its gradient has been
    /// much smaller than the current one for three iterations in a row. Returns new itest.
    #[inline(always)]
    fn frobenius_test<S: Simd>(&mut self, simd: S, kopt: usize, mut itest: usize) -> usize {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        let fk = self.fval[kopt];
        for k in 0..npt {
            self.vlag[k] = self.fval[k] - fk;
        }
        self.wk1.fill(0.0);
        for jj in 0..nptm {
            let zc = &self.zmat[jj * npt..(jj + 1) * npt];
            let sum = dot(simd, zc, &self.vlag[..npt]);
            axpy(simd, sum, zc, &mut self.wk1);
        }
        self.refresh_yx(simd);
        for k in 0..npt {
            self.wk3[k] = self.wk1[k];
            self.wk1[k] *= self.yx[k];
        }
        // g_i = sum_k bmat[k,i] vlag_k + xpt[k,i] wk1_k
        self.wn.fill(0.0);
        for k in 0..npt {
            let (b, y) = (&self.bmat[k * n..(k + 1) * n], &self.xpt[k * n..(k + 1) * n]);
            axpy2(simd, self.vlag[k], b, self.wk1[k], y, &mut self.wn);
        }
        let mut gqsq = 0.0;
        let mut gisq = 0.0;
        for i in 0..n {
            let sum = self.wn[i];
            let g = self.gopt[i];
            if self.xopt[i] == self.sl[i] {
                gqsq += g.min(0.0).powi(2);
                gisq += sum.min(0.0).powi(2);
            } else if self.xopt[i] == self.su[i] {
                gqsq += g.max(0.0).powi(2);
                gisq += sum.max(0.0).powi(2);
            } else {
                gqsq += g * g;
                gisq += sum * sum;
            }
            self.vlag[npt + i] = sum;
        }
        itest += 1;
        if gqsq < 10.0 * gisq {
            itest = 0;
        }
        if itest >= 3 {
            self.gopt.copy_from_slice(&self.wn);
            self.pq.copy_from_slice(&self.wk3);
            self.hq.fill(0.0);
            self.hfull_fresh = false;
            itest = 0;
        }
        itest
    }

    /// UPDATE: revises BMAT and ZMAT when point `knew` moves (rank-2 change of H).
    #[inline(always)]
    fn update<S: Simd>(&mut self, simd: S, beta: f64, denom: f64, knew: usize) {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        self.hdiag_fresh = false;
        let zmax = abs_max(simd, &self.zmat);
        let ztest = 1.0e-20 * zmax;
        // Givens rotations zeroing row knew of Z except its first column.
        for j in 1..nptm {
            let zkj = self.zmat[j * npt + knew];
            if zkj.abs() > ztest {
                let zk1 = self.zmat[knew];
                let temp = (zk1 * zk1 + zkj * zkj).sqrt();
                let ta = zk1 / temp;
                let tb = zkj / temp;
                let (c0, cj) = self.zmat.split_at_mut(j * npt);
                let c0 = &mut c0[..npt];
                givens(simd, ta, tb, c0, &mut cj[..npt]);
            }
            self.zmat[j * npt + knew] = 0.0;
        }
        let zk1 = self.zmat[knew];
        for (w, z) in self.wu[..npt].iter_mut().zip(&self.zmat[..npt]) {
            *w = zk1 * z;
        }
        let alpha = self.wu[knew];
        let tau = self.vlag[knew];
        self.vlag[knew] -= 1.0;
        let sq = denom.sqrt();
        let tb = zk1 / sq;
        let ta = tau / sq;
        for (z, v) in self.zmat[..npt].iter_mut().zip(&self.vlag[..npt]) {
            *z = ta * *z - tb * v;
        }
        // BMAT
        for j in 0..n {
            let wj = self.bmat[knew * n + j];
            self.wu[npt + j] = wj;
            let vj = self.vlag[npt + j];
            self.wa[j] = (alpha * vj - tau * wj) / denom;
            self.wb[j] = (-beta * wj - tau * vj) / denom;
        }
        // all npt + n rows (the last n form the symmetric block: updated by whole rows, the
        // change is symmetric)
        let (wa, wb) = (&self.wa[..n], &self.wb[..n]);
        let ndim = npt + n;
        for ((row, &vi), &wi) in self.bmat[..ndim * n]
            .chunks_exact_mut(n)
            .zip(&self.vlag[..ndim])
            .zip(&self.wu[..ndim])
        {
            axpy2(simd, vi, wa, wi, wb, row);
        }
    }

    /// ALTMOV: alternative new positions for point `knew` (returns alpha, cauchy; sets
    /// `xnew`, `xalt`).
    #[allow(clippy::too_many_lines)]
    #[inline(always)]
    fn altmov<S: Simd>(&mut self, simd: S, kopt: usize, knew: usize, adelt: f64) -> (f64, f64) {
        let (n, npt) = (self.n, self.npt);
        let nptm = npt - n - 1;
        let cnst = 1.0 + std::f64::consts::SQRT_2;
        self.hcol.fill(0.0);
        for j in 0..nptm {
            let zc = &self.zmat[j * npt..(j + 1) * npt];
            axpy(simd, zc[knew], zc, &mut self.hcol);
        }
        let alpha = self.hcol[knew];
        let ha = 0.5 * alpha;
        self.glag.copy_from_slice(&self.bmat[knew * n..(knew + 1) * n]);
        self.refresh_yx(simd);
        for k in 0..npt {
            let row = &self.xpt[k * n..(k + 1) * n];
            let t = self.hcol[k] * self.yx[k];
            axpy(simd, t, row, &mut self.glag);
        }
        let mut presav = 0.0;
        let mut ksav = knew;
        let mut stpsav = 0.0;
        let mut ibdsav: isize = 0;
        // the bounds relative to xopt (wn, wn2), once per call; y_k - xopt in wa
        for i in 0..n {
            self.wn[i] = self.sl[i] - self.xopt[i];
            self.wn2[i] = self.su[i] - self.xopt[i];
        }
        for k in 0..npt {
            if k == kopt {
                continue;
            }
            let row = &self.xpt[k * n..(k + 1) * n];
            let (dderiv, distsq) = dderiv_dist(simd, row, &self.xopt, &self.glag, &mut self.wa);
            let mut subd = adelt / distsq.sqrt();
            let mut slbd = -subd;
            let mut ilbd: isize = 0;
            let mut iubd: isize = 0;
            let sumin = subd.min(1.0);
            let (rel, los, his) = (&self.wa[..n], &self.wn[..n], &self.wn2[..n]);
            for (i, ((&t, &lo), &hi)) in rel.iter().zip(los).zip(his).enumerate() {
                let ii = i as isize + 1;
                if t > 0.0 {
                    if slbd * t < lo {
                        slbd = lo / t;
                        ilbd = -ii;
                    }
                    if subd * t > hi {
                        subd = sumin.max(hi / t);
                        iubd = ii;
                    }
                } else if t < 0.0 {
                    if slbd * t > hi {
                        slbd = hi / t;
                        ilbd = ii;
                    }
                    if subd * t < lo {
                        subd = sumin.max(lo / t);
                        iubd = -ii;
                    }
                }
            }
            let (step, vlag, isbd);
            if k == knew {
                let diff = dderiv - 1.0;
                let mut st = slbd;
                let mut vl = slbd * (dderiv - slbd * diff);
                let mut ib = ilbd;
                let temp = subd * (dderiv - subd * diff);
                if temp.abs() > vl.abs() {
                    st = subd;
                    vl = temp;
                    ib = iubd;
                }
                let tempd = 0.5 * dderiv;
                let tempa = tempd - diff * slbd;
                let tempb = tempd - diff * subd;
                if tempa * tempb < 0.0 {
                    let temp = tempd * tempd / diff;
                    if temp.abs() > vl.abs() {
                        st = tempd / diff;
                        vl = temp;
                        ib = 0;
                    }
                }
                step = st;
                vlag = vl;
                isbd = ib;
            } else {
                let mut st = slbd;
                let mut vl = slbd * (1.0 - slbd);
                let mut ib = ilbd;
                let temp = subd * (1.0 - subd);
                if temp.abs() > vl.abs() {
                    st = subd;
                    vl = temp;
                    ib = iubd;
                }
                if subd > 0.5 && vl.abs() < 0.25 {
                    st = 0.5;
                    vl = 0.25;
                    ib = 0;
                }
                step = st;
                vlag = vl * dderiv;
                isbd = ib;
            }
            let temp = step * (1.0 - step) * distsq;
            let predsq = vlag * vlag * (vlag * vlag + ha * temp * temp);
            if predsq > presav {
                presav = predsq;
                ksav = k;
                stpsav = step;
                ibdsav = isbd;
            }
        }
        for i in 0..n {
            let t = self.xopt[i] + stpsav * (self.xpt[ksav * n + i] - self.xopt[i]);
            self.xnew[i] = t.min(self.su[i]).max(self.sl[i]);
        }
        if ibdsav < 0 {
            let i = (-ibdsav - 1) as usize;
            self.xnew[i] = self.sl[i];
        } else if ibdsav > 0 {
            let i = (ibdsav - 1) as usize;
            self.xnew[i] = self.su[i];
        }
        // constrained Cauchy step of the Lagrange function, both signs
        let bigstp = adelt + adelt;
        let mut iflag = 0;
        let mut csave = 0.0;
        let mut cauchy;
        loop {
            let mut wfixsq = 0.0;
            let mut ggfree = 0.0;
            for i in 0..n {
                self.wa[i] = 0.0;
                let tempa = (self.xopt[i] - self.sl[i]).min(self.glag[i]);
                let tempb = (self.xopt[i] - self.su[i]).max(self.glag[i]);
                if tempa > 0.0 || tempb < 0.0 {
                    self.wa[i] = bigstp;
                    ggfree += self.glag[i] * self.glag[i];
                }
            }
            if ggfree == 0.0 {
                return (alpha, 0.0);
            }
            let mut step = 0.0;
            loop {
                let temp = adelt * adelt - wfixsq;
                if temp > 0.0 {
                    let wsqsav = wfixsq;
                    step = (temp / ggfree).sqrt();
                    ggfree = 0.0;
                    for i in 0..n {
                        if self.wa[i] == bigstp {
                            let t = self.xopt[i] - step * self.glag[i];
                            if t <= self.sl[i] {
                                self.wa[i] = self.sl[i] - self.xopt[i];
                                wfixsq += self.wa[i] * self.wa[i];
                            } else if t >= self.su[i] {
                                self.wa[i] = self.su[i] - self.xopt[i];
                                wfixsq += self.wa[i] * self.wa[i];
                            } else {
                                ggfree += self.glag[i] * self.glag[i];
                            }
                        }
                    }
                    if wfixsq > wsqsav && ggfree > 0.0 {
                        continue;
                    }
                }
                break;
            }
            let mut gw = 0.0;
            for i in 0..n {
                if self.wa[i] == bigstp {
                    self.wa[i] = -step * self.glag[i];
                    self.xalt[i] = (self.xopt[i] + self.wa[i]).min(self.su[i]).max(self.sl[i]);
                } else if self.wa[i] == 0.0 {
                    self.xalt[i] = self.xopt[i];
                } else if self.glag[i] > 0.0 {
                    self.xalt[i] = self.sl[i];
                } else {
                    self.xalt[i] = self.su[i];
                }
                gw += self.glag[i] * self.wa[i];
            }
            let mut curv = 0.0;
            for k in 0..npt {
                let t = dot(simd, &self.xpt[k * n..(k + 1) * n], &self.wa);
                curv += self.hcol[k] * t * t;
            }
            if iflag == 1 {
                curv = -curv;
            }
            if curv > -gw && curv < -cnst * gw {
                let scale = -gw / curv;
                for i in 0..n {
                    let t = self.xopt[i] + scale * self.wa[i];
                    self.xalt[i] = t.min(self.su[i]).max(self.sl[i]);
                }
                cauchy = (0.5 * gw * scale) * (0.5 * gw * scale);
            } else {
                cauchy = (gw + 0.5 * curv) * (gw + 0.5 * curv);
            }
            if iflag == 0 {
                for i in 0..n {
                    self.glag[i] = -self.glag[i];
                    self.wb[i] = self.xalt[i];
                }
                csave = cauchy;
                iflag = 1;
                continue;
            }
            if csave > cauchy {
                self.xalt.copy_from_slice(&self.wb);
                cauchy = csave;
            }
            return (alpha, cauchy);
        }
    }

    /// TRSBOX: approximate minimiser of the model in the trust region and the box; sets
    /// `xnew`, `d` (= xnew - xopt), `gnew`; returns `(|d|^2, crvmin)`.
    #[allow(clippy::too_many_lines)]
    #[inline(always)]
    fn trsbox<S: Simd>(&mut self, simd: S, delta: f64) -> (f64, f64) {
        #[derive(Clone, Copy)]
        enum T {
            L20,
            L30,
            L50,
            L90,
            L100,
            L120,
            L150,
            L190,
            L210,
        }
        let (n, npt) = (self.n, self.npt);
        if !self.hfull_fresh {
            build_hessian(simd, n, &self.hq, &self.pq, &self.xpt, &mut self.hw, &mut self.hfull);
            self.hfull_fresh = true;
        }
        let Bobyqa {
            xopt,
            gopt,
            hfull,
            sl,
            su,
            xnew,
            d,
            gnew,
            xbdi,
            s,
            hs,
            hred,
            ..
        } = self;
        let _ = npt;
        let mut iterc = 0usize;
        let mut nact = 0usize;
        for i in 0..n {
            xbdi[i] = 0.0;
            if xopt[i] <= sl[i] {
                if gopt[i] >= 0.0 {
                    xbdi[i] = -1.0;
                }
            } else if xopt[i] >= su[i] && gopt[i] <= 0.0 {
                xbdi[i] = 1.0;
            }
            if xbdi[i] != 0.0 {
                nact += 1;
            }
            d[i] = 0.0;
            gnew[i] = gopt[i];
        }
        let mut delsq = delta * delta;
        let mut qred = 0.0;
        let mut crvmin = -1.0;
        let mut beta = 0.0;
        let mut stepsq = 0.0;
        let mut gredsq = 0.0;
        let mut itermax = 0usize;
        let mut ggsav = 0.0;
        let mut itcsav = 0usize;
        let mut dredsq = 0.0;
        let mut dredg = 0.0;
        let mut sredg = 0.0;
        let mut angbd = 1.0;
        let mut iact = NONE;
        let mut xsav = 0.0;
        let mut st = T::L20;
        loop {
            match st {
                T::L20 => {
                    beta = 0.0;
                    st = T::L30;
                }
                T::L30 => {
                    stepsq = cg_direction(simd, &xbdi[..n], beta, &gnew[..n], &mut s[..n]);
                    if stepsq == 0.0 {
                        st = T::L190;
                        continue;
                    }
                    if beta == 0.0 {
                        gredsq = stepsq;
                        itermax = iterc + n - nact;
                    }
                    st = if gredsq * delsq <= 1.0e-4 * qred * qred {
                        T::L190
                    } else {
                        T::L210
                    };
                }
                T::L50 => {
                    // s is zero on the fixed variables
                    let (dd, ds, shs) = free_dots3(simd, &xbdi[..n], &d[..n], &d[..n], &s[..n], &hs[..n]);
                    let resid = delsq - dd;
                    if resid <= 0.0 {
                        st = T::L90;
                        continue;
                    }
                    let temp = (stepsq * resid + ds * ds).sqrt();
                    let blen = if ds < 0.0 {
                        (temp - ds) / stepsq
                    } else {
                        resid / (temp + ds)
                    };
                    let mut stplen = blen;
                    if shs > 0.0 {
                        stplen = blen.min(gredsq / shs);
                    }
                    iact = NONE;
                    for i in 0..n {
                        if s[i] != 0.0 {
                            let xsum = xopt[i] + d[i];
                            let temp = if s[i] > 0.0 {
                                (su[i] - xsum) / s[i]
                            } else {
                                (sl[i] - xsum) / s[i]
                            };
                            if temp < stplen {
                                stplen = temp;
                                iact = i;
                            }
                        }
                    }
                    let mut sdec = 0.0;
                    if stplen > 0.0 {
                        iterc += 1;
                        let temp = shs / stepsq;
                        if iact == NONE && temp > 0.0 {
                            crvmin = f64::min(crvmin, temp);
                            if crvmin == -1.0 {
                                crvmin = temp;
                            }
                        }
                        ggsav = gredsq;
                        gredsq = cg_step(simd, &xbdi[..n], stplen, &hs[..n], &s[..n], &mut gnew[..n], &mut d[..n]);
                        sdec = (stplen * (ggsav - 0.5 * stplen * shs)).max(0.0);
                        qred += sdec;
                    }
                    if iact != NONE {
                        nact += 1;
                        xbdi[iact] = if s[iact] < 0.0 { -1.0 } else { 1.0 };
                        delsq -= d[iact] * d[iact];
                        st = if delsq <= 0.0 { T::L90 } else { T::L20 };
                        continue;
                    }
                    if stplen < blen {
                        if iterc == itermax || sdec <= 0.01 * qred {
                            st = T::L190;
                            continue;
                        }
                        beta = gredsq / ggsav;
                        st = T::L30;
                        continue;
                    }
                    st = T::L90;
                }
                T::L90 => {
                    crvmin = 0.0;
                    st = T::L100;
                }
                T::L100 => {
                    if nact + 1 >= n {
                        st = T::L190;
                        continue;
                    }
                    (dredsq, dredg, gredsq) = free_dots3(simd, &xbdi[..n], &d[..n], &d[..n], &gnew[..n], &gnew[..n]);
                    for i in 0..n {
                        s[i] = if xbdi[i] == 0.0 { d[i] } else { 0.0 };
                    }
                    itcsav = iterc;
                    st = T::L210;
                }
                T::L120 => {
                    iterc += 1;
                    let temp = gredsq * dredsq - dredg * dredg;
                    if temp <= 1.0e-4 * qred * qred {
                        st = T::L190;
                        continue;
                    }
                    let temp = temp.sqrt();
                    for i in 0..n {
                        s[i] = if xbdi[i] == 0.0 {
                            (dredg * d[i] - dredsq * gnew[i]) / temp
                        } else {
                            0.0
                        };
                    }
                    sredg = -temp;
                    angbd = 1.0;
                    iact = NONE;
                    let mut fixed = false;
                    for i in 0..n {
                        if xbdi[i] == 0.0 {
                            let tempa = xopt[i] + d[i] - sl[i];
                            let tempb = su[i] - xopt[i] - d[i];
                            if tempa <= 0.0 {
                                nact += 1;
                                xbdi[i] = -1.0;
                                fixed = true;
                                break;
                            } else if tempb <= 0.0 {
                                nact += 1;
                                xbdi[i] = 1.0;
                                fixed = true;
                                break;
                            }
                            let ssq = d[i] * d[i] + s[i] * s[i];
                            let t = ssq - (xopt[i] - sl[i]) * (xopt[i] - sl[i]);
                            if t > 0.0 {
                                let t = t.sqrt() - s[i];
                                if angbd * t > tempa {
                                    angbd = tempa / t;
                                    iact = i;
                                    xsav = -1.0;
                                }
                            }
                            let t = ssq - (su[i] - xopt[i]) * (su[i] - xopt[i]);
                            if t > 0.0 {
                                let t = t.sqrt() + s[i];
                                if angbd * t > tempb {
                                    angbd = tempb / t;
                                    iact = i;
                                    xsav = 1.0;
                                }
                            }
                        }
                    }
                    st = if fixed { T::L100 } else { T::L210 };
                }
                T::L150 => {
                    let (dhd, dhs, shs) = free_dots3(simd, &xbdi[..n], &d[..n], &hred[..n], &hs[..n], &s[..n]);
                    let mut redmax = 0.0;
                    let mut isav = 0usize;
                    let mut redsav = 0.0;
                    let mut rdprev = 0.0;
                    let mut rdnext = 0.0;
                    let iu = (17.0 * angbd + 3.1) as usize;
                    let mut angt = 0.0;
                    for i in 1..=iu {
                        angt = angbd * i as f64 / iu as f64;
                        let sth = (angt + angt) / (1.0 + angt * angt);
                        let temp = shs + angt * (angt * dhd - dhs - dhs);
                        let rednew = sth * (angt * dredg - sredg - 0.5 * sth * temp);
                        if rednew > redmax {
                            redmax = rednew;
                            isav = i;
                            rdprev = redsav;
                        } else if i == isav + 1 {
                            rdnext = rednew;
                        }
                        redsav = rednew;
                    }
                    if isav == 0 {
                        st = T::L190;
                        continue;
                    }
                    if isav < iu {
                        let temp = (rdnext - rdprev) / (redmax + redmax - rdprev - rdnext);
                        angt = angbd * (isav as f64 + 0.5 * temp) / iu as f64;
                    }
                    let cth = (1.0 - angt * angt) / (1.0 + angt * angt);
                    let sth = (angt + angt) / (1.0 + angt * angt);
                    let temp = shs + angt * (angt * dhd - dhs - dhs);
                    let sdec = sth * (angt * dredg - sredg - 0.5 * sth * temp);
                    if sdec <= 0.0 {
                        st = T::L190;
                        continue;
                    }
                    (dredg, gredsq) = cg_rotate(
                        simd,
                        &xbdi[..n],
                        cth,
                        sth,
                        &hs[..n],
                        &s[..n],
                        &mut hred[..n],
                        &mut gnew[..n],
                        &mut d[..n],
                    );
                    qred += sdec;
                    if iact != NONE && isav == iu {
                        nact += 1;
                        xbdi[iact] = xsav;
                        st = T::L100;
                        continue;
                    }
                    st = if sdec > 0.01 * qred { T::L120 } else { T::L190 };
                }
                T::L190 => {
                    let mut dsq = 0.0;
                    for i in 0..n {
                        let mut v = (xopt[i] + d[i]).min(su[i]).max(sl[i]);
                        if xbdi[i] == -1.0 {
                            v = sl[i];
                        }
                        if xbdi[i] == 1.0 {
                            v = su[i];
                        }
                        xnew[i] = v;
                        d[i] = v - xopt[i];
                        dsq += d[i] * d[i];
                    }
                    return (dsq, crvmin);
                }
                T::L210 => {
                    sym_mul(simd, n, hfull, s, hs);
                    if crvmin != 0.0 {
                        st = T::L50;
                    } else if iterc > itcsav {
                        st = T::L150;
                    } else {
                        hred.copy_from_slice(hs);
                        st = T::L120;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
    }

    fn all_close(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y))
    }

    /// Every SIMD kernel against a plain scalar reference, on seeded random inputs and sizes
    /// with and without a scalar tail (returns the number of checks that failed).
    struct KernelCheck {
        seed: u64,
    }

    impl pulp::WithSimd for KernelCheck {
        type Output = usize;
        fn with_simd<S: Simd>(self, simd: S) -> usize {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.seed);
            let mut bad = 0;
            let mut check = |ok: bool, what: &str, n: usize| {
                if !ok {
                    eprintln!("{what} differs from its reference (n = {n})");
                    bad += 1;
                }
            };
            for n in [2usize, 3, 4, 5, 8, 16, 17, 23, 53] {
                let npt = 2 * n + 1;
                let mut v = |m: usize| -> Vec<f64> { (0..m).map(|_| rng.random_range(-1.0..1.0)).collect() };
                let (a, b, c) = (v(n), v(n), v(n));
                let (al, be) = (0.7, -1.3);
                let rdot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>();
                check(close(dot(simd, &a, &b), rdot(&a, &b)), "dot", n);
                let (d1, d2) = dot2(simd, &a, &b, &c);
                check(close(d1, rdot(&a, &c)) && close(d2, rdot(&b, &c)), "dot2", n);
                let diff: Vec<f64> = a.iter().zip(&b).map(|(p, q)| p - q).collect();
                check(close(dist_sq(simd, &a, &b), rdot(&diff, &diff)), "dist_sq", n);
                let mut out = vec![0.0; n];
                let (g1, g2) = dderiv_dist(simd, &a, &b, &c, &mut out);
                check(
                    close(g1, rdot(&c, &diff)) && close(g2, rdot(&diff, &diff)) && out == diff,
                    "dderiv_dist",
                    n,
                );
                let amax = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                check(abs_max(simd, &a) == amax, "abs_max", n);
                let mut y = c.clone();
                axpy(simd, al, &a, &mut y);
                let ry: Vec<f64> = c.iter().zip(&a).map(|(z, x)| z + al * x).collect();
                check(all_close(&y, &ry), "axpy", n);
                let mut y = c.clone();
                axpy2(simd, al, &a, be, &b, &mut y);
                let ry: Vec<f64> = (0..n).map(|i| c[i] + al * a[i] + be * b[i]).collect();
                check(all_close(&y, &ry), "axpy2", n);
                let (mut x1, mut y1) = (a.clone(), b.clone());
                givens(simd, 0.6, 0.8, &mut x1, &mut y1);
                let rx: Vec<f64> = (0..n).map(|i| 0.6 * a[i] + 0.8 * b[i]).collect();
                let ryy: Vec<f64> = (0..n).map(|i| 0.6 * b[i] - 0.8 * a[i]).collect();
                check(all_close(&x1, &rx) && all_close(&y1, &ryy), "givens", n);
                // TRSBOX kernels (variables 0 and 2 fixed, when present)
                let (e, f2) = (v(n), v(n));
                let xb: Vec<f64> = (0..n)
                    .map(|i| {
                        if i == 0 {
                            -1.0
                        } else if i == 2 {
                            1.0
                        } else {
                            0.0
                        }
                    })
                    .collect();
                let fr = |i: usize| xb[i] == 0.0;
                let rf = |x: &[f64], y: &[f64]| (0..n).filter(|&i| fr(i)).map(|i| x[i] * y[i]).sum::<f64>();
                let (r0, r1, r2) = free_dots3(simd, &xb, &a, &b, &c, &e);
                check(
                    close(r0, rf(&a, &b)) && close(r1, rf(&a, &c)) && close(r2, rf(&e, &c)),
                    "free_dots3",
                    n,
                );
                let mut sv = c.clone();
                let sq = cg_direction(simd, &xb, al, &a, &mut sv);
                let rs: Vec<f64> = (0..n).map(|i| if fr(i) { al * c[i] - a[i] } else { 0.0 }).collect();
                check(all_close(&sv, &rs) && close(sq, rdot(&rs, &rs)), "cg_direction", n);
                let (mut gv, mut dv) = (c.clone(), e.clone());
                let gg = cg_step(simd, &xb, al, &a, &b, &mut gv, &mut dv);
                let rg: Vec<f64> = (0..n).map(|i| c[i] + al * a[i]).collect();
                let rd: Vec<f64> = (0..n).map(|i| e[i] + al * b[i]).collect();
                check(
                    all_close(&gv, &rg) && all_close(&dv, &rd) && close(gg, rf(&rg, &rg)),
                    "cg_step",
                    n,
                );
                let (ct, st) = (0.8, 0.6);
                let (mut hr, mut gv, mut dv) = (c.clone(), e.clone(), f2.clone());
                let (dg, gg) = cg_rotate(simd, &xb, ct, st, &a, &b, &mut hr, &mut gv, &mut dv);
                let rg: Vec<f64> = (0..n).map(|i| e[i] + (ct - 1.0) * c[i] + st * a[i]).collect();
                let rd: Vec<f64> = (0..n)
                    .map(|i| if fr(i) { ct * f2[i] + st * b[i] } else { f2[i] })
                    .collect();
                let rh: Vec<f64> = (0..n).map(|i| ct * c[i] + st * a[i]).collect();
                check(
                    all_close(&gv, &rg)
                        && all_close(&dv, &rd)
                        && all_close(&hr, &rh)
                        && close(dg, rf(&rd, &rg))
                        && close(gg, rf(&rg, &rg)),
                    "cg_rotate",
                    n,
                );
                // Hessian build, products
                let xpt = v(npt * n);
                let pq = v(npt);
                let mut hq = v(n * n);
                for i in 0..n {
                    for j in 0..i {
                        hq[i * n + j] = hq[j * n + i];
                    }
                }
                let mut href = hq.clone();
                for k in 0..npt {
                    for i in 0..n {
                        for j in 0..n {
                            href[i * n + j] += pq[k] * xpt[k * n + i] * xpt[k * n + j];
                        }
                    }
                }
                let (mut w, mut h) = (vec![0.0; npt * n], vec![0.0; n * n]);
                build_hessian(simd, n, &hq, &pq, &xpt, &mut w, &mut h);
                check(all_close(&h, &href), "build_hessian", n);
                let mut sv = v(n);
                sv[0] = 0.0; // a fixed variable (skipped row)
                let rhs: Vec<f64> = (0..n).map(|i| rdot(&href[i * n..(i + 1) * n], &sv)).collect();
                let mut hs = vec![0.0; n];
                sym_mul(simd, n, &href, &sv, &mut hs);
                check(all_close(&hs, &rhs), "sym_mul", n);
                let mut hs = vec![0.0; n];
                hess_mul(simd, n, &hq, &pq, &xpt, &sv, &mut hs);
                check(all_close(&hs, &rhs), "hess_mul", n);
            }
            bad
        }
    }

    #[test]
    fn simd_kernels_match_scalar_references() {
        for seed in 0..4 {
            // the dispatched code (AVX2 + FMA where available) and the portable fallback
            assert_eq!(pulp::Arch::new().dispatch(KernelCheck { seed }), 0);
            assert_eq!(pulp::WithSimd::with_simd(KernelCheck { seed }, pulp::Scalar::new()), 0);
        }
    }

    fn run(rb: f64, re: f64) -> BobyqaRun {
        BobyqaRun {
            rho_begin: rb,
            rho_end: re,
            max_evals: 100_000,
        }
    }

    #[test]
    fn errors_not_panics() {
        assert!(Bobyqa::new(1, 3).is_err());
        assert!(Bobyqa::new(3, 4).is_err());
        assert!(Bobyqa::new(3, 11).is_err());
        let mut b = Bobyqa::new(3, 7).unwrap();
        let mut x = [0.0; 3];
        let (lo, hi) = ([0.0; 3], [1.0; 3]);
        let f = |x: &[f64]| x.iter().sum::<f64>();
        assert!(b.minimize(f, &mut x, &lo, &hi, &run(0.6, 0.01)).is_err()); // box too small
        assert!(b.minimize(f, &mut x, &lo, &hi, &run(0.1, 0.2)).is_err());
        assert!(b.minimize(f, &mut x, &lo, &hi, &run(f64::NAN, 0.01)).is_err());
        assert!(b.minimize(f, &mut x[..2], &lo, &hi, &run(0.1, 0.01)).is_err());
        let r = BobyqaRun {
            max_evals: 7,
            ..run(0.1, 0.01)
        };
        assert!(b.minimize(f, &mut x, &lo, &hi, &r).is_err());
        let mut x = [0.5; 3];
        let e = b.minimize(
            |x: &[f64]| if x[0] > 0.55 { f64::NAN } else { 1.0 },
            &mut x,
            &lo,
            &hi,
            &run(0.1, 0.01),
        );
        assert!(matches!(e, Err(Error::Numerical { .. })));
        // usable again after an error
        let mut x = [0.5; 3];
        let o = b.minimize(
            |x: &[f64]| x.iter().map(|v| (v - 0.3) * (v - 0.3)).sum(),
            &mut x,
            &lo,
            &hi,
            &run(0.1, 1e-6),
        );
        let o = o.unwrap();
        assert!(o.f < 1e-10, "{o:?} {x:?}");
    }
}
