//! Y'CbCr helpers shared by the ffmpeg and Y4M sources: luma range expansion and
//! Y'CbCr -> RGB conversion.
//!
//! Conversion (ITU-R BT.601 / BT.709, Poynton "Digital Video and HD", ch. 25-26):
//!
//! ```text
//! limited ("tv") range:  Y' = (Y - 16) * 255/219,   Cb' = (Cb - 128) * 255/224,   Cr' likewise
//! full ("pc") range:     Y' = Y,                    Cb' = Cb - 128,               Cr' likewise
//! R = Y' + 2 (1 - Kr) Cr'
//! G = Y' - 2 Kb (1 - Kb) / Kg * Cb' - 2 Kr (1 - Kr) / Kg * Cr'
//! B = Y' + 2 (1 - Kb) Cb'
//! BT.601: Kr = 0.299, Kb = 0.114;  BT.709: Kr = 0.2126, Kb = 0.0722;  Kg = 1 - Kr - Kb
//! ```
//!
//! evaluated in 16.16 fixed point and rounded, then clamped to 0..=255 (the clamp is
//! the definition of the conversion for out-of-gamut codes, not a silent fix-up).
//! Chroma planes subsampled by (sx, sy) are sampled nearest (the chroma sample whose
//! block covers the pixel); for 4:4:4 input that is exact.

use image::{GrayImage, RgbImage};

/// Which Y'CbCr matrix a stream uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColorMatrix {
    /// ITU-R BT.601 (SD video, JPEG, and the default when a stream says nothing).
    #[default]
    Bt601,
    /// ITU-R BT.709 (HD video).
    Bt709,
}

/// Whether 8-bit codes use the limited ("tv", 16..235 / 16..240) or full ("pc", 0..255) range.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColorRange {
    /// 16..=235 luma, 16..=240 chroma (almost all camera and web video).
    #[default]
    Limited,
    /// 0..=255 (JPEG, `yuvj*` formats).
    Full,
}

const FIX_SHIFT: u32 = 16;
const FIX_ONE: f64 = (1u32 << FIX_SHIFT) as f64;
const FIX_HALF: i32 = 1 << (FIX_SHIFT - 1);
/// Chroma samples per block of the 4:2:0 conversion (32 pixels of each row).
const CHROMA_BLOCK: usize = 16;

/// Lookup table mapping limited-range luma codes to full range:
/// `round((y - 16) * 255 / 219)` clamped to 0..=255.
pub fn limited_to_full_luma_lut() -> [u8; 256] {
    let mut lut = [0u8; 256];
    for (y, v) in lut.iter_mut().enumerate() {
        let f = ((y as f64 - 16.0) * 255.0 / 219.0).round();
        *v = f.clamp(0.0, 255.0) as u8;
    }
    lut
}

/// Expands limited-range luma codes to full range in place: the same bytes as
/// [`limited_to_full_luma_lut`] through [`apply_lut`] (unit test
/// `luma_expansion_equals_the_table`), in 16-bit integer arithmetic that the compiler
/// vectorises, where a table lookup goes byte by byte. `round((y - 16) * 255 / 219)` is
/// `(255 k + 109) / 219` for `k = y - 16 >= 0` (no code lies halfway between two).
pub fn expand_limited_luma(img: &mut GrayImage) {
    struct Run<'a>(&'a mut [u8]);
    impl pulp::WithSimd for Run<'_> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) {
            for p in self.0.iter_mut() {
                let k = u16::from(*p).saturating_sub(16);
                *p = ((k * 255 + 109) / 219).min(255) as u8;
            }
        }
    }
    pulp::Arch::new().dispatch(Run(img.as_mut()));
}

/// Applies a 256-entry lookup table to every pixel in place.
pub fn apply_lut(img: &mut GrayImage, lut: &[u8; 256]) {
    for p in img.as_mut().iter_mut() {
        *p = lut[usize::from(*p)];
    }
}

/// Fixed-point Y'CbCr -> RGB converter for one matrix and range.
#[derive(Debug, Clone, Copy)]
pub struct YuvToRgb {
    y_off: i32,
    y_mul: i32,
    r_cr: i32,
    g_cb: i32,
    g_cr: i32,
    b_cb: i32,
}

