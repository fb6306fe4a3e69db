//! The per-point LK kernel (fixed-point, OpenCV-compatible). See the module docs of
//! [`super`] for the maths and the numeric conventions.

use std::cell::RefCell;

use nalgebra::Point2;
use wide::{i16x8, i32x4, u8x16};

use super::pyramid::{Pyramid, PyramidLevel, LANES};
use super::{LkParams, PointOutcome, TrackStatus};

/// Fractional bits of the bilinear weights (OpenCV `W_BITS`).
const W_BITS: i32 = 14;
/// Fractional bits kept for window intensities (`W_BITS - 5` are shifted away).
const INTENSITY_SHIFT: i32 = W_BITS - 5;
/// Scale of `G` and `b` (OpenCV `FLT_SCALE = 2^-20`).
const FLT_SCALE: f32 = 1.0 / (1 << 20) as f32;
/// Largest `|Σ diff·I'|` one chunk adds to one `i32` accumulator lane.
const MAX_LANE_ROW_SUM: usize = 2 * (255 * 32) * (16 * 255);
/// Oscillation test tolerance per axis (px), OpenCV's hard-coded 0.01.
const OSCILLATION_TOL: f32 = 0.01;

/// Per-call constants.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Config {
    pub window: usize,
    half: f32,
    levels: usize,
    max_iterations: usize,
    eps2: f64,
    min_eig: f32,
    fb: Option<f32>,
    require_convergence: bool,
    use_initial_flow: bool,
}

impl Config {
    pub fn new(p: &LkParams, levels: usize) -> Self {
        Config {
            window: p.window,
            half: (p.window as f32 - 1.0) * 0.5,
            levels,
            max_iterations: p.max_iterations,
            eps2: p.epsilon * p.epsilon,
            min_eig: p.min_eig_threshold as f32,
            fb: p.forward_backward.map(|t| t as f32),
            require_convergence: p.require_convergence,
            use_initial_flow: p.use_initial_flow,
        }
    }
}

/// Per-thread window buffers (see [`with_scratch`]).
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// Interpolated window of `I` (5 fractional bits), `window x wp`, lanes in
    /// [`LANE_ORDER`] within each chunk of 8, tail zero.
    i: Vec<i16>,
    /// Interpolated Scharr `Ix` of the window, same layout.
    dx: Vec<i16>,
    /// Interpolated Scharr `Iy` of the window, same layout.
    dy: Vec<i16>,
    /// Scharr `Ix` at integer pixels `(ipx + c, ipy + r)`, `r in 0..=window`,
    /// `c in 0..gs` (`gs = wp + LANES`), row stride `gs`.
    gx: Vec<i16>,
    /// Scharr `Iy`, same layout.
    gy: Vec<i16>,
    /// Horizontal Scharr difference `p[x+1] - p[x-1]`, pixel rows `ipy - 1 ..= ipy + window + 1`.
    hd: Vec<i16>,
    /// Horizontal Scharr smoothing `3 p[x-1] + 10 p[x] + 3 p[x+1]`, same rows.
    hs: Vec<i16>,
}

/// Window column (within its chunk of 8) held by each lane of the window
/// buffers: even columns first, then odd. Bilinear interpolation of 8 columns is
/// then two 8-byte loads per image row (at `x` and `x + 1`), whose zero-extended
/// `i16` pairs `(p[x+2k], p[x+2k+1])` and `(p[x+2k+1], p[x+2k+2])` feed `pmaddwd`
/// directly. All window sums are order-independent, so the order never shows.
pub(crate) const LANE_ORDER: [usize; 8] = [0, 2, 4, 6, 1, 3, 5, 7];

thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// Padded row length for window side `window` (multiple of [`LANES`]).
#[inline]
fn padded(window: usize) -> usize {
    window.next_multiple_of(LANES)
}

