//! Sliding-window scoring of fHOG images with linear filters, as dlib's
//! `scan_fhog_pyramid` (`build_fhog_filterbank`, `apply_filters_to_fhog`,
//! `detect_from_fhog_pyramid`).
//!
//! A sub-detector is 31 filters `F_i` of `fh x fw` cells and a threshold `b`. The
//! score of the window whose centre cell is `(r, c)` is
//!
//! ```text
//! s(r, c) = sum_i sum_{m < fh, n < fw} F_i[m][n] * H_i[r - fh/2 + m][c - fw/2 + n]
//! ```
//!
//! evaluated for `fh/2 <= r < rows - (fh-1)/2` (and likewise `c`); a window is a
//! candidate when `s >= b + adjust_threshold` and its confidence is `s - b`.
//!
//! dlib approximates each `F_i` by its SVD `F_i = sum_j s_j u_j v_j^T` truncated to
//! the singular values `>= max(1e-4, 0.001 s_max)` and uses the separable form (a row
//! pass with `v_j sqrt(s_j)`, then a column pass with `u_j sqrt(s_j)`) whenever that
//! is cheaper than the full filters, which it is for the frontal face detector (54-66
//! rank-1 terms per sub-detector instead of 31 full 10 x 10 filters). We do the same,
//! with the same float association of the 10-tap sums (three interleaved
//! accumulators in dlib's 8-column SIMD blocks, a plain running sum in its scalar
//! tail), so scores agree with dlib up to the last bits of the SVD.

use super::fhog::{FhogImage, PLANES};

/// One rank-1 term of a separable filter bank.
#[derive(Debug, Clone, PartialEq)]
pub struct SeparableTerm {
    /// Feature plane the term applies to.
    pub plane: usize,
    /// Horizontal taps (`fw`), `v_j sqrt(s_j)`.
    pub row: Vec<f32>,
    /// Vertical taps (`fh`), `u_j sqrt(s_j)`.
    pub col: Vec<f32>,
}

/// The filters of one sub-detector.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterBank {
    /// Filter width in cells.
    pub fw: usize,
    /// Filter height in cells.
    pub fh: usize,
    /// Full filters, `31 x fh x fw` (plane-major, row-major), f32 as dlib.
    pub full: Vec<f32>,
    /// Rank-1 terms in dlib's order (plane ascending, singular value descending).
    pub terms: Vec<SeparableTerm>,
    /// Detection threshold `b` (the last weight).
    pub threshold: f64,
    /// Whether dlib would use the full filters (more rank-1 terms than
    /// `31 * min(fh, fw) / 3`).
    pub use_full: bool,
}

impl FilterBank {
    /// Builds the bank from a weight vector of length `31 * fh * fw + 1`.
    pub fn new(weights: &[f64], fw: usize, fh: usize) -> Self {
        let size = fw * fh;
        let mut full = Vec::with_capacity(PLANES * size);
        let mut terms = Vec::new();
        for i in 0..PLANES {
            let f = &weights[i * size..(i + 1) * size];
            full.extend(f.iter().map(|&v| v as f32));
            let (u, s, v) = jacobi_svd(f, fh, fw);
            let mut order: Vec<usize> = (0..s.len()).collect();
            order.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
            let smax = s.iter().copied().fold(0.0f64, f64::max);
            let thresh = (smax * 0.001).max(1e-4);
            for &j in &order {
                let sj = s[j];
                if !(sj >= thresh || sj <= -thresh) {
                    continue;
                }
                let k = sj.sqrt();
                terms.push(SeparableTerm {
                    plane: i,
                    row: (0..fw).map(|n| (v[j * fw + n] * k) as f32).collect(),
                    col: (0..fh).map(|m| (u[j * fh + m] * k) as f32).collect(),
                });
            }
        }
        let use_full = terms.len() as f64 > (PLANES * fw.min(fh)) as f64 / 3.0;
        FilterBank {
            fw,
            fh,
            full,
            terms,
            threshold: weights.get(PLANES * size).copied().unwrap_or(0.0),
            use_full,
        }
    }
}

/// Singular value decomposition `A = sum_j s_j u_j v_j^T` of a row-major `m x n`
/// matrix by one-sided Jacobi rotations (Hestenes 1958), accurate to a few ulps also
/// for rank-deficient matrices (the detector's filters are rank 1-3). Returns `u`
/// (`n` vectors of length `m`, vector-major), `s` (`n` values, unsorted) and `v` (`n`
/// vectors of length `n`).
pub fn jacobi_svd(a: &[f64], m: usize, n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    const MAX_SWEEPS: usize = 80;
    let mut u = vec![0.0; n * m];
    for i in 0..m {
        for j in 0..n {
            u[j * m + i] = a[i * n + j];
        }
    }
    let mut v = vec![0.0; n * n];
    for j in 0..n {
        v[j * n + j] = 1.0;
    }
    for _ in 0..MAX_SWEEPS {
        let mut rotated = false;
        for p in 0..n {
            for q in p + 1..n {
                let (mut alpha, mut beta, mut gamma) = (0.0, 0.0, 0.0);
                for i in 0..m {
                    let (x, y) = (u[p * m + i], u[q * m + i]);
                    alpha += x * x;
                    beta += y * y;
                    gamma += x * y;
                }
                if gamma == 0.0 || gamma.abs() <= f64::EPSILON * (alpha * beta).sqrt() {
                    continue;
                }
                rotated = true;
                let zeta = (beta - alpha) / (2.0 * gamma);
                let t = zeta.signum() / (zeta.abs() + (1.0 + zeta * zeta).sqrt());
                let c = 1.0 / (1.0 + t * t).sqrt();
                let s = c * t;
                for i in 0..m {
                    let (x, y) = (u[p * m + i], u[q * m + i]);
                    u[p * m + i] = c * x - s * y;
                    u[q * m + i] = s * x + c * y;
                }
                for i in 0..n {
                    let (x, y) = (v[p * n + i], v[q * n + i]);
                    v[p * n + i] = c * x - s * y;
                    v[q * n + i] = s * x + c * y;
                }
            }
        }
        if !rotated {
            break;
        }
    }
    let mut s = vec![0.0; n];
    for j in 0..n {
        let norm = u[j * m..(j + 1) * m].iter().map(|x| x * x).sum::<f64>().sqrt();
        s[j] = norm;
        if norm > 0.0 {
            u[j * m..(j + 1) * m].iter_mut().for_each(|x| *x /= norm);
        }
    }
    (u, s, v)
}

