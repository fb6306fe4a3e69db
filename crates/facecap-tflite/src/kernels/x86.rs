//! The AVX-512 (x86-64-v4) level's register kernels, written over the vector width
//! ([`Lanes`]): `f32x16` blocks where a layer has 16 channels or more, `f32x8` blocks
//! (with 32 registers) elsewhere. Each entry point ([`gemm_at`], [`conv_direct_at`],
//! [`depthwise_at`]) is compiled once, out of line, inside the level's target features. Accumulators are explicit
//! vector types so that they stay in registers across the `k` loop (the array-of-floats
//! version of [`super::micro`] spills them to the stack).
//!
//! Every output value is summed in the same order at both widths (bias, then the taps
//! in `k` order, one fused multiply-add each, then the epilogue), so AVX-512 and AVX2
//! give the same bits; only how many channels one instruction carries differs.
//!
//! With AVX-512 the GEMM and the direct convolution take two consecutive full 16-wide
//! panels as one `M x 32` block (two `f32x16` per row), a lone 16-wide panel as `M x 16`;
//! 8- and 24-wide panels (layers of 8 channels, remainders) keep the `f32x8` blocks,
//! which then have 32 registers to live in.

use super::{Activation, Epilogue, Geom, Level, Packed, Panel, Post};
use pulp::bytemuck;
use pulp::x86::{V3, V4};
use pulp::{f32x16, f32x8};

/// Widest register block row, in floats (`3 x 8` or `2 x 16`).
const MAX_ROW: usize = 32;

/// Most accumulator vectors per row of a register block.
const MAX_V: usize = 3;

/// Runs `body` for `r = 0, 1, .., m - 1` (`m <= 12`, a constant), written out
/// statement by statement: each `r` is then a constant, so register-block arrays indexed
/// by it stay in registers (a loop the compiler chose not to unroll would index them at
/// run time and keep them in memory, storing every accumulator on every `k` step).
macro_rules! for_rows {
    ($m:expr, |$r:ident| $body:block) => {{
        for_rows!(@ $m, $r, $body, 0 1 2 3 4 5 6 7 8 9 10 11);
    }};
    (@ $m:expr, $r:ident, $body:block, $($i:literal)*) => {
        $(
            if $i < $m {
                let $r: usize = $i;
                $body
            }
        )*
    };
}

/// One vector width: its register type and the operations the kernels use.
pub trait Lanes: Copy {
    /// The register.
    type V: Copy;
    /// Whether a register block's weights come one panel per register (`[k][N]` each)
    /// rather than as one `[k][N * V]` panel.
    const SPLIT: bool;
    /// Floats per register.
    const N: usize;
    /// Most rows of a register block with `v` registers per row.
    fn block_rows(v: usize) -> usize;
    /// `x` in every lane.
    fn splat(self, x: f32) -> Self::V;
    /// `s[..N]`.
    fn load(self, s: &[f32]) -> Self::V;
    /// `out[..N] = v`.
    fn store(self, out: &mut [f32], v: Self::V);
    /// `a * b + c`, rounded once.
    fn fma(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    /// `a + b`.
    fn add(self, a: Self::V, b: Self::V) -> Self::V;
    /// Lane-wise maximum.
    fn max(self, a: Self::V, b: Self::V) -> Self::V;
    /// Lane-wise minimum.
    fn min(self, a: Self::V, b: Self::V) -> Self::V;
    /// [`micro_direct`] over `m <= block_rows(V)` rows, dispatched on `m`.
    fn block<const V: usize>(self, m: usize, b: &Block<'_>, out: &mut [f32]);
}

/// AVX2/FMA: eight floats per register, sixteen registers (or 32 under AVX-512).
#[derive(Debug, Clone, Copy)]
pub struct L8(pub V3);

impl Lanes for L8 {
    type V = f32x8;
    const N: usize = 8;
    const SPLIT: bool = false;

    #[inline(always)]
    fn block_rows(v: usize) -> usize {
        // 3 x 24: nine accumulators, three weight registers and a broadcast leave room
        // for the epilogue's constants (4 x 24 needs all sixteen registers, and the
        // compiler then keeps two accumulators in memory across the `k` loop).
        match v {
            1 => 8,
            2 => 6,
            _ => 3,
        }
    }
    #[inline(always)]
    fn splat(self, x: f32) -> f32x8 {
        self.0.splat_f32x8(x)
    }
    #[inline(always)]
    fn load(self, s: &[f32]) -> f32x8 {
        let mut t = [0.0f32; 8];
        t.copy_from_slice(&s[..8]);
        bytemuck::cast(t)
    }
    #[inline(always)]
    fn store(self, out: &mut [f32], v: f32x8) {
        let v: [f32; 8] = bytemuck::cast(v);
        if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut out[..8]) {
            *dst = v;
        }
    }
    #[inline(always)]
    fn fma(self, a: f32x8, b: f32x8, c: f32x8) -> f32x8 {
        self.0.mul_add_f32x8(a, b, c)
    }
    #[inline(always)]
    fn add(self, a: f32x8, b: f32x8) -> f32x8 {
        self.0.add_f32x8(a, b)
    }
    #[inline(always)]
    fn max(self, a: f32x8, b: f32x8) -> f32x8 {
        self.0.max_f32x8(a, b)
    }
    #[inline(always)]
    fn min(self, a: f32x8, b: f32x8) -> f32x8 {
        self.0.min_f32x8(a, b)
    }
    #[inline(always)]
    fn block<const V: usize>(self, m: usize, b: &Block<'_>, out: &mut [f32]) {
        match m {
            8 => micro_direct::<Self, 8, V>(self, b, out),
            7 => micro_direct::<Self, 7, V>(self, b, out),
            6 => micro_direct::<Self, 6, V>(self, b, out),
            5 => micro_direct::<Self, 5, V>(self, b, out),
            4 => micro_direct::<Self, 4, V>(self, b, out),
            3 => micro_direct::<Self, 3, V>(self, b, out),
            2 => micro_direct::<Self, 2, V>(self, b, out),
            _ => micro_direct::<Self, 1, V>(self, b, out),
        }
    }
}

/// AVX-512: sixteen floats per register, 32 registers.
#[derive(Debug, Clone, Copy)]
pub struct L16(pub V4);

impl Lanes for L16 {
    type V = f32x16;
    const N: usize = 16;
    const SPLIT: bool = true;