/// Runs `f` with this thread's window buffers (allocated on first use per
/// thread and window size, reused after).
pub(crate) fn with_scratch<R>(window: usize, f: impl FnOnce(&mut Scratch) -> R) -> R {
    SCRATCH.with(|c| {
        let mut guard = c.borrow_mut();
        let v = &mut *guard;
        let wp = padded(window);
        let n = window * wp;
        let g = (window + 1) * (wp + LANES);
        let h = (window + 3) * (wp + LANES);
        for (buf, len) in [
            (&mut v.i, n),
            (&mut v.dx, n),
            (&mut v.dy, n),
            (&mut v.gx, g),
            (&mut v.gy, g),
            (&mut v.hd, h),
            (&mut v.hs, h),
        ] {
            if buf.len() < len {
                buf.resize(len, 0);
            }
        }
        f(v)
    })
}

/// Outcome of one level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LevelStatus {
    Ok { iterations: usize, converged: bool },
    OutOfImage,
    LowTexture,
}

/// Bilinear weights `[iw00, iw01, iw10, iw11]` for fractions `a` (x) and `b` (y).
/// Each fits `i16` (at most `2^14`), which lets the compiler use 16-bit
/// multiply-add instructions for the products with `u8` / `i16` samples.
#[inline]
fn weights(a: f32, b: f32) -> [i16; 4] {
    let one = (1 << W_BITS) as f32;
    let w00 = ((1.0 - a) * (1.0 - b) * one).round_ties_even() as i32;
    let w01 = (a * (1.0 - b) * one).round_ties_even() as i32;
    let w10 = ((1.0 - a) * b * one).round_ties_even() as i32;
    let w11 = (1 << W_BITS) - w00 - w01 - w10;
    [w00 as i16, w01 as i16, w10 as i16, w11 as i16]
}

/// 8 bytes from the start of `s` into the low half of a vector (callers pass
/// `chunks_exact(8)` items; a short slice would read zeros, never out of bounds).
#[inline(always)]
fn load8_u8(s: &[u8]) -> u8x16 {
    match s.first_chunk::<8>() {
        Some(a) => u8x16::new([a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], 0, 0, 0, 0, 0, 0, 0, 0]),
        None => u8x16::ZERO,
    }
}

/// 8 `i16` from the start of `s` (same contract as [`load8_u8`]).
#[inline(always)]
fn load_i16(s: &[i16]) -> i16x8 {
    match s.first_chunk::<8>() {
        Some(a) => i16x8::new(*a),
        None => i16x8::ZERO,
    }
}

/// All-ones `i16` lanes for the window columns of the last chunk, zeros past `win`.
#[inline]
fn tail_mask(win: usize, wp: usize) -> i16x8 {
    let first = wp - LANES;
    i16x8::new(std::array::from_fn(
        |l| if first + LANE_ORDER[l] < win { -1 } else { 0 },
    ))
}

/// `s`, opaque to the optimiser (see [`mismatch_row`]).
#[inline(always)]
fn shifted<T>(s: &[T]) -> &[T] {
    std::hint::black_box(s)
}

/// Stores `v` at the start of `s` (`chunks_exact_mut(8)` items).
#[inline(always)]
fn store_i16(s: &mut [i16], v: i16x8) {
    if let Some(a) = s.first_chunk_mut::<8>() {
        *a = v.to_array();
    }
}

/// Interleaved weight pairs for `pmaddwd`: `([w00 w01]x4, [w10 w11]x4)`.
#[inline(always)]
fn weight_pairs(w: &[i16; 4]) -> (i16x8, i16x8) {
    (
        i16x8::new([w[0], w[1], w[0], w[1], w[0], w[1], w[0], w[1]]),
        i16x8::new([w[2], w[3], w[2], w[3], w[2], w[3], w[2], w[3]]),
    )
}

/// Bilinear sums (before descaling) of 8 window columns in [`LANE_ORDER`]:
/// `a0`, `a1` are the 8 bytes of the upper row starting at the first column and
/// one to the right, `b0`, `b1` the same for the lower row. Zero-extended to
/// `i16`, `a0` holds the pairs `(p[x+2k], p[x+2k+1])` of the even columns and `a1`
/// those of the odd ones, so each column is one `pmaddwd` lane with the weight
/// pairs, as in OpenCV's SSE2 path. Returns (even columns, odd columns).
#[inline(always)]
fn bilinear8_u8(a0: &[u8], a1: &[u8], b0: &[u8], b1: &[u8], w01: i16x8, w23: i16x8) -> (i32x4, i32x4) {
    let wid = |s: &[u8]| i16x8::from_u8x16_low(load8_u8(s));
    let even = wid(a0).dot(w01) + wid(b0).dot(w23);
    let odd = wid(a1).dot(w01) + wid(b1).dot(w23);
    (even, odd)
}