/// The valid output area of a filtering: rows `r0..r1`, columns `c0..c1` (exclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Area {
    /// First valid row.
    pub r0: usize,
    /// One past the last valid row.
    pub r1: usize,
    /// First valid column.
    pub c0: usize,
    /// One past the last valid column.
    pub c1: usize,
}

/// The `n`-tap dot product `sum_k a(k) * f[k]` with dlib's association: in SIMD blocks
/// three accumulators (`k = 0, 3, 6, ...`, `1, 4, ...`, `2, 5, ...`, the taps past the
/// last full triple added to the first) combined as `acc0 + (acc1 + acc2)`; in the
/// scalar tail a running sum.
#[inline(always)]
fn dot_dlib(simd: bool, f: &[f32], a: impl Fn(usize) -> f32) -> f32 {
    let n = f.len();
    if simd {
        let (mut t0, mut t1, mut t2) = (0f32, 0f32, 0f32);
        let mut k = 0;
        while k + 2 < n {
            t0 += a(k) * f[k];
            t1 += a(k + 1) * f[k + 1];
            t2 += a(k + 2) * f[k + 2];
            k += 3;
        }
        while k < n {
            t0 += a(k) * f[k];
            k += 1;
        }
        t0 + (t1 + t2)
    } else {
        let mut t = 0f32;
        for (k, &fk) in f.iter().enumerate() {
            t += a(k) * fk;
        }
        t
    }
}

/// First column handled by dlib's scalar tail for output columns `c0..c1`.
fn simd_end(c0: usize, c1: usize) -> usize {
    let mut c = c0;
    while c + 7 < c1 {
        c += 8;
    }
    c
}

/// Scratch buffers of [`saliency`] and [`candidates`].
#[derive(Debug, Clone, Default)]
pub struct ScanScratch {
    rowpass: Vec<f32>,
    acc: Vec<f32>,
    fast: Vec<f32>,
    /// Area positions `(r, j)` whose fast score is near or above the threshold.
    near: Vec<(usize, usize)>,
}

/// [`candidates`] recomputes a window's score in dlib's float association when the
/// fast pass puts it at most this far below the threshold. The two evaluations of the
/// same separable sum differ only by rounding (at most a few 1e-6 on real and seeded
/// random features, `fast_scores_stay_far_within_the_recheck_margin`), so no window
/// dlib accepts is lost.
pub const EXACT_RECHECK_MARGIN: f64 = 1e-2;

/// A window that passed the threshold: centre cell `(r, c)` and its score as dlib
/// computes it (bit for bit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Row of the window's centre cell.
    pub r: usize,
    /// Column of the window's centre cell.
    pub c: usize,
    /// dlib's window score (before subtracting the threshold).
    pub score: f32,
}

/// The windows of one sub-detector whose dlib score is `>= thresh`, in row-major
/// order, appended to `out`; returns the valid area like [`saliency`].
///
/// Two passes instead of dlib's one: (1) all scores of the separable filters with
/// fused multiply-adds in 8-wide vectors (AVX2 + FMA chosen at run time through
/// `pulp`, plain scalar code otherwise), an association dlib does not use, then (2) for
/// the few windows within [`EXACT_RECHECK_MARGIN`] of the threshold or above it, the
/// score in dlib's association ([`exact_score_at`]), which decides and is reported. So
/// the accepted windows and their scores are those of [`saliency`] (tests
/// `candidates_equal_the_exact_saliency_threshold` and the dlib fixture).
pub fn candidates(
    bank: &FilterBank,
    feats: &FhogImage,
    thresh: f64,
    scratch: &mut ScanScratch,
    out: &mut Vec<Hit>,
) -> Option<Area> {
    let (w, h) = (feats.width, feats.height);
    let (fw, fh) = (bank.fw, bank.fh);
    if w < fw || h < fh || w == 0 || h == 0 {
        return None;
    }
    if bank.use_full {
        // not the frontal detector's case: the exact full filtering, thresholded
        let mut sal = std::mem::take(&mut scratch.fast);
        let area = saliency(bank, feats, scratch, &mut sal);
        if let Some(area) = area {
            for r in area.r0..area.r1 {
                for c in area.c0..area.c1 {
                    let v = sal[r * w + c];
                    if f64::from(v) >= thresh {
                        out.push(Hit { r, c, score: v });
                    }
                }
            }
        }
        scratch.fast = sal;
        return area;
    }
    if bank.terms.is_empty() {
        return None;
    }
    let area = Area {
        r0: fh / 2,
        r1: h - (fh - 1) / 2,
        c0: fw / 2,
        c1: w - (fw - 1) / 2,
    };
    let layout = fast_scores_dispatch(bank, feats, area, scratch);
    let tail = simd_end(area.c0, area.c1);
    let cut = thresh - EXACT_RECHECK_MARGIN;
    scratch.near.clear();
    layout.push_at_least(&scratch.fast, cut, &mut scratch.near);
    // row-major order, as dlib scans
    scratch.near.sort_unstable();
    for &(r, j) in &scratch.near {
        let (r, c) = (area.r0 + r, area.c0 + j);
        let s = exact_score_at(bank, feats, tail, r, c);
        if f64::from(s) >= thresh {
            out.push(Hit { r, c, score: s });
        }
    }
    Some(area)
}