    #[inline(always)]
    fn block_rows(_v: usize) -> usize {
        // 12 x 32: 24 accumulators, two weight registers and a broadcast; the GEMM's
        // row chunk (24) is two blocks.
        12
    }
    #[inline(always)]
    fn splat(self, x: f32) -> f32x16 {
        self.0.splat_f32x16(x)
    }
    #[inline(always)]
    fn load(self, s: &[f32]) -> f32x16 {
        let mut t = [0.0f32; 16];
        t.copy_from_slice(&s[..16]);
        bytemuck::cast(t)
    }
    #[inline(always)]
    fn store(self, out: &mut [f32], v: f32x16) {
        let v: [f32; 16] = bytemuck::cast(v);
        if let Ok(dst) = <&mut [f32; 16]>::try_from(&mut out[..16]) {
            *dst = v;
        }
    }
    #[inline(always)]
    fn fma(self, a: f32x16, b: f32x16, c: f32x16) -> f32x16 {
        self.0.mul_add_f32x16(a, b, c)
    }
    #[inline(always)]
    fn add(self, a: f32x16, b: f32x16) -> f32x16 {
        self.0.add_f32x16(a, b)
    }
    #[inline(always)]
    fn max(self, a: f32x16, b: f32x16) -> f32x16 {
        self.0.max_f32x16(a, b)
    }
    #[inline(always)]
    fn min(self, a: f32x16, b: f32x16) -> f32x16 {
        self.0.min_f32x16(a, b)
    }
    #[inline(always)]
    fn block<const V: usize>(self, m: usize, b: &Block<'_>, out: &mut [f32]) {
        match m {
            12 => micro_direct::<Self, 12, V>(self, b, out),
            11 => micro_direct::<Self, 11, V>(self, b, out),
            10 => micro_direct::<Self, 10, V>(self, b, out),
            9 => micro_direct::<Self, 9, V>(self, b, out),
            8 => micro_direct::<Self, 8, V>(self, b, out),
            7 => micro_direct::<Self, 7, V>(self, b, out),
            6 => micro_direct::<Self, 6, V>(self, b, out),
            5 => micro_direct::<Self, 5, V>(self, b, out),
            4 => micro_direct::<Self, 4, V>(self, b, out),
            3 => micro_direct::<Self, 3, V>(self, b, out),
            2 => micro_direct::<Self, 2, V>(self, b, out),
            _ => micro_direct::<Self, 1, V>(self, b, out),
        }
    }
}

/// The register widths a kernel call may use: always AVX2, AVX-512 where the level has it.
#[derive(Debug, Clone, Copy)]
pub struct Widths {
    narrow: L8,
    wide: Option<L16>,
}

impl Widths {
    /// Whether 16-wide registers are available.
    #[inline(always)]
    fn has_wide(&self) -> bool {
        self.wide.is_some()
    }
}

/// An x86 SIMD level as a type: its target features and its register widths.
pub trait Kind: pulp::Simd + Copy {
    /// The register widths (a constant inside this level's target features).
    fn widths(self) -> Widths;
    /// The level as a value.
    fn level(self) -> Level;
}

impl Kind for V4 {
    #[inline(always)]
    fn widths(self) -> Widths {
        Widths {
            narrow: L8(*self),
            wide: Some(L16(self)),
        }
    }
    #[inline(always)]
    fn level(self) -> Level {
        Level::V4(self)
    }
}

/// [`gemm`] compiled once per level (out of line, inside the level's target features).
#[inline(never)]
pub fn gemm_at<K: Kind>(k: K, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    struct Op<'a, 'b, K> {
        k: K,
        a: &'a [f32],
        rows: usize,
        w: &'a Packed,
        ep: &'a Epilogue<'b>,
        out: &'a mut [f32],
    }
    impl<K: Kind> pulp::WithSimd for Op<'_, '_, K> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) {
            gemm(&self.k.widths(), self.a, self.rows, self.w, self.ep, self.out)
        }
    }
    k.vectorize(Op { k, a, rows, w, ep, out })
}

/// [`conv_direct`] compiled once per level (see [`gemm_at`]).
#[inline(never)]
pub fn conv_direct_at<K: Kind>(
    k: K,
    input: &[f32],
    g: &Geom,
    w: &Packed,
    ep: &Epilogue<'_>,
    col: &mut [f32],
    out: &mut [f32],
) {
    struct Op<'a, 'b, K> {
        k: K,
        input: &'a [f32],
        g: &'a Geom,
        w: &'a Packed,
        ep: &'a Epilogue<'b>,
        col: &'a mut [f32],
        out: &'a mut [f32],
    }
    impl<K: Kind> pulp::WithSimd for Op<'_, '_, K> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) {
            let Op {
                k,
                input,
                g,
                w,
                ep,
                col,
                out,
            } = self;
            conv_direct(k.level(), &k.widths(), input, g, w, ep, col, out)
        }
    }
    k.vectorize(Op {
        k,
        input,
        g,
        w,
        ep,
        col,
        out,
    })
}