/// `CV_DESCALE(x, n)` on 8 lanes and packs to `i16` (values fit: no saturation).
#[inline(always)]
fn descale_pack(lo: i32x4, hi: i32x4, n: i32) -> i16x8 {
    let d = i32x4::splat(1 << (n - 1));
    i16x8::from_i32x8_saturate(bytemuck::cast([(lo + d) >> n, (hi + d) >> n]))
}

/// Bilinear interpolation of 8 window columns of a gradient patch in
/// [`LANE_ORDER`] (`g0`, `g1`: upper / lower row from the first column, `g0s`,
/// `g1s`: the same one column to the right), descaled by `W_BITS`.
#[inline(always)]
fn bilinear8_i16(g0: &[i16], g0s: &[i16], g1: &[i16], g1s: &[i16], w01: i16x8, w23: i16x8) -> i16x8 {
    let even = load_i16(g0).dot(w01) + load_i16(g1).dot(w23);
    let odd = load_i16(g0s).dot(w01) + load_i16(g1s).dot(w23);
    descale_pack(even, odd, W_BITS)
}

/// One window row of the iteration: interpolates `J` (rows `r0`, `r1`, at least
/// `wp + 1` values each) at the current sub-pixel offset, subtracts the stored
/// `I` (`CV_DESCALE(., W_BITS - 5) - I`) and adds `diff·Ix`, `diff·Iy` to the lane
/// accumulators. The tail lanes have `Ix = Iy = 0` and contribute nothing.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn mismatch_row(
    r0: &[u8],
    r1: &[u8],
    io: &[i16],
    dxo: &[i16],
    dyo: &[i16],
    w01: i16x8,
    w23: i16x8,
    acc: &mut (i32x4, i32x4),
) {
    let wp = io.len();
    // `shifted` keeps LLVM from rebuilding the load at x + 1 from the one at x
    // with shifts and byte inserts (slower than a second 8-byte load).
    let (a0, a1) = (
        r0[..wp].chunks_exact(LANES),
        shifted(&r0[1..wp + 1]).chunks_exact(LANES),
    );
    let (b0, b1) = (
        r1[..wp].chunks_exact(LANES),
        shifted(&r1[1..wp + 1]).chunks_exact(LANES),
    );
    let lanes = io
        .chunks_exact(LANES)
        .zip(dxo.chunks_exact(LANES))
        .zip(dyo.chunks_exact(LANES));
    for (((a0, a1), (b0, b1)), ((iv, xv), yv)) in a0.zip(a1).zip(b0.zip(b1)).zip(lanes) {
        let (even, odd) = bilinear8_u8(a0, a1, b0, b1, w01, w23);
        // |diff| <= 255 · 32: exact in i16.
        let d = descale_pack(even, odd, INTENSITY_SHIFT) - load_i16(iv);
        acc.0 += d.dot(load_i16(xv));
        acc.1 += d.dot(load_i16(yv));
    }
}

#[inline]
fn inside(ix: i32, iy: i32, win: i32, l: &PyramidLevel) -> bool {
    !(ix < -win || ix >= l.width as i32 || iy < -win || iy >= l.height as i32)
}

#[inline]
fn padded_index(l: &PyramidLevel, ix: i32, iy: i32) -> usize {
    (iy + l.border as i32) as usize * l.stride + (ix + l.border as i32) as usize
}