impl YuvToRgb {
    /// Precomputes the coefficients.
    pub fn new(matrix: ColorMatrix, range: ColorRange) -> Self {
        let (kr, kb) = match matrix {
            ColorMatrix::Bt601 => (0.299, 0.114),
            ColorMatrix::Bt709 => (0.2126, 0.0722),
        };
        let kg = 1.0 - kr - kb;
        let (y_off, y_scale, c_scale) = match range {
            ColorRange::Limited => (16, 255.0 / 219.0, 255.0 / 224.0),
            ColorRange::Full => (0, 1.0, 1.0),
        };
        let fx = |v: f64| (v * FIX_ONE).round() as i32;
        YuvToRgb {
            y_off,
            y_mul: fx(y_scale),
            r_cr: fx(2.0 * (1.0 - kr) * c_scale),
            g_cb: fx(2.0 * kb * (1.0 - kb) / kg * c_scale),
            g_cr: fx(2.0 * kr * (1.0 - kr) / kg * c_scale),
            b_cb: fx(2.0 * (1.0 - kb) * c_scale),
        }
    }

    /// Converts one pixel.
    #[inline]
    pub fn pixel(&self, y: u8, cb: u8, cr: u8) -> [u8; 3] {
        let yy = (i32::from(y) - self.y_off) * self.y_mul + FIX_HALF;
        let cb = i32::from(cb) - 128;
        let cr = i32::from(cr) - 128;
        let clamp = |v: i32| (v >> FIX_SHIFT).clamp(0, 255) as u8;
        [
            clamp(yy + self.r_cr * cr),
            clamp(yy - self.g_cb * cb - self.g_cr * cr),
            clamp(yy + self.b_cb * cb),
        ]
    }

    /// 4:4:4 planes to interleaved RGB: [`YuvToRgb::pixel`] on every pixel, 16 pixels at
    /// a time in vector registers where AVX2 is available (integer arithmetic, so the same
    /// bytes; unit test `vector_444_equals_the_pixel_formula`).
    fn convert_444(&self, y: &[u8], cb: &[u8], cr: &[u8], out: &mut [u8]) {
        self.dispatch(y, cb, cr, None, out);
    }

    /// 4:2:0 planes of a `size` image to interleaved RGB ([`YuvToRgb::convert_420_rows`]),
    /// vectorised like [`YuvToRgb::convert_444`] (same bytes as the plain formula: unit
    /// test `vector_420_equals_the_pixel_formula`).
    fn convert_420(&self, y: &[u8], cb: &[u8], cr: &[u8], size: (usize, usize), out: &mut [u8]) {
        self.dispatch(y, cb, cr, Some(size), out);
    }