/// The score of the window centred at `(r, c)` exactly as [`saliency`] computes it
/// (dlib's association; `tail` = first column of dlib's scalar tail). Rows of zeros are
/// not special-cased here, which can change only the sign of an exact zero.
pub fn exact_score_at(bank: &FilterBank, feats: &FhogImage, tail: usize, r: usize, c: usize) -> f32 {
    let w = feats.width;
    let (hr, hc) = (bank.fh / 2, bank.fw / 2);
    let simd = c < tail;
    let mut total = 0f32;
    for (t_idx, term) in bank.terms.iter().enumerate() {
        let plane = feats.plane(term.plane);
        let rp = |m: usize| {
            let base = (r - hr + m) * w + c - hc;
            dot_dlib(simd, &term.row, |k| plane[base + k])
        };
        let v = dot_dlib(simd, &term.col, rp);
        total = if t_idx == 0 { v } else { total + v };
    }
    total
}

/// Where [`candidates`]' fast pass leaves the score of area row `r`, column `j`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FastLayout {
    /// Row-major, `nc` values per row ([`FastScores`]).
    Rows { nc: usize, nr: usize },
    /// Blocks of 8 columns one after the other, each `nr` rows of 8 lanes; the last
    /// block holds columns `nc - 8..nc` (it overlaps the one before it) ([`FastV3`]).
    Blocks { nc: usize, nr: usize },
}

impl FastLayout {
    /// Index of the score of area row `r`, column `j`.
    #[cfg(test)]
    fn index(self, r: usize, j: usize) -> usize {
        match self {
            FastLayout::Rows { nc, .. } => r * nc + j,
            FastLayout::Blocks { nc, nr } => {
                let last = nc.div_ceil(V3_LANES) - 1;
                let (b, lane) = if j >= last * V3_LANES {
                    (last, j + V3_LANES - nc)
                } else {
                    (j / V3_LANES, j % V3_LANES)
                };
                (b * nr + r) * V3_LANES + lane
            }
        }
    }