/// Scharr derivatives at the integer pixels `(ipx + c, ipy + r)`, `r in 0..=win`,
/// `c in 0..gs` (`gs = wp + LANES`, only `c <= win` are used), into `gx`, `gy`
/// (row stride `gs`). Separable: a horizontal pass per pixel row (`hd`, `hs`),
/// then a vertical one. Matches OpenCV's `calcScharrDeriv` on the reflect-101
/// level and its zero border: pixels outside the level get 0.
#[allow(clippy::too_many_arguments)]
fn scharr_patch(
    l: &PyramidLevel,
    ipx: i32,
    ipy: i32,
    win: usize,
    gs: usize,
    scratch_h: (&mut [i16], &mut [i16]),
    gx: &mut [i16],
    gy: &mut [i16],
) {
    let (hd, hs) = scratch_h;
    let (three, ten) = (i16x8::splat(3), i16x8::splat(10));
    let wid = |s: &[u8]| i16x8::from_u8x16_low(load8_u8(s));
    for r in 0..win + 3 {
        let b = padded_index(l, ipx - 1, ipy + r as i32 - 1);
        let row = &l.img[b..b + gs + 2];
        let q = row[..gs]
            .chunks_exact(LANES)
            .zip(row[1..gs + 1].chunks_exact(LANES))
            .zip(row[2..gs + 2].chunks_exact(LANES));
        let outs = hd[r * gs..(r + 1) * gs]
            .chunks_exact_mut(LANES)
            .zip(hs[r * gs..(r + 1) * gs].chunks_exact_mut(LANES));
        for (((q0, q1), q2), (od, os)) in q.zip(outs) {
            let (a0, a1, a2) = (wid(q0), wid(q1), wid(q2));
            store_i16(od, a2 - a0);
            store_i16(os, (a0 + a2) * three + a1 * ten);
        }
    }
    for r in 0..=win {
        let (u, m, d) = (r * gs, (r + 1) * gs, (r + 2) * gs);
        let gxr = gx[r * gs..(r + 1) * gs].chunks_exact_mut(LANES);
        let gyr = gy[r * gs..(r + 1) * gs].chunks_exact_mut(LANES);
        let hdv = hd[u..u + gs]
            .chunks_exact(LANES)
            .zip(hd[m..m + gs].chunks_exact(LANES))
            .zip(hd[d..d + gs].chunks_exact(LANES));
        let hsv = hs[u..u + gs].chunks_exact(LANES).zip(hs[d..d + gs].chunks_exact(LANES));
        for ((((hu, hm), hdn), (su, sd)), (ox, oy)) in hdv.zip(hsv).zip(gxr.zip(gyr)) {
            let (hu, hm, hdn) = (load_i16(hu), load_i16(hm), load_i16(hdn));
            store_i16(ox, (hu + hdn) * three + hm * ten);
            store_i16(oy, load_i16(sd) - load_i16(su));
        }
    }
    let (w, h) = (l.width as i32, l.height as i32);
    let wi = win as i32;
    if ipx < 0 || ipy < 0 || ipx + wi >= w || ipy + wi >= h {
        for r in 0..=win {
            let y = ipy + r as i32;
            for c in 0..=win {
                let x = ipx + c as i32;
                if x < 0 || y < 0 || x >= w || y >= h {
                    gx[r * gs + c] = 0;
                    gy[r * gs + c] = 0;
                }
            }
        }
    }
}

/// Tracks one point through all levels (and backwards when asked).
#[allow(clippy::too_many_arguments)]
pub(crate) fn track_point(
    cfg: &Config,
    prev: &Pyramid,
    next: &Pyramid,
    p: Point2<f64>,
    q: &mut Point2<f64>,
    status: &mut TrackStatus,
    err: &mut f64,
    scratch: &mut Scratch,
) -> PointOutcome {
    let p32 = [p.x as f32, p.y as f32];
    let init = if cfg.use_initial_flow && q.x.is_finite() && q.y.is_finite() {
        Some([q.x as f32, q.y as f32])
    } else {
        None
    };
    let (out, st, e, iters) = track_pyramid(cfg, prev, next, p32, init, true, scratch);
    let mut st = st;
    if st == TrackStatus::Tracked {
        if let Some(t) = cfg.fb {
            let (back, bst, _, _) = track_pyramid(cfg, next, prev, out, None, false, scratch);
            let (dx, dy) = (back[0] - p32[0], back[1] - p32[1]);
            if bst != TrackStatus::Tracked || (dx * dx + dy * dy).sqrt() > t {
                st = TrackStatus::LostForwardBackward;
            }
        }
    }
    *q = Point2::new(out[0] as f64, out[1] as f64);
    *status = st;
    *err = if st == TrackStatus::Tracked { e as f64 } else { f64::NAN };
    PointOutcome {
        status: st,
        iterations_level0: iters,
    }
}

