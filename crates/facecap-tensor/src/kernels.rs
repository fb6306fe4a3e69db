//! Hot kernels of the fitter ([`crate::fit`]), compiled for the CPU found at run time
//! (`pulp::Arch::dispatch`: AVX2 + FMA where available, portable scalar code otherwise).
//!
//! * [`contract_exp`] / [`contract_id`]: the per-point core slices (stored in `f32`,
//!   widened exactly to `f64`, all arithmetic in `f64`) contracted with the identity
//!   mode coordinates `alpha` (giving `r_exp` values per point and coordinate) or the
//!   expression mode coordinates `beta` (giving `r_id` values). These two passes read
//!   the whole restricted core (500 points: 2.35 MB in `f32`) and are memory bound;
//!   [`contract_id`] walks the points in reverse order so that it starts on the slices
//!   [`contract_exp`] read last, which are still in the L2 cache.
//! * [`points`]: `m + <C, alpha kron beta>` per point and coordinate.
//! * [`syrk_upper`]: `H += D^T D` (upper-triangle tiles) for the design rows `D`
//!   (`[M][rp]`, `rp` a multiple of 8, rows already scaled by `sqrt(w_k)`), a register
//!   tiled rank-`M` update: 4 x 8 tiles of `H` held in registers while a block of 64
//!   rows (in L1) streams past, fused multiply-adds where the CPU has them.
//!
//! Each kernel has a slow reference in the tests below (seeded property tests).

use pulp::{Simd, WithSimd};

/// Rows per cache block of [`syrk_upper`] (64 rows x 56 x 8 bytes = 28 KB, fits L1).
const SYRK_ROWS: usize = 64;

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
        let ri = self.alpha.len();
        let blk = ri * self.r_exp;
        for (core, out) in self.core.chunks_exact(blk).zip(self.out.chunks_exact_mut(self.r_exp)) {
            for (o, row) in out.iter_mut().zip(core.chunks_exact(ri)) {
                *o = dot_f32(row, self.alpha);
            }
        }
    }
}

/// `out[k][c][e] = sum_j core[k][c][e][j] alpha[j]` (`core`: `[N][3][r_exp][r_id]`,
/// `out`: `[N][3][r_exp]`), points in increasing order.
pub(crate) fn contract_exp(core: &[f32], alpha: &[f64], r_exp: usize, out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
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
    pulp::Arch::new().dispatch(ContractExp {
        core,
        alpha,
        r_exp,
        out,
    });
}

struct ContractId<'a> {
    core: &'a [f32],
    beta: &'a [f64],
    r_id: usize,
    out: &'a mut [f64],
}

impl WithSimd for ContractId<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let ri = self.r_id;
        let blk = ri * self.beta.len();
        // Reverse order: start where `contract_exp` ended (cache reuse).
        for (core, out) in self.core.chunks_exact(blk).zip(self.out.chunks_exact_mut(ri)).rev() {
            // Four expression modes per pass over `out`.
            let rows4 = core.chunks_exact(4 * ri);
            let rest = rows4.remainder();
            let b4 = self.beta.chunks_exact(4);
            let brest = b4.remainder();
            out.iter_mut().for_each(|o| *o = 0.0);
            let n = out.len();
            for (rows, b) in rows4.zip(b4) {
                let (c0, c1, c2, c3) = (
                    &rows[..n],
                    &rows[ri..ri + n],
                    &rows[2 * ri..2 * ri + n],
                    &rows[3 * ri..3 * ri + n],
                );
                for j in 0..n {
                    out[j] += (b[0] * f64::from(c0[j]) + b[1] * f64::from(c1[j]))
                        + (b[2] * f64::from(c2[j]) + b[3] * f64::from(c3[j]));
                }
            }
            for (b, row) in brest.iter().zip(rest.chunks_exact(ri)) {
                for (o, cv) in out.iter_mut().zip(row) {
                    *o += b * f64::from(*cv);
                }
            }
        }
    }
}

/// `out[k][c][j] = sum_e core[k][c][e][j] beta[e]` (`out`: `[N][3][r_id]`), points in
/// decreasing order.
pub(crate) fn contract_id(core: &[f32], beta: &[f64], r_id: usize, out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        return pulp::Simd::vectorize(
            v3,
            avx2::ContractId {
                v3,
                core,
                beta,
                r_id,
                out,
            },
        );
    }
    pulp::Arch::new().dispatch(ContractId { core, beta, r_id, out });
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

/// `out[k][c] = mean[k][c] + <core[k][c], ab>` (`ab = beta kron alpha`, `[r_exp][r_id]`).
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
    rp: usize,
    h: &'a mut [f64],
}

