//! The per-point LK kernel (fixed-point, OpenCV-compatible). See the module docs of
//! [`super`] for the maths and the numeric conventions.

use std::cell::RefCell;

use nalgebra::Point2;

use super::pyramid::{Pyramid, PyramidLevel};
use super::{LkParams, PointOutcome, TrackStatus, MAX_WINDOW};

/// Fractional bits of the bilinear weights (OpenCV `W_BITS`).
const W_BITS: i32 = 14;
/// Fractional bits kept for window intensities (`W_BITS - 5` are shifted away).
const INTENSITY_SHIFT: i32 = W_BITS - 5;
/// Scale of `G` and `b` (OpenCV `FLT_SCALE = 2^-20`).
const FLT_SCALE: f32 = 1.0 / (1 << 20) as f32;
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

thread_local! {
    static SCRATCH: RefCell<Vec<i16>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's window buffer (`3 * window²` values; allocated
/// on first use per thread, reused after).
pub(crate) fn with_scratch<R>(window: usize, f: impl FnOnce(&mut [i16]) -> R) -> R {
    SCRATCH.with(|c| {
        let mut v = c.borrow_mut();
        let n = 3 * window * window;
        if v.len() < n {
            v.resize(n, 0);
        }
        f(&mut v[..n])
    })
}

/// Outcome of one level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LevelStatus {
    Ok { iterations: usize, converged: bool },
    OutOfImage,
    LowTexture,
}

#[inline]
fn descale(x: i32, n: i32) -> i32 {
    (x + (1 << (n - 1))) >> n
}

/// Bilinear weights `(iw00, iw01, iw10, iw11)` for fractions `a` (x) and `b` (y).
#[inline]
fn weights(a: f32, b: f32) -> (i32, i32, i32, i32) {
    let one = (1 << W_BITS) as f32;
    let w00 = ((1.0 - a) * (1.0 - b) * one).round_ties_even() as i32;
    let w01 = (a * (1.0 - b) * one).round_ties_even() as i32;
    let w10 = ((1.0 - a) * b * one).round_ties_even() as i32;
    (w00, w01, w10, (1 << W_BITS) - w00 - w01 - w10)
}

/// The weights as `f32` for [`interp_diff_row`].
#[inline]
fn weights_f32(w: (i32, i32, i32, i32)) -> [f32; 4] {
    [w.0 as f32, w.1 as f32, w.2 as f32, w.3 as f32]
}