/// [`depthwise`] / [`depthwise3x3`] compiled once per level (see [`gemm_at`]); `false`
/// when no register path fits the layer.
#[inline(never)]
pub fn depthwise_at<K: Kind>(
    k: K,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) -> bool {
    struct Op<'a, 'b, K> {
        k: K,
        input: &'a [f32],
        g: &'a Geom,
        filter: &'a [f32],
        bias: &'a [f32],
        ep: &'a Epilogue<'b>,
        out: &'a mut [f32],
    }
    impl<K: Kind> pulp::WithSimd for Op<'_, '_, K> {
        type Output = bool;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> bool {
            let Op {
                k,
                input,
                g,
                filter,
                bias,
                ep,
                out,
            } = self;
            depthwise_widths(&k.widths(), input, g, filter, bias, ep, out)
        }
    }
    k.vectorize(Op {
        k,
        input,
        g,
        filter,
        bias,
        ep,
        out,
    })
}

/// `V` consecutive vectors from `s`. (A plain loop: closures passed to
/// `std::array::from_fn` do not inherit the target features, so they are compiled out
/// of line and the registers around the call go through memory.)
#[inline(always)]
fn load_n<L: Lanes, const V: usize>(l: L, s: &[f32]) -> [L::V; V] {
    let mut v = [l.splat(0.0); V];
    for (j, vj) in v.iter_mut().enumerate() {
        *vj = l.load(&s[L::N * j..L::N * j + L::N]);
    }
    v
}

/// `M` slices of `len` floats starting `stride` floats apart from `s[base..]`.
#[inline(always)]
fn rows_of<const M: usize>(s: &[f32], base: usize, stride: usize, len: usize) -> [&[f32]; M] {
    let mut rows: [&[f32]; M] = [&[]; M];
    for (r, row) in rows.iter_mut().enumerate() {
        *row = &s[base + r * stride..base + r * stride + len];
    }
    rows
}

/// `x` through a fused activation, on a register.
#[inline(always)]
fn activate<L: Lanes>(l: L, act: Activation, x: L::V) -> L::V {
    match act {
        Activation::None => x,
        Activation::Relu => l.max(x, l.splat(0.0)),
        Activation::Relu6 => l.min(l.max(x, l.splat(0.0)), l.splat(6.0)),
        Activation::ReluN1To1 => l.min(l.max(x, l.splat(-1.0)), l.splat(1.0)),
    }
}

/// `acc[r] += sum_kk rows[r][kk] * W[kk]` over the rows' common length `k` (one
/// broadcast per row and `kk`, `V` weight registers per `kk`). The weights are one
/// panel `w[0]` of `[k][N * V]` floats, or with [`Lanes::SPLIT`] one `[k][N]` panel
/// per register (`w[j]`); both exactly `k` rows long, so the loads need no bounds checks.
#[inline(always)]
fn accumulate<L: Lanes, const M: usize, const V: usize>(
    l: L,
    acc: &mut [[L::V; V]; M],
    rows: [&[f32]; M],
    w: [&[f32]; V],
) {
    let k = rows[0].len();
    let n = L::N;
    if L::SPLIT {
        let mut ws: [&[f32]; V] = [&[]; V];
        for (wj, src) in ws.iter_mut().zip(w) {
            *wj = &src[..k * n];
        }
        for kk in 0..k {
            let mut wv = [l.splat(0.0); V];
            for (v, wj) in wv.iter_mut().zip(ws) {
                *v = l.load(&wj[kk * n..(kk + 1) * n]);
            }
            for r in 0..M {
                let x = l.splat(rows[r][kk]);
                for j in 0..V {
                    acc[r][j] = l.fma(x, wv[j], acc[r][j]);
                }
            }
        }
    } else {
        let panel = &w[0][..k * n * V];
        for kk in 0..k {
            let wv = load_n::<L, V>(l, &panel[kk * n * V..(kk + 1) * n * V]);
            for r in 0..M {
                let x = l.splat(rows[r][kk]);
                for j in 0..V {
                    acc[r][j] = l.fma(x, wv[j], acc[r][j]);
                }
            }
        }
    }
}

/// Epilogue and store of an `M x NV` register block: row `r` goes to
/// `out[r * ldo..]`, flat output index `at + r * ldo`, channels `c0..c0 + ncols`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn finish<L: Lanes, const M: usize, const V: usize>(
    l: L,
    acc: &[[L::V; V]; M],
    ep: &Epilogue<'_>,
    out: &mut [f32],
    at: usize,
    ldo: usize,
    c0: usize,
    ncols: usize,
) {
    let nv = L::N * V;
    if ncols == nv {
        // Vector epilogue: activation, residual add and ReLU / PReLU on the registers.
        let zero = l.splat(0.0);
        let alpha: [L::V; V] = match ep.post {
            Post::Prelu(al) => load_n::<L, V>(l, &al[c0..c0 + nv]),
            _ => [zero; V],
        };
        for_rows!(M, |r| {
            let off = r * ldo;
            let mut v = acc[r];
            for vj in v.iter_mut() {
                *vj = activate(l, ep.act, *vj);
            }
            if let Some(res) = ep.residual {
                let base = at + off;
                for (j, vj) in v.iter_mut().enumerate() {
                    *vj = l.add(*vj, l.load(&res[base + L::N * j..base + L::N * (j + 1)]));
                }
            }
            match ep.post {
                Post::None => {}
                Post::Relu => {
                    for vj in v.iter_mut() {
                        *vj = l.max(*vj, zero);
                    }
                }
                Post::Prelu(_) => {
                    for (vj, aj) in v.iter_mut().zip(alpha) {
                        *vj = l.fma(aj, l.min(*vj, zero), l.max(*vj, zero));
                    }
                }
            }
            for (j, vj) in v.iter().enumerate() {
                l.store(&mut out[off + L::N * j..off + L::N * (j + 1)], *vj);
            }
        });
    } else {
        for_rows!(M, |r| {
            let mut vals = [0.0f32; MAX_ROW];
            for (j, vj) in acc[r].iter().enumerate() {
                l.store(&mut vals[L::N * j..L::N * (j + 1)], *vj);
            }
            let vals = &mut vals[..ncols];
            ep.apply(vals, at + r * ldo, c0);
            out[r * ldo..r * ldo + ncols].copy_from_slice(vals);
        });
    }
}