    /// Runs [`YuvToRgb::convert_444_blocks`] (`half` = `None`) or
    /// [`YuvToRgb::convert_420_rows`] (`half` = the image size) compiled for AVX2 where
    /// the CPU has it.
    fn dispatch(&self, y: &[u8], cb: &[u8], cr: &[u8], half: Option<(usize, usize)>, out: &mut [u8]) {
        struct Run<'a> {
            conv: &'a YuvToRgb,
            planes: [&'a [u8]; 3],
            half: Option<(usize, usize)>,
            out: &'a mut [u8],
        }
        impl pulp::WithSimd for Run<'_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _simd: S) {
                let [y, cb, cr] = self.planes;
                match self.half {
                    None => self.conv.convert_444_blocks(y, cb, cr, self.out),
                    Some(size) => self.conv.convert_420_rows(y, cb, cr, size, self.out),
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            if let Some(size) = half {
                struct Run420<'a> {
                    v3: pulp::x86::V3,
                    conv: &'a YuvToRgb,
                    planes: [&'a [u8]; 3],
                    size: (usize, usize),
                    out: &'a mut [u8],
                }
                impl pulp::NullaryFnOnce for Run420<'_> {
                    type Output = ();
                    #[inline(always)]
                    fn call(self) {
                        let [y, cb, cr] = self.planes;
                        avx2::convert_420_rows(self.v3, self.conv, [y, cb, cr], self.size, self.out);
                    }
                }
                v3.vectorize(Run420 {
                    v3,
                    conv: self,
                    planes: [y, cb, cr],
                    size,
                    out,
                });
                return;
            }
        }
        let run = Run {
            conv: self,
            planes: [y, cb, cr],
            half,
            out,
        };
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            pulp::Simd::vectorize(v3, run);
            return;
        }
        pulp::WithSimd::with_simd(run, pulp::Scalar::new());
    }

    /// [`YuvToRgb::convert_444`]'s body: [`YuvToRgb::pixel`] on blocks of 16 pixels into
    /// three plain arrays (which the compiler keeps in vector registers when built for
    /// AVX2), interleaved afterwards, then on the remainder.
    #[inline(always)]
    fn convert_444_blocks(&self, y: &[u8], cb: &[u8], cr: &[u8], out: &mut [u8]) {
        const B: usize = 16;
        let n = y.len().min(cb.len()).min(cr.len()).min(out.len() / 3);
        let whole = n / B * B;
        let blocks = y[..whole]
            .chunks_exact(B)
            .zip(cb[..whole].chunks_exact(B))
            .zip(cr[..whole].chunks_exact(B))
            .zip(out[..3 * whole].chunks_exact_mut(3 * B));
        for (((ys, us), vs), o) in blocks {
            let (mut r, mut g, mut b) = ([0u8; B], [0u8; B], [0u8; B]);
            for k in 0..B {
                [r[k], g[k], b[k]] = self.pixel(ys[k], us[k], vs[k]);
            }
            for (k, px) in o.chunks_exact_mut(3).enumerate() {
                px.copy_from_slice(&[r[k], g[k], b[k]]);
            }
        }
        let rest = y[whole..n].iter().zip(&cb[whole..n]).zip(&cr[whole..n]);
        for (((yv, u), v), o) in rest.zip(out[3 * whole..3 * n].chunks_exact_mut(3)) {
            o.copy_from_slice(&self.pixel(*yv, *u, *v));
        }
    }

    /// 4:2:0 planes to interleaved RGB, each chroma sample used for the 2x2 pixels it
    /// covers (nearest, as [`YuvToRgb::convert_into`] documents), by [`walk_420`] with
    /// the portable [`Blocks420`] kernel (fixed-size arrays the compiler vectorises
    /// under the caller's SIMD dispatch). Integer arithmetic throughout, so the bytes are
    /// [`YuvToRgb::pixel`]'s (unit tests `vector_420_equals_the_pixel_formula` and
    /// `planes_420_convert_like_pixel_by_pixel_at_odd_and_even_widths`). Sizes are
    /// checked by the caller: `y` is `w * h`, `cb`/`cr` hold `ceil(w/2) * ceil(h/2)`
    /// samples.
    #[inline(always)]
    fn convert_420_rows(&self, y: &[u8], cb: &[u8], cr: &[u8], size: (usize, usize), out: &mut [u8]) {
        walk_420(self, &Portable(self), [y, cb, cr], size, out);
    }

    /// Converts planar Y'CbCr to RGB. `y` is `width*height`; `cb`/`cr` are
    /// `ceil(width/sx) * ceil(height/sy)` with row stride `ceil(width/sx)`.
    /// `out` is resized only when its size differs.
    #[allow(clippy::too_many_arguments)]
    pub fn convert_into(
        &self,
        y: &[u8],
        cb: &[u8],
        cr: &[u8],
        width: u32,
        height: u32,
        sx: u32,
        sy: u32,
        out: &mut RgbImage,
    ) {
        if out.dimensions() != (width, height) {
            *out = RgbImage::new(width, height);
        }
        let w = width as usize;
        let cw = width.div_ceil(sx) as usize;
        let (sx, sy) = (sx as usize, sy as usize);
        debug_assert_eq!(y.len(), w * height as usize);
        let out = out.as_mut();
        if (sx, sy) == (1, 1) && cb.len() >= y.len() && cr.len() >= y.len() {
            // 4:4:4: one chroma sample per pixel, no index arithmetic
            self.convert_444(y, cb, cr, out);
            return;
        }
        let chroma_420 = cw * (height as usize).div_ceil(2);
        if (sx, sy) == (2, 2) && cb.len() >= chroma_420 && cr.len() >= chroma_420 {
            // 4:2:0: each chroma sample covers a pair of pixels on two rows
            self.convert_420(y, cb, cr, (w, height as usize), out);
            return;
        }
        for (row, (yrow, orow)) in y.chunks_exact(w).zip(out.chunks_exact_mut(3 * w)).enumerate() {
            let crow = (row / sy) * cw;
            for (col, (yv, o)) in yrow.iter().zip(orow.chunks_exact_mut(3)).enumerate() {
                let ci = crow + col / sx;
                o.copy_from_slice(&self.pixel(*yv, cb[ci], cr[ci]));
            }
        }
    }
}

