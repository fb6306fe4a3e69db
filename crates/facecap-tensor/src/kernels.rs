//! Hot kernels of the fitter ([`crate::fit`]), compiled for the CPU found at run time
//! (`pulp::Arch::dispatch`: AVX2 + FMA where available, portable scalar code otherwise).
//!
//! * Layout of the restricted core ([`pack_point`]): per point and coordinate, the
//!   `r_id x r_exp` slice in panels of four identity columns, `[q][e][4]` (`q` the
//!   column group `j / 4`, the last one zero-padded): both contractions then read
//!   contiguous 4-wide vectors, one per `(q, e)`, with `r_exp <= 8` accumulators or
//!   broadcast weights held in registers.
//! * [`contract_exp`] / [`contract_id_rot`]: the per-point core slices (stored in
//!   `f32`, widened exactly to `f64`, all arithmetic in `f64`) contracted with the
//!   identity mode coordinates `alpha` (giving `r_exp` values per point and coordinate)
//!   or the expression mode coordinates `beta` (giving `r_id` values per point and
//!   coordinate, rotated at once by the pose rotation `R`: the first two rotated rows
//!   are the identity design rows, and `A^T W y` is summed on the way, so no separate
//!   design pass is needed). These two passes read the whole restricted core (500
//!   points: 2.35 MB in `f32`) and are memory bound; [`contract_id_rot`] walks the
//!   points in reverse order so that it starts on the slices [`contract_exp`] read
//!   last, which are still in the L2 cache.
//! * [`points`]: `m + <C, alpha kron beta>` per point and coordinate (`ab` in the
//!   panel layout, [`pack_ab`]).
//! * [`syrk_points`]: `H += sum_k w_k (d_k0 d_k0^T + d_k1 d_k1^T)` (upper-triangle
//!   tiles) for two rows per point (`rp` a multiple of 8), a register-tiled update:
//!   6 x 8 tiles of `H` held in registers while a block of 32 points (in L1) streams
//!   past, fused multiply-adds where the CPU has them.
//!
//! Each kernel has a slow reference in the tests below (seeded property tests).

use pulp::{Simd, WithSimd};

/// Points per cache block of [`syrk_points`] (32 points x 2 rows x 56 x 8 bytes = 28 KB).
const SYRK_POINTS: usize = 32;

/// `a . b` with `a` in `f32` (widened exactly), eight independent accumulators so
/// the loop vectorises.
#[inline(always)]
fn dot_f32(a: &[f32], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..8 {
            acc[j] += f64::from(x[j]) * y[j];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (x, y) in ra.iter().zip(rb) {
        s += f64::from(*x) * y;
    }
    s
}

/// Values per point and coordinate in the panel layout: `r_id` rounded up to a
/// multiple of 4, times `r_exp`.
pub(crate) fn panel_len(r_id: usize, r_exp: usize) -> usize {
    r_id.div_ceil(4) * 4 * r_exp
}

/// Index of `(e, j)` in one point-coordinate panel block (`[q][e][4]`, `q = j / 4`).
#[inline(always)]
fn panel_index(r_exp: usize, e: usize, j: usize) -> usize {
    (j / 4 * r_exp + e) * 4 + j % 4
}

/// Appends one point's core (`value(c, e, j)` for coordinate `c`, expression mode `e`,
/// identity mode `j`) in the panel layout `[3][q][e][4]` (zero padding for `j >= r_id`).
pub(crate) fn pack_point(out: &mut Vec<f32>, r_id: usize, r_exp: usize, value: impl Fn(usize, usize, usize) -> f32) {
    let len = panel_len(r_id, r_exp);
    for c in 0..3 {
        let base = out.len();
        out.resize(base + len, 0.0);
        for e in 0..r_exp {
            for j in 0..r_id {
                out[base + panel_index(r_exp, e, j)] = value(c, e, j);
            }
        }
    }
}

/// `ab[(e, j)] = beta[e] alpha[j]` in the panel layout of one point-coordinate block
/// (the weights of [`points`]); `ab` must hold [`panel_len`] values.
pub(crate) fn pack_ab(alpha: &[f64], beta: &[f64], ab: &mut [f64]) {
    let re = beta.len();
    ab.iter_mut().for_each(|v| *v = 0.0);
    for (e, &b) in beta.iter().enumerate() {
        for (j, &a) in alpha.iter().enumerate() {
            ab[panel_index(re, e, j)] = a * b;
        }
    }
}

struct ContractExp<'a> {
    core: &'a [f32],
    alpha: &'a [f64],
    r_exp: usize,
    out: &'a mut [f64],
}