    /// Appends `(r, j)` of every score `>= cut` (each position once, in no particular
    /// order).
    fn push_at_least(self, fast: &[f32], cut: f64, out: &mut Vec<(usize, usize)>) {
        match self {
            FastLayout::Rows { nc, nr } => {
                for (r, row) in fast[..nr * nc].chunks_exact(nc).enumerate() {
                    for (j, &v) in row.iter().enumerate() {
                        if f64::from(v) >= cut {
                            out.push((r, j));
                        }
                    }
                }
            }
            FastLayout::Blocks { nc, nr } => {
                let nb = nc.div_ceil(V3_LANES);
                for (b, block) in fast[..nb * nr * V3_LANES].chunks_exact(nr * V3_LANES).enumerate() {
                    // first column of the block, first lane not already in the block before
                    let (col0, lane0) = if b + 1 == nb {
                        (nc - V3_LANES, nb * V3_LANES - nc)
                    } else {
                        (b * V3_LANES, 0)
                    };
                    for (r, lanes) in block.chunks_exact(V3_LANES).enumerate() {
                        if lanes.iter().all(|&v| f64::from(v) < cut) {
                            continue;
                        }
                        for (l, &v) in lanes.iter().enumerate().skip(lane0) {
                            if f64::from(v) >= cut {
                                out.push((r, col0 + l));
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Fills `scratch.fast` (rows `area.r0..r1` x columns `area.c0..c1`, laid out as the
/// returned [`FastLayout`] says) with the fast scores: the AVX2 + FMA kernel for
/// 10-tap filters when the CPU has them ([`FastV3`]), else the generic `pulp` pass.
fn fast_scores_dispatch(bank: &FilterBank, feats: &FhogImage, area: Area, scratch: &mut ScanScratch) -> FastLayout {
    let (nc, nr) = (area.c1 - area.c0, area.r1 - area.r0);
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        if bank.fw == TAPS && bank.fh == TAPS && nc >= V3_LANES {
            pulp::Simd::vectorize(
                v3,
                FastV3 {
                    v3,
                    bank,
                    feats,
                    area,
                    rowpass: &mut scratch.rowpass,
                    out: &mut scratch.fast,
                },
            );
            return FastLayout::Blocks { nc, nr };
        }
    }
    pulp::Arch::new().dispatch(FastScores {
        bank,
        feats,
        area,
        rowpass: &mut scratch.rowpass,
        out: &mut scratch.fast,
    });
    FastLayout::Rows { nc, nr }
}

/// Filter taps the AVX2 kernel is specialised for (dlib's 10 x 10 cell windows).
const TAPS: usize = 10;

/// f32 lanes of an AVX register.
const V3_LANES: usize = 8;

/// Input columns of one 8-column block of a 10-tap row pass.
#[cfg(target_arch = "x86_64")]
const SPAN: usize = V3_LANES + TAPS - 1;

/// Output rows of one step of the column pass (they share `TAPS - 1` input rows; with
/// the taps and one input row that fills the 16 AVX registers).
#[cfg(target_arch = "x86_64")]
const COL_ROWS: usize = 4;

/// The fast pass for 10 x 10 filters on AVX2 + FMA: the same sums as [`FastScores`],
/// computed per block of 8 output columns (the last block shifted left to end at the
/// area's last column): per term, the row pass of the block's columns over the rows
/// that are not entirely zero into a column of vectors (`rowpass`, one vector per
/// fHOG row, stays in L1), then the column pass from it, four output rows at a time,
/// into the block's scores (`out`, block after block, one vector per row). One
/// pointer and constant offsets per loop, taps in registers.
#[cfg(target_arch = "x86_64")]
struct FastV3<'a> {
    v3: pulp::x86::V3,
    bank: &'a FilterBank,
    feats: &'a FhogImage,
    area: Area,
    rowpass: &'a mut Vec<f32>,
    out: &'a mut Vec<f32>,
}

/// Eight floats from `s[at..]` as one vector.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn ld8(s: &[f32], at: usize) -> pulp::f32x8 {
    // a plain unaligned load (building the vector from elements lets LLVM turn the
    // ten overlapping loads of a window into chains of shuffles)
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&s[at..at + V3_LANES]))
}

/// Per fHOG plane, the rows `y0..y1` outside which every row is entirely zero
/// (`(0, 0)` for an all-zero plane).
#[cfg(target_arch = "x86_64")]
fn nonzero_rows(feats: &FhogImage) -> [(usize, usize); PLANES] {
    let w = feats.width;
    std::array::from_fn(|i| {
        let p = feats.plane(i);
        // no early exit, so that it vectorises (the zero rows are read whole anyway)
        let nonzero = |y: &usize| p[y * w..(y + 1) * w].iter().fold(0u32, |a, v| a | (v.to_bits() << 1)) != 0;
        let Some(y0) = (0..feats.height).find(nonzero) else {
            return (0, 0);
        };
        let y1 = (y0..feats.height).rev().find(nonzero).map_or(y0, |y| y + 1);
        (y0, y1)
    })
}

/// Row pass of one block: `tmp[y] = sum_k fr[k] plane[y][off + k..off + k + 8]` for
/// rows `y0..y1`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)] // plane geometry, taps and output, all needed
fn row_pass_block(
    v3: pulp::x86::V3,
    plane: &[f32],
    w: usize,
    off: usize,
    (y0, y1): (usize, usize),
    fr: &[pulp::f32x8; TAPS],
    tmp: &mut [pulp::f32x8],
) {
    for (y, t) in (y0..y1).zip(&mut tmp[y0..y1]) {
        let s = &plane[y * w + off..y * w + off + SPAN];
        // two chains of dependent multiply-adds (even and odd taps) instead of one
        let mut even = v3.mul_f32x8(ld8(s, 0), fr[0]);
        let mut odd = v3.mul_f32x8(ld8(s, 1), fr[1]);
        for k in (2..TAPS).step_by(2) {
            even = v3.mul_add_f32x8(ld8(s, k), fr[k], even);
            odd = v3.mul_add_f32x8(ld8(s, k + 1), fr[k + 1], odd);
        }
        *t = v3.add_f32x8(even, odd);
    }
}

/// Column pass of one block: `o[r] (+)= sum_m fc[m] tmp[r + m]` (`=` for the first
/// term), [`COL_ROWS`] output rows at a time.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn col_pass_block<const FIRST: bool>(
    v3: pulp::x86::V3,
    tmp: &[pulp::f32x8],
    fc: &[pulp::f32x8; TAPS],
    o: &mut [pulp::f32x8],
) {
    let zero = v3.splat_f32x8(0.0);
    let nr = o.len();
    let mut r = 0;
    while r + COL_ROWS <= nr {
        let x = &tmp[r..r + TAPS + COL_ROWS - 1];
        let oo = &mut o[r..r + COL_ROWS];
        let mut acc: [pulp::f32x8; COL_ROWS] = std::array::from_fn(|k| if FIRST { zero } else { oo[k] });
        for m in 0..TAPS + COL_ROWS - 1 {
            let xm = x[m];
            for (k, a) in acc.iter_mut().enumerate() {
                if m >= k && m - k < TAPS {
                    *a = v3.mul_add_f32x8(xm, fc[m - k], *a);
                }
            }
        }
        oo.copy_from_slice(&acc);
        r += COL_ROWS;
    }
    while r < nr {
        let x = &tmp[r..r + TAPS];
        let mut acc = if FIRST { zero } else { o[r] };
        for m in 0..TAPS {
            acc = v3.mul_add_f32x8(x[m], fc[m], acc);
        }
        o[r] = acc;
        r += 1;
    }
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for FastV3<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let FastV3 {
            v3,
            bank,
            feats,
            area,
            rowpass,
            out,
        } = self;
        let (w, h) = (feats.width, feats.height);
        let hc = bank.fw / 2;
        let nc = area.c1 - area.c0;
        let nr = area.r1 - area.r0;
        let nb = nc.div_ceil(V3_LANES);
        let len = nb * nr * V3_LANES;
        if out.len() != len {
            // (every value is written by the first term)
            out.clear();
            out.resize(len, 0.0);
        }
        rowpass.clear();
        rowpass.resize(nb * h * V3_LANES, 0.0);
        let out: &mut [pulp::f32x8] = bytemuck::cast_slice_mut(&mut out[..]);
        let tmp: &mut [pulp::f32x8] = bytemuck::cast_slice_mut(&mut rowpass[..]);
        let zero = v3.splat_f32x8(0.0);
        let live_rows = nonzero_rows(feats);
        // rows of every block of `tmp` that may hold non-zero values
        let mut dirty = (0usize, 0usize);
        let mut first = true;
        for term in &bank.terms {
            let (y0, y1) = live_rows[term.plane];
            if y0 == y1 && !first {
                // an all-zero plane adds zeros
                continue;
            }
            let plane = feats.plane(term.plane);
            // row passes of all blocks, then the column passes (so that only one set
            // of taps is live at a time)
            let fr: [pulp::f32x8; TAPS] = std::array::from_fn(|k| v3.splat_f32x8(term.row[k]));
            for (b, t) in tmp.chunks_exact_mut(h).enumerate() {
                // rows outside `y0..y1` are zero rows of the plane: zero them in `tmp`
                if dirty.0 < dirty.1 {
                    t[dirty.0..y0.clamp(dirty.0, dirty.1)].fill(zero);
                    t[y1.clamp(dirty.0, dirty.1)..dirty.1].fill(zero);
                }
                let j = (b * V3_LANES).min(nc - V3_LANES);
                row_pass_block(v3, plane, w, area.c0 - hc + j, (y0, y1), &fr, t);
            }
            dirty = (y0, y1);
            let fc: [pulp::f32x8; TAPS] = std::array::from_fn(|m| v3.splat_f32x8(term.col[m]));
            for (o, t) in out.chunks_exact_mut(nr).zip(tmp.chunks_exact(h)) {
                if first {
                    col_pass_block::<true>(v3, t, &fc, o);
                } else {
                    col_pass_block::<false>(v3, t, &fc, o);
                }
            }
            first = false;
        }
    }
}

/// The fast pass as a `pulp` operation (compiled for the dispatched CPU features).
struct FastScores<'a> {
    bank: &'a FilterBank,
    feats: &'a FhogImage,
    area: Area,
    rowpass: &'a mut Vec<f32>,
    out: &'a mut Vec<f32>,
}

/// `lanes` floats from the start of `s` as one vector (unaligned load).
#[inline(always)]
fn load<S: pulp::Simd>(s: &[f32]) -> S::f32s {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(s))
}