/// Pixels of each row in one block of the 4:2:0 conversion.
const BLOCK_PIXELS: usize = 2 * CHROMA_BLOCK;

/// A block kernel of the 4:2:0 conversion ([`walk_420`]): the chroma terms of
/// [`YuvToRgb::pixel`] for [`CHROMA_BLOCK`] samples, then one row's [`BLOCK_PIXELS`]
/// pixels from them.
trait Blocks420 {
    /// The chroma terms, doubled over the two columns each sample covers.
    type Terms;
    /// The terms of `CHROMA_BLOCK` chroma samples.
    fn terms(&self, cb: &[u8; CHROMA_BLOCK], cr: &[u8; CHROMA_BLOCK]) -> Self::Terms;
    /// One row's pixels: luma term plus `terms`, shifted, clamped, interleaved.
    fn row(&self, terms: &Self::Terms, ys: &[u8; BLOCK_PIXELS], out: &mut [u8; 3 * BLOCK_PIXELS]);
}

/// The traversal of the 4:2:0 conversion: rows in pairs (the two rows one chroma row
/// covers), in blocks of [`CHROMA_BLOCK`] chroma samples whose terms `kernel` computes
/// once for both rows; the columns after the last whole block go through
/// [`YuvToRgb::pixel`]. Sizes as [`YuvToRgb::convert_420_rows`].
#[inline(always)]
fn walk_420<K: Blocks420>(
    conv: &YuvToRgb,
    kernel: &K,
    [y, cb, cr]: [&[u8]; 3],
    (w, h): (usize, usize),
    out: &mut [u8],
) {
    const C: usize = CHROMA_BLOCK;
    const P: usize = BLOCK_PIXELS;
    let cw = w.div_ceil(2);
    let mut row = 0;
    while row < h {
        let rows = (h - row).min(2);
        let c0 = (row / 2) * cw;
        let (cb_row, cr_row) = (&cb[c0..c0 + cw], &cr[c0..c0 + cw]);
        let mut x = 0;
        while x + P <= w {
            let ci = x / 2;
            let (Ok(u), Ok(v)) = (
                <&[u8; C]>::try_from(&cb_row[ci..ci + C]),
                <&[u8; C]>::try_from(&cr_row[ci..ci + C]),
            ) else {
                break;
            };
            let terms = kernel.terms(u, v);
            for r in row..row + rows {
                let at = r * w + x;
                if let (Ok(ys), Ok(o)) = (
                    <&[u8; P]>::try_from(&y[at..at + P]),
                    <&mut [u8; 3 * P]>::try_from(&mut out[3 * at..3 * (at + P)]),
                ) {
                    kernel.row(&terms, ys, o);
                }
            }
            x += P;
        }
        for r in row..row + rows {
            for col in x..w {
                let ci = col / 2;
                let at = r * w + col;
                out[3 * at..3 * at + 3].copy_from_slice(&conv.pixel(y[at], cb_row[ci], cr_row[ci]));
            }
        }
        row += rows;
    }
}

/// The portable [`Blocks420`] kernel: fixed-size arrays, which the compiler keeps in
/// vector registers under the caller's SIMD dispatch.
struct Portable<'a>(&'a YuvToRgb);