impl WithSimd for ContractExp<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let (ri, re) = (self.alpha.len(), self.r_exp);
        for (block, out) in self
            .core
            .chunks_exact(panel_len(ri, re))
            .zip(self.out.chunks_exact_mut(re))
        {
            for (e, o) in out.iter_mut().enumerate() {
                *o = (0..ri)
                    .map(|j| f64::from(block[panel_index(re, e, j)]) * self.alpha[j])
                    .sum();
            }
        }
    }
}

/// `out[k][c][e] = sum_j core[k][c][e][j] alpha[j]` (`core` in the panel layout of
/// [`pack_point`], `out`: `[N][3][r_exp]`), points in increasing order.
pub(crate) fn contract_exp(core: &[f32], alpha: &[f64], r_exp: usize, out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        if r_exp <= avx2::MAX_EXP {
            return pulp::Simd::vectorize(
                v3,
                avx2::ContractExp {
                    v3,
                    core,
                    alpha,
                    r_exp,
                    out,
                },
            );
        }
    }
    pulp::Arch::new().dispatch(ContractExp {
        core,
        alpha,
        r_exp,
        out,
    });
}

struct ContractIdRot<'a> {
    core: &'a [f32],
    beta: &'a [f64],
    r_id: usize,
    rp: usize,
    rot: &'a [f64; 9],
    y: &'a [f64],
    w: &'a [f64],
    out: &'a mut [f64],
    g: &'a mut [f64],
}

impl WithSimd for ContractIdRot<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let ContractIdRot {
            core,
            beta,
            r_id: ri,
            rp,
            rot,
            y,
            w,
            out,
            g,
        } = self;
        let re = beta.len();
        let len = panel_len(ri, re);
        // Reverse order: start where `contract_exp` ended (cache reuse).
        for (((core, out), yk), &wk) in core
            .chunks_exact(3 * len)
            .zip(out.chunks_exact_mut(3 * rp))
            .zip(y.chunks_exact(2))
            .zip(w)
            .rev()
        {
            for j in 0..ri {
                let mut t = [0.0f64; 3];
                for (c, tc) in t.iter_mut().enumerate() {
                    for (e, &b) in beta.iter().enumerate() {
                        *tc += b * f64::from(core[c * len + panel_index(re, e, j)]);
                    }
                }
                let mut o = [0.0f64; 3];
                for (i, oi) in o.iter_mut().enumerate() {
                    *oi = rot[3 * i] * t[0] + rot[3 * i + 1] * t[1] + rot[3 * i + 2] * t[2];
                    out[i * rp + j] = *oi;
                }
                g[j] += wk * (yk[0] * o[0] + yk[1] * o[1]);
            }
        }
    }
}

/// Identity-block contraction, rotated: with `t[k][c][j] = sum_e core[k][c][e][j] beta[e]`,
/// `out[k][i][j] = sum_c rot[i][c] t[k][c][j]` (`out`: `[N][3][rp]`, columns `r_id..rp`
/// untouched) and `g[j] += w[k] (y[k][0] out[k][0][j] + y[k][1] out[k][1][j])`. Points in
/// decreasing order. `rot` is the row-major rotation matrix; `core` in the panel layout.
#[allow(clippy::too_many_arguments)]
pub(crate) fn contract_id_rot(
    core: &[f32],
    beta: &[f64],
    r_id: usize,
    rp: usize,
    rot: &[f64; 9],
    y: &[f64],
    w: &[f64],
    out: &mut [f64],
    g: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        if beta.len() <= avx2::MAX_EXP {
            return pulp::Simd::vectorize(
                v3,
                avx2::ContractIdRot {
                    v3,
                    core,
                    beta,
                    r_id,
                    rp,
                    rot,
                    y,
                    w,
                    out,
                    g,
                },
            );
        }
    }
    pulp::Arch::new().dispatch(ContractIdRot {
        core,
        beta,
        r_id,
        rp,
        rot,
        y,
        w,
        out,
        g,
    });
}