/// One vector into the start of `d`.
#[inline(always)]
fn store<S: pulp::Simd>(d: &mut [f32], v: S::f32s) {
    d.copy_from_slice(bytemuck::cast_slice(std::slice::from_ref(&v)));
}

impl pulp::WithSimd for FastScores<'_> {
    type Output = ();

    /// `s(r, c) = sum_terms sum_m col[m] sum_k row[k] H[r - hr + m][c - hc + k]`: per
    /// term a row pass into `rowpass`, then a column pass added into `out`, each on
    /// blocks of one vector of output columns kept in a register across the taps
    /// (`mul_add_e`: fused where the CPU has FMA), a scalar loop for the last columns.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let FastScores {
            bank,
            feats,
            area,
            rowpass,
            out,
        } = self;
        let lanes = std::mem::size_of::<S::f32s>() / std::mem::size_of::<f32>();
        let (w, h) = (feats.width, feats.height);
        let (hr, hc) = (bank.fh / 2, bank.fw / 2);
        let nc = area.c1 - area.c0;
        let nr = area.r1 - area.r0;
        out.clear();
        out.resize(nr * nc, 0.0);
        rowpass.clear();
        rowpass.resize(h * nc, 0.0);
        let blocks = nc / lanes * lanes;
        for term in &bank.terms {
            let plane = feats.plane(term.plane);
            let (fr, fcol) = (&term.row[..], &term.col[..]);
            let span = lanes + fr.len() - 1;
            // row pass: rowpass[y][j] = sum_k row[k] H[y][c0 - hc + j + k]
            for y in 0..h {
                let src = &plane[y * w + area.c0 - hc..(y + 1) * w];
                let dst = &mut rowpass[y * nc..(y + 1) * nc];
                let mut j = 0;
                while j < blocks {
                    let win = &src[j..j + span];
                    let mut acc = simd.splat_f32s(0.0);
                    for (k, &f) in fr.iter().enumerate() {
                        acc = simd.mul_add_e_f32s(load::<S>(&win[k..k + lanes]), simd.splat_f32s(f), acc);
                    }
                    store::<S>(&mut dst[j..j + lanes], acc);
                    j += lanes;
                }
                for j in blocks..nc {
                    let mut a = 0f32;
                    for (k, &f) in fr.iter().enumerate() {
                        a += src[j + k] * f;
                    }
                    dst[j] = a;
                }
            }
            // column pass: out[r][j] += sum_m col[m] rowpass[r - hr + m][j]
            for r in 0..nr {
                let top = area.r0 + r - hr;
                let rows = &rowpass[top * nc..(top + fcol.len()) * nc];
                let o = &mut out[r * nc..(r + 1) * nc];
                let mut j = 0;
                while j < blocks {
                    let mut acc = load::<S>(&o[j..j + lanes]);
                    for (m, &f) in fcol.iter().enumerate() {
                        let at = m * nc + j;
                        acc = simd.mul_add_e_f32s(load::<S>(&rows[at..at + lanes]), simd.splat_f32s(f), acc);
                    }
                    store::<S>(&mut o[j..j + lanes], acc);
                    j += lanes;
                }
                for j in blocks..nc {
                    let mut a = o[j];
                    for (m, &f) in fcol.iter().enumerate() {
                        a += rows[m * nc + j] * f;
                    }
                    o[j] = a;
                }
            }
        }
    }
}