impl Blocks420 for Portable<'_> {
    type Terms = [[i32; BLOCK_PIXELS]; 3];

    #[inline(always)]
    fn terms(&self, cb: &[u8; CHROMA_BLOCK], cr: &[u8; CHROMA_BLOCK]) -> Self::Terms {
        let c = self.0;
        let mut t = [[0i32; BLOCK_PIXELS]; 3];
        for k in 0..CHROMA_BLOCK {
            let u = i32::from(cb[k]) - 128;
            let v = i32::from(cr[k]) - 128;
            for (ch, term) in [c.r_cr * v, -c.g_cb * u - c.g_cr * v, c.b_cb * u]
                .into_iter()
                .enumerate()
            {
                t[ch][2 * k] = term;
                t[ch][2 * k + 1] = term;
            }
        }
        t
    }

    #[inline(always)]
    fn row(&self, [tr, tg, tb]: &Self::Terms, ys: &[u8; BLOCK_PIXELS], out: &mut [u8; 3 * BLOCK_PIXELS]) {
        let c = self.0;
        let clamp = |v: i32| (v >> FIX_SHIFT).clamp(0, 255) as u8;
        let (mut r, mut g, mut b) = ([0u8; BLOCK_PIXELS], [0u8; BLOCK_PIXELS], [0u8; BLOCK_PIXELS]);
        for k in 0..BLOCK_PIXELS {
            let yy = (i32::from(ys[k]) - c.y_off) * c.y_mul + FIX_HALF;
            r[k] = clamp(yy + tr[k]);
            g[k] = clamp(yy + tg[k]);
            b[k] = clamp(yy + tb[k]);
        }
        for (k, px) in out.chunks_exact_mut(3).enumerate() {
            px.copy_from_slice(&[r[k], g[k], b[k]]);
        }
    }
}