/// Coarse-to-fine tracking of `p` from `ip` to `jp`: (position, status, error, level-0 steps).
fn track_pyramid(
    cfg: &Config,
    ip: &Pyramid,
    jp: &Pyramid,
    p: [f32; 2],
    init: Option<[f32; 2]>,
    want_err: bool,
    scratch: &mut Scratch,
) -> ([f32; 2], TrackStatus, f32, usize) {
    let max_level = cfg.levels - 1;
    let mut out = [0.0f32; 2];
    let mut status = TrackStatus::Tracked;
    let mut iters0 = 0;
    for level in (0..=max_level).rev() {
        let scale = 1.0 / (1u32 << level) as f32;
        let pl = [p[0] * scale, p[1] * scale];
        out = if level == max_level {
            match init {
                Some(g) => [g[0] * scale, g[1] * scale],
                None => pl,
            }
        } else {
            [out[0] * 2.0, out[1] * 2.0]
        };
        let r = track_level(cfg, ip.lvl(level), jp.lvl(level), pl, &mut out, scratch);
        if level == 0 {
            status = match r {
                LevelStatus::Ok { iterations, converged } => {
                    iters0 = iterations;
                    if cfg.require_convergence && !converged {
                        TrackStatus::LostNoConvergence
                    } else {
                        TrackStatus::Tracked
                    }
                }
                LevelStatus::OutOfImage => TrackStatus::LostOutOfImage,
                LevelStatus::LowTexture => TrackStatus::LostLowTexture,
            };
        }
    }
    let mut e = 0.0;
    if status == TrackStatus::Tracked && want_err {
        match window_error(cfg, jp.lvl(0), out, scratch) {
            Some(v) => e = v,
            None => status = TrackStatus::LostOutOfImage,
        }
    }
    (out, status, e, iters0)
}