/// The score image of one sub-detector on one fHOG image, written to `out`
/// (`height x width`, only [`Area`] is meaningful). Returns the valid area, or `None`
/// when the image is smaller than the filter or the bank has no terms.
pub fn saliency(bank: &FilterBank, feats: &FhogImage, scratch: &mut ScanScratch, out: &mut Vec<f32>) -> Option<Area> {
    let (w, h) = (feats.width, feats.height);
    let (fw, fh) = (bank.fw, bank.fh);
    if w < fw || h < fh || w == 0 || h == 0 {
        return None;
    }
    let area = Area {
        r0: fh / 2,
        r1: h - (fh - 1) / 2,
        c0: fw / 2,
        c1: w - (fw - 1) / 2,
    };
    out.clear();
    out.resize(w * h, 0.0);
    if bank.use_full {
        full_filter(bank, feats, area, out);
        return Some(area);
    }
    if bank.terms.is_empty() {
        return None;
    }
    scratch.rowpass.clear();
    scratch.rowpass.resize(w * h, 0.0);
    let tail = simd_end(area.c0, area.c1);
    let (hr, hc) = (fh / 2, fw / 2);
    for (t_idx, term) in bank.terms.iter().enumerate() {
        let plane = feats.plane(term.plane);
        // row pass on every row (rows that are entirely zero give zeros)
        for r in 0..h {
            let src = &plane[r * w..(r + 1) * w];
            let dst = &mut scratch.rowpass[r * w..(r + 1) * w];
            if src.iter().all(|&v| v == 0.0) {
                dst[area.c0..area.c1].iter_mut().for_each(|v| *v = 0.0);
                continue;
            }
            row_pass(src, &term.row, area.c0, tail, area.c1, hc, dst);
        }
        // column pass: dlib's three accumulators in its SIMD columns, written as
        // whole-row operations so they vectorise; a running sum in the scalar tail
        let rp = &scratch.rowpass;
        let nb = tail - area.c0;
        scratch.acc.resize(3 * w, 0.0);
        let (a0, rest) = scratch.acc.split_at_mut(w);
        let (a1, a2) = rest.split_at_mut(w);
        let n = term.col.len();
        let triples = if n >= 3 { (n - 3) / 3 + 1 } else { 0 };
        for r in area.r0..area.r1 {
            let base = r - hr;
            let row = |m: usize| &rp[(base + m) * w + area.c0..(base + m) * w + tail];
            let (a0, a1, a2) = (&mut a0[..nb], &mut a1[..nb], &mut a2[..nb]);
            a0.fill(0.0);
            a1.fill(0.0);
            a2.fill(0.0);
            for t in 0..triples {
                let m = 3 * t;
                let (f0, f1, f2) = (term.col[m], term.col[m + 1], term.col[m + 2]);
                for (((x0, x1), x2), ((p0, p1), p2)) in a0
                    .iter_mut()
                    .zip(a1.iter_mut())
                    .zip(a2.iter_mut())
                    .zip(row(m).iter().zip(row(m + 1)).zip(row(m + 2)))
                {
                    *x0 += p0 * f0;
                    *x1 += p1 * f1;
                    *x2 += p2 * f2;
                }
            }
            for m in 3 * triples..n {
                let f = term.col[m];
                for (x0, p) in a0.iter_mut().zip(row(m)) {
                    *x0 += p * f;
                }
            }
            let orow = &mut out[r * w + area.c0..r * w + tail];
            if t_idx == 0 {
                for (o, ((x0, x1), x2)) in orow.iter_mut().zip(a0.iter().zip(a1.iter()).zip(a2.iter())) {
                    *o = x0 + (x1 + x2);
                }
            } else {
                for (o, ((x0, x1), x2)) in orow.iter_mut().zip(a0.iter().zip(a1.iter()).zip(a2.iter())) {
                    *o += x0 + (x1 + x2);
                }
            }
            for c in tail..area.c1 {
                let v = dot_dlib(false, &term.col, |m| rp[(base + m) * w + c]);
                if t_idx == 0 {
                    out[r * w + c] = v;
                } else {
                    out[r * w + c] += v;
                }
            }
        }
    }
    Some(area)
}

/// Horizontal pass for output columns `c0..c1` of one row; `tail` is the first scalar
/// column. Written so the SIMD part vectorises across columns.
#[inline]
fn row_pass(src: &[f32], f: &[f32], c0: usize, tail: usize, c1: usize, hc: usize, dst: &mut [f32]) {
    let n = f.len();
    if n == 10 {
        let f: [f32; 10] = [f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9]];
        for c in c0..tail {
            let s = &src[c - hc..c - hc + 10];
            let t0 = (((s[0] * f[0]) + s[3] * f[3]) + s[6] * f[6]) + s[9] * f[9];
            let t1 = ((s[1] * f[1]) + s[4] * f[4]) + s[7] * f[7];
            let t2 = ((s[2] * f[2]) + s[5] * f[5]) + s[8] * f[8];
            dst[c] = t0 + (t1 + t2);
        }
    } else {
        for c in c0..tail {
            dst[c] = dot_dlib(true, f, |k| src[c - hc + k]);
        }
    }
    for c in tail..c1 {
        dst[c] = dot_dlib(false, f, |k| src[c - hc + k]);
    }
}

/// Full (non-separable) filtering, dlib's `float_spatially_filter_image` summed over
/// planes. Only used for models whose filters are not low rank.
fn full_filter(bank: &FilterBank, feats: &FhogImage, area: Area, out: &mut [f32]) {
    let (w, fw, fh) = (feats.width, bank.fw, bank.fh);
    let tail = simd_end(area.c0, area.c1);
    let (hr, hc) = (fh / 2, fw / 2);
    for i in 0..PLANES {
        let plane = feats.plane(i);
        let f = &bank.full[i * fw * fh..(i + 1) * fw * fh];
        for r in area.r0..area.r1 {
            for c in area.c0..area.c1 {
                let v = if c < tail {
                    let (mut t0, mut t1, mut t2) = (0f32, 0f32, 0f32);
                    for m in 0..fh {
                        let row = &plane[(r - hr + m) * w + c - hc..];
                        let fr = &f[m * fw..(m + 1) * fw];
                        let mut n = 0;
                        while n + 2 < fw {
                            t0 += row[n] * fr[n];
                            t1 += row[n + 1] * fr[n + 1];
                            t2 += row[n + 2] * fr[n + 2];
                            n += 3;
                        }
                        while n < fw {
                            t0 += row[n] * fr[n];
                            n += 1;
                        }
                    }
                    t0 + (t1 + t2)
                } else {
                    let mut t = 0f32;
                    for m in 0..fh {
                        for n in 0..fw {
                            t += plane[(r - hr + m) * w + c - hc + n] * f[m * fw + n];
                        }
                    }
                    t
                };
                if i == 0 {
                    out[r * w + c] = v;
                } else {
                    out[r * w + c] += v;
                }
            }
        }
    }
}