struct Points<'a> {
    core: &'a [f32],
    mean: &'a [f64],
    ab: &'a [f64],
    out: &'a mut [f64],
}

impl WithSimd for Points<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let blk = self.ab.len();
        for ((o, m), row) in self.out.iter_mut().zip(self.mean).zip(self.core.chunks_exact(blk)) {
            *o = m + dot_f32(row, self.ab);
        }
    }
}

/// `out[k][c] = mean[k][c] + <core[k][c], ab>` (`ab[(e, j)] = beta[e] alpha[j]` in the
/// panel layout, [`pack_ab`]).
pub(crate) fn points(core: &[f32], mean: &[f64], ab: &[f64], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        return pulp::Simd::vectorize(
            v3,
            avx2::Points {
                v3,
                core,
                mean,
                ab,
                out,
            },
        );
    }
    pulp::Arch::new().dispatch(Points { core, mean, ab, out });
}

struct Syrk<'a> {
    d: &'a [f64],
    ps: usize,
    rp: usize,
    w: &'a [f64],
    scratch: &'a mut [f64],
    h: &'a mut [f64],
}

impl WithSimd for Syrk<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Syrk {
            d,
            ps,
            rp,
            w,
            scratch,
            h,
        } = self;
        for (block, wb) in d.chunks(SYRK_POINTS * ps).zip(w.chunks(SYRK_POINTS)) {
            // The block's rows contiguously, `[2 n][rp]`, plus a weighted copy (in L1).
            let n2 = 2 * wb.len();
            let (rows, wrows) = scratch[..2 * n2 * rp].split_at_mut(n2 * rp);
            for ((pt, &wk), (r2, wr2)) in block
                .chunks(ps)
                .zip(wb)
                .zip(rows.chunks_exact_mut(2 * rp).zip(wrows.chunks_exact_mut(2 * rp)))
            {
                r2.copy_from_slice(&pt[..2 * rp]);
                for (o, v) in wr2.iter_mut().zip(&pt[..2 * rp]) {
                    *o = wk * v;
                }
            }
            // Row blocks of 6 (12 accumulators with AVX2), the last ones of 4 or 2.
            let mut i0 = 0;
            while i0 < rp {
                let height = (rp - i0).min(6);
                for j0 in (i0 / 8 * 8..rp).step_by(8) {
                    match height {
                        6 => syrk_tile::<S, 6>(simd, rows, wrows, rp, i0, j0, h),
                        4 => syrk_tile::<S, 4>(simd, rows, wrows, rp, i0, j0, h),
                        _ => syrk_tile::<S, 2>(simd, rows, wrows, rp, i0, j0, h),
                    }
                }
                i0 += height;
            }
        }
    }
}

/// One `H x 8` tile of [`syrk_points`] (rows `i0..i0 + H`, columns `j0..j0 + 8` of `h`)
/// held in registers while the block's rows stream past.
#[inline(always)]
fn syrk_tile<S: Simd, const H: usize>(
    simd: S,
    rows: &[f64],
    wrows: &[f64],
    rp: usize,
    i0: usize,
    j0: usize,
    h: &mut [f64],
) {
    // Vectors per 8-wide tile row (2 with AVX2, 8 in the scalar fallback).
    let nv = 8 / S::F64_LANES;
    let zero = simd.splat_f64s(0.0);
    let mut acc = [[zero; 8]; H];
    for (row, wrow) in rows.chunks_exact(rp).zip(wrows.chunks_exact(rp)) {
        let (bv, _) = S::as_simd_f64s(&row[j0..j0 + 8]);
        for (acc_i, &ai) in acc.iter_mut().zip(&wrow[i0..i0 + H]) {
            let av = simd.splat_f64s(ai);
            for (acc_v, &b) in acc_i[..nv].iter_mut().zip(bv) {
                *acc_v = simd.mul_add_e_f64s(av, b, *acc_v);
            }
        }
    }
    for (i, acc_i) in acc.iter().enumerate() {
        let hrow = &mut h[(i0 + i) * rp + j0..(i0 + i) * rp + j0 + 8];
        let (hv, _) = S::as_mut_simd_f64s(hrow);
        for (hv, &a) in hv.iter_mut().zip(&acc_i[..nv]) {
            *hv = simd.add_f64s(*hv, a);
        }
    }
}

