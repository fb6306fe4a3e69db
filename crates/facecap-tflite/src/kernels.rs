//! Float32 NHWC kernels of the interpreter, each with a slow obvious reference
//! (`reference` module) that the tests compare against on seeded random inputs.
//!
//! Layouts (TFLite's): activations `[1, H, W, C]` row-major; convolution filters
//! `[Cout, KH, KW, Cin]`; depthwise filters `[1, KH, KW, C]`; biases `[Cout]`.
//!
//! Convolution is a GEMM: `out[p, co] = bias[co] + sum_k A[p, k] W[k, co]` where `A` is
//! the input itself for 1x1 stride-1 convolutions and an im2col matrix
//! (`k = (ky * KW + kx) * Cin + ci`) otherwise. `W` is packed at load into column panels
//! of 8, 16 or 24 output channels ([`panel_widths`]: `[panel][k][width]`, zero-padded),
//! and an `M x width` register block of accumulators runs over `k` with fused
//! multiply-adds (AVX2: `8 x 8`, `6 x 16` or `4 x 24`, at most twelve accumulator
//! registers). The kernels are written
//! as plain loops over fixed-size arrays and are compiled inside a `pulp` dispatch, so
//! they vectorise with AVX2/FMA where the CPU has them (the interpreter calls them from
//! one [`pulp::WithSimd`] body per inference).

use super::model::{Activation, Window};

/// Widest packed panel, in output channels (three 8-lane registers).
pub const MAX_NR: usize = 24;

/// Rows (output pixels) per register block of the portable kernel.
pub const MR: usize = 4;
/// Rows per chunk of the GEMM: every panel of a layer runs over one chunk of `A` rows
/// (in L1) before the next chunk; a multiple of every register block's row count.
const CHUNK: usize = 24;

/// What a convolution does to its sums after the bias and fused activation: add a
/// residual tensor of the output's shape (a following `ADD`), then apply a following
/// `RELU` or `PRELU`. Fusing these saves two passes over the activations.
#[derive(Debug, Clone, Copy)]
pub struct Epilogue<'a> {
    /// Activation fused into the convolution itself (applied first).
    pub act: Activation,
    /// Residual added after `act`, laid out like the output.
    pub residual: Option<&'a [f32]>,
    /// Activation applied after the residual.
    pub post: Post<'a>,
}

/// An activation following a convolution (see [`Epilogue`]).
#[derive(Debug, Clone, Copy)]
pub enum Post<'a> {
    /// Nothing.
    None,
    /// `max(x, 0)`.
    Relu,
    /// `x >= 0 ? x : alpha[channel] * x`.
    Prelu(&'a [f32]),
}

impl Epilogue<'_> {
    /// Whether the epilogue leaves the sums unchanged.
    #[inline(always)]
    fn is_identity(&self) -> bool {
        self.act == Activation::None && self.residual.is_none() && matches!(self.post, Post::None)
    }

    /// Only a fused activation.
    pub fn act(act: Activation) -> Epilogue<'static> {
        Epilogue {
            act,
            residual: None,
            post: Post::None,
        }
    }

    /// Applies the epilogue to `vals` (channels `c0..c0 + vals.len()` of the output
    /// element block starting at flat index `at`).
    #[inline(always)]
    fn apply(&self, vals: &mut [f32], at: usize, c0: usize) {
        let n = vals.len();
        if self.act != Activation::None {
            for v in vals.iter_mut() {
                *v = self.act.apply(*v);
            }
        }
        if let Some(r) = self.residual {
            for (v, &x) in vals.iter_mut().zip(&r[at..at + n]) {
                *v += x;
            }
        }
        match self.post {
            Post::None => {}
            Post::Relu => {
                for v in vals.iter_mut() {
                    *v = v.max(0.0);
                }
            }
            Post::Prelu(alpha) => {
                for (v, &a) in vals.iter_mut().zip(&alpha[c0..c0 + n]) {
                    *v = if *v >= 0.0 { *v } else { *v * a };
                }
            }
        }
    }
}

/// One column panel of [`Packed`] weights: output channels `c0..c0 + cols`, stored
/// `width` wide (zero-padded past `cols`) from padded column `pc` on (weights at
/// `data[pc * k..]` as `[k][width]`, bias at `bias[pc..pc + width]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Panel {
    /// First output channel.
    pub c0: usize,
    /// Output channels held (`<= width`).
    pub cols: usize,
    /// Stored width: 8, 16 or 24 (one, two or three 8-lane registers).
    pub width: usize,
    /// Padded column of the panel's first channel.
    pub pc: usize,
}

/// Panel widths for `n` output channels: 16-wide panels (two registers), the remainder
/// of `n % 16 <= 8` merged into one 24-wide panel (or an 8-wide one when `n <= 8`), so
/// that 8-, 24- and 40-channel layers multiply no zero columns.
pub fn panel_widths(n: usize) -> Vec<usize> {
    let (q, r) = (n / 16, n % 16);
    let mut v = vec![16; q];
    match r {
        0 => {}
        1..=8 if q > 0 => v[q - 1] = 24,
        1..=8 => v.push(8),
        _ => v.push(16),
    }
    v
}

/// Convolution weights packed for [`gemm`].
#[derive(Debug, Clone)]
pub struct Packed {
    /// Reduction length (`KH * KW * Cin`).
    pub k: usize,
    /// Output channels.
    pub n: usize,
    /// Column panels ([`panel_widths`]).
    pub panels: Vec<Panel>,
    /// Panel after panel, each `[k][width]`.
    pub data: Vec<f32>,
    /// Bias per padded column (zero in the padding).
    pub bias: Vec<f32>,
}

impl Packed {
    /// Packs OHWI filters (`n` rows of `k` values) and an optional bias.
    pub fn new(filter: &[f32], bias: Option<&[f32]>, n: usize, k: usize) -> Packed {
        let mut panels = Vec::new();
        let (mut c0, mut pc) = (0, 0);
        for width in panel_widths(n) {
            let cols = (n - c0).min(width);
            panels.push(Panel { c0, cols, width, pc });
            c0 += cols;
            pc += width;
        }
        let mut data = vec![0.0; pc * k];
        let mut b = vec![0.0; pc];
        for p in &panels {
            for j in 0..p.cols {
                let co = p.c0 + j;
                for kk in 0..k {
                    data[p.pc * k + kk * p.width + j] = filter[co * k + kk];
                }
                if let Some(bias) = bias {
                    b[p.pc + j] = bias[co];
                }
            }
        }
        Packed {
            k,
            n,
            panels,
            data,
            bias: b,
        }
    }