/// One level of iterative LK. `out` holds the initial guess (level coordinates)
/// and receives the result. Leaves the interpolated window of `I` in `scratch`.
fn track_level(
    cfg: &Config,
    il: &PyramidLevel,
    jl: &PyramidLevel,
    pl: [f32; 2],
    out: &mut [f32; 2],
    scratch: &mut Scratch,
) -> LevelStatus {
    let win = cfg.window;
    let wp = padded(win);
    let wi = win as i32;
    let half = cfg.half;
    let px = pl[0] - half;
    let py = pl[1] - half;
    let ipx = px.floor() as i32;
    let ipy = py.floor() as i32;
    if !inside(ipx, ipy, wi, il) {
        return LevelStatus::OutOfImage;
    }
    let w = weights(px - ipx as f32, py - ipy as f32);
    let Scratch {
        i: ibuf,
        dx: dxbuf,
        dy: dybuf,
        gx,
        gy,
        hd,
        hs,
    } = scratch;
    let gs = wp + LANES;
    scharr_patch(il, ipx, ipy, win, gs, (hd, hs), gx, gy);
    let s = il.stride;
    let (mut a11, mut a12, mut a22) = (0i64, 0i64, 0i64);
    let base0 = padded_index(il, ipx, ipy);
    let (w01, w23) = weight_pairs(&w);
    // Lanes of the last chunk that lie inside the window (the rest are zeroed).
    let tail = tail_mask(win, wp);
    let nc = wp / LANES;
    for y in 0..win {
        let b = base0 + y * s;
        let r0 = &il.img[b..b + wp + 1];
        let r1 = &il.img[b + s..b + s + wp + 1];
        let (g0, g1) = (&gx[y * gs..(y + 1) * gs], &gx[(y + 1) * gs..(y + 2) * gs]);
        let (h0, h1) = (&gy[y * gs..(y + 1) * gs], &gy[(y + 1) * gs..(y + 2) * gs]);
        let gxs = g0[..wp]
            .chunks_exact(LANES)
            .zip(g0[1..wp + 1].chunks_exact(LANES))
            .zip(g1[..wp].chunks_exact(LANES).zip(g1[1..wp + 1].chunks_exact(LANES)));
        let gys = h0[..wp]
            .chunks_exact(LANES)
            .zip(h0[1..wp + 1].chunks_exact(LANES))
            .zip(h1[..wp].chunks_exact(LANES).zip(h1[1..wp + 1].chunks_exact(LANES)));
        let io = ibuf[y * wp..(y + 1) * wp].chunks_exact_mut(LANES);
        let dxo = dxbuf[y * wp..(y + 1) * wp].chunks_exact_mut(LANES);
        let dyo = dybuf[y * wp..(y + 1) * wp].chunks_exact_mut(LANES);
        let rows = r0[..wp]
            .chunks_exact(LANES)
            .zip(shifted(&r0[1..]).chunks_exact(LANES))
            .zip(r1[..wp].chunks_exact(LANES).zip(shifted(&r1[1..]).chunks_exact(LANES)));
        // |Ix|, |Iy| <= 16 · 255: a row of products fits i32.
        let (mut s11, mut s12, mut s22) = (i32x4::ZERO, i32x4::ZERO, i32x4::ZERO);
        for (k, ((((a0, a1), (b0, b1)), (((p0, p0s), (p1, p1s)), ((q0, q0s), (q1, q1s)))), ((io, dxo), dyo))) in
            rows.zip(gxs.zip(gys)).zip(io.zip(dxo).zip(dyo)).enumerate()
        {
            let m = if k + 1 == nc { tail } else { i16x8::splat(-1) };
            let (even, odd) = bilinear8_u8(a0, a1, b0, b1, w01, w23);
            let iv = descale_pack(even, odd, INTENSITY_SHIFT) & m;
            let xv = bilinear8_i16(p0, p0s, p1, p1s, w01, w23) & m;
            let yv = bilinear8_i16(q0, q0s, q1, q1s, w01, w23) & m;
            store_i16(io, iv);
            store_i16(dxo, xv);
            store_i16(dyo, yv);
            s11 += xv.dot(xv);
            s12 += xv.dot(yv);
            s22 += yv.dot(yv);
        }
        a11 += s11.reduce_add() as i64;
        a12 += s12.reduce_add() as i64;
        a22 += s22.reduce_add() as i64;
    }
    let a11 = a11 as f32 * FLT_SCALE;
    let a12 = a12 as f32 * FLT_SCALE;
    let a22 = a22 as f32 * FLT_SCALE;
    let det = a11 * a22 - a12 * a12;
    let min_eig = (a22 + a11 - ((a11 - a22) * (a11 - a22) + 4.0 * a12 * a12).sqrt()) / (2 * win * win) as f32;
    if min_eig < cfg.min_eig || det < f32::EPSILON {
        return LevelStatus::LowTexture;
    }
    let inv_det = 1.0 / det;
    let mut nx = out[0] - half;
    let mut ny = out[1] - half;
    let mut prev_delta = [0.0f32; 2];
    let sj = jl.stride;
    let mut iterations = 0;
    let mut converged = false;
    let (ibuf, dxbuf, dybuf) = (&ibuf[..win * wp], &dxbuf[..win * wp], &dybuf[..win * wp]);
    // Rows whose lane sums may share an i32 accumulator: one chunk adds at most
    // 2 · (255 · 32) · (16 · 255) per lane, i.e. 66 585 600.
    let flush_rows = (i32::MAX as usize / (MAX_LANE_ROW_SUM * (wp / LANES))).max(1);
    for j in 0..cfg.max_iterations {
        let inx = nx.floor() as i32;
        let iny = ny.floor() as i32;
        if !inside(inx, iny, wi, jl) {
            return LevelStatus::OutOfImage;
        }
        iterations = j + 1;
        let (w01, w23) = weight_pairs(&weights(nx - inx as f32, ny - iny as f32));
        let base = padded_index(jl, inx, iny);
        let (mut ib1, mut ib2) = (0i64, 0i64);
        let mut acc = (i32x4::ZERO, i32x4::ZERO);
        for (y, ((io, dxo), dyo)) in ibuf
            .chunks_exact(wp)
            .zip(dxbuf.chunks_exact(wp))
            .zip(dybuf.chunks_exact(wp))
            .enumerate()
        {
            let b = base + y * sj;
            let r0 = &jl.img[b..b + wp + 1];
            let r1 = &jl.img[b + sj..b + sj + wp + 1];
            mismatch_row(r0, r1, io, dxo, dyo, w01, w23, &mut acc);
            if (y + 1) % flush_rows == 0 {
                ib1 += acc.0.reduce_add() as i64;
                ib2 += acc.1.reduce_add() as i64;
                acc = (i32x4::ZERO, i32x4::ZERO);
            }
        }
        ib1 += acc.0.reduce_add() as i64;
        ib2 += acc.1.reduce_add() as i64;
        let b1 = ib1 as f32 * FLT_SCALE;
        let b2 = ib2 as f32 * FLT_SCALE;
        let dx = (a12 * b2 - a22 * b1) * inv_det;
        let dy = (a12 * b1 - a11 * b2) * inv_det;
        nx += dx;
        ny += dy;
        *out = [nx + half, ny + half];
        if (dx as f64) * (dx as f64) + (dy as f64) * (dy as f64) <= cfg.eps2 {
            converged = true;
            break;
        }
        if j > 0 && (dx + prev_delta[0]).abs() < OSCILLATION_TOL && (dy + prev_delta[1]).abs() < OSCILLATION_TOL {
            out[0] -= dx * 0.5;
            out[1] -= dy * 0.5;
            converged = true;
            break;
        }
        prev_delta = [dx, dy];
    }
    LevelStatus::Ok { iterations, converged }
}