/// One register block's operands: `M` output pixels `pstride` floats apart in the
/// input, the first one's patch row `ky < kh` at `input[base + ky * rstride..]` (`seg`
/// contiguous floats, the weights' rows `ky * seg..(ky + 1) * seg`); the weights `w`
/// as [`accumulate`] takes them, rows `stride` floats long; `N * V` biases; the output's flat
/// index `at`, row pitch `ldo`, channels `c0..c0 + ncols`.
#[derive(Clone, Copy)]
pub struct Block<'a> {
    input: &'a [f32],
    base: usize,
    pstride: usize,
    rstride: usize,
    kh: usize,
    seg: usize,
    w: [&'a [f32]; MAX_V],
    stride: usize,
    bias: &'a [f32],
    ep: &'a Epilogue<'a>,
    at: usize,
    ldo: usize,
    c0: usize,
    ncols: usize,
}

/// A register block of `M` pixels by `V` registers (see [`Block`]).
#[inline(always)]
fn micro_direct<L: Lanes, const M: usize, const V: usize>(l: L, b: &Block<'_>, out: &mut [f32]) {
    let mut acc = [load_n::<L, V>(l, b.bias); M];
    for ky in 0..b.kh {
        let rows = rows_of::<M>(b.input, b.base + ky * b.rstride, b.pstride, b.seg);
        // Each weight slice holds `kh * seg` rows of `stride` floats.
        let len = b.seg * b.stride;
        let mut w: [&[f32]; V] = [&[]; V];
        for (j, wj) in w.iter_mut().enumerate() {
            *wj = &b.w[j][ky * len..(ky + 1) * len];
        }
        accumulate::<L, M, V>(l, &mut acc, rows, w);
    }
    finish::<L, M, V>(l, &acc, b.ep, out, b.at, b.ldo, b.c0, b.ncols);
}

/// Panels `first..first + count` of a weight matrix, run as one register block of `v`
/// registers per row (`wide`: 16-float registers, one per 16-wide panel; otherwise
/// 8-float registers over one panel of `8 v` columns).
#[derive(Debug, Clone, Copy)]
struct Group {
    first: usize,
    count: usize,
    wide: bool,
    v: usize,
}

/// The register block group starting at panel `i`: with 16-wide registers, two
/// consecutive full 16-wide panels together, or a lone 16-wide one; 8- and 24-wide panels
/// (and every panel without 16-wide registers) alone, at 8 floats per register.
#[inline(always)]
fn group(panels: &[Panel], i: usize, wide: bool) -> Group {
    let p = panels[i];
    if wide && p.width == 16 {
        if let Some(q) = panels.get(i + 1) {
            if q.width == 16 && p.cols == 16 && q.cols == 16 && q.pc == p.pc + 16 {
                return Group {
                    first: i,
                    count: 2,
                    wide: true,
                    v: 2,
                };
            }
        }
        return Group {
            first: i,
            count: 1,
            wide: true,
            v: 1,
        };
    }
    Group {
        first: i,
        count: 1,
        wide: false,
        v: p.width / 8,
    }
}

/// Weights, bias, first channel and columns of a group, with its register stride.
#[inline(always)]
fn group_operands<'a>(w: &'a Packed, g: &Group) -> ([&'a [f32]; MAX_V], usize, &'a [f32], usize, usize) {
    let p = w.panels[g.first];
    let mut ws: [&[f32]; MAX_V] = [&[]; MAX_V];
    let mut ncols = 0;
    if g.wide {
        for (j, wj) in ws.iter_mut().enumerate().take(g.count) {
            let q = w.panels[g.first + j];
            *wj = &w.data[q.pc * w.k..(q.pc + q.width) * w.k];
            ncols += q.cols;
        }
        (ws, 16, &w.bias[p.pc..p.pc + 16 * g.count], p.c0, ncols)
    } else {
        // One panel for all registers (`accumulate` reads only the first).
        let panel = &w.data[p.pc * w.k..(p.pc + p.width) * w.k];
        for wj in ws.iter_mut().take(g.v) {
            *wj = panel;
        }
        (ws, p.width, &w.bias[p.pc..p.pc + p.width], p.c0, p.cols)
    }
}

/// Runs one block of a group at the widths it needs.
#[inline(always)]
fn run_block(widths: &Widths, g: &Group, m: usize, b: &Block<'_>, out: &mut [f32]) {
    if let (true, Some(l)) = (g.wide, widths.wide) {
        match g.v {
            1 => l.block::<1>(m, b, out),
            _ => l.block::<2>(m, b, out),
        }
        return;
    }
    let l = widths.narrow;
    match g.v {
        1 => l.block::<1>(m, b, out),
        2 => l.block::<2>(m, b, out),
        _ => l.block::<3>(m, b, out),
    }
}

/// Rows of a group's register block.
#[inline(always)]
fn group_rows(g: &Group) -> usize {
    if g.wide {
        return L16::block_rows(g.v);
    }
    L8::block_rows(g.v)
}

/// A convolution read straight from the input, without im2col (dilation 1; the
/// caller checks). With dilation 1 the taps of one kernel row of one output pixel
/// are `KW * Cin` contiguous input floats, in the packed weights' `k` order, so the
/// GEMM register blocks can broadcast them in place: per output row and panel group,
/// blocks of pixels whose taps are all inside the image. Pixels with a tap in the
/// padding (borders, and rows with a kernel row outside the image) go through
/// [`super::conv_rows`] (im2col patches in `col`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn conv_direct(
    level: Level,
    widths: &Widths,
    input: &[f32],
    g: &Geom,
    w: &Packed,
    ep: &Epilogue<'_>,
    col: &mut [f32],
    out: &mut [f32],
) {
    let (n, c) = (w.n, g.ic);
    let (kh, kw, sh, sw) = (g.win.kh, g.win.kw, g.win.sh, g.win.sw);
    let rstride = g.iw * c;
    let pstride = sw * c;
    // Output columns whose taps are all inside the input row.
    let (lo, hi) = g.interior(kw, sw);
    for oy in 0..g.oh {
        let p_row = oy * g.ow;
        let iy0 = (oy * sh).checked_sub(g.pt).filter(|&y| y + kh <= g.ih);
        let Some(iy0) = iy0.filter(|_| lo < hi) else {
            super::conv_rows(level, input, g, w, ep, col, out, p_row, p_row + g.ow);
            continue;
        };
        if lo > 0 {
            super::conv_rows(level, input, g, w, ep, col, out, p_row, p_row + lo);
        }
        let mut i = 0;
        while i < w.panels.len() {
            let grp = group(&w.panels, i, widths.has_wide());
            i += grp.count;
            let (ws, stride, bias, c0, ncols) = group_operands(w, &grp);
            let mr = group_rows(&grp);
            let mut ox = lo;
            while ox < hi {
                let m = (hi - ox).min(mr);
                let at = (p_row + ox) * n + c0;
                let b = Block {
                    input,
                    base: (iy0 * g.iw + ox * sw - g.pl) * c,
                    pstride,
                    rstride,
                    kh,
                    seg: kw * c,
                    w: ws,
                    stride,
                    bias,
                    ep,
                    at,
                    ldo: n,
                    c0,
                    ncols,
                };
                run_block(widths, &grp, m, &b, &mut out[at..]);
                ox += m;
            }
        }
        if hi < g.ow {
            super::conv_rows(level, input, g, w, ep, col, out, p_row + hi, p_row + g.ow);
        }
    }
}