/// `h += sum_k w_k (d_k0 d_k0^T + d_k1 d_k1^T)` on the tiles of the `rp x rp`
/// row-major `h` that cover its upper triangle (some entries below the diagonal are
/// written too; callers read the upper triangle only). Point `k`'s two rows of length
/// `rp` start at `d[k ps]` and `d[k ps + rp]`; there are `w.len()` points. `rp` must be
/// a multiple of 8 (pad the rows with zeros), `ps >= 2 rp`; `scratch` must hold
/// [`syrk_scratch_len`]`(rp)` values.
pub(crate) fn syrk_points(d: &[f64], ps: usize, rp: usize, w: &[f64], scratch: &mut [f64], h: &mut [f64]) {
    debug_assert_eq!(rp % 8, 0);
    debug_assert!(ps >= 2 * rp && d.len() >= w.len().saturating_sub(1) * ps + 2 * rp);
    debug_assert_eq!(h.len(), rp * rp);
    debug_assert!(scratch.len() >= syrk_scratch_len(rp));
    pulp::Arch::new().dispatch(Syrk {
        d,
        ps,
        rp,
        w,
        scratch,
        h,
    });
}

/// Scratch length of [`syrk_points`] for padded rows of length `rp`.
pub(crate) fn syrk_scratch_len(rp: usize) -> usize {
    4 * SYRK_POINTS * rp
}