/// OpenCV's error value: mean |J(window at out) - I(window)| in grey levels, or
/// `None` when the final window is outside the image. Needs the level-0 window of
/// `I` in `scratch` (left there by [`track_level`]).
fn window_error(cfg: &Config, jl: &PyramidLevel, out: [f32; 2], scratch: &Scratch) -> Option<f32> {
    let win = cfg.window;
    let wp = padded(win);
    let nx = out[0] - cfg.half;
    let ny = out[1] - cfg.half;
    let inx = nx.floor() as i32;
    let iny = ny.floor() as i32;
    if !inside(inx, iny, win as i32, jl) {
        return None;
    }
    let (w01, w23) = weight_pairs(&weights(nx - inx as f32, ny - iny as f32));
    let base = padded_index(jl, inx, iny);
    let s = jl.stride;
    let tail = tail_mask(win, wp);
    let nc = wp / LANES;
    let ones = i16x8::splat(1);
    let mut acc = i32x4::ZERO;
    for (y, io) in scratch.i[..win * wp].chunks_exact(wp).enumerate() {
        let b = base + y * s;
        let r0 = &jl.img[b..b + wp + 1];
        let r1 = &jl.img[b + s..b + s + wp + 1];
        let rows = r0[..wp]
            .chunks_exact(LANES)
            .zip(shifted(&r0[1..]).chunks_exact(LANES))
            .zip(r1[..wp].chunks_exact(LANES).zip(shifted(&r1[1..]).chunks_exact(LANES)));
        for (k, (((a0, a1), (b0, b1)), iv)) in rows.zip(io.chunks_exact(LANES)).enumerate() {
            let m = if k + 1 == nc { tail } else { i16x8::splat(-1) };
            let (even, odd) = bilinear8_u8(a0, a1, b0, b1, w01, w23);
            let d = (descale_pack(even, odd, INTENSITY_SHIFT) - load_i16(iv)) & m;
            // |d| <= 255 · 32, window sum < 2^31.
            acc += d.abs().dot(ones);
        }
    }
    Some(acc.reduce_add() as f32 / (32 * win * win) as f32)
}