/// [`super::gemm`] with the register blocks: chunk by chunk of rows, every panel group
/// over the chunk.
#[inline(always)]
fn gemm(widths: &Widths, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    let (k, n) = (w.k, w.n);
    if let (Some(l), [p]) = (widths.wide, w.panels.as_slice()) {
        if k == PAIR_K && n == PAIR_CHANNELS && p.width == PAIR_CHANNELS && p.cols == PAIR_CHANNELS {
            gemm_pairs(l, widths.narrow, a, rows, w, ep, out);
            return;
        }
    }
    let mut p0 = 0;
    while p0 < rows {
        let end = (p0 + super::CHUNK).min(rows);
        let mut i = 0;
        while i < w.panels.len() {
            let grp = group(&w.panels, i, widths.has_wide());
            i += grp.count;
            let (ws, stride, bias, c0, ncols) = group_operands(w, &grp);
            let mr = group_rows(&grp);
            let mut p = p0;
            while p < end {
                let m = (end - p).min(mr);
                let at = p * n + c0;
                // Rows of `a` are `k` floats apart: one kernel row of `k` taps.
                let b = Block {
                    input: a,
                    base: p * k,
                    pstride: k,
                    rstride: 0,
                    kh: 1,
                    seg: k,
                    w: ws,
                    stride,
                    bias,
                    ep,
                    at,
                    ldo: n,
                    c0,
                    ncols,
                };
                run_block(widths, &grp, m, &b, &mut out[at..]);
                p += m;
            }
        }
        p0 = end;
    }
}

/// [`finish`]'s vector epilogue on one register of [`gemm_pairs`] (two output pixels at
/// flat index `at`; `alpha` the PReLU slopes written twice). A function, not a closure:
/// closures do not inherit the target features and run out of line.
#[inline(always)]
fn pair_epilogue(l: L16, ep: &Epilogue<'_>, alpha: f32x16, v: f32x16, at: usize, out: &mut [f32]) {
    const W: usize = 2 * PAIR_CHANNELS;
    let zero = l.splat(0.0);
    let mut v = activate(l, ep.act, v);
    if let Some(res) = ep.residual {
        v = l.add(v, l.load(&res[at..at + W]));
    }
    match ep.post {
        Post::None => {}
        Post::Relu => v = l.max(v, zero),
        Post::Prelu(_) => v = l.fma(alpha, l.min(v, zero), l.max(v, zero)),
    }
    l.store(&mut out[at..at + W], v);
}

/// Reduction length of the pointwise layers [`gemm_pairs`] runs (`1x1 16 -> 8`).
const PAIR_K: usize = 16;

/// Pixel pairs per register block of [`gemm_pairs`].
const PAIR_ROWS: usize = 6;