    /// Weights and bias of panel `p`.
    #[inline(always)]
    fn panel(&self, p: &Panel) -> (&[f32], &[f32]) {
        (
            &self.data[p.pc * self.k..(p.pc + p.width) * self.k],
            &self.bias[p.pc..p.pc + p.width],
        )
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn micro<const M: usize, const W: usize>(
    a: &[f32],
    lda: usize,
    panel: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
    at: usize,
    ldo: usize,
    c0: usize,
    ncols: usize,
) {
    let mut acc = [[0.0f32; W]; M];
    let mut b = [0.0f32; W];
    b.copy_from_slice(&bias[..W]);
    for row in acc.iter_mut() {
        *row = b;
    }
    let k = panel.len() / W;
    let rows: [&[f32]; M] = std::array::from_fn(|r| &a[r * lda..r * lda + k]);
    for (kk, w) in panel.chunks_exact(W).enumerate() {
        let mut wv = [0.0f32; W];
        wv.copy_from_slice(w);
        for r in 0..M {
            let x = rows[r][kk];
            for j in 0..W {
                acc[r][j] = x.mul_add(wv[j], acc[r][j]);
            }
        }
    }
    for (r, row) in acc.iter_mut().enumerate() {
        store(row, ep, out, at, r * ldo, c0, ncols);
    }
}

/// Applies the epilogue to one register row and stores it at `out[off..]`. A full row
/// goes through fixed-size arrays: variable-length copies would become memmove calls.
#[inline(always)]
fn store<const W: usize>(
    vals: &mut [f32; W],
    ep: &Epilogue<'_>,
    out: &mut [f32],
    at: usize,
    off: usize,
    c0: usize,
    ncols: usize,
) {
    if ncols == W {
        ep.apply(vals, at + off, c0);
        if let Ok(dst) = <&mut [f32; W]>::try_from(&mut out[off..off + W]) {
            *dst = *vals;
        }
    } else {
        let vals = &mut vals[..ncols];
        ep.apply(vals, at + off, c0);
        for (d, &v) in out[off..off + ncols].iter_mut().zip(vals.iter()) {
            *d = v;
        }
    }
}

/// The AVX2/FMA register block: `MR_V3 x 16` accumulators in twelve `f32x8` registers,
/// written with explicit vector types so they stay in registers across the `k` loop
/// (the array-of-floats version of [`micro`] spills them to the stack). The AVX2 level
/// runs these, inlined into the interpreter's body, except the GEMM of the im2col
/// chunks ([`v3::gemm`], one out-of-line copy); the AVX-512 level runs [`x86`] (the same
/// blocks written over the register width, compiled once per kernel).
#[cfg(target_arch = "x86_64")]
mod v3 {
    use super::{Activation, Epilogue, Packed, Panel, Post, MAX_NR};
    use pulp::bytemuck;
    use pulp::f32x8;
    use pulp::x86::V3;
    use pulp::Simd;

    #[inline(always)]
    fn load(s: &[f32]) -> f32x8 {
        let mut t = [0.0f32; 8];
        t.copy_from_slice(&s[..8]);
        bytemuck::cast(t)
    }

    /// `V` consecutive vectors from `s`. (A plain loop: closures passed to
    /// `std::array::from_fn` do not inherit the AVX2 target features, so they are
    /// compiled out of line and the registers around the call go through memory.)
    #[inline(always)]
    fn load_n<const V: usize>(simd: V3, s: &[f32]) -> [f32x8; V] {
        let mut v = [simd.splat_f32x8(0.0); V];
        for (j, vj) in v.iter_mut().enumerate() {
            *vj = load(&s[8 * j..8 * j + 8]);
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
    fn activate(simd: V3, act: Activation, x: f32x8) -> f32x8 {
        match act {
            Activation::None => x,
            Activation::Relu => simd.max_f32s(x, simd.splat_f32x8(0.0)),
            Activation::Relu6 => simd.min_f32s(simd.max_f32s(x, simd.splat_f32x8(0.0)), simd.splat_f32x8(6.0)),
            Activation::ReluN1To1 => simd.min_f32s(simd.max_f32s(x, simd.splat_f32x8(-1.0)), simd.splat_f32x8(1.0)),
        }
    }

    /// `acc[r] += sum_kk rows[r][kk] * panel[kk]` over the rows' common length `k`
    /// (panel `[k][8V]`; one broadcast per row and `kk`, `V` weight registers per `kk`).
    #[inline(always)]
    fn accumulate<const M: usize, const V: usize>(
        simd: V3,
        acc: &mut [[f32x8; V]; M],
        rows: [&[f32]; M],
        panel: &[f32],
    ) {
        let k = rows[0].len();
        let panel = &panel[..k * 8 * V];
        for kk in 0..k {
            let wv = load_n::<V>(simd, &panel[kk * 8 * V..(kk + 1) * 8 * V]);
            for r in 0..M {
                let x = simd.splat_f32x8(rows[r][kk]);
                for j in 0..V {
                    acc[r][j] = simd.mul_add_f32x8(x, wv[j], acc[r][j]);
                }
            }
        }
    }

    /// Epilogue and store of an `M x 8V` register block: row `r` goes to
    /// `out[r * ldo..]`, flat output index `at + r * ldo`, channels `c0..c0 + ncols`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn finish<const M: usize, const V: usize>(
        simd: V3,
        acc: &[[f32x8; V]; M],
        ep: &Epilogue<'_>,
        out: &mut [f32],
        at: usize,
        ldo: usize,
        c0: usize,
        ncols: usize,
    ) {
        if ncols == 8 * V {
            // Vector epilogue: activation, residual add and ReLU / PReLU on the registers.
            let zero = simd.splat_f32x8(0.0);
            let alpha: [f32x8; V] = match ep.post {
                Post::Prelu(al) => load_n::<V>(simd, &al[c0..c0 + 8 * V]),
                _ => [zero; V],
            };
            for (r, row) in acc.iter().enumerate() {
                let off = r * ldo;
                let mut v = *row;
                for vj in v.iter_mut() {
                    *vj = activate(simd, ep.act, *vj);
                }
                if let Some(res) = ep.residual {
                    let base = at + off;
                    for j in 0..V {
                        v[j] = simd.add_f32s(v[j], load(&res[base + 8 * j..base + 8 * j + 8]));
                    }
                }
                match ep.post {
                    Post::None => {}
                    Post::Relu => {
                        for vj in v.iter_mut() {
                            *vj = simd.max_f32s(*vj, zero);
                        }
                    }
                    Post::Prelu(_) => {
                        for (vj, aj) in v.iter_mut().zip(alpha) {
                            *vj = simd.mul_add_f32x8(aj, simd.min_f32s(*vj, zero), simd.max_f32s(*vj, zero));
                        }
                    }
                }
                for (j, vj) in v.iter().enumerate() {
                    let vals: [f32; 8] = bytemuck::cast(*vj);
                    if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut out[off + 8 * j..off + 8 * j + 8]) {
                        *dst = vals;
                    }
                }
            }
        } else {
            for (r, row) in acc.iter().enumerate() {
                let mut vals = [0.0f32; MAX_NR];
                for (j, vj) in row.iter().enumerate() {
                    let t: [f32; 8] = bytemuck::cast(*vj);
                    vals[8 * j..8 * j + 8].copy_from_slice(&t);
                }
                let vals = &mut vals[..ncols];
                ep.apply(vals, at + r * ldo, c0);
                out[r * ldo..r * ldo + ncols].copy_from_slice(vals);
            }
        }
    }

    /// Most kernel taps per axis of the register depthwise path.
    pub const MAX_TAPS: usize = 8;

    /// Output pixels per register block of [`depthwise3x3`].
    const DW_BLOCK: usize = 4;

    /// One output vector (channels `cb..cb + 8` of pixel `(oy, ox)`) of a depthwise
    /// convolution over the valid taps only: the border path of [`depthwise3x3`].
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn dw_pixel(
        simd: V3,
        input: &[f32],
        g: &super::Geom,
        filter: &[f32],
        bias: &[f32],
        ty: &[(usize, usize)],
        ox: usize,
        cb: usize,
    ) -> f32x8 {
        let (c, kw) = (g.ic, g.win.kw);
        let mut acc = load(&bias[cb..cb + 8]);
        for &(ky, iy) in ty {
            for kx in 0..kw {
                if let Some(ix) = g.ix(ox, kx) {
                    let i = (iy * g.iw + ix) * c + cb;
                    let w = (ky * kw + kx) * c + cb;
                    acc = simd.mul_add_f32x8(load(&input[i..i + 8]), load(&filter[w..w + 8]), acc);
                }
            }
        }
        acc
    }

    #[inline(always)]
    fn store8(out: &mut [f32], o: usize, v: f32x8) {
        let v: [f32; 8] = bytemuck::cast(v);
        if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut out[o..o + 8]) {
            *dst = v;
        }
    }

    /// 3x3 depthwise convolution (dilation 1, any stride, `c >= 8`; the caller
    /// checks). Row by row and 8 channels at a time: the nine weight vectors stay in
    /// registers over the whole output row, and the interior columns run in blocks of
    /// [`DW_BLOCK`] pixels whose overlapping input vectors are loaded once per block
    /// (stride 1: 6 loads per input row for 4 pixels instead of 12). Border pixels
    /// (and rows with a tap outside the image) take the tap-checked path.
    #[inline(always)]
    pub fn depthwise3x3(
        simd: V3,
        input: &[f32],
        g: &super::Geom,
        filter: &[f32],
        bias: &[f32],
        ep: &Epilogue<'_>,
        out: &mut [f32],
    ) {
        match g.win.sw {
            1 => depthwise3x3_s::<1>(simd, input, g, filter, bias, ep, out),
            2 => depthwise3x3_s::<2>(simd, input, g, filter, bias, ep, out),
            _ => depthwise3x3_s::<0>(simd, input, g, filter, bias, ep, out),
        }
    }

    /// [`depthwise3x3`] with the column stride `S` fixed at compile time (`S = 0`: the
    /// stride from `g`), so the overlapping loads of a block are recognised as such.
    #[inline(always)]
    fn depthwise3x3_s<const S: usize>(
        simd: V3,
        input: &[f32],
        g: &super::Geom,
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
            // With `c % 8 != 0` the last block overlaps the one before: its channels are
            // computed twice, with the same arithmetic, and stored twice.
            for cb in (0..c).step_by(8).map(|cb| cb.min(c - 8)) {
                let mut ox = 0;
                if ny == 3 {
                    let b = load(&bias[cb..cb + 8]);
                    // Plain loops, not `std::array::from_fn`: its closures do not inherit
                    // the AVX2 target features and ran out of line, through the stack.
                    let mut wv = [[simd.splat_f32x8(0.0); 3]; 3];
                    for (ky, wrow) in wv.iter_mut().enumerate() {
                        for (kx, wk) in wrow.iter_mut().enumerate() {
                            let w = (ky * 3 + kx) * c + cb;
                            *wk = load(&filter[w..w + 8]);
                        }
                    }
                    // All three taps inside: input rows `ty[0].1..ty[0].1 + 3`.
                    let rows = rows_of::<3>(input, ty[0].1 * row_len, row_len, row_len);
                    while ox < lo {
                        store8(
                            out,
                            orow + ox * c + cb,
                            dw_pixel(simd, input, g, filter, bias, &ty, ox, cb),
                        );
                        ox += 1;
                    }
                    while ox + DW_BLOCK <= hi {
                        let x0 = (ox * sw - g.pl) * c + cb;
                        let mut acc = [b; DW_BLOCK];
                        for (row, w) in rows.iter().zip(&wv) {
                            let win = &row[x0..x0 + ((DW_BLOCK - 1) * sw + 2) * c + 8];
                            for (j, a) in acc.iter_mut().enumerate() {
                                for (kx, wk) in w.iter().enumerate() {
                                    let i = (j * sw + kx) * c;
                                    *a = simd.mul_add_f32x8(load(&win[i..i + 8]), *wk, *a);
                                }
                            }
                        }
                        for (j, a) in acc.iter().enumerate() {
                            store8(out, orow + (ox + j) * c + cb, *a);
                        }
                        ox += DW_BLOCK;
                    }
                    while ox < hi {
                        let x0 = ox * sw - g.pl;
                        let mut a = b;
                        for (row, w) in rows.iter().zip(&wv) {
                            for (kx, wk) in w.iter().enumerate() {
                                let i = (x0 + kx) * c + cb;
                                a = simd.mul_add_f32x8(load(&row[i..i + 8]), *wk, a);
                            }
                        }
                        store8(out, orow + ox * c + cb, a);
                        ox += 1;
                    }
                }
                while ox < g.ow {
                    store8(
                        out,
                        orow + ox * c + cb,
                        dw_pixel(simd, input, g, filter, bias, &ty[..ny], ox, cb),
                    );
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

    /// [`super::depthwise`] with each 8-channel accumulator kept in a register over all
    /// taps (one store per output vector instead of a load and a store per tap). Needs
    /// `c % 8 == 0` and kernels of at most [`MAX_TAPS`] per axis; the caller checks.
    #[inline(always)]
    pub fn depthwise(
        simd: V3,
        input: &[f32],
        g: &super::Geom,
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
                    for cb in (0..c).step_by(8) {
                        let b = load(&bias[cb..cb + 8]);
                        let mut acc = [b; 4];
                        for &(ky, iy) in &ty[..ny] {
                            let row = iy * g.iw * c + cb;
                            for kx in 0..kw {
                                let w = load(&filter[(ky * kw + kx) * c + cb..(ky * kw + kx) * c + cb + 8]);
                                let i0 = row + (x0 + kx * g.win.dw) * c;
                                for (j, a) in acc.iter_mut().enumerate() {
                                    let i = i0 + j * step;
                                    *a = simd.mul_add_f32x8(load(&input[i..i + 8]), w, *a);
                                }
                            }
                        }
                        for (j, a) in acc.iter().enumerate() {
                            let v: [f32; 8] = bytemuck::cast(*a);
                            let o = at + j * c + cb;
                            if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut out[o..o + 8]) {
                                *dst = v;
                            }
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
                for cb in (0..c).step_by(8) {
                    let mut acc = load(&bias[cb..cb + 8]);
                    for &(ky, iy) in &ty[..ny] {
                        for &(kx, ix) in &tx[..nx] {
                            let i = (iy * g.iw + ix) * c + cb;
                            let w = (ky * kw + kx) * c + cb;
                            acc = simd.mul_add_f32x8(load(&input[i..i + 8]), load(&filter[w..w + 8]), acc);
                        }
                    }
                    let v: [f32; 8] = bytemuck::cast(acc);
                    if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut px[cb..cb + 8]) {
                        *dst = v;
                    }
                }
                ep.apply(px, at, 0);
                ox += 1;
            }
        }
    }

    /// Rows of the register block for a panel of `v` registers.
    pub const fn block_rows(v: usize) -> usize {
        // 3 x 24: nine accumulators, three weight registers and a broadcast leave room
        // for the epilogue's constants (4 x 24 needs all sixteen registers, and the
        // compiler then keeps two accumulators in memory across the `k` loop).
        match v {
            1 => 8,
            2 => 6,
            _ => 3,
        }
    }

    /// One panel over rows `p..p + m` (`m <= block_rows`), dispatched on the block shape.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn block<const V: usize>(
        simd: V3,
        m: usize,
        a: &[f32],
        k: usize,
        panel: &[f32],
        bias: &[f32],
        ep: &Epilogue<'_>,
        out: &mut [f32],
        at: usize,
        n: usize,
        c0: usize,
        ncols: usize,
    ) {
        // rows of `a` are `k` floats apart: one kernel row of `panel.len() / 8V` taps
        let seg = (1, panel.len() / (8 * V));
        block_direct::<V>(simd, m, a, 0, k, 0, seg, panel, bias, ep, out, at, n, c0, ncols);
    }

    /// A register block of [`conv_direct`]: `M` output pixels `pstride` floats apart
    /// in the input, the first one's patch row `ky < kh` at `input[base + ky * rstride..]`
    /// (`seg = KW * Cin` contiguous floats, the panel's rows `ky * seg..(ky + 1) * seg`).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn micro_direct<const M: usize, const V: usize>(
        simd: V3,
        input: &[f32],
        base: usize,
        pstride: usize,
        rstride: usize,
        (kh, seg): (usize, usize),
        panel: &[f32],
        bias: &[f32],
        ep: &Epilogue<'_>,
        out: &mut [f32],
        at: usize,
        ldo: usize,
        c0: usize,
        ncols: usize,
    ) {
        let mut acc = [load_n::<V>(simd, bias); M];
        let len = seg * 8 * V;
        for ky in 0..kh {
            let rows = rows_of::<M>(input, base + ky * rstride, pstride, seg);
            accumulate(simd, &mut acc, rows, &panel[ky * len..(ky + 1) * len]);
        }
        finish(simd, &acc, ep, out, at, ldo, c0, ncols);
    }