/// AVX2 + FMA versions with explicit `f32 -> f64` widening (`vcvtps2pd`): the
/// auto-vectorised generic code above shuffles instead.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use pulp::bytemuck::cast;
    use pulp::x86::V3;
    use pulp::{f64x4, Simd, WithSimd};

    #[inline(always)]
    fn widen(v3: V3, a: [f32; 4]) -> f64x4 {
        v3.convert_f32x4_to_f64x4(cast(a))
    }

    /// `a . b`, `a` widened from `f32`; two accumulators.
    #[inline(always)]
    fn dot(v3: V3, a: &[f32], b: &[f64]) -> f64 {
        let (a4, ar) = pulp::as_arrays::<4, f32>(a);
        let (b4, br) = pulp::as_arrays::<4, f64>(b);
        let zero = v3.splat_f64x4(0.0);
        let (mut s0, mut s1) = (zero, zero);
        let (a8, b8) = (a4.chunks_exact(2), b4.chunks_exact(2));
        let (a4r, b4r) = (a8.remainder(), b8.remainder());
        for (x, y) in a8.zip(b8) {
            s0 = v3.mul_add_f64x4(widen(v3, x[0]), cast(y[0]), s0);
            s1 = v3.mul_add_f64x4(widen(v3, x[1]), cast(y[1]), s1);
        }
        for (x, y) in a4r.iter().zip(b4r) {
            s0 = v3.mul_add_f64x4(widen(v3, *x), cast(*y), s0);
        }
        let mut s = v3.reduce_sum_f64s(v3.add_f64x4(s0, s1));
        for (x, y) in ar.iter().zip(br) {
            s += f64::from(*x) * y;
        }
        s
    }

    /// Largest `r_exp` of the AVX2 contractions (accumulators or broadcast weights in
    /// registers); larger ranks take the portable code.
    pub(super) const MAX_EXP: usize = 8;

    pub(super) struct ContractExp<'a> {
        pub v3: V3,
        pub core: &'a [f32],
        pub alpha: &'a [f64],
        pub r_exp: usize,
        pub out: &'a mut [f64],
    }

    impl WithSimd for ContractExp<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: Simd>(self, _simd: S) {
            let ContractExp {
                v3,
                core,
                alpha,
                r_exp,
                out,
            } = self;
            match r_exp {
                1 => exp_all::<1>(v3, core, alpha, out),
                2 => exp_all::<2>(v3, core, alpha, out),
                3 => exp_all::<3>(v3, core, alpha, out),
                4 => exp_all::<4>(v3, core, alpha, out),
                5 => exp_all::<5>(v3, core, alpha, out),
                6 => exp_all::<6>(v3, core, alpha, out),
                7 => exp_all::<7>(v3, core, alpha, out),
                _ => exp_all::<8>(v3, core, alpha, out),
            }
        }
    }

    /// [`super::contract_exp`] for `r_exp = E`: per point and coordinate, `E`
    /// accumulators over the column groups, one `alpha` vector per group.
    #[inline(always)]
    fn exp_all<const E: usize>(v3: V3, core: &[f32], alpha: &[f64], out: &mut [f64]) {
        let (a4, ar) = pulp::as_arrays::<4, f64>(alpha);
        let mut tail = [0.0f64; 4];
        tail[..ar.len()].copy_from_slice(ar);
        let len = super::panel_len(alpha.len(), E);
        for (block, out) in core.chunks_exact(len).zip(out.chunks_exact_mut(E)) {
            let (groups, _) = pulp::as_arrays::<4, f32>(block);
            let mut groups = groups.chunks_exact(E);
            let mut acc = [v3.splat_f64x4(0.0); E];
            for (a, grp) in a4.iter().zip(groups.by_ref()) {
                let av: f64x4 = cast(*a);
                for (acc, c) in acc.iter_mut().zip(grp) {
                    *acc = v3.mul_add_f64x4(widen(v3, *c), av, *acc);
                }
            }
            if let Some(grp) = groups.next() {
                let av: f64x4 = cast(tail);
                for (acc, c) in acc.iter_mut().zip(grp) {
                    *acc = v3.mul_add_f64x4(widen(v3, *c), av, *acc);
                }
            }
            for (o, a) in out.iter_mut().zip(acc) {
                *o = v3.reduce_sum_f64s(a);
            }
        }
    }

    pub(super) struct ContractIdRot<'a> {
        pub v3: V3,
        pub core: &'a [f32],
        pub beta: &'a [f64],
        pub r_id: usize,
        pub rp: usize,
        pub rot: &'a [f64; 9],
        pub y: &'a [f64],
        pub w: &'a [f64],
        pub out: &'a mut [f64],
        pub g: &'a mut [f64],
    }

    impl WithSimd for ContractIdRot<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: Simd>(self, _simd: S) {
            match self.beta.len() {
                1 => id_all::<1>(self),
                2 => id_all::<2>(self),
                3 => id_all::<3>(self),
                4 => id_all::<4>(self),
                5 => id_all::<5>(self),
                6 => id_all::<6>(self),
                7 => id_all::<7>(self),
                _ => id_all::<8>(self),
            }
        }
    }

    /// `sum_e beta[e] widen(grp[e])` for one column group.
    #[inline(always)]
    fn combine<const E: usize>(v3: V3, grp: &[[f32; 4]], bv: &[f64x4; E]) -> f64x4 {
        let mut t = v3.splat_f64x4(0.0);
        for (c, b) in grp.iter().zip(bv) {
            t = v3.mul_add_f64x4(widen(v3, *c), *b, t);
        }
        t
    }

    /// [`super::contract_id_rot`] for `r_exp = E`: per point and column group, the
    /// three coordinates' contractions with the broadcast `beta` (in registers),
    /// rotated, stored, and added to `g`.
    #[inline(always)]
    fn id_all<const E: usize>(k: ContractIdRot<'_>) {
        let ContractIdRot {
            v3,
            core,
            beta,
            r_id: ri,
            rp,
            rot,
            y,
            w,
            out,
            g,
        } = k;
        let bv: [f64x4; E] = std::array::from_fn(|e| v3.splat_f64x4(beta[e]));
        let rv: [f64x4; 9] = std::array::from_fn(|i| v3.splat_f64x4(rot[i]));
        let len = super::panel_len(ri, E);
        let q4 = ri / 4;
        let (g4, gr) = g[..ri].split_at_mut(4 * q4);
        let g4 = pulp::as_arrays_mut::<4, f64>(g4).0;
        let rotate = |t0: f64x4, t1: f64x4, t2: f64x4| -> [f64x4; 3] {
            std::array::from_fn(|i| {
                let v = v3.mul_f64x4(rv[3 * i], t0);
                let v = v3.mul_add_f64x4(rv[3 * i + 1], t1, v);
                v3.mul_add_f64x4(rv[3 * i + 2], t2, v)
            })
        };
        // Reverse order: start where `contract_exp` ended (cache reuse).
        for (((block, out), yk), &wk) in core
            .chunks_exact(3 * len)
            .zip(out.chunks_exact_mut(3 * rp))
            .zip(y.chunks_exact(2))
            .zip(w)
            .rev()
        {
            let (wy0, wy1) = (v3.splat_f64x4(wk * yk[0]), v3.splat_f64x4(wk * yk[1]));
            let (b0, rest) = block.split_at(len);
            let (b1, b2) = rest.split_at(len);
            let (p0, p1, p2) = (
                pulp::as_arrays::<4, f32>(b0).0,
                pulp::as_arrays::<4, f32>(b1).0,
                pulp::as_arrays::<4, f32>(b2).0,
            );
            let (o0, rest) = out.split_at_mut(rp);
            let (o1, o2) = rest.split_at_mut(rp);
            let (o0, o1, o2) = (
                pulp::as_arrays_mut::<4, f64>(&mut o0[..4 * q4]).0,
                pulp::as_arrays_mut::<4, f64>(&mut o1[..4 * q4]).0,
                pulp::as_arrays_mut::<4, f64>(&mut o2[..4 * q4]).0,
            );
            let (mut i0, mut i1, mut i2) = (p0.chunks_exact(E), p1.chunks_exact(E), p2.chunks_exact(E));
            for (((gq, (q0, q1)), q2), ((s0, s1), s2)) in g4
                .iter_mut()
                .zip(i0.by_ref().zip(i1.by_ref()))
                .zip(i2.by_ref())
                .zip(o0.iter_mut().zip(o1.iter_mut()).zip(o2.iter_mut()))
            {
                let o = rotate(combine(v3, q0, &bv), combine(v3, q1, &bv), combine(v3, q2, &bv));
                *s0 = cast(o[0]);
                *s1 = cast(o[1]);
                *s2 = cast(o[2]);
                let gv = v3.mul_add_f64x4(wy0, o[0], cast(*gq));
                *gq = cast(v3.mul_add_f64x4(wy1, o[1], gv));
            }
            if let (Some(q0), Some(q1), Some(q2)) = (i0.next(), i1.next(), i2.next()) {
                // The zero-padded last group: only its first `ri % 4` lanes are stored.
                let o = rotate(combine(v3, q0, &bv), combine(v3, q1, &bv), combine(v3, q2, &bv));
                let o: [[f64; 4]; 3] = o.map(cast);
                for (l, gl) in gr.iter_mut().enumerate() {
                    for (i, oi) in o.iter().enumerate() {
                        out[i * rp + 4 * q4 + l] = oi[l];
                    }
                    *gl += wk * (yk[0] * o[0][l] + yk[1] * o[1][l]);
                }
            }
        }
    }

    pub(super) struct Points<'a> {
        pub v3: V3,
        pub core: &'a [f32],
        pub mean: &'a [f64],
        pub ab: &'a [f64],
        pub out: &'a mut [f64],
    }

    impl WithSimd for Points<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: Simd>(self, _simd: S) {
            let blk = self.ab.len();
            for ((o, m), row) in self.out.iter_mut().zip(self.mean).zip(self.core.chunks_exact(blk)) {
                *o = m + dot(self.v3, row, self.ab);
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn close(a: f64, b: f64, scale: f64) -> bool {
        (a - b).abs() <= 1e-12 * scale.max(1.0)
    }

    /// `src` (`[N][3][r_exp][r_id]`) in the panel layout.
    fn pack(src: &[f32], n: usize, ri: usize, re: usize) -> Vec<f32> {
        let mut core = Vec::new();
        for k in 0..n {
            pack_point(&mut core, ri, re, |c, e, j| src[((k * 3 + c) * re + e) * ri + j]);
        }
        assert_eq!(core.len(), n * 3 * panel_len(ri, re));
        core
    }

    #[test]
    fn contractions_and_points_match_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for &(n, ri, re) in &[
            (5usize, 56usize, 7usize),
            (3, 9, 5),
            (2, 1, 1),
            (4, 13, 3),
            (3, 6, 8),
            (2, 7, 11),
        ] {
            // `src` in the natural order [N][3][r_exp][r_id], `core` packed from it.
            let src: Vec<f32> = (0..n * 3 * ri * re).map(|_| rng.random_range(-1.0..1.0)).collect();
            let core = pack(&src, n, ri, re);
            let mean: Vec<f64> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
            let alpha: Vec<f64> = (0..ri).map(|_| rng.random_range(-1.0..1.0)).collect();
            let beta: Vec<f64> = (0..re).map(|_| rng.random_range(-1.0..1.0)).collect();
            let c = |p: usize, e: usize, j: usize| f64::from(src[(p * re + e) * ri + j]);
            let mut te = vec![0.0; n * 3 * re];
            contract_exp(&core, &alpha, re, &mut te);
            let rp = ri.div_ceil(8) * 8;
            let mut ti = vec![7.0; n * 3 * rp];
            let rot = [0.36, 0.48, -0.8, -0.8, 0.6, 0.0, 0.48, 0.64, 0.6];
            let y: Vec<f64> = (0..2 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let w: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
            let g0: Vec<f64> = (0..ri).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut g = g0.clone();
            contract_id_rot(&core, &beta, ri, rp, &rot, &y, &w, &mut ti, &mut g);
            for j in 0..ri {
                let mut gr = g0[j];
                for k in 0..n {
                    let tt: Vec<f64> = (0..3)
                        .map(|cc| (0..re).map(|e| c(k * 3 + cc, e, j) * beta[e]).sum::<f64>())
                        .collect();
                    for i in 0..3 {
                        let r = rot[3 * i] * tt[0] + rot[3 * i + 1] * tt[1] + rot[3 * i + 2] * tt[2];
                        let v = ti[(k * 3 + i) * rp + j];
                        assert!(close(v, r, re as f64), "({k},{i},{j}) {v} vs {r}");
                        if i < 2 {
                            gr += w[k] * y[2 * k + i] * r;
                        }
                    }
                }
                assert!(close(g[j], gr, (n * re) as f64), "g[{j}] {} vs {gr}", g[j]);
            }
            for k in 0..3 * n {
                assert!(
                    ti[k * rp + ri..(k + 1) * rp].iter().all(|&v| v == 7.0),
                    "padding written"
                );
            }
            let mut ab = vec![0.0; panel_len(ri, re)];
            pack_ab(&alpha, &beta, &mut ab);
            let mut pts = vec![0.0; n * 3];
            points(&core, &mean, &ab, &mut pts);
            for p in 0..n * 3 {
                for e in 0..re {
                    let r: f64 = (0..ri).map(|j| c(p, e, j) * alpha[j]).sum();
                    assert!(close(te[p * re + e], r, ri as f64), "{} vs {r}", te[p * re + e]);
                }
                let r: f64 = mean[p]
                    + (0..re)
                        .map(|e| (0..ri).map(|j| c(p, e, j) * alpha[j] * beta[e]).sum::<f64>())
                        .sum::<f64>();
                assert!(close(pts[p], r, (ri * re) as f64), "{} vs {r}", pts[p]);
            }
        }
    }

    #[test]
    fn syrk_matches_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for &(m, rp, rows) in &[
            (500usize, 56usize, 3usize),
            (7, 8, 2),
            (65, 16, 3),
            (1, 64, 2),
            (33, 8, 2),
        ] {
            let ps = rows * rp;
            let d: Vec<f64> = (0..m * ps).map(|_| rng.random_range(-1.0..1.0)).collect();
            let w: Vec<f64> = (0..m).map(|_| rng.random_range(0.0..1.0)).collect();
            let h0: Vec<f64> = (0..rp * rp).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut h = h0.clone();
            let mut sc = vec![0.0; syrk_scratch_len(rp)];
            syrk_points(&d, ps, rp, &w, &mut sc, &mut h);
            for i in 0..rp {
                for j in i..rp {
                    let r: f64 = h0[i * rp + j]
                        + (0..m)
                            .map(|k| {
                                let b = k * ps;
                                w[k] * (d[b + i] * d[b + j] + d[b + rp + i] * d[b + rp + j])
                            })
                            .sum::<f64>();
                    assert!(close(h[i * rp + j], r, m as f64), "({i},{j}) {} vs {r}", h[i * rp + j]);
                }
            }
        }
    }

    #[test]
    fn portable_fallbacks_match_dispatched_kernels() {
        // The generic code paths (what a CPU without AVX2 runs), forced with pulp's
        // scalar level, against the dispatched ones.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (n, ri, re) = (9usize, 13usize, 5usize);
        let rp = ri.div_ceil(8) * 8;
        let src: Vec<f32> = (0..n * 3 * ri * re).map(|_| rng.random_range(-1.0..1.0)).collect();
        let core = pack(&src, n, ri, re);
        let mean: Vec<f64> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        let alpha: Vec<f64> = (0..ri).map(|_| rng.random_range(-1.0..1.0)).collect();
        let beta: Vec<f64> = (0..re).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut ab = vec![0.0; panel_len(ri, re)];
        pack_ab(&alpha, &beta, &mut ab);
        let rot = [0.36, 0.48, -0.8, -0.8, 0.6, 0.0, 0.48, 0.64, 0.6];
        let y: Vec<f64> = (0..2 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let w: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
        let scalar = pulp::Scalar::new();
        let same = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| close(*x, *y, 100.0));

        let (mut te1, mut te2) = (vec![0.0; n * 3 * re], vec![0.0; n * 3 * re]);
        contract_exp(&core, &alpha, re, &mut te1);
        ContractExp {
            core: &core,
            alpha: &alpha,
            r_exp: re,
            out: &mut te2,
        }
        .with_simd(scalar);
        assert!(same(&te1, &te2));

        let (mut p1, mut p2) = (vec![0.0; n * 3], vec![0.0; n * 3]);
        points(&core, &mean, &ab, &mut p1);
        Points {
            core: &core,
            mean: &mean,
            ab: &ab,
            out: &mut p2,
        }
        .with_simd(scalar);
        assert!(same(&p1, &p2));

        let (mut o1, mut o2) = (vec![0.0; n * 3 * rp], vec![0.0; n * 3 * rp]);
        let (mut g1, mut g2) = (vec![0.0; ri], vec![0.0; ri]);
        contract_id_rot(&core, &beta, ri, rp, &rot, &y, &w, &mut o1, &mut g1);
        ContractIdRot {
            core: &core,
            beta: &beta,
            r_id: ri,
            rp,
            rot: &rot,
            y: &y,
            w: &w,
            out: &mut o2,
            g: &mut g2,
        }
        .with_simd(scalar);
        assert!(same(&o1, &o2) && same(&g1, &g2));

        let d: Vec<f64> = (0..n * 3 * rp).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (mut h1, mut h2) = (vec![0.0; rp * rp], vec![0.0; rp * rp]);
        let mut sc = vec![0.0; syrk_scratch_len(rp)];
        syrk_points(&d, 3 * rp, rp, &w, &mut sc, &mut h1);
        Syrk {
            d: &d,
            ps: 3 * rp,
            rp,
            w: &w,
            scratch: &mut sc,
            h: &mut h2,
        }
        .with_simd(scalar);
        for i in 0..rp {
            assert!(same(&h1[i * rp + i..(i + 1) * rp], &h2[i * rp + i..(i + 1) * rp]));
        }
    }
}