/// A pointwise convolution `16 -> 8` with 16-lane registers that hold two neighbouring
/// output pixels (lanes 0-7 the channels of pixel `p`, 8-15 those of `p + 1`, which are
/// also neighbours in the output). Each pixel's 16 inputs are one register; one two-table
/// permute per `k` spreads input `k` of both pixels over their halves, against weight row
/// `k` written twice, so one 16-lane FMA does the work of two 8-lane ones. Each output is
/// still the bias, then one FMA per `k` in order, then [`finish`]'s epilogue, so the bits
/// are the same as on the 8-lane path (which takes the last odd pixels).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gemm_pairs(l: L16, narrow: L8, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    const K: usize = PAIR_K;
    const C: usize = PAIR_CHANNELS;
    let f = l.0.avx512f;
    let panel = &w.data[..K * C];
    let mut wd = [[0.0f32; 2 * C]; K];
    for (kk, row) in wd.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = panel[kk * C + j % C];
        }
    }
    let mut idx = [[0i32; 2 * C]; K];
    for (kk, row) in idx.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            // lanes 0-7 take input kk of the first table, 8-15 input kk of the second
            *v = (kk + if j < C { 0 } else { K }) as i32;
        }
    }
    let mut dup = [0.0f32; 2 * C];
    for (j, v) in dup.iter_mut().enumerate() {
        *v = w.bias[j % C];
    }
    let bias = l.load(&dup);
    let alpha = match ep.post {
        Post::Prelu(al) => {
            for (j, v) in dup.iter_mut().enumerate() {
                *v = al[j % C];
            }
            l.load(&dup)
        }
        _ => l.splat(0.0),
    };
    let zero = l.splat(0.0);
    let pairs = rows / 2;
    let mut q = 0;
    while q + PAIR_ROWS <= pairs {
        let base = 2 * q * K;
        let x = &a[base..base + 2 * PAIR_ROWS * K];
        let mut xs = [[zero; 2]; PAIR_ROWS];
        for_rows!(PAIR_ROWS, |r| {
            xs[r] = [l.load(&x[2 * r * K..]), l.load(&x[(2 * r + 1) * K..])];
        });
        let mut acc = [bias; PAIR_ROWS];
        for (wk, ik) in wd.iter().zip(&idx) {
            let wv = l.load(wk);
            let iv: core::arch::x86_64::__m512i = bytemuck::cast(*ik);
            for_rows!(PAIR_ROWS, |r| {
                let b: f32x16 = pulp::cast(f._mm512_permutex2var_ps(pulp::cast(xs[r][0]), iv, pulp::cast(xs[r][1])));
                acc[r] = l.fma(b, wv, acc[r]);
            });
        }
        for_rows!(PAIR_ROWS, |r| {
            pair_epilogue(l, ep, alpha, acc[r], (2 * (q + r)) * C, out);
        });
        q += PAIR_ROWS;
    }
    while q < pairs {
        let base = 2 * q * K;
        let x = [l.load(&a[base..]), l.load(&a[base + K..])];
        let mut acc = bias;
        for (wk, ik) in wd.iter().zip(&idx) {
            let iv: core::arch::x86_64::__m512i = bytemuck::cast(*ik);
            let b: f32x16 = pulp::cast(f._mm512_permutex2var_ps(pulp::cast(x[0]), iv, pulp::cast(x[1])));
            acc = l.fma(b, l.load(wk), acc);
        }
        pair_epilogue(l, ep, alpha, acc, 2 * q * C, out);
        q += 1;
    }
    if rows % 2 == 1 {
        // the last pixel: the 8-lane path's block of one row
        let p = rows - 1;
        let b = Block {
            input: a,
            base: p * K,
            pstride: K,
            rstride: 0,
            kh: 1,
            seg: K,
            w: [panel, &[], &[]],
            stride: C,
            bias: &w.bias[..C],
            ep,
            at: p * C,
            ldo: C,
            c0: 0,
            ncols: C,
        };
        narrow.block::<1>(1, &b, &mut out[p * C..]);
    }
}

/// Most kernel taps per axis of the register depthwise path.
pub const MAX_TAPS: usize = 8;

/// Output pixels per register block of [`depthwise3x3`].
const DW_BLOCK: usize = 4;

/// One output vector (channels `cb..cb + N` of pixel `(oy, ox)`) of a depthwise
/// convolution over the valid taps only: the border path of [`depthwise3x3`].
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn dw_pixel<L: Lanes>(
    l: L,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ty: &[(usize, usize)],
    ox: usize,
    cb: usize,
) -> L::V {
    let (c, kw) = (g.ic, g.win.kw);
    let mut acc = l.load(&bias[cb..cb + L::N]);
    for &(ky, iy) in ty {
        for kx in 0..kw {
            if let Some(ix) = g.ix(ox, kx) {
                let i = (iy * g.iw + ix) * c + cb;
                let w = (ky * kw + kx) * c + cb;
                acc = l.fma(l.load(&input[i..i + L::N]), l.load(&filter[w..w + L::N]), acc);
            }
        }
    }
    acc
}

/// 3x3 depthwise convolution (dilation 1, any stride, `c >= N`; the caller checks).
/// Row by row and `N` channels at a time: the nine weight vectors stay in registers over
/// the whole output row, and the interior columns run in blocks of [`DW_BLOCK`] pixels
/// whose overlapping input vectors are loaded once per block (stride 1: 6 loads per
/// input row for 4 pixels instead of 12). Border pixels (and rows with a tap outside
/// the image) take the tap-checked path.
#[inline(always)]
fn depthwise3x3<L: Lanes>(
    l: L,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) {
    match g.win.sw {
        1 => depthwise3x3_s::<L, 1>(l, input, g, filter, bias, ep, out),
        2 => depthwise3x3_s::<L, 2>(l, input, g, filter, bias, ep, out),
        _ => depthwise3x3_s::<L, 0>(l, input, g, filter, bias, ep, out),
    }
}