    /// [`micro_direct`] over `m <= block_rows(V)` pixels, dispatched on `m`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn block_direct<const V: usize>(
        simd: V3,
        m: usize,
        input: &[f32],
        base: usize,
        pstride: usize,
        rstride: usize,
        seg: (usize, usize),
        panel: &[f32],
        bias: &[f32],
        ep: &Epilogue<'_>,
        out: &mut [f32],
        at: usize,
        n: usize,
        c0: usize,
        ncols: usize,
    ) {
        let (i, b, p, r, s) = (input, base, pstride, rstride, seg);
        match m {
            8 => micro_direct::<8, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            7 => micro_direct::<7, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            6 => micro_direct::<6, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            5 => micro_direct::<5, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            4 => micro_direct::<4, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            3 => micro_direct::<3, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            2 => micro_direct::<2, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
            _ => micro_direct::<1, V>(simd, i, b, p, r, s, panel, bias, ep, out, at, n, c0, ncols),
        }
    }

    /// A convolution read straight from the input, without im2col (dilation 1; the
    /// caller checks). With dilation 1 the taps of one kernel row of one output pixel
    /// are `KW * Cin` contiguous input floats, in the packed weights' `k` order, so the
    /// GEMM register blocks can broadcast them in place: per output row and panel,
    /// blocks of pixels whose taps are all inside the image. Pixels with a tap in the
    /// padding (borders, and rows with a kernel row outside the image) go through
    /// [`super::conv_rows`] (im2col patches in `col`).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn conv_direct(
        simd: V3,
        input: &[f32],
        g: &super::Geom,
        w: &Packed,
        ep: &Epilogue<'_>,
        col: &mut [f32],
        out: &mut [f32],
    ) {
        let level = super::Level::V3(simd);
        let (n, c) = (w.n, g.ic);
        let (kh, kw, sh, sw) = (g.win.kh, g.win.kw, g.win.sh, g.win.sw);
        // Kernel rows and floats per kernel row (passed together; the kernel row count
        // is not derived from the panel length, a division per block).
        let seg = (kh, kw * c);
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
            let mut panels: &[Panel] = &w.panels;
            if hi - lo == 1 {
                // One pixel (the landmark model's heads: a 2x2 window over a 2x2 input):
                // four 16-wide panels at a time.
                while let [p0, p1, p2, p3, rest @ ..] = panels {
                    let four = [*p0, *p1, *p2, *p3];
                    if four.iter().any(|p| p.width != 16) {
                        break;
                    }
                    let base = (iy0 * g.iw + lo * sw - g.pl) * c;
                    gemv4(simd, input, base, rstride, seg, w, &four, ep, out, (p_row + lo) * n);
                    panels = rest;
                }
            }
            for pn in panels {
                let (panel, bias) = w.panel(pn);
                let v = pn.width / 8;
                let mr = block_rows(v);
                let mut ox = lo;
                while ox < hi {
                    let m = (hi - ox).min(mr);
                    let base = (iy0 * g.iw + ox * sw - g.pl) * c;
                    let at = (p_row + ox) * n + pn.c0;
                    let o = &mut out[at..];
                    let (ps, rs) = (pstride, rstride);
                    match v {
                        1 => block_direct::<1>(
                            simd, m, input, base, ps, rs, seg, panel, bias, ep, o, at, n, pn.c0, pn.cols,
                        ),
                        2 => block_direct::<2>(
                            simd, m, input, base, ps, rs, seg, panel, bias, ep, o, at, n, pn.c0, pn.cols,
                        ),
                        _ => block_direct::<3>(
                            simd, m, input, base, ps, rs, seg, panel, bias, ep, o, at, n, pn.c0, pn.cols,
                        ),
                    }
                    ox += m;
                }
            }
            if hi < g.ow {
                super::conv_rows(level, input, g, w, ep, col, out, p_row + hi, p_row + g.ow);
            }
        }
    }

    /// One output pixel (flat output index `at`, its patch row `ky` at
    /// `input[base + ky * rstride..]`, `seg = (kh, KW * Cin)`) against four 16-wide
    /// panels at once: eight accumulators, where one panel alone has two, each waiting
    /// on the latency of its last fused multiply-add. Each output is summed in
    /// [`micro_direct`]'s order, so the bits are the same.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn gemv4(
        simd: V3,
        input: &[f32],
        base: usize,
        rstride: usize,
        (kh, seg): (usize, usize),
        w: &Packed,
        four: &[Panel; 4],
        ep: &Epilogue<'_>,
        out: &mut [f32],
        at: usize,
    ) {
        let len = seg * 16;
        let mut acc = [[simd.splat_f32x8(0.0); 2]; 4];
        let mut panels: [&[f32]; 4] = [&[]; 4];
        for q in 0..4 {
            let (panel, bias) = w.panel(&four[q]);
            acc[q] = load_n::<2>(simd, bias);
            panels[q] = &panel[..kh * len];
        }
        for ky in 0..kh {
            let row = &input[base + ky * rstride..base + ky * rstride + seg];
            for (kk, &xv) in row.iter().enumerate() {
                let x = simd.splat_f32x8(xv);
                let o = ky * len + kk * 16;
                for q in 0..4 {
                    let wv = load_n::<2>(simd, &panels[q][o..o + 16]);
                    acc[q][0] = simd.mul_add_f32x8(x, wv[0], acc[q][0]);
                    acc[q][1] = simd.mul_add_f32x8(x, wv[1], acc[q][1]);
                }
            }
        }
        for q in 0..4 {
            let (c0, cols) = (four[q].c0, four[q].cols);
            finish::<1, 2>(simd, &[acc[q]], ep, &mut out[at + c0..], at + c0, w.n, c0, cols);
        }
    }

    /// [`gemm_inline`] compiled once, out of line inside the AVX2/FMA features, for the
    /// im2col chunks ([`super::conv_rows`]: the border rows of [`conv_direct`], dilated
    /// windows). Inlined there, each of those call sites held its own copy of the
    /// register blocks, which made this crate the slowest of the workspace to compile;
    /// the 1x1 layers, most of the model's work, keep the inlined copy (calling this one
    /// for them made the landmark model ~10 % slower).
    #[inline(never)]
    pub fn gemm(simd: V3, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
        struct Op<'a, 'b> {
            simd: V3,
            a: &'a [f32],
            rows: usize,
            w: &'a Packed,
            ep: &'a Epilogue<'b>,
            out: &'a mut [f32],
        }
        impl pulp::WithSimd for Op<'_, '_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _simd: S) {
                gemm_inline(self.simd, self.a, self.rows, self.w, self.ep, self.out)
            }
        }
        pulp::Simd::vectorize(
            simd,
            Op {
                simd,
                a,
                rows,
                w,
                ep,
                out,
            },
        )
    }

    /// [`super::gemm`] with the AVX2/FMA blocks: `8 x 8`, `6 x 16` or `3 x 24` by panel.
    #[inline(always)]
    pub fn gemm_inline(simd: V3, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
        let (k, n) = (w.k, w.n);
        let mut p0 = 0;
        while p0 < rows {
            let end = (p0 + super::CHUNK).min(rows);
            for pn in &w.panels {
                let (panel, bias) = w.panel(pn);
                let v = pn.width / 8;
                let mr = block_rows(v);
                let mut p = p0;
                while p < end {
                    let m = (end - p).min(mr);
                    let a_blk = &a[p * k..];
                    let at = p * n + pn.c0;
                    let o = &mut out[at..];
                    match v {
                        1 => block::<1>(simd, m, a_blk, k, panel, bias, ep, o, at, n, pn.c0, pn.cols),
                        2 => block::<2>(simd, m, a_blk, k, panel, bias, ep, o, at, n, pn.c0, pn.cols),
                        _ => block::<3>(simd, m, a_blk, k, panel, bias, ep, o, at, n, pn.c0, pn.cols),
                    }
                    p += m;
                }
            }
            p0 = end;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86;

/// The SIMD level the kernels run with, chosen once per inference.
///
/// Every level gives the same bits: the register kernels sum each output value in the
/// same order as the portable ones, with one fused multiply-add per tap.
#[derive(Debug, Clone, Copy)]
pub enum Level {
    /// Portable loops (auto-vectorised for the build target).
    Portable,
    /// AVX2 + FMA (x86-64-v3) register blocks.
    #[cfg(target_arch = "x86_64")]
    V3(pulp::x86::V3),
    /// AVX-512 (x86-64-v4): 16-float register blocks where a layer has 16 or more
    /// channels, the AVX2 blocks (with 32 registers) elsewhere.
    #[cfg(target_arch = "x86_64")]
    V4(pulp::x86::V4),
}

/// Environment variable that caps the SIMD level: `portable`, `avx2` (or `v3`); any
/// other value, or none, lets the CPU decide. For comparing levels on one machine.
pub const SIMD_ENV: &str = "FACECAP_SIMD";

impl Level {
    /// The best level this CPU supports, capped by [`SIMD_ENV`] (read once per process).
    pub fn detect() -> Level {
        static LEVEL: std::sync::OnceLock<Level> = std::sync::OnceLock::new();
        *LEVEL.get_or_init(|| {
            let cap = match std::env::var(SIMD_ENV).as_deref() {
                Ok("portable") => 0,
                Ok("avx2" | "v3") => 1,
                _ => 2,
            };
            Level::all()
                .into_iter()
                .rev()
                .find(|l| l.rank() <= cap)
                .unwrap_or(Level::Portable)
        })
    }

    /// Every level this CPU supports, from [`Level::Portable`] up (for tests and
    /// benchmarks that compare them).
    pub fn all() -> Vec<Level> {
        let mut v = vec![Level::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if let Some(v3) = pulp::x86::V3::try_new() {
                v.push(Level::V3(v3));
            }
            if let Some(v4) = pulp::x86::V4::try_new() {
                v.push(Level::V4(v4));
            }
        }
        v
    }

    /// 0 portable, 1 AVX2, 2 AVX-512.
    fn rank(&self) -> u8 {
        match self {
            Level::Portable => 0,
            #[cfg(target_arch = "x86_64")]
            Level::V3(_) => 1,
            #[cfg(target_arch = "x86_64")]
            Level::V4(_) => 2,
        }
    }

    /// Runs `op` with this level's target features enabled. `op` receives the level as
    /// a constant, so each level's body compiles only its own kernels.
    #[inline(always)]
    pub fn vectorize<Op: WithLevel>(self, op: Op) -> Op::Output {
        match self {
            #[cfg(target_arch = "x86_64")]
            Level::V4(simd) => pulp::Simd::vectorize(simd, AtV4(simd, op)),
            #[cfg(target_arch = "x86_64")]
            Level::V3(simd) => pulp::Simd::vectorize(simd, AtV3(simd, op)),
            Level::Portable => pulp::Simd::vectorize(pulp::Scalar::new(), AtPortable(op)),
        }
    }
}

/// A body run by [`Level::vectorize`].
pub trait WithLevel {
    /// What the body returns.
    type Output;
    /// Runs the body at `level`.
    fn with_level(self, level: Level) -> Self::Output;
}

/// `op` at one level, inside that level's target features. One type per level, so that
/// the level handed to the body is a constant there (a field would be read at run time,
/// and every level's kernels compiled into every body).
struct AtPortable<Op>(Op);
#[cfg(target_arch = "x86_64")]
struct AtV3<Op>(pulp::x86::V3, Op);
#[cfg(target_arch = "x86_64")]
struct AtV4<Op>(pulp::x86::V4, Op);

impl<Op: WithLevel> pulp::WithSimd for AtPortable<Op> {
    type Output = Op::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Op::Output {
        self.0.with_level(Level::Portable)
    }
}

#[cfg(target_arch = "x86_64")]
impl<Op: WithLevel> pulp::WithSimd for AtV3<Op> {
    type Output = Op::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Op::Output {
        self.1.with_level(Level::V3(self.0))
    }
}

#[cfg(target_arch = "x86_64")]
impl<Op: WithLevel> pulp::WithSimd for AtV4<Op> {
    type Output = Op::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Op::Output {
        self.1.with_level(Level::V4(self.0))
    }
}

/// [`depthwise`] at a given SIMD level.
#[inline(always)]
pub fn depthwise_at(
    level: Level,
    input: &[f32],
    g: &Geom,
    filter: &[f32],
    bias: &[f32],
    ep: &Epilogue<'_>,
    out: &mut [f32],
) {
    let done = match level {
        #[cfg(target_arch = "x86_64")]
        Level::V4(simd) => x86::depthwise_at(simd, input, g, filter, bias, ep, out),
        #[cfg(target_arch = "x86_64")]
        Level::V3(simd) if g.ic >= 8 && g.win.kh == 3 && g.win.kw == 3 && g.win.dh == 1 && g.win.dw == 1 => {
            v3::depthwise3x3(simd, input, g, filter, bias, ep, out);
            true
        }
        #[cfg(target_arch = "x86_64")]
        Level::V3(simd) if g.ic % 8 == 0 && g.win.kh <= v3::MAX_TAPS && g.win.kw <= v3::MAX_TAPS => {
            v3::depthwise(simd, input, g, filter, bias, ep, out);
            true
        }
        _ => false,
    };
    if !done {
        depthwise(input, g, filter, bias, ep, out)
    }
}

/// [`gemm`] at a given SIMD level (the AVX2 blocks inlined at the call site).
#[inline(always)]
pub fn gemm_at(level: Level, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    match level {
        #[cfg(target_arch = "x86_64")]
        Level::V4(simd) => x86::gemm_at(simd, a, rows, w, ep, out),
        #[cfg(target_arch = "x86_64")]
        Level::V3(simd) => v3::gemm_inline(simd, a, rows, w, ep, out),
        Level::Portable => gemm_portable(a, rows, w, ep, out),
    }
}

/// [`gemm`] compiled once, out of line (the portable level needs no target features):
/// one copy instead of one per call site (1x1 layers and the im2col chunks).
#[inline(never)]
fn gemm_portable(a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    gemm(a, rows, w, ep, out)
}

/// A convolution through im2col, chunk by chunk ([`im2col_chunk_rows`] output pixels):
/// each chunk's patches are built in `col` (at least `im2col_chunk_rows(w.k) * w.k`
/// floats) and multiplied while they are in L1, instead of writing the whole im2col
/// matrix (1.8 MB for the landmark model's first layer) and reading it back.
#[inline(always)]
pub fn conv_im2col(
    level: Level,
    input: &[f32],
    g: &Geom,
    w: &Packed,
    ep: &Epilogue<'_>,
    col: &mut [f32],
    out: &mut [f32],
) {
    conv_rows(level, input, g, w, ep, col, out, 0, g.oh * g.ow);
}

/// Output pixels `p0..p1` (flat `oy * ow + ox`) of [`conv_im2col`], chunk by chunk;
/// `out` and the residual are the whole output.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn conv_rows(
    level: Level,
    input: &[f32],
    g: &Geom,
    w: &Packed,
    ep: &Epilogue<'_>,
    col: &mut [f32],
    out: &mut [f32],
    p0: usize,
    p1: usize,
) {
    let (k, n) = (w.k, w.n);
    let step = im2col_chunk_rows(k);
    let mut p = p0;
    while p < p1 {
        let q = (p + step).min(p1);
        let c = &mut col[..(q - p) * k];
        im2col_rows(input, g, p, q, c);
        let ep = Epilogue {
            residual: ep.residual.map(|r| &r[p * n..]),
            ..*ep
        };
        let o = &mut out[p * n..q * n];
        match level {
            // The AVX2 blocks' one out-of-line copy (every other level's GEMM is one).
            #[cfg(target_arch = "x86_64")]
            Level::V3(simd) => v3::gemm(simd, c, q - p, w, &ep, o),
            _ => gemm_at(level, c, q - p, w, &ep, o),
        }
        p = q;
    }
}

/// A convolution that is not 1x1 stride 1: read in place from the input by the SIMD
/// kernel (dilation 1), through [`conv_im2col`] otherwise. `col` as for
/// [`conv_im2col`].
#[inline(always)]
pub fn conv_window(
    level: Level,
    input: &[f32],
    g: &Geom,
    w: &Packed,
    ep: &Epilogue<'_>,
    col: &mut [f32],
    out: &mut [f32],
) {
    match level {
        #[cfg(target_arch = "x86_64")]
        Level::V4(simd) if g.win.dh == 1 && g.win.dw == 1 => x86::conv_direct_at(simd, input, g, w, ep, col, out),
        #[cfg(target_arch = "x86_64")]
        Level::V3(simd) if g.win.dh == 1 && g.win.dw == 1 => v3::conv_direct(simd, input, g, w, ep, col, out),
        _ => conv_im2col(level, input, g, w, ep, col, out),
    }
}

/// `out[p * n + co] = ep(bias[co] + sum_k a[p * k + kk] * W[kk, co])` for `rows` rows.
#[inline(always)]
pub fn gemm(a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
    let (k, n) = (w.k, w.n);
    debug_assert!(a.len() >= rows * k && out.len() >= rows * n);
    let mut p0 = 0;
    while p0 < rows {
        let end = (p0 + CHUNK).min(rows);
        for pn in &w.panels {
            let (panel, bias) = w.panel(pn);
            let mut p = p0;
            while p < end {
                let m = (end - p).min(MR);
                let a_blk = &a[p * k..];
                let at = p * n + pn.c0;
                let o = &mut out[at..];
                let (c0, nc) = (pn.c0, pn.cols);
                match (pn.width, m) {
                    (8, 4) => micro::<4, 8>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (8, 3) => micro::<3, 8>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (8, 2) => micro::<2, 8>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (8, _) => micro::<1, 8>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (16, 4) => micro::<4, 16>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (16, 3) => micro::<3, 16>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (16, 2) => micro::<2, 16>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (16, _) => micro::<1, 16>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (_, 4) => micro::<4, 24>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (_, 3) => micro::<3, 24>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (_, 2) => micro::<2, 24>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                    (_, _) => micro::<1, 24>(a_blk, k, panel, bias, ep, o, at, n, c0, nc),
                }
                p += m;
            }
        }
        p0 = end;
    }
}

/// Geometry of one window operator on one input, resolved at load.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Geom {
    /// Input height, width, channels.
    pub ih: usize,
    /// Input width.
    pub iw: usize,
    /// Input channels.
    pub ic: usize,
    /// Output height.
    pub oh: usize,
    /// Output width.
    pub ow: usize,
    /// Padding before, top.
    pub pt: usize,
    /// Padding before, left.
    pub pl: usize,
    /// The window.
    pub win: Window,
}