/// Slow reference: the exact (full-rank) window scores in f64.
pub fn saliency_reference_full(weights: &[f64], fw: usize, fh: usize, feats: &FhogImage) -> Option<(Area, Vec<f64>)> {
    let (w, h) = (feats.width, feats.height);
    if w < fw || h < fh || w == 0 {
        return None;
    }
    let area = Area {
        r0: fh / 2,
        r1: h - (fh - 1) / 2,
        c0: fw / 2,
        c1: w - (fw - 1) / 2,
    };
    let mut out = vec![0.0; w * h];
    for r in area.r0..area.r1 {
        for c in area.c0..area.c1 {
            let mut s = 0.0;
            for i in 0..PLANES {
                let p = feats.plane(i);
                for m in 0..fh {
                    for n in 0..fw {
                        s += weights[i * fw * fh + m * fw + n] * f64::from(p[(r - fh / 2 + m) * w + c - fw / 2 + n]);
                    }
                }
            }
            out[r * w + c] = s;
        }
    }
    Some((area, out))
}

/// Slow reference for the separable path: the same terms evaluated with plain
/// running sums in f64 (no association tricks).
pub fn saliency_reference_separable(bank: &FilterBank, feats: &FhogImage) -> Option<(Area, Vec<f64>)> {
    let (w, h) = (feats.width, feats.height);
    let (fw, fh) = (bank.fw, bank.fh);
    if w < fw || h < fh || w == 0 || bank.terms.is_empty() {
        return None;
    }
    let area = Area {
        r0: fh / 2,
        r1: h - (fh - 1) / 2,
        c0: fw / 2,
        c1: w - (fw - 1) / 2,
    };
    let mut out = vec![0.0; w * h];
    for t in &bank.terms {
        let p = feats.plane(t.plane);
        for r in area.r0..area.r1 {
            for c in area.c0..area.c1 {
                let mut s = 0.0;
                for m in 0..fh {
                    let mut rs = 0.0;
                    for n in 0..fw {
                        rs += f64::from(t.row[n]) * f64::from(p[(r - fh / 2 + m) * w + c - fw / 2 + n]);
                    }
                    s += f64::from(t.col[m]) * rs;
                }
                out[r * w + c] += s;
            }
        }
    }
    Some((area, out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// dlib's loops written literally, one output pixel at a time.
    fn literal(bank: &FilterBank, feats: &FhogImage) -> Option<(Area, Vec<f32>)> {
        let (w, h, fw, fh) = (feats.width, feats.height, bank.fw, bank.fh);
        let area = Area {
            r0: fh / 2,
            r1: h - (fh - 1) / 2,
            c0: fw / 2,
            c1: w - (fw - 1) / 2,
        };
        let tail = simd_end(area.c0, area.c1);
        let mut out = vec![0f32; w * h];
        for (t, term) in bank.terms.iter().enumerate() {
            let p = feats.plane(term.plane);
            let mut scratch = vec![0f32; w * h];
            for r in 0..h {
                for c in area.c0..area.c1 {
                    scratch[r * w + c] = dot_dlib(c < tail, &term.row, |k| p[r * w + c - fw / 2 + k]);
                }
            }
            for r in area.r0..area.r1 {
                for c in area.c0..area.c1 {
                    let v = dot_dlib(c < tail, &term.col, |m| scratch[(r - fh / 2 + m) * w + c]);
                    if t == 0 {
                        out[r * w + c] = v;
                    } else {
                        out[r * w + c] += v;
                    }
                }
            }
        }
        Some((area, out))
    }

    fn random_case(seed: u64, w: usize, h: usize) -> (Vec<f64>, FhogImage) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // low-rank filters (rank 1-3 per plane) like a trained detector
        let mut weights = Vec::new();
        for _ in 0..PLANES {
            let rank = rng.random_range(1..=3);
            let mut f = vec![0.0f64; 100];
            for _ in 0..rank {
                let u: Vec<f64> = (0..10).map(|_| rng.random_range(-0.1..0.1)).collect();
                let v: Vec<f64> = (0..10).map(|_| rng.random_range(-0.1..0.1)).collect();
                for m in 0..10 {
                    for n in 0..10 {
                        f[m * 10 + n] += u[m] * v[n];
                    }
                }
            }
            weights.extend(f);
        }
        weights.push(0.5);
        let mut feats = FhogImage {
            width: w,
            height: h,
            data: vec![0.0; PLANES * w * h],
        };
        for v in feats.data.iter_mut() {
            *v = rng.random_range(0.0..0.3);
        }
        (weights, feats)
    }

    #[test]
    fn jacobi_svd_reconstructs_rank_deficient_matrices() {
        let (weights, _) = random_case(5, 12, 12);
        for i in 0..PLANES {
            let a = &weights[i * 100..(i + 1) * 100];
            let (u, s, v) = jacobi_svd(a, 10, 10);
            for m in 0..10 {
                for n in 0..10 {
                    let rec: f64 = (0..10).map(|j| s[j] * u[j * 10 + m] * v[j * 10 + n]).sum();
                    assert!((rec - a[m * 10 + n]).abs() < 1e-14, "plane {i} ({m},{n})");
                }
            }
            // orthonormal right vectors
            for p in 0..10 {
                for q in 0..10 {
                    let d: f64 = (0..10).map(|k| v[p * 10 + k] * v[q * 10 + k]).sum();
                    assert!((d - if p == q { 1.0 } else { 0.0 }).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn separable_kernel_equals_literal_dlib_loops_bit_for_bit() {
        for (seed, w, h) in [(1u64, 40usize, 30usize), (2, 10, 10), (3, 27, 19), (4, 61, 12)] {
            let (weights, feats) = random_case(seed, w, h);
            let bank = FilterBank::new(&weights, 10, 10);
            assert!(!bank.use_full && !bank.terms.is_empty());
            let mut scratch = ScanScratch::default();
            let mut out = Vec::new();
            let area = saliency(&bank, &feats, &mut scratch, &mut out).unwrap();
            let (area2, lit) = literal(&bank, &feats).unwrap();
            assert_eq!(area, area2);
            for r in area.r0..area.r1 {
                for c in area.c0..area.c1 {
                    assert_eq!(
                        out[r * w + c].to_bits(),
                        lit[r * w + c].to_bits(),
                        "seed {seed} ({r},{c})"
                    );
                }
            }
        }
    }

    /// The exact scores of `saliency` at or above `thresh`, as `Hit`s.
    fn exact_hits(bank: &FilterBank, feats: &FhogImage, thresh: f64) -> Vec<Hit> {
        let mut scratch = ScanScratch::default();
        let mut sal = Vec::new();
        let area = saliency(bank, feats, &mut scratch, &mut sal).unwrap();
        let mut hits = Vec::new();
        for r in area.r0..area.r1 {
            for c in area.c0..area.c1 {
                let v = sal[r * feats.width + c];
                if f64::from(v) >= thresh {
                    hits.push(Hit { r, c, score: v });
                }
            }
        }
        hits
    }

    #[test]
    fn exact_score_at_equals_saliency_bit_for_bit() {
        for (seed, w, h) in [(11u64, 40usize, 30usize), (12, 10, 10), (13, 27, 19), (14, 61, 12)] {
            let (weights, feats) = random_case(seed, w, h);
            let bank = FilterBank::new(&weights, 10, 10);
            let mut scratch = ScanScratch::default();
            let mut sal = Vec::new();
            let area = saliency(&bank, &feats, &mut scratch, &mut sal).unwrap();
            let tail = simd_end(area.c0, area.c1);
            for r in area.r0..area.r1 {
                for c in area.c0..area.c1 {
                    let e = exact_score_at(&bank, &feats, tail, r, c);
                    assert_eq!(e.to_bits(), sal[r * w + c].to_bits(), "seed {seed} ({r},{c})");
                }
            }
        }
    }

    #[test]
    fn fast_scores_stay_far_within_the_recheck_margin() {
        // both the dispatched (AVX2 + FMA where present) and the portable pass
        let mut worst = 0f64;
        for (seed, w, h) in [(21u64, 87usize, 67usize), (22, 10, 10), (23, 33, 19), (24, 120, 15)] {
            let (weights, feats) = random_case(seed, w, h);
            let bank = FilterBank::new(&weights, 10, 10);
            let mut scratch = ScanScratch::default();
            let mut sal = Vec::new();
            let area = saliency(&bank, &feats, &mut scratch, &mut sal).unwrap();
            let (nc, nr) = (area.c1 - area.c0, area.r1 - area.r0);
            for portable in [false, true] {
                let layout = if portable {
                    let op = FastScores {
                        bank: &bank,
                        feats: &feats,
                        area,
                        rowpass: &mut scratch.rowpass,
                        out: &mut scratch.fast,
                    };
                    pulp::Simd::vectorize(pulp::Scalar, op);
                    FastLayout::Rows { nc, nr }
                } else {
                    fast_scores_dispatch(&bank, &feats, area, &mut scratch)
                };
                for r in area.r0..area.r1 {
                    for c in area.c0..area.c1 {
                        let fast = scratch.fast[layout.index(r - area.r0, c - area.c0)];
                        let d = f64::from(fast) - f64::from(sal[r * w + c]);
                        worst = worst.max(d.abs());
                    }
                }
            }
        }
        assert!(worst < EXACT_RECHECK_MARGIN / 100.0, "fast vs exact {worst:e}");
    }

    #[test]
    fn candidates_equal_the_exact_saliency_threshold() {
        for (seed, w, h) in [(31u64, 87usize, 67usize), (32, 10, 10), (33, 45, 40)] {
            let (weights, feats) = random_case(seed, w, h);
            let bank = FilterBank::new(&weights, 10, 10);
            let mut scratch = ScanScratch::default();
            let mut sal = Vec::new();
            let area = saliency(&bank, &feats, &mut scratch, &mut sal).unwrap();
            // thresholds at several quantiles of the scores, so some windows pass and
            // some sit just below
            let mut vals: Vec<f32> = (area.r0..area.r1)
                .flat_map(|r| (area.c0..area.c1).map(move |c| (r, c)))
                .map(|(r, c)| sal[r * w + c])
                .collect();
            vals.sort_by(f32::total_cmp);
            for q in [0.0, 0.5, 0.9, 0.99, 1.0] {
                let i = ((vals.len() - 1) as f64 * q) as usize;
                for thresh in [f64::from(vals[i]), f64::from(vals[i]) + 1e-7, f64::from(vals[i]) - 1e-3] {
                    let mut hits = Vec::new();
                    candidates(&bank, &feats, thresh, &mut scratch, &mut hits).unwrap();
                    let want = exact_hits(&bank, &feats, thresh);
                    assert_eq!(hits.len(), want.len(), "seed {seed} q {q}");
                    for (a, b) in hits.iter().zip(&want) {
                        assert_eq!((a.r, a.c, a.score.to_bits()), (b.r, b.c, b.score.to_bits()));
                    }
                }
            }
        }
    }

    #[test]
    fn separable_scores_approximate_the_full_filters() {
        let (weights, feats) = random_case(9, 45, 33);
        let bank = FilterBank::new(&weights, 10, 10);
        let mut scratch = ScanScratch::default();
        let mut out = Vec::new();
        let area = saliency(&bank, &feats, &mut scratch, &mut out).unwrap();
        let (_, full) = saliency_reference_full(&weights, 10, 10, &feats).unwrap();
        let (_, sep) = saliency_reference_separable(&bank, &feats).unwrap();
        for r in area.r0..area.r1 {
            for c in area.c0..area.c1 {
                let i = r * 45 + c;
                assert!(
                    (f64::from(out[i]) - sep[i]).abs() < 1e-4,
                    "f32 vs f64 separable at ({r},{c})"
                );
                assert!((sep[i] - full[i]).abs() < 1e-3, "separable vs full at ({r},{c})");
            }
        }
    }
}