impl WithSimd for Syrk<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Syrk { d, rp, h } = self;
        // Vectors per 8-wide tile row (2 with AVX2, 8 in the scalar fallback).
        let nv = 8 / S::F64_LANES;
        let zero = simd.splat_f64s(0.0);
        for block in d.chunks(SYRK_ROWS * rp) {
            for i0 in (0..rp).step_by(4) {
                for j0 in (i0 / 8 * 8..rp).step_by(8) {
                    let mut acc = [[zero; 8]; 4];
                    for row in block.chunks_exact(rp) {
                        let (bv, _) = S::as_simd_f64s(&row[j0..j0 + 8]);
                        let a = [row[i0], row[i0 + 1], row[i0 + 2], row[i0 + 3]];
                        for (acc_i, &ai) in acc.iter_mut().zip(&a) {
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
            }
        }
    }
}

/// `h += sum_m d_m d_m^T` on the tiles of the `rp x rp` row-major `h` that cover its
/// upper triangle (some entries below the diagonal are written too; callers read the
/// upper triangle only). `d` holds `M` rows of length `rp`; `rp` must be a multiple
/// of 8 (pad the rows with zeros).
pub(crate) fn syrk_upper(d: &[f64], rp: usize, h: &mut [f64]) {
    debug_assert_eq!(rp % 8, 0);
    debug_assert_eq!(d.len() % rp, 0);
    debug_assert_eq!(h.len(), rp * rp);
    pulp::Arch::new().dispatch(Syrk { d, rp, h });
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
            let v3 = self.v3;
            let ri = self.alpha.len();
            let blk = ri * self.r_exp;
            for (core, out) in self.core.chunks_exact(blk).zip(self.out.chunks_exact_mut(self.r_exp)) {
                for (o, row) in out.iter_mut().zip(core.chunks_exact(ri)) {
                    *o = dot(v3, row, self.alpha);
                }
            }
        }
    }

    /// `out[n] = sum_e beta[e] core[e][4 (q + n) .. 4 (q + n) + 4]` for `n < N`.
    #[inline(always)]
    fn block<const N: usize>(v3: V3, core: &[f32], beta: &[f64], ri: usize, q: usize, out: &mut [[f64; 4]]) {
        let mut acc = [v3.splat_f64x4(0.0); N];
        for (row, &b) in core.chunks_exact(ri).zip(beta) {
            let bv = v3.splat_f64x4(b);
            let c = &pulp::as_arrays::<4, f32>(row).0[q..q + N];
            for (a, c) in acc.iter_mut().zip(c) {
                *a = v3.mul_add_f64x4(bv, widen(v3, *c), *a);
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = cast(a);
        }
    }

    pub(super) struct ContractId<'a> {
        pub v3: V3,
        pub core: &'a [f32],
        pub beta: &'a [f64],
        pub r_id: usize,
        pub out: &'a mut [f64],
    }

    impl WithSimd for ContractId<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: Simd>(self, _simd: S) {
            let v3 = self.v3;
            let ri = self.r_id;
            let re = self.beta.len();
            let blk = ri * re;
            for (core, out) in self.core.chunks_exact(blk).zip(self.out.chunks_exact_mut(ri)).rev() {
                let (o4, orem) = pulp::as_arrays_mut::<4, f64>(out);
                let q4 = o4.len();
                // Blocks of 4 x 4 outputs (independent FMA chains), summed over the
                // expression modes; then 2 x 4 and 1 x 4.
                let mut q = 0;
                while q + 4 <= q4 {
                    block::<4>(v3, core, self.beta, ri, q, &mut o4[q..q + 4]);
                    q += 4;
                }
                if q + 2 <= q4 {
                    block::<2>(v3, core, self.beta, ri, q, &mut o4[q..q + 2]);
                    q += 2;
                }
                if q < q4 {
                    block::<1>(v3, core, self.beta, ri, q, &mut o4[q..q + 1]);
                }
                for (jr, o) in orem.iter_mut().enumerate() {
                    let j = 4 * q4 + jr;
                    let mut acc = 0.0;
                    for (row, &b) in core.chunks_exact(ri).zip(self.beta) {
                        acc += b * f64::from(row[j]);
                    }
                    *o = acc;
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

    #[test]
    fn contractions_and_points_match_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for &(n, ri, re) in &[(5usize, 56usize, 7usize), (3, 9, 5), (2, 1, 1), (4, 13, 3)] {
            let core: Vec<f32> = (0..n * 3 * ri * re).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mean: Vec<f64> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
            let alpha: Vec<f64> = (0..ri).map(|_| rng.random_range(-1.0..1.0)).collect();
            let beta: Vec<f64> = (0..re).map(|_| rng.random_range(-1.0..1.0)).collect();
            let c = |p: usize, e: usize, j: usize| f64::from(core[(p * re + e) * ri + j]);
            let mut te = vec![0.0; n * 3 * re];
            contract_exp(&core, &alpha, re, &mut te);
            let mut ti = vec![0.0; n * 3 * ri];
            contract_id(&core, &beta, ri, &mut ti);
            let ab: Vec<f64> = (0..re * ri).map(|q| beta[q / ri] * alpha[q % ri]).collect();
            let mut pts = vec![0.0; n * 3];
            points(&core, &mean, &ab, &mut pts);
            for p in 0..n * 3 {
                for e in 0..re {
                    let r: f64 = (0..ri).map(|j| c(p, e, j) * alpha[j]).sum();
                    assert!(close(te[p * re + e], r, ri as f64), "{} vs {r}", te[p * re + e]);
                }
                for j in 0..ri {
                    let r: f64 = (0..re).map(|e| c(p, e, j) * beta[e]).sum();
                    assert!(close(ti[p * ri + j], r, re as f64), "{} vs {r}", ti[p * ri + j]);
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
        for &(m, rp) in &[(1000usize, 56usize), (7, 8), (130, 16), (1, 64)] {
            let d: Vec<f64> = (0..m * rp).map(|_| rng.random_range(-1.0..1.0)).collect();
            let h0: Vec<f64> = (0..rp * rp).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut h = h0.clone();
            syrk_upper(&d, rp, &mut h);
            for i in 0..rp {
                for j in i..rp {
                    let r: f64 = h0[i * rp + j] + (0..m).map(|q| d[q * rp + i] * d[q * rp + j]).sum::<f64>();
                    assert!(close(h[i * rp + j], r, m as f64), "({i},{j}) {} vs {r}", h[i * rp + j]);
                }
            }
        }
    }
}