impl Geom {
    /// Resolves output size and padding; `None` when the window does not fit.
    pub fn new(ih: usize, iw: usize, ic: usize, win: Window) -> Option<Geom> {
        let (oh, pt) = Window::out_and_pad(ih, win.kh, win.sh, win.dh, win.padding)?;
        let (ow, pl) = Window::out_and_pad(iw, win.kw, win.sw, win.dw, win.padding)?;
        Some(Geom {
            ih,
            iw,
            ic,
            oh,
            ow,
            pt,
            pl,
            win,
        })
    }
    /// Input row for output row `oy` and tap `ky`, if inside the image.
    #[inline(always)]
    pub fn iy(&self, oy: usize, ky: usize) -> Option<usize> {
        (oy * self.win.sh + ky * self.win.dh)
            .checked_sub(self.pt)
            .filter(|&y| y < self.ih)
    }
    /// Input column for output column `ox` and tap `kx`, if inside the image.
    #[inline(always)]
    pub fn ix(&self, ox: usize, kx: usize) -> Option<usize> {
        (ox * self.win.sw + kx * self.win.dw)
            .checked_sub(self.pl)
            .filter(|&x| x < self.iw)
    }
    /// The output columns `lo..hi` whose `kw` taps (stride `sw`, no dilation) all lie
    /// inside the input row, so that a kernel can skip the edge checks there.
    #[inline(always)]
    pub(crate) fn interior(&self, kw: usize, sw: usize) -> (usize, usize) {
        let lo = self.pl.div_ceil(sw).min(self.ow);
        let hi = if self.iw + self.pl >= kw {
            ((self.iw + self.pl - kw) / sw + 1).min(self.ow)
        } else {
            0
        }
        .max(lo);
        (lo, hi)
    }
    /// The rows of a 3-tall window that lie inside the input for output row `oy`:
    /// `(kernel row, input row)` pairs in kernel-row order, and how many there are.
    #[inline(always)]
    pub(crate) fn taps3(&self, oy: usize) -> ([(usize, usize); 3], usize) {
        let mut ty = [(0usize, 0usize); 3];
        let mut ny = 0;
        for ky in 0..3 {
            if let Some(iy) = self.iy(oy, ky) {
                ty[ny] = (ky, iy);
                ny += 1;
            }
        }
        (ty, ny)
    }
    /// Whether the window is a plain 1x1 stride-1 convolution (GEMM on the input).
    pub fn is_pointwise(&self) -> bool {
        self.win.kh == 1 && self.win.kw == 1 && self.win.sh == 1 && self.win.sw == 1 && self.pt == 0 && self.pl == 0
    }
    /// im2col length for this geometry.
    pub fn im2col_len(&self) -> usize {
        self.oh * self.ow * self.win.kh * self.win.kw * self.ic
    }
}