/// [`depthwise3x3`] with the column stride `S` fixed at compile time (`S = 0`: the
/// stride from `g`), so the overlapping loads of a block are recognised as such.
#[inline(always)]
fn depthwise3x3_s<L: Lanes, const S: usize>(
    l: L,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) {
    let c = g.ic;
    let sw = if S == 0 { g.win.sw } else { S };
    let row_len = g.iw * c;
    // Interior columns: all three taps inside the row.
    let (lo, hi) = g.interior(3, sw);
    for oy in 0..g.oh {
        let (ty, ny) = g.taps3(oy);
        let orow = oy * g.ow * c;
        // With `c % N != 0` the last block overlaps the one before: its channels are
        // computed twice, with the same arithmetic, and stored twice.
        for cb in (0..c).step_by(L::N).map(|cb| cb.min(c - L::N)) {
            let mut ox = 0;
            if ny == 3 {
                let b = l.load(&bias[cb..cb + L::N]);
                // Plain loops, not `std::array::from_fn`: its closures do not inherit
                // the target features and ran out of line, through the stack.
                let mut wv = [[l.splat(0.0); 3]; 3];
                for (ky, wrow) in wv.iter_mut().enumerate() {
                    for (kx, wk) in wrow.iter_mut().enumerate() {
                        let w = (ky * 3 + kx) * c + cb;
                        *wk = l.load(&filter[w..w + L::N]);
                    }
                }
                // All three taps inside: input rows `ty[0].1..ty[0].1 + 3`.
                let rows = rows_of::<3>(input, ty[0].1 * row_len, row_len, row_len);
                while ox < lo {
                    let v = dw_pixel(l, input, g, filter, bias, &ty, ox, cb);
                    l.store(&mut out[orow + ox * c + cb..], v);
                    ox += 1;
                }
                while ox + DW_BLOCK <= hi {
                    let x0 = (ox * sw - g.pl) * c + cb;
                    let mut acc = [b; DW_BLOCK];
                    for (row, w) in rows.iter().zip(&wv) {
                        let win = &row[x0..x0 + ((DW_BLOCK - 1) * sw + 2) * c + L::N];
                        for (j, a) in acc.iter_mut().enumerate() {
                            for (kx, wk) in w.iter().enumerate() {
                                let i = (j * sw + kx) * c;
                                *a = l.fma(l.load(&win[i..i + L::N]), *wk, *a);
                            }
                        }
                    }
                    for (j, a) in acc.iter().enumerate() {
                        l.store(&mut out[orow + (ox + j) * c + cb..], *a);
                    }
                    ox += DW_BLOCK;
                }
                while ox < hi {
                    let x0 = ox * sw - g.pl;
                    let mut a = b;
                    for (row, w) in rows.iter().zip(&wv) {
                        for (kx, wk) in w.iter().enumerate() {
                            let i = (x0 + kx) * c + cb;
                            a = l.fma(l.load(&row[i..i + L::N]), *wk, a);
                        }
                    }
                    l.store(&mut out[orow + ox * c + cb..], a);
                    ox += 1;
                }
            }
            while ox < g.ow {
                let v = dw_pixel(l, input, g, filter, bias, &ty[..ny], ox, cb);
                l.store(&mut out[orow + ox * c + cb..], v);
                ox += 1;
            }
        }
        if !ep.is_identity() {
            for ox in 0..g.ow {
                let a = orow + ox * c;
                ep.apply(&mut out[a..a + c], a, 0);
            }
        }
    }
}

/// Channels of the layers [`depthwise3x3_pairs`] runs.
const PAIR_CHANNELS: usize = 8;

/// Output pixel pairs per register block of [`depthwise3x3_pairs`].
const PAIR_BLOCK: usize = 4;

/// 3x3 depthwise convolution at stride 1 on 8 channels with 16-lane registers that hold two
/// neighbouring output pixels: lanes 0-7 the channels of pixel `x`, lanes 8-15 those of
/// `x + 1`, so one 16-float load at input pixel `x - pl + kx` is tap `kx` of both, against
/// the tap's weights written twice. Half the instructions of the 8-lane path on the
/// landmark model's four 128x128x8 layers. Each output is summed as in [`depthwise3x3_s`]
/// (bias, then the taps row by row), so the bits are the same; border pixels and an odd
/// last interior pixel take the 8-lane paths.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn depthwise3x3_pairs<L: Lanes, M: Lanes>(
    wide: L,
    narrow: M,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) {
    const C: usize = PAIR_CHANNELS;
    debug_assert!(L::N == 2 * C && M::N == C && g.ic == C && g.win.sw == 1);
    let row_len = g.iw * C;
    // Interior columns: all three taps inside the row.
    let (lo, hi) = g.interior(3, 1);
    // The nine taps' weights and the bias, each written twice.
    let mut wd = [[0.0f32; 2 * C]; 9];
    for (t, w) in wd.iter_mut().enumerate() {
        for (j, v) in w.iter_mut().enumerate() {
            *v = filter[t * C + j % C];
        }
    }
    let mut bd = [0.0f32; 2 * C];
    for (j, v) in bd.iter_mut().enumerate() {
        *v = bias[j % C];
    }
    for oy in 0..g.oh {
        let (ty, ny) = g.taps3(oy);
        let orow = oy * g.ow * C;
        let mut ox = 0;
        if ny == 3 {
            let b = wide.load(&bd);
            let mut wv = [[wide.splat(0.0); 3]; 3];
            for (ky, wrow) in wv.iter_mut().enumerate() {
                for (kx, wk) in wrow.iter_mut().enumerate() {
                    *wk = wide.load(&wd[ky * 3 + kx]);
                }
            }
            let rows = rows_of::<3>(input, ty[0].1 * row_len, row_len, row_len);
            while ox < lo {
                let v = dw_pixel(narrow, input, g, filter, bias, &ty, ox, 0);
                narrow.store(&mut out[orow + ox * C..], v);
                ox += 1;
            }
            while ox + 2 * PAIR_BLOCK <= hi {
                let x0 = (ox - g.pl) * C;
                let mut acc = [b; PAIR_BLOCK];
                for (row, w) in rows.iter().zip(&wv) {
                    let win = &row[x0..x0 + (2 * PAIR_BLOCK + 2) * C];
                    for (j, a) in acc.iter_mut().enumerate() {
                        for (kx, wk) in w.iter().enumerate() {
                            let i = (2 * j + kx) * C;
                            *a = wide.fma(wide.load(&win[i..i + 2 * C]), *wk, *a);
                        }
                    }
                }
                for (j, a) in acc.iter().enumerate() {
                    wide.store(&mut out[orow + (ox + 2 * j) * C..], *a);
                }
                ox += 2 * PAIR_BLOCK;
            }
            while ox + 2 <= hi {
                let x0 = (ox - g.pl) * C;
                let mut a = b;
                for (row, w) in rows.iter().zip(&wv) {
                    for (kx, wk) in w.iter().enumerate() {
                        let i = x0 + kx * C;
                        a = wide.fma(wide.load(&row[i..i + 2 * C]), *wk, a);
                    }
                }
                wide.store(&mut out[orow + ox * C..], a);
                ox += 2;
            }
            while ox < hi {
                let v = dw_pixel(narrow, input, g, filter, bias, &ty, ox, 0);
                narrow.store(&mut out[orow + ox * C..], v);
                ox += 1;
            }
        }
        while ox < g.ow {
            let v = dw_pixel(narrow, input, g, filter, bias, &ty[..ny], ox, 0);
            narrow.store(&mut out[orow + ox * C..], v);
            ox += 1;
        }
        if !ep.is_identity() {
            for ox in 0..g.ow {
                let a = orow + ox * C;
                ep.apply(&mut out[a..a + C], a, 0);
            }
        }
    }
}

