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
    /// covers (nearest, as [`YuvToRgb::convert_into`] documents): each row in blocks of
    /// up to 64 pixels, the chroma doubled into two stack arrays, then
    /// [`YuvToRgb::convert_444_blocks`] (vectorised under the caller's SIMD dispatch).
    /// Sizes are checked by the caller: `y` is `w * h`, `cb`/`cr` hold
    /// `ceil(w/2) * ceil(h/2)` samples.
    #[inline(always)]
    fn convert_420_rows(&self, y: &[u8], cb: &[u8], cr: &[u8], (w, h): (usize, usize), out: &mut [u8]) {
        const B: usize = 64;
        let cw = w.div_ceil(2);
        for row in 0..h {
            let c0 = (row / 2) * cw;
            let (cb_row, cr_row) = (&cb[c0..c0 + cw], &cr[c0..c0 + cw]);
            let yrow = &y[row * w..][..w];
            let orow = &mut out[3 * row * w..][..3 * w];
            let mut x = 0;
            while x < w {
                let n = (w - x).min(B);
                let i0 = x / 2;
                let pairs = n.div_ceil(2);
                let (mut ub, mut ur) = ([0u8; B], [0u8; B]);
                for (k, (u, v)) in cb_row[i0..i0 + pairs].iter().zip(&cr_row[i0..i0 + pairs]).enumerate() {
                    ub[2 * k] = *u;
                    ub[2 * k + 1] = *u;
                    ur[2 * k] = *v;
                    ur[2 * k + 1] = *v;
                }
                self.convert_444_blocks(&yrow[x..x + n], &ub[..n], &ur[..n], &mut orow[3 * x..3 * (x + n)]);
                x += n;
            }
        }
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
        for (w, h) in [(1usize, 1usize), (2, 2), (3, 5), (64, 3), (65, 4), (130, 7), (480, 6)] {
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