/// Fills `col` (`[oh * ow][kh * kw * ic]`) with the input patches, zeros outside.
#[inline(always)]
pub fn im2col(input: &[f32], g: &Geom, col: &mut [f32]) {
    im2col_rows(input, g, 0, g.oh * g.ow, col);
}

/// Rows (output pixels) of [`im2col`] per chunk of [`conv_im2col`]: a multiple of the
/// GEMM's row chunk, about 16 KiB of patches (at least one row chunk).
pub fn im2col_chunk_rows(k: usize) -> usize {
    (4096 / k.max(1) / CHUNK).max(1) * CHUNK
}

/// Rows `p0..p1` of [`im2col`] into `col[..(p1 - p0) * kh * kw * ic]`.
#[inline(always)]
pub fn im2col_rows(input: &[f32], g: &Geom, p0: usize, p1: usize, col: &mut [f32]) {
    let c = g.ic;
    let kk = g.win.kh * g.win.kw * c;
    let (mut oy, mut ox) = (p0 / g.ow, p0 % g.ow);
    for p in p0..p1 {
        if ox == g.ow {
            (oy, ox) = (oy + 1, 0);
        }
        let x = ox;
        ox += 1;
        {
            let ox = x;
            let row = &mut col[(p - p0) * kk..(p - p0 + 1) * kk];
            for ky in 0..g.win.kh {
                let seg = g.win.kw * c;
                let dst = &mut row[ky * seg..(ky + 1) * seg];
                let Some(iy) = g.iy(oy, ky) else {
                    for d in dst.iter_mut() {
                        *d = 0.0;
                    }
                    continue;
                };
                // With dilation 1 the taps of one kernel row are contiguous in the input.
                let x0 = (ox * g.win.sw).checked_sub(g.pl);
                if let (1, Some(x0)) = (g.win.dw, x0) {
                    if x0 + g.win.kw <= g.iw {
                        let src = &input[(iy * g.iw + x0) * c..(iy * g.iw + x0) * c + seg];
                        for (d, &v) in dst.iter_mut().zip(src) {
                            *d = v;
                        }
                        continue;
                    }
                }
                for kx in 0..g.win.kw {
                    let d = &mut dst[kx * c..(kx + 1) * c];
                    match g.ix(ox, kx) {
                        Some(ix) => {
                            for (d, &v) in d.iter_mut().zip(&input[(iy * g.iw + ix) * c..(iy * g.iw + ix + 1) * c]) {
                                *d = v;
                            }
                        }
                        None => {
                            for d in d.iter_mut() {
                                *d = 0.0;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `o += i * w` over one pixel's channels, in blocks of eight.
#[inline(always)]
fn fma_row(o: &mut [f32], i: &[f32], w: &[f32]) {
    let mut oc = o.chunks_exact_mut(8);
    let mut ic = i.chunks_exact(8);
    let mut wc = w.chunks_exact(8);
    for ((o8, i8), w8) in (&mut oc).zip(&mut ic).zip(&mut wc) {
        let mut acc = [0.0f32; 8];
        acc.copy_from_slice(o8);
        for j in 0..8 {
            acc[j] = i8[j].mul_add(w8[j], acc[j]);
        }
        o8.copy_from_slice(&acc);
    }
    for ((d, &x), &y) in oc.into_remainder().iter_mut().zip(ic.remainder()).zip(wc.remainder()) {
        *d = x.mul_add(y, *d);
    }
}

/// Output columns `ox` whose tap at offset `off = kx * dw` lands inside the input:
/// `0 <= ox * sw + off - pl < iw`.
#[inline(always)]
fn valid_cols(g: &Geom, off: usize) -> (usize, usize) {
    let sw = g.win.sw;
    let lo = if g.pl > off { (g.pl - off).div_ceil(sw) } else { 0 };
    let hi = if g.iw + g.pl > off {
        (g.iw + g.pl - off).div_ceil(sw)
    } else {
        0
    };
    (lo, hi.min(g.ow))
}

/// Depthwise convolution (depth multiplier 1): filter `[kh * kw][c]`, bias `[c]`.
/// Row by row: the output row (in L1) accumulates each tap over its valid columns.
#[inline(always)]
pub fn depthwise(input: &[f32], g: &Geom, filter: &[f32], bias: &[f32], ep: &Epilogue<'_>, out: &mut [f32]) {
    let c = g.ic;
    let row_len = g.ow * c;
    for oy in 0..g.oh {
        let orow = &mut out[oy * row_len..(oy + 1) * row_len];
        for px in orow.chunks_exact_mut(c) {
            let mut pc = px.chunks_exact_mut(8);
            let mut bc = bias[..c].chunks_exact(8);
            for (d, b) in (&mut pc).zip(&mut bc) {
                let mut t = [0.0f32; 8];
                t.copy_from_slice(b);
                d.copy_from_slice(&t);
            }
            for (d, &b) in pc.into_remainder().iter_mut().zip(bc.remainder()) {
                *d = b;
            }
        }
        for ky in 0..g.win.kh {
            let Some(iy) = g.iy(oy, ky) else { continue };
            let irow = &input[iy * g.iw * c..(iy + 1) * g.iw * c];
            for kx in 0..g.win.kw {
                let wt = &filter[(ky * g.win.kw + kx) * c..(ky * g.win.kw + kx + 1) * c];
                let off = kx * g.win.dw;
                let (lo, hi) = valid_cols(g, off);
                for ox in lo..hi {
                    let ix = ox * g.win.sw + off - g.pl;
                    fma_row(&mut orow[ox * c..(ox + 1) * c], &irow[ix * c..(ix + 1) * c], wt);
                }
            }
        }
        for (ox, px) in orow.chunks_exact_mut(c).enumerate() {
            ep.apply(px, (oy * g.ow + ox) * c, 0);
        }
    }
}

/// Most kernel taps per axis of the 8-channel max pooling path.
const POOL_TAPS: usize = 8;

/// Max pooling (padding taps are ignored, as in TFLite).
#[inline(always)]
pub fn max_pool(input: &[f32], g: &Geom, act: Activation, out: &mut [f32]) {
    let c = g.ic;
    let w = &g.win;
    let fits = |o: usize, i: usize| 2 * o <= i;
    if c >= 8
        && (w.kh, w.kw, w.sh, w.sw, w.dh, w.dw) == (2, 2, 2, 2, 1, 1)
        && (g.pt, g.pl) == (0, 0)
        && fits(g.oh, g.ih)
        && fits(g.ow, g.iw)
    {
        max_pool2x2(input, g, act, out);
        return;
    }
    if c >= 8 && g.win.kh <= POOL_TAPS && g.win.kw <= POOL_TAPS {
        max_pool8(input, g, act, out);
        return;
    }
    for oy in 0..g.oh {
        for ox in 0..g.ow {
            let o = &mut out[(oy * g.ow + ox) * c..(oy * g.ow + ox + 1) * c];
            o.fill(f32::NEG_INFINITY);
            for ky in 0..g.win.kh {
                let Some(iy) = g.iy(oy, ky) else { continue };
                for kx in 0..g.win.kw {
                    let Some(ix) = g.ix(ox, kx) else { continue };
                    let ip = &input[(iy * g.iw + ix) * c..(iy * g.iw + ix + 1) * c];
                    for (d, &x) in o.iter_mut().zip(ip) {
                        *d = d.max(x);
                    }
                }
            }
            for d in o.iter_mut() {
                *d = act.apply(*d);
            }
        }
    }
}

/// [`max_pool`] 8 channels at a time on fixed-size arrays (registers), the valid taps
/// of each row and pixel found once; `c >= 8`, at most [`POOL_TAPS`] taps per axis.
/// With `c % 8 != 0` the last block overlaps the one before (the same maxima, stored
/// twice).
#[inline(always)]
fn max_pool8(input: &[f32], g: &Geom, act: Activation, out: &mut [f32]) {
    let c = g.ic;
    let mut ty = [0usize; POOL_TAPS];
    let mut tx = [0usize; POOL_TAPS];
    for oy in 0..g.oh {
        let mut ny = 0;
        for ky in 0..g.win.kh {
            if let Some(iy) = g.iy(oy, ky) {
                ty[ny] = iy;
                ny += 1;
            }
        }
        for ox in 0..g.ow {
            let mut nx = 0;
            for kx in 0..g.win.kw {
                if let Some(ix) = g.ix(ox, kx) {
                    tx[nx] = ix;
                    nx += 1;
                }
            }
            let o = (oy * g.ow + ox) * c;
            for cb in (0..c).step_by(8).map(|cb| cb.min(c - 8)) {
                let mut acc = [f32::NEG_INFINITY; 8];
                for &iy in &ty[..ny] {
                    for &ix in &tx[..nx] {
                        for (a, v) in acc.iter_mut().zip(load8(input, (iy * g.iw + ix) * c + cb)) {
                            *a = a.max(v);
                        }
                    }
                }
                for a in acc.iter_mut() {
                    *a = act.apply(*a);
                }
                store8(out, o + cb, acc);
            }
        }
    }
}

/// Eight floats of `s` from `at` (a fixed-size copy: registers, no call).
#[inline(always)]
fn load8(s: &[f32], at: usize) -> [f32; 8] {
    let mut x = [0.0f32; 8];
    x.copy_from_slice(&s[at..at + 8]);
    x
}

/// Stores eight floats at `s[at..]`.
#[inline(always)]
fn store8(s: &mut [f32], at: usize, x: [f32; 8]) {
    if let Ok(dst) = <&mut [f32; 8]>::try_from(&mut s[at..at + 8]) {
        *dst = x;
    }
}

/// Writes `src` (zeros when `None`) over `dst`, 8 floats at a time and the rest one by
/// one.
#[inline(always)]
fn fill8(dst: &mut [f32], src: Option<&[f32]>) {
    let n8 = dst.len() / 8 * 8;
    match src {
        Some(s) => {
            for j in (0..n8).step_by(8) {
                store8(dst, j, load8(s, j));
            }
            for (d, &v) in dst[n8..].iter_mut().zip(&s[n8..]) {
                *d = v;
            }
        }
        None => {
            for j in (0..n8).step_by(8) {
                store8(dst, j, [0.0; 8]);
            }
            for v in &mut dst[n8..] {
                *v = 0.0;
            }
        }
    }
}

/// [`max_pool`] for the 2x2 stride-2 windows that lie inside the input (every pooling
/// of both models), `c >= 8`: the four taps at fixed offsets, 8 channels at a time (the
/// last block overlapping the one before when `c % 8 != 0`), folded in [`max_pool8`]'s
/// order (top left, top right, bottom left, bottom right) from `-inf`, so the bits are
/// the same.
#[inline(always)]
fn max_pool2x2(input: &[f32], g: &Geom, act: Activation, out: &mut [f32]) {
    let c = g.ic;
    let row = g.iw * c;
    for oy in 0..g.oh {
        let top = &input[2 * oy * row..(2 * oy + 1) * row];
        let bot = &input[(2 * oy + 1) * row..(2 * oy + 2) * row];
        let o_row = &mut out[oy * g.ow * c..(oy + 1) * g.ow * c];
        for ox in 0..g.ow {
            let (i, o) = (2 * ox * c, ox * c);
            for cb in (0..c).step_by(8).map(|cb| cb.min(c - 8)) {
                let mut acc = [f32::NEG_INFINITY; 8];
                for x in [
                    load8(top, i + cb),
                    load8(top, i + c + cb),
                    load8(bot, i + cb),
                    load8(bot, i + c + cb),
                ] {
                    for (a, v) in acc.iter_mut().zip(x) {
                        *a = a.max(v);
                    }
                }
                for a in acc.iter_mut() {
                    *a = act.apply(*a);
                }
                store8(o_row, o + cb, acc);
            }
        }
    }
}

/// Zero padding of a `[n, h, w, c]` tensor; `pads[axis] = [before, after]`.
#[inline(always)]
pub fn pad4(input: &[f32], shape: [usize; 4], pads: [[usize; 2]; 4], out: &mut [f32]) {
    let [n, h, w, c] = shape;
    let oh = h + pads[1][0] + pads[1][1];
    let ow = w + pads[2][0] + pads[2][1];
    let oc = c + pads[3][0] + pads[3][1];
    if pads[..3] == [[0, 0]; 3] && c > 0 {
        // Channels only (the residual shortcuts of both models): each pixel's values and
        // zeros written in place, 8 at a time, with no pass that zeroes the whole output
        // first and no copy call per pixel.
        let before = pads[3][0];
        for (src, dst) in input.chunks_exact(c).zip(out.chunks_exact_mut(oc)).take(n * h * w) {
            let (head, rest) = dst.split_at_mut(before);
            let (mid, tail) = rest.split_at_mut(c);
            fill8(head, None);
            fill8(mid, Some(src));
            fill8(tail, None);
        }
        return;
    }
    out.fill(0.0);
    for b in 0..n {
        for y in 0..h {
            for x in 0..w {
                let src = ((b * h + y) * w + x) * c;
                let dst = (((b + pads[0][0]) * oh + y + pads[1][0]) * ow + x + pads[2][0]) * oc + pads[3][0];
                out[dst..dst + c].copy_from_slice(&input[src..src + c]);
            }
        }
    }
}

/// Element-wise sum with a fused activation.
#[inline(always)]
pub fn add(a: &[f32], b: &[f32], act: Activation, out: &mut [f32]) {
    for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
        *o = act.apply(x + y);
    }
}

/// `max(x, 0)`.
#[inline(always)]
pub fn relu(a: &[f32], out: &mut [f32]) {
    for (o, &x) in out.iter_mut().zip(a) {
        *o = x.max(0.0);
    }
}

/// Parametric ReLU with a per-channel slope: `x >= 0 ? x : alpha[c] * x`.
#[inline(always)]
pub fn prelu(a: &[f32], alpha: &[f32], out: &mut [f32]) {
    let c = alpha.len();
    for (o, x) in out.chunks_exact_mut(c).zip(a.chunks_exact(c)) {
        for ((d, &v), &s) in o.iter_mut().zip(x).zip(alpha) {
            *d = if v >= 0.0 { v } else { v * s };
        }
    }
}

/// `1 / (1 + exp(-x))`.
#[inline(always)]
pub fn logistic(a: &[f32], out: &mut [f32]) {
    for (o, &x) in out.iter_mut().zip(a) {
        *o = 1.0 / (1.0 + (-x).exp());
    }
}

/// Slow, obvious implementations the fast kernels are tested against.
pub mod reference {
    use super::super::model::Activation;
    use super::Geom;

    /// Direct convolution with OHWI filters.
    pub fn conv(input: &[f32], g: &Geom, filter: &[f32], bias: Option<&[f32]>, oc: usize, act: Activation) -> Vec<f32> {
        let (kh, kw, ic) = (g.win.kh, g.win.kw, g.ic);
        let mut out = vec![0.0; g.oh * g.ow * oc];
        for oy in 0..g.oh {
            for ox in 0..g.ow {
                for co in 0..oc {
                    let mut s = bias.map_or(0.0, |b| b[co]) as f64;
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (oy * g.win.sh + ky * g.win.dh) as isize - g.pt as isize;
                            let ix = (ox * g.win.sw + kx * g.win.dw) as isize - g.pl as isize;
                            if iy < 0 || ix < 0 || iy >= g.ih as isize || ix >= g.iw as isize {
                                continue;
                            }
                            for ci in 0..ic {
                                let x = input[((iy as usize) * g.iw + ix as usize) * ic + ci];
                                let w = filter[((co * kh + ky) * kw + kx) * ic + ci];
                                s += (x * w) as f64;
                            }
                        }
                    }
                    out[(oy * g.ow + ox) * oc + co] = act.apply(s as f32);
                }
            }
        }
        out
    }

    /// Direct depthwise convolution (`[1, KH, KW, C]` filters).
    pub fn depthwise(input: &[f32], g: &Geom, filter: &[f32], bias: &[f32], act: Activation) -> Vec<f32> {
        let c = g.ic;
        let mut out = vec![0.0; g.oh * g.ow * c];
        for oy in 0..g.oh {
            for ox in 0..g.ow {
                for ch in 0..c {
                    let mut s = bias[ch] as f64;
                    for ky in 0..g.win.kh {
                        for kx in 0..g.win.kw {
                            let iy = (oy * g.win.sh + ky * g.win.dh) as isize - g.pt as isize;
                            let ix = (ox * g.win.sw + kx * g.win.dw) as isize - g.pl as isize;
                            if iy < 0 || ix < 0 || iy >= g.ih as isize || ix >= g.iw as isize {
                                continue;
                            }
                            s += (input[((iy as usize) * g.iw + ix as usize) * c + ch]
                                * filter[(ky * g.win.kw + kx) * c + ch]) as f64;
                        }
                    }
                    out[(oy * g.ow + ox) * c + ch] = act.apply(s as f32);
                }
            }
        }
        out
    }
}