/// The 4:2:0 conversion in AVX2 registers: [`YuvToRgb::convert_420_rows`]'s method (row
/// pairs, blocks of [`CHROMA_BLOCK`] chroma samples, the chroma terms once per sample) with
/// the same integer arithmetic, 8 pixels to a register, then packed with saturation (which
/// is the clamp to 0..=255: the shifted values fit in 16 bits) and interleaved by byte
/// shuffles. Same bytes as [`YuvToRgb::pixel`] (unit tests `vector_420_equals_the_pixel_formula`
/// and `planes_420_convert_like_pixel_by_pixel_at_odd_and_even_widths` run it where the
/// CPU has AVX2).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{YuvToRgb, BLOCK_PIXELS, CHROMA_BLOCK, FIX_HALF, FIX_SHIFT};
    use core::arch::x86_64::{__m128i, __m256i};
    use pulp::x86::V3;

    const C: usize = CHROMA_BLOCK;
    const P: usize = BLOCK_PIXELS;

    /// Byte shuffle that puts channel `ch` of a lane's 16 pixels at its places in chunk `j`
    /// (bytes `16 j .. 16 j + 16`) of their 48 interleaved bytes; `0x80` (zero) elsewhere.
    /// Both lanes alike.
    const fn mask(ch: usize, j: usize) -> [u8; 32] {
        let mut m = [0x80u8; 32];
        let mut i = 0;
        while i < 16 {
            let q = 16 * j + i;
            if q % 3 == ch {
                m[i] = (q / 3) as u8;
                m[i + 16] = (q / 3) as u8;
            }
            i += 1;
        }
        m
    }

    /// `MASKS[ch][j]`, see [`mask`].
    const MASKS: [[[u8; 32]; 3]; 3] = [
        [mask(0, 0), mask(0, 1), mask(0, 2)],
        [mask(1, 0), mask(1, 1), mask(1, 2)],
        [mask(2, 0), mask(2, 1), mask(2, 2)],
    ];

    /// The three chroma terms of [`YuvToRgb::pixel`] for `C` samples, each doubled over the
    /// two pixel columns it covers: `[channel][8 pixels]`.
    #[inline(always)]
    fn chroma_terms(v3: V3, conv: &YuvToRgb, cb: &[u8; C], cr: &[u8; C]) -> [[__m256i; 4]; 3] {
        let (avx, sse2) = (v3.avx2, v3.sse2);
        let centre = v3.avx._mm256_set1_epi32(128);
        let widen = |s: &[u8; C]| -> [__m256i; 2] {
            let v: __m128i = pulp::cast(*s);
            [
                avx._mm256_sub_epi32(avx._mm256_cvtepu8_epi32(v), centre),
                avx._mm256_sub_epi32(avx._mm256_cvtepu8_epi32(sse2._mm_srli_si128::<8>(v)), centre),
            ]
        };
        let (u, v) = (widen(cb), widen(cr));
        let k = |c: i32| v3.avx._mm256_set1_epi32(c);
        let lo: __m256i = pulp::cast([0i32, 0, 1, 1, 2, 2, 3, 3]);
        let hi: __m256i = pulp::cast([4i32, 4, 5, 5, 6, 6, 7, 7]);
        let mut t = [[v3.avx._mm256_setzero_si256(); 4]; 3];
        for half in 0..2 {
            let (u, v) = (u[half], v[half]);
            let r = avx._mm256_mullo_epi32(v, k(conv.r_cr));
            let g = avx._mm256_sub_epi32(
                v3.avx._mm256_setzero_si256(),
                avx._mm256_add_epi32(
                    avx._mm256_mullo_epi32(u, k(conv.g_cb)),
                    avx._mm256_mullo_epi32(v, k(conv.g_cr)),
                ),
            );
            let b = avx._mm256_mullo_epi32(u, k(conv.b_cb));
            for (ch, term) in [r, g, b].into_iter().enumerate() {
                t[ch][2 * half] = avx._mm256_permutevar8x32_epi32(term, lo);
                t[ch][2 * half + 1] = avx._mm256_permutevar8x32_epi32(term, hi);
            }
        }
        t
    }

    /// One row's `P` pixels: luma term plus `terms`, shifted, packed (clamped), interleaved
    /// into `out` (`3 P` bytes).
    #[inline(always)]
    fn block(v3: V3, conv: &YuvToRgb, ys: &[u8; P], terms: &[[__m256i; 4]; 3], out: &mut [u8; 3 * P]) {
        let (avx, sse2) = (v3.avx2, v3.sse2);
        let halves: [[u8; 16]; 2] = pulp::cast(*ys);
        let (a, b): (__m128i, __m128i) = (pulp::cast(halves[0]), pulp::cast(halves[1]));
        let mul = v3.avx._mm256_set1_epi32(conv.y_mul);
        let add = v3.avx._mm256_set1_epi32(FIX_HALF - conv.y_off * conv.y_mul);
        let yy = [a, sse2._mm_srli_si128::<8>(a), b, sse2._mm_srli_si128::<8>(b)]
            .map(|q| avx._mm256_add_epi32(avx._mm256_mullo_epi32(avx._mm256_cvtepu8_epi32(q), mul), add));
        let order: __m256i = pulp::cast([0i32, 4, 1, 5, 2, 6, 3, 7]);
        let channel = |t: &[__m256i; 4]| -> __m256i {
            let v: [__m256i; 4] = std::array::from_fn(|k| {
                avx._mm256_srai_epi32::<{ FIX_SHIFT as i32 }>(avx._mm256_add_epi32(yy[k], t[k]))
            });
            let bytes = avx._mm256_packus_epi16(avx._mm256_packs_epi32(v[0], v[1]), avx._mm256_packs_epi32(v[2], v[3]));
            avx._mm256_permutevar8x32_epi32(bytes, order)
        };
        let rgb = [channel(&terms[0]), channel(&terms[1]), channel(&terms[2])];
        let chunk = |j: usize| -> __m256i {
            let s = |ch: usize| avx._mm256_shuffle_epi8(rgb[ch], pulp::cast(MASKS[ch][j]));
            avx._mm256_or_si256(avx._mm256_or_si256(s(0), s(1)), s(2))
        };
        let (o0, o1, o2) = (chunk(0), chunk(1), chunk(2));
        let parts: [[u8; 32]; 3] = [
            pulp::cast(avx._mm256_permute2x128_si256::<0x20>(o0, o1)),
            pulp::cast(avx._mm256_permute2x128_si256::<0x30>(o2, o0)),
            pulp::cast(avx._mm256_permute2x128_si256::<0x31>(o1, o2)),
        ];
        for (dst, src) in out.chunks_exact_mut(32).zip(parts.iter()) {
            dst.copy_from_slice(src);
        }
    }

    /// The AVX2 [`super::Blocks420`] kernel (module docs).
    struct Avx2Blocks<'a>(V3, &'a YuvToRgb);

    impl super::Blocks420 for Avx2Blocks<'_> {
        type Terms = [[__m256i; 4]; 3];

        #[inline(always)]
        fn terms(&self, cb: &[u8; C], cr: &[u8; C]) -> Self::Terms {
            chroma_terms(self.0, self.1, cb, cr)
        }

        #[inline(always)]
        fn row(&self, terms: &Self::Terms, ys: &[u8; P], out: &mut [u8; 3 * P]) {
            block(self.0, self.1, ys, terms, out);
        }
    }

    /// [`YuvToRgb::convert_420_rows`] in AVX2 (module docs), by [`super::walk_420`].
    #[inline(always)]
    pub(super) fn convert_420_rows(v3: V3, conv: &YuvToRgb, planes: [&[u8]; 3], size: (usize, usize), out: &mut [u8]) {
        super::walk_420(conv, &Avx2Blocks(v3, conv), planes, size, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limited_range_black_white_grey() {
        let c = YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Limited);
        assert_eq!(c.pixel(16, 128, 128), [0, 0, 0]);
        assert_eq!(c.pixel(235, 128, 128), [255, 255, 255]);
        assert_eq!(c.pixel(126, 128, 128), [128, 128, 128]);
        let f = YuvToRgb::new(ColorMatrix::Bt709, ColorRange::Full);
        assert_eq!(f.pixel(77, 128, 128), [77, 77, 77]);
    }

    #[test]
    fn primaries_round_trip_bt601() {
        // Limited-range BT.601 red: Y=81, Cb=90, Cr=240.
        let c = YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Limited);
        let [r, g, b] = c.pixel(81, 90, 240);
        assert!(r >= 253 && g <= 2 && b <= 2, "{r} {g} {b}");
    }

    /// The vector 4:4:4 conversion gives `pixel`'s bytes: every (Y, Cb, Cr) corner and
    /// random planes of lengths around the block size, both matrices and ranges.
    #[test]
    fn vector_444_equals_the_pixel_formula() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(444);
        for matrix in [ColorMatrix::Bt601, ColorMatrix::Bt709] {
            for range in [ColorRange::Limited, ColorRange::Full] {
                let c = YuvToRgb::new(matrix, range);
                for n in [0usize, 1, 15, 16, 17, 31, 33, 480 * 7 + 5] {
                    let mut planes: [Vec<u8>; 3] =
                        std::array::from_fn(|_| (0..n).map(|_| rng.random::<u8>()).collect());
                    for (i, corner) in [0u8, 255].iter().enumerate().take(n.min(2)) {
                        for p in planes.iter_mut() {
                            p[i] = *corner;
                        }
                    }
                    let mut got = vec![7u8; 3 * n];
                    c.convert_444(&planes[0], &planes[1], &planes[2], &mut got);
                    for (k, px) in got.chunks_exact(3).enumerate() {
                        assert_eq!(
                            px,
                            c.pixel(planes[0][k], planes[1][k], planes[2][k]),
                            "{matrix:?} {range:?} n {n} k {k}"
                        );
                    }
                }
            }
        }
    }

    /// The vector 4:2:0 conversion gives `pixel` with the chroma sample covering each
    /// pixel, on odd and even sizes around the 64-pixel block.
    #[test]
    fn vector_420_equals_the_pixel_formula() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(420);
        let c = YuvToRgb::new(ColorMatrix::Bt709, ColorRange::Limited);
        for (w, h) in [
            (1usize, 1usize),
            (2, 2),
            (3, 5),
            (31, 2),
            (32, 1),
            (33, 3),
            (64, 3),
            (65, 4),
            (95, 5),
            (130, 7),
            (480, 6),
        ] {
            let cw = w.div_ceil(2);
            let y: Vec<u8> = (0..w * h).map(|_| rng.random()).collect();
            let cb: Vec<u8> = (0..cw * h.div_ceil(2)).map(|_| rng.random()).collect();
            let cr: Vec<u8> = (0..cw * h.div_ceil(2)).map(|_| rng.random()).collect();
            let mut got = RgbImage::new(1, 1);
            c.convert_into(&y, &cb, &cr, w as u32, h as u32, 2, 2, &mut got);
            assert_eq!(got.dimensions(), (w as u32, h as u32));
            for row in 0..h {
                for col in 0..w {
                    let ci = (row / 2) * cw + col / 2;
                    let want = c.pixel(y[row * w + col], cb[ci], cr[ci]);
                    assert_eq!(
                        got.get_pixel(col as u32, row as u32).0,
                        want,
                        "{w}x{h} at ({col}, {row})"
                    );
                }
            }
        }
    }

    /// The portable block kernel (what runs without AVX2) gives the same bytes as the
    /// pixel formula too, whatever this CPU dispatches to.
    #[test]
    fn portable_420_equals_the_pixel_formula() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(421);
        let c = YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Full);
        for (w, h) in [(1usize, 1usize), (31, 2), (32, 3), (95, 5), (480, 4)] {
            let cw = w.div_ceil(2);
            let y: Vec<u8> = (0..w * h).map(|_| rng.random()).collect();
            let cb: Vec<u8> = (0..cw * h.div_ceil(2)).map(|_| rng.random()).collect();
            let cr: Vec<u8> = (0..cw * h.div_ceil(2)).map(|_| rng.random()).collect();
            let mut got = vec![0u8; 3 * w * h];
            walk_420(&c, &Portable(&c), [&y, &cb, &cr], (w, h), &mut got);
            for (i, px) in got.chunks_exact(3).enumerate() {
                let (row, col) = (i / w, i % w);
                let ci = (row / 2) * cw + col / 2;
                assert_eq!(px, c.pixel(y[i], cb[ci], cr[ci]), "{w}x{h} at ({col}, {row})");
            }
        }
    }

    #[test]
    fn luma_expansion_equals_the_table() {
        let lut = limited_to_full_luma_lut();
        // every code, at lengths around the vector widths
        for n in [1usize, 15, 31, 64, 256, 1000] {
            let codes: Vec<u8> = (0..n).map(|i| (i * 97 % 256) as u8).collect();
            let mut a = GrayImage::from_raw(n as u32, 1, codes.clone()).unwrap();
            let mut b = a.clone();
            expand_limited_luma(&mut a);
            apply_lut(&mut b, &lut);
            assert_eq!(a, b, "n {n}");
        }
        let all = GrayImage::from_fn(256, 1, |x, _| image::Luma([x as u8]));
        let (mut a, mut b) = (all.clone(), all);
        expand_limited_luma(&mut a);
        apply_lut(&mut b, &lut);
        assert_eq!(a, b);
    }

    #[test]
    fn lut_endpoints() {
        let l = limited_to_full_luma_lut();
        assert_eq!(l[0], 0);
        assert_eq!(l[16], 0);
        assert_eq!(l[235], 255);
        assert_eq!(l[255], 255);
        assert_eq!(l[126], 128);
    }

    #[test]
    fn planes_420_convert_like_pixel_by_pixel_at_odd_and_even_widths() {
        let c = YuvToRgb::new(ColorMatrix::Bt709, ColorRange::Limited);
        for (w, h) in [(6u32, 4u32), (7, 5), (1, 1)] {
            let (cw, ch) = (w.div_ceil(2) as usize, h.div_ceil(2) as usize);
            let y: Vec<u8> = (0..w * h).map(|i| (i * 37 % 256) as u8).collect();
            let cb: Vec<u8> = (0..cw * ch).map(|i| (i * 53 % 256) as u8).collect();
            let cr: Vec<u8> = (0..cw * ch).map(|i| (255 - i * 29 % 256) as u8).collect();
            let mut out = RgbImage::new(1, 1);
            c.convert_into(&y, &cb, &cr, w, h, 2, 2, &mut out);
            for (row, col) in (0..h).flat_map(|r| (0..w).map(move |c| (r, c))) {
                let ci = (row as usize / 2) * cw + col as usize / 2;
                let want = c.pixel(y[(row * w + col) as usize], cb[ci], cr[ci]);
                assert_eq!(out.get_pixel(col, row).0, want, "{w}x{h} at ({col}, {row})");
            }
        }
    }
}