/// [`super::depthwise`] with each `N`-channel accumulator kept in a register over all
/// taps (one store per output vector instead of a load and a store per tap). Needs
/// `c % N == 0` and kernels of at most [`MAX_TAPS`] per axis; the caller checks.
#[inline(always)]
fn depthwise<L: Lanes>(
    l: L,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) {
    let c = g.ic;
    let kw = g.win.kw;
    // (kernel index, input index) of the valid taps of the current row / column.
    let mut ty = [(0usize, 0usize); MAX_TAPS];
    let mut tx = [(0usize, 0usize); MAX_TAPS];
    for oy in 0..g.oh {
        let mut ny = 0;
        for ky in 0..g.win.kh {
            if let Some(iy) = g.iy(oy, ky) {
                ty[ny] = (ky, iy);
                ny += 1;
            }
        }
        let mut ox = 0;
        while ox < g.ow {
            // Four output pixels at once where all their taps are inside the row:
            // each weight vector is loaded once for the four.
            let interior = |o: usize| o * g.win.sw >= g.pl && o * g.win.sw - g.pl + (kw - 1) * g.win.dw < g.iw;
            if ox + 4 <= g.ow && interior(ox) && interior(ox + 3) {
                let at = (oy * g.ow + ox) * c;
                let x0 = ox * g.win.sw - g.pl;
                let step = g.win.sw * c;
                for cb in (0..c).step_by(L::N) {
                    let b = l.load(&bias[cb..cb + L::N]);
                    let mut acc = [b; 4];
                    for &(ky, iy) in &ty[..ny] {
                        let row = iy * g.iw * c + cb;
                        for kx in 0..kw {
                            let wi = (ky * kw + kx) * c + cb;
                            let w = l.load(&filter[wi..wi + L::N]);
                            let i0 = row + (x0 + kx * g.win.dw) * c;
                            for (j, a) in acc.iter_mut().enumerate() {
                                let i = i0 + j * step;
                                *a = l.fma(l.load(&input[i..i + L::N]), w, *a);
                            }
                        }
                    }
                    for (j, a) in acc.iter().enumerate() {
                        l.store(&mut out[at + j * c + cb..], *a);
                    }
                }
                for j in 0..4 {
                    let a = at + j * c;
                    ep.apply(&mut out[a..a + c], a, 0);
                }
                ox += 4;
                continue;
            }
            let mut nx = 0;
            for kx in 0..kw {
                if let Some(ix) = g.ix(ox, kx) {
                    tx[nx] = (kx, ix);
                    nx += 1;
                }
            }
            let at = (oy * g.ow + ox) * c;
            let px = &mut out[at..at + c];
            for cb in (0..c).step_by(L::N) {
                let mut acc = l.load(&bias[cb..cb + L::N]);
                for &(ky, iy) in &ty[..ny] {
                    for &(kx, ix) in &tx[..nx] {
                        let i = (iy * g.iw + ix) * c + cb;
                        let w = (ky * kw + kx) * c + cb;
                        acc = l.fma(l.load(&input[i..i + L::N]), l.load(&filter[w..w + L::N]), acc);
                    }
                }
                l.store(&mut px[cb..], acc);
            }
            ep.apply(px, at, 0);
            ox += 1;
        }
    }
}

/// Depthwise convolution at the widest registers that fit the channel count, or `false`
/// when no register path applies (the caller runs the portable one).
#[inline(always)]
fn depthwise_widths(
    widths: &Widths,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) -> bool {
    let w3 = g.win.kh == 3 && g.win.kw == 3 && g.win.dh == 1 && g.win.dw == 1;
    let small = g.win.kh <= MAX_TAPS && g.win.kw <= MAX_TAPS;
    if let Some(l) = widths.wide {
        if w3 && g.ic == PAIR_CHANNELS && g.win.sw == 1 {
            depthwise3x3_pairs(l, widths.narrow, input, g, filter, bias, ep, out);
            return true;
        }
        if w3 && g.ic >= 16 {
            depthwise3x3(l, input, g, filter, bias, ep, out);
            return true;
        }
        if small && g.ic % 16 == 0 {
            depthwise(l, input, g, filter, bias, ep, out);
            return true;
        }
    }
    let l = widths.narrow;
    if w3 && g.ic >= 8 {
        depthwise3x3(l, input, g, filter, bias, ep, out);
        true
    } else if small && g.ic % 8 == 0 {
        depthwise(l, input, g, filter, bias, ep, out);
        true
    } else {
        false
    }
}