/// `diff[x] = CV_DESCALE(bilinear(J) , 9) - I[x]` for one window row, in `f32`.
///
/// Exact: every product `u8 · w` (w <= 2^14) and every partial sum is an integer
/// below 255 · 2^14 < 2^24, so `f32` holds it exactly; adding 2^8 and scaling by
/// 2^-9 are exact too, and truncation of the non-negative result is the floor of
/// the integer shift. `f32` lets the compiler use SIMD without 32-bit integer
/// multiplies.
#[inline]
fn interp_diff_row(r0: &[u8], r1: &[u8], io: &[i16], w: [f32; 4], diff: &mut [i16]) {
    const HALF: f32 = (1 << (INTENSITY_SHIFT - 1)) as f32;
    const SCALE: f32 = 1.0 / (1 << INTENSITY_SHIFT) as f32;
    let n = diff.len();
    let (r0, r1, io) = (&r0[..n + 1], &r1[..n + 1], &io[..n]);
    for x in 0..n {
        let s = r0[x] as f32 * w[0] + r0[x + 1] as f32 * w[1] + r1[x] as f32 * w[2] + r1[x + 1] as f32 * w[3];
        let v = ((s + HALF) * SCALE) as i32;
        diff[x] = (v - io[x] as i32) as i16;
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
    scratch: &mut [i16],
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
    scratch: &mut [i16],
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
    scratch: &mut [i16],
) -> LevelStatus {
    let win = cfg.window;
    let wi = win as i32;
    let half = cfg.half;
    let px = pl[0] - half;
    let py = pl[1] - half;
    let ipx = px.floor() as i32;
    let ipy = py.floor() as i32;
    if !inside(ipx, ipy, wi, il) {
        return LevelStatus::OutOfImage;
    }
    let (w00, w01, w10, w11) = weights(px - ipx as f32, py - ipy as f32);
    let (ibuf, rest) = scratch.split_at_mut(win * win);
    let (dxbuf, dybuf) = rest.split_at_mut(win * win);
    let s = il.stride;
    let (mut a11, mut a12, mut a22) = (0i64, 0i64, 0i64);
    let base0 = padded_index(il, ipx, ipy);
    for y in 0..win {
        let b = base0 + y * s;
        let r0 = &il.img[b..b + win + 1];
        let r1 = &il.img[b + s..b + s + win + 1];
        let x0 = &il.ix[b..b + win + 1];
        let x1 = &il.ix[b + s..b + s + win + 1];
        let y0 = &il.iy[b..b + win + 1];
        let y1 = &il.iy[b + s..b + s + win + 1];
        let io = &mut ibuf[y * win..(y + 1) * win];
        let dxo = &mut dxbuf[y * win..(y + 1) * win];
        let dyo = &mut dybuf[y * win..(y + 1) * win];
        let (mut s11, mut s12, mut s22) = (0i64, 0i64, 0i64);
        for x in 0..win {
            let iv = descale(
                r0[x] as i32 * w00 + r0[x + 1] as i32 * w01 + r1[x] as i32 * w10 + r1[x + 1] as i32 * w11,
                INTENSITY_SHIFT,
            );
            let gx = descale(
                x0[x] as i32 * w00 + x0[x + 1] as i32 * w01 + x1[x] as i32 * w10 + x1[x + 1] as i32 * w11,
                W_BITS,
            );
            let gy = descale(
                y0[x] as i32 * w00 + y0[x + 1] as i32 * w01 + y1[x] as i32 * w10 + y1[x + 1] as i32 * w11,
                W_BITS,
            );
            io[x] = iv as i16;
            dxo[x] = gx as i16;
            dyo[x] = gy as i16;
            s11 += (gx * gx) as i64;
            s12 += (gx * gy) as i64;
            s22 += (gy * gy) as i64;
        }
        a11 += s11;
        a12 += s12;
        a22 += s22;
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
    let mut diff_row = [0i16; MAX_WINDOW];
    let sj = jl.stride;
    let mut iterations = 0;
    let mut converged = false;
    for j in 0..cfg.max_iterations {
        let inx = nx.floor() as i32;
        let iny = ny.floor() as i32;
        if !inside(inx, iny, wi, jl) {
            return LevelStatus::OutOfImage;
        }
        iterations = j + 1;
        let wf = weights_f32(weights(nx - inx as f32, ny - iny as f32));
        let base = padded_index(jl, inx, iny);
        let (mut ib1, mut ib2) = (0i64, 0i64);
        for y in 0..win {
            let b = base + y * sj;
            let r0 = &jl.img[b..b + win + 1];
            let r1 = &jl.img[b + sj..b + sj + win + 1];
            let io = &ibuf[y * win..(y + 1) * win];
            let dxo = &dxbuf[y * win..(y + 1) * win];
            let dyo = &dybuf[y * win..(y + 1) * win];
            let diff = &mut diff_row[..win];
            interp_diff_row(r0, r1, io, wf, diff);
            let (mut s1, mut s2) = (0i32, 0i32);
            for x in 0..win {
                s1 += diff[x] as i32 * dxo[x] as i32;
                s2 += diff[x] as i32 * dyo[x] as i32;
            }
            ib1 += s1 as i64;
            ib2 += s2 as i64;
        }
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
fn window_error(cfg: &Config, jl: &PyramidLevel, out: [f32; 2], scratch: &[i16]) -> Option<f32> {
    let win = cfg.window;
    let nx = out[0] - cfg.half;
    let ny = out[1] - cfg.half;
    let inx = nx.floor() as i32;
    let iny = ny.floor() as i32;
    if !inside(inx, iny, win as i32, jl) {
        return None;
    }
    let wf = weights_f32(weights(nx - inx as f32, ny - iny as f32));
    let base = padded_index(jl, inx, iny);
    let s = jl.stride;
    let mut acc = 0.0f32;
    let mut diff_row = [0i16; MAX_WINDOW];
    for y in 0..win {
        let b = base + y * s;
        let r0 = &jl.img[b..b + win + 1];
        let r1 = &jl.img[b + s..b + s + win + 1];
        let io = &scratch[y * win..(y + 1) * win];
        let diff = &mut diff_row[..win];
        interp_diff_row(r0, r1, io, wf, diff);
        for d in diff.iter() {
            acc += (*d as f32).abs();
        }
    }
    Some(acc / (32 * win * win) as f32)
}
