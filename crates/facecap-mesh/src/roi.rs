//! Regions of interest and the image-to-tensor warp, as MediaPipe's CPU graph does them.
//!
//! A region is a rotated rectangle in *normalised* image coordinates ([`NormRect`]:
//! centre, size as fractions of the image width and height, rotation in radians,
//! clockwise on screen since y points down). The tensor of an `n x n` model input is
//! sampled from it with the affine map MediaPipe's OpenCV converter builds from the
//! rectangle's corners (`cv::getPerspectiveTransform` of `cv::boxPoints`):
//!
//! ```text
//! src(u, v) = c + R(theta) * ((u / n - 0.5) * w_px, (v / n - 0.5) * h_px)
//! ```
//!
//! for integer tensor pixels `(u, v)` (so tensor pixel 0 samples the rectangle's edge),
//! where `c` is the centre in pixels (centre of the top-left pixel = (0, 0)). Sampling is
//! OpenCV's `INTER_LINEAR`: source coordinates rounded to 1/32 pixel, 15-bit fixed-point
//! weights, the result rounded to 8 bits, then scaled to floats.

use crate::{Error, Result};

/// Sub-pixel positions per pixel of OpenCV's interpolation tables (`INTER_TAB_SIZE`).
const TAB: i32 = 32;
/// Fixed-point scale of OpenCV's interpolation weights (`INTER_REMAP_COEF_SCALE`).
const COEF_SCALE: i32 = 1 << 15;

/// A rotated rectangle in normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NormRect {
    /// Centre x as a fraction of the image width.
    pub x_center: f32,
    /// Centre y as a fraction of the image height.
    pub y_center: f32,
    /// Width as a fraction of the image width.
    pub width: f32,
    /// Height as a fraction of the image height.
    pub height: f32,
    /// Rotation in radians (positive = clockwise on screen).
    pub rotation: f32,
}

/// `a - 2 pi floor((a + pi) / (2 pi))`, MediaPipe's `NormalizeRadians`.
pub fn normalize_radians(a: f32) -> f32 {
    let two_pi = 2.0 * std::f32::consts::PI;
    a - two_pi * ((a + std::f32::consts::PI) / two_pi).floor()
}

/// Rotation that makes the vector `p0 -> p1` (pixels) horizontal, as MediaPipe's
/// `DetectionsToRectsCalculator::ComputeRotation` with a target angle of 0.
pub fn rotation_from(p0: [f32; 2], p1: [f32; 2]) -> f32 {
    normalize_radians(-(-(p1[1] - p0[1])).atan2(p1[0] - p0[0]))
}

/// What lies outside the image when sampling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Border {
    /// Pixel value 0 (`cv::BORDER_CONSTANT`, the detector's letterbox).
    Zero,
    /// Nearest edge pixel (`cv::BORDER_REPLICATE`, the landmark crop).
    Replicate,
}

/// An 8-bit RGB image borrowed as rows of `width * 3` bytes.
#[derive(Debug, Clone, Copy)]
pub struct RgbView<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `height * width * 3` bytes, row-major RGB.
    pub data: &'a [u8],
}

impl<'a> RgbView<'a> {
    /// Wraps raw bytes, checking the size.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] when `data` does not hold `width * height` RGB pixels or the
    /// image is empty.
    pub fn new(width: usize, height: usize, data: &'a [u8]) -> Result<Self> {
        if width == 0 || height == 0 || width.checked_mul(height).and_then(|n| n.checked_mul(3)) != Some(data.len()) {
            return Err(Error::InvalidInput {
                what: format!("{} bytes for a {width}x{height} RGB image", data.len()),
            });
        }
        Ok(RgbView { width, height, data })
    }

    /// Borrows an `image::RgbImage`.
    ///
    /// # Errors
    /// As for [`RgbView::new`].
    pub fn from_image(img: &'a image::RgbImage) -> Result<Self> {
        RgbView::new(img.width() as usize, img.height() as usize, img.as_raw())
    }
}

/// The affine map from tensor pixels to image pixels for a region (see module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// Image position of tensor pixel (0, 0).
    pub origin: [f64; 2],
    /// Image step per tensor column.
    pub du: [f64; 2],
    /// Image step per tensor row.
    pub dv: [f64; 2],
}

impl Affine {
    /// The map for `rect` on a `w x h` image and an `n x n` tensor.
    pub fn for_rect(rect: &NormRect, w: usize, h: usize, n: usize) -> Affine {
        let (cx, cy) = (rect.x_center as f64 * w as f64, rect.y_center as f64 * h as f64);
        let (rw, rh) = (rect.width as f64 * w as f64, rect.height as f64 * h as f64);
        let (s, c) = (rect.rotation as f64).sin_cos();
        let n = n as f64;
        // Image offset of the rectangle-local point (a, b) is R (a, b).
        let du = [c * rw / n, s * rw / n];
        let dv = [-s * rh / n, c * rh / n];
        let origin = [cx - 0.5 * rw * c + 0.5 * rh * s, cy - 0.5 * rw * s - 0.5 * rh * c];
        Affine { origin, du, dv }
    }
}

/// OpenCV's bilinear weight table: `[32 * 32][4]` weights summing to 2^15.
#[derive(Debug, Clone)]
pub struct BilinearTable {
    w: Vec<[i32; 4]>,
}

impl Default for BilinearTable {
    fn default() -> Self {
        Self::new()
    }
}

impl BilinearTable {
    /// Builds the table as OpenCV's `initInterTab2D(INTER_LINEAR, fixpt = true)` does.
    pub fn new() -> Self {
        let mut w = Vec::with_capacity((TAB * TAB) as usize);
        for iy in 0..TAB {
            for ix in 0..TAB {
                let fy = iy as f32 / TAB as f32;
                let fx = ix as f32 / TAB as f32;
                let vals = [(1.0 - fy) * (1.0 - fx), (1.0 - fy) * fx, fy * (1.0 - fx), fy * fx];
                let mut q = [0i32; 4];
                let mut sum = 0;
                for k in 0..4 {
                    q[k] = (vals[k] * COEF_SCALE as f32).round() as i32;
                    sum += q[k];
                }
                if sum != COEF_SCALE {
                    // Put the rounding excess on the largest (OpenCV fixes the min/max entry).
                    let diff = sum - COEF_SCALE;
                    let (mut kmax, mut kmin) = (0, 0);
                    for k in 1..4 {
                        if q[k] > q[kmax] {
                            kmax = k;
                        }
                        if q[k] < q[kmin] {
                            kmin = k;
                        }
                    }
                    if diff < 0 {
                        q[kmax] -= diff;
                    } else {
                        q[kmin] -= diff;
                    }
                }
                w.push(q);
            }
        }
        BilinearTable { w }
    }
}

/// How 8-bit samples become tensor values: `v8 * scale + offset`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueMap {
    /// Factor.
    pub scale: f32,
    /// Offset.
    pub offset: f32,
}

impl ValueMap {
    /// [0, 255] -> [0, 1] (the landmark model).
    pub const UNIT: ValueMap = ValueMap {
        scale: 1.0 / 255.0,
        offset: 0.0,
    };
    /// [0, 255] -> [-1, 1] (the detector).
    pub const SIGNED: ValueMap = ValueMap {
        scale: 2.0 / 255.0,
        offset: -1.0,
    };
}

/// Samples an `n x n x 3` float tensor from `img` through `map`: value
/// `v8 * values.scale + values.offset`, `v8` the rounded 8-bit bilinear sample.
///
/// With AVX2, interior pixels mix their three channels in vector registers and each
/// row's source positions are computed in one vector loop first; the integer sums, the
/// roundings and the float operations are the scalar ones, so the tensor is the same bit
/// for bit (unit test `warp_equals_the_per_pixel_formula`).
pub fn warp_to_tensor(
    img: &RgbView<'_>,
    map: &Affine,
    n: usize,
    border: Border,
    values: ValueMap,
    table: &BilinearTable,
    out: &mut [f32],
) {
    let args = WarpArgs {
        img,
        map,
        n,
        border,
        values,
        table,
    };
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        pulp::Simd::vectorize(v3, WarpV3 { v3, args, out });
        return;
    }
    warp_with(&args, out, |_, _, _| None, |_| {});
}

/// The inputs of [`warp_to_tensor`].
struct WarpArgs<'a, 'b> {
    img: &'a RgbView<'b>,
    map: &'a Affine,
    n: usize,
    border: Border,
    values: ValueMap,
    table: &'a BilinearTable,
}

/// [`warp_with`] compiled for AVX2, with the interior pixels' bilinear mix in vector
/// registers ([`mix_v3`]).
#[cfg(target_arch = "x86_64")]
struct WarpV3<'a, 'b, 'c> {
    v3: pulp::x86::V3,
    args: WarpArgs<'a, 'b>,
    out: &'c mut [f32],
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for WarpV3<'_, '_, '_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let WarpV3 { v3, args, out } = self;
        let ValueMap { scale, offset } = args.values;
        warp_with(
            &args,
            out,
            |top, bottom, wt| mix_v3(v3, top, bottom, wt, scale, offset),
            |p| v3.sse._mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(p.cast()),
        );
    }
}

/// The three channels of one interior pixel (and a spare fourth lane) from its
/// neighbours' rows: `top` and `bottom` start at the left neighbour and hold at least 8
/// bytes, else `None`. The same integer sums, rounding and `v8 * scale + offset` as the
/// scalar mix, so bit for bit the same values.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn mix_v3(v3: pulp::x86::V3, top: &[u8], bottom: &[u8], wt: &[i32; 4], scale: f32, offset: f32) -> Option<[f32; 4]> {
    use core::arch::x86_64::__m128i;
    let (t, b): ([u8; 8], [u8; 8]) = (top.get(..8)?.try_into().ok()?, bottom.get(..8)?.try_into().ok()?);
    let t: __m128i = pulp::cast([u64::from_le_bytes(t), 0]);
    let b: __m128i = pulp::cast([u64::from_le_bytes(b), 0]);
    let (sse2, sse41) = (v3.sse2, v3.sse4_1);
    // lanes: channels 0-2 of the left (right) neighbour and one spare byte
    let tl = sse41._mm_cvtepu8_epi32(t);
    let tr = sse41._mm_cvtepu8_epi32(sse2._mm_srli_si128::<3>(t));
    let bl = sse41._mm_cvtepu8_epi32(b);
    let br = sse41._mm_cvtepu8_epi32(sse2._mm_srli_si128::<3>(b));
    let w = |k: usize| sse2._mm_set1_epi32(wt[k]);
    let s = sse2._mm_add_epi32(
        sse2._mm_add_epi32(sse41._mm_mullo_epi32(tl, w(0)), sse41._mm_mullo_epi32(tr, w(1))),
        sse2._mm_add_epi32(sse41._mm_mullo_epi32(bl, w(2)), sse41._mm_mullo_epi32(br, w(3))),
    );
    let v8 = sse2._mm_srai_epi32::<15>(sse2._mm_add_epi32(s, sse2._mm_set1_epi32(1 << 14)));
    let v8 = sse41._mm_min_epi32(
        sse41._mm_max_epi32(v8, sse2._mm_setzero_si128()),
        sse2._mm_set1_epi32(255),
    );
    let f = sse2._mm_cvtepi32_ps(v8);
    let f = v3.sse._mm_add_ps(
        v3.sse._mm_mul_ps(f, v3.sse._mm_set1_ps(scale)),
        v3.sse._mm_set1_ps(offset),
    );
    Some(pulp::cast(f))
}

/// The warp; `fast(top, bottom, weights)` may mix an interior pixel's three channels
/// (see [`mix_v3`]).
#[inline(always)]
fn warp_with(
    args: &WarpArgs<'_, '_>,
    out: &mut [f32],
    fast: impl Fn(&[u8], &[u8], &[i32; 4]) -> Option<[f32; 4]>,
    prefetch: impl Fn(*const u8),
) {
    let WarpArgs {
        img,
        map,
        n,
        border,
        values,
        table,
    } = *args;
    let ValueMap { scale, offset } = values;
    let (w, h) = (img.width as i64, img.height as i64);
    let px = |x: i64, y: i64, c: usize| -> i32 {
        match border {
            Border::Replicate => {
                let (x, y) = (x.clamp(0, w - 1), y.clamp(0, h - 1));
                img.data[((y * w + x) * 3) as usize + c] as i32
            }
            Border::Zero => {
                if x < 0 || y < 0 || x >= w || y >= h {
                    0
                } else {
                    img.data[((y * w + x) * 3) as usize + c] as i32
                }
            }
        }
    };
    // 8-bit value -> tensor value.
    let lut: [f32; 256] = std::array::from_fn(|v| v as f32 * scale + offset);
    let row = (w * 3) as usize;
    // `origin + u du` per column, computed once: the per-pixel source position is
    // `(origin + u du) + v dv` in this order, so the sums (and the rounding) are unchanged.
    let column = |u: usize| {
        [
            map.origin[0] + u as f64 * map.du[0],
            map.origin[1] + u as f64 * map.du[1],
        ]
    };
    let mut cols = [[0.0f64; 2]; MAX_PRECOMPUTED_COLUMNS];
    let precomputed = n <= MAX_PRECOMPUTED_COLUMNS;
    if precomputed {
        for (u, c) in cols.iter_mut().take(n).enumerate() {
            *c = column(u);
        }
    }
    // OpenCV: X = saturate_cast<int>(x * INTER_TAB_SIZE), i.e. cvRound (see `fixed`).
    // Byte offset from a pixel's source to the source of the pixel PREFETCH_ROWS tensor rows
    // below it (the map is affine, so the same for every pixel up to rounding).
    let ahead_x = (PREFETCH_ROWS * map.dv[0]).round().clamp(-COORD_LIMIT, COORD_LIMIT) as isize;
    let ahead_y = (PREFETCH_ROWS * map.dv[1]).round().clamp(-COORD_LIMIT, COORD_LIMIT) as isize;
    let ahead = ahead_y.wrapping_mul(w as isize).wrapping_add(ahead_x).wrapping_mul(3);
    let mut fx = [0i64; MAX_PRECOMPUTED_COLUMNS];
    let mut fy = [0i64; MAX_PRECOMPUTED_COLUMNS];
    for (v, out_row) in out.chunks_exact_mut(3 * n).take(n).enumerate() {
        let (bx, by) = (v as f64 * map.dv[0], v as f64 * map.dv[1]);
        if precomputed {
            // the row's positions first: one loop of vector arithmetic
            for ((c, x), y) in cols[..n].iter().zip(&mut fx[..n]).zip(&mut fy[..n]) {
                *x = fixed(c[0] + bx);
                *y = fixed(c[1] + by);
            }
        }
        for (u, o) in out_row.chunks_exact_mut(3).enumerate() {
            let (xi, yi) = if precomputed {
                (fx[u], fy[u])
            } else {
                let [ax, ay] = column(u);
                (fixed(ax + bx), fixed(ay + by))
            };
            let (x0, y0) = (xi >> 5, yi >> 5);
            let wt = &table.w[((yi & 31) * 32 + (xi & 31)) as usize];
            let mix = |p00: i32, p01: i32, p10: i32, p11: i32| -> f32 {
                let s = p00 * wt[0] + p01 * wt[1] + p10 * wt[2] + p11 * wt[3];
                // cast_op: (s + (1 << 14)) >> 15, saturated to u8.
                lut[((s + (1 << 14)) >> 15).clamp(0, 255) as usize]
            };
            if x0 >= 0 && y0 >= 0 && x0 + 1 < w && y0 + 1 < h {
                // the four neighbours: one slice from (x0, y0) to (x0 + 1, y0 + 1)
                let i = ((y0 * w + x0) * 3) as usize;
                if u % PREFETCH_EVERY == 0 {
                    // The frame is usually cold here (decoded while other frames were
                    // tracked): ask for the lines a few rows ahead. A prefetch of an address
                    // outside the image is harmless (it is a hint; nothing is read).
                    let p = img.data.as_ptr().wrapping_add(i).wrapping_offset(ahead);
                    prefetch(p);
                    prefetch(p.wrapping_add(row));
                }
                if let Some(v) = fast(&img.data[i..], &img.data[(i + row).min(img.data.len())..], wt) {
                    o.copy_from_slice(&v[..3]);
                } else {
                    let p = &img.data[i..i + row + 6];
                    for c in 0..3 {
                        o[c] = mix(p[c] as i32, p[c + 3] as i32, p[row + c] as i32, p[row + c + 3] as i32);
                    }
                }
            } else if border == Border::Zero && (x0 + 1 < 0 || y0 + 1 < 0 || x0 >= w || y0 >= h) {
                o.fill(lut[0]);
            } else {
                for (c, dst) in o.iter_mut().enumerate() {
                    *dst = mix(
                        px(x0, y0, c),
                        px(x0 + 1, y0, c),
                        px(x0, y0 + 1, c),
                        px(x0 + 1, y0 + 1, c),
                    );
                }
            }
        }
    }
}

/// The interior pixels prefetch the source lines this many tensor rows ahead ...
const PREFETCH_ROWS: f64 = 3.0;

/// ... at every this many pixels (a 64-byte line holds ~21 source pixels).
const PREFETCH_EVERY: usize = 8;

/// Tensor widths up to this take their columns' source offsets from a stack table.
const MAX_PRECOMPUTED_COLUMNS: usize = 512;

/// Source coordinates (in 1/32 px) are clamped to this before rounding.
const COORD_LIMIT: f64 = (1u64 << 40) as f64;

/// 1.5 * 2^52: a float of that exponent has a unit last place, see [`rint`].
const MAGIC: f64 = 6_755_399_441_055_744.0;

/// A source coordinate in 1/32 px as OpenCV's `saturate_cast<int>(x * INTER_TAB_SIZE)`:
/// `rint(s * 32)` after clamping to [`COORD_LIMIT`]. `v + MAGIC` has the exponent of
/// 2^52 for |v| < 2^51, so its bits minus MAGIC's are the integer `rint(v)` (the same sum
/// as [`rint`], read without a float-to-integer conversion, so that a row of positions is
/// plain vector arithmetic).
#[inline(always)]
fn fixed(s: f64) -> i64 {
    let v = (s * TAB as f64).clamp(-COORD_LIMIT, COORD_LIMIT);
    ((v + MAGIC).to_bits() as i64).wrapping_sub(MAGIC.to_bits() as i64)
}

/// Round half to even (`cvRound` / `lrint` in the default rounding mode) without a libm
/// call: adding and subtracting 1.5 * 2^52 leaves the nearest integer for |v| < 2^51.
#[cfg(test)]
fn rint(v: f64) -> f64 {
    (v + MAGIC) - MAGIC
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The warp as a plain per-pixel loop: the position `origin + u du + v dv`, rounded to
    /// 1/32 px, and the fixed-point bilinear mix with the border rule.
    fn reference_warp(img: &RgbView<'_>, map: &Affine, n: usize, border: Border, values: ValueMap) -> Vec<f32> {
        let table = BilinearTable::new();
        let (w, h) = (img.width as i64, img.height as i64);
        let mut out = vec![0.0f32; n * n * 3];
        for v in 0..n {
            for u in 0..n {
                let sx = map.origin[0] + u as f64 * map.du[0] + v as f64 * map.dv[0];
                let sy = map.origin[1] + u as f64 * map.du[1] + v as f64 * map.dv[1];
                let xi = rint((sx * TAB as f64).clamp(-COORD_LIMIT, COORD_LIMIT)) as i64;
                let yi = rint((sy * TAB as f64).clamp(-COORD_LIMIT, COORD_LIMIT)) as i64;
                let (x0, y0) = (xi >> 5, yi >> 5);
                let wt = table.w[((yi & 31) * 32 + (xi & 31)) as usize];
                for c in 0..3 {
                    let px = |x: i64, y: i64| -> i32 {
                        let (x, y) = match border {
                            Border::Replicate => (x.clamp(0, w - 1), y.clamp(0, h - 1)),
                            Border::Zero if x < 0 || y < 0 || x >= w || y >= h => return 0,
                            Border::Zero => (x, y),
                        };
                        img.data[((y * w + x) * 3) as usize + c] as i32
                    };
                    let s = px(x0, y0) * wt[0]
                        + px(x0 + 1, y0) * wt[1]
                        + px(x0, y0 + 1) * wt[2]
                        + px(x0 + 1, y0 + 1) * wt[3];
                    let v8 = ((s + (1 << 14)) >> 15).clamp(0, 255);
                    out[(v * n + u) * 3 + c] = v8 as f32 * values.scale + values.offset;
                }
            }
        }
        out
    }

    /// The warp equals the plain loop bit for bit: rotated and scaled maps, inside, across
    /// and outside the image, both borders, tensor widths with and without the column table.
    #[test]
    fn warp_equals_the_per_pixel_formula() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // a face-sized image, and one too small for any 8-byte load of the vector mix
        for (w, h, trials) in [(97usize, 61usize, 40), (3, 2, 12)] {
            let data: Vec<u8> = (0..w * h * 3).map(|_| rng.random_range(0..=255u8)).collect();
            let img = RgbView {
                width: w,
                height: h,
                data: &data,
            };
            let table = BilinearTable::new();
            for trial in 0..trials {
                let n = [8, 33, 128, 600, 256, 192][trial % 6];
                let angle: f64 = rng.random_range(-3.2..3.2);
                let step: f64 = rng.random_range(0.05..1.7) * 64.0 / n as f64 * w as f64 / 97.0;
                let map = Affine {
                    origin: [
                        rng.random_range(-40.0..w as f64 + 33.0),
                        rng.random_range(-40.0..h as f64 + 39.0),
                    ],
                    du: [step * angle.cos(), step * angle.sin()],
                    dv: [-step * angle.sin(), step * angle.cos()],
                };
                for border in [Border::Zero, Border::Replicate] {
                    for values in [ValueMap::SIGNED, ValueMap::UNIT] {
                        let want = reference_warp(&img, &map, n, border, values);
                        let mut got = vec![f32::NAN; n * n * 3];
                        warp_to_tensor(&img, &map, n, border, values, &table, &mut got);
                        assert!(
                            want.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "{w}x{h}, trial {trial}, n {n}, {border:?}"
                        );
                    }
                }
            }
        }
    }

    /// `fixed` is `rint(s * 32)` as an integer: halves to even, negatives, the clamp.
    #[test]
    fn fixed_is_the_rounded_position_in_32nds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut values: Vec<f64> = (0..20_000).map(|_| rng.random_range(-5000.0..5000.0)).collect();
        values.extend((-200..200).map(|k| k as f64 / 64.0));
        values.extend([1e13, -1e13, 3.4e38, -3.4e38, 0.0, -0.0]);
        for s in values {
            let want = rint((s * TAB as f64).clamp(-COORD_LIMIT, COORD_LIMIT)) as i64;
            assert_eq!(fixed(s), want, "{s}");
        }
    }

    #[test]
    fn rint_rounds_half_to_even() {
        for (v, r) in [
            (0.5, 0.0),
            (1.5, 2.0),
            (2.5, 2.0),
            (-0.5, 0.0),
            (-1.5, -2.0),
            (3.2, 3.0),
            (-3.7, -4.0),
        ] {
            assert_eq!(rint(v), r, "{v}");
        }
        assert_eq!(rint(1e12 + 0.25), 1e12);
    }

    #[test]
    fn table_rows_sum_to_one() {
        let t = BilinearTable::new();
        for q in &t.w {
            assert_eq!(q.iter().sum::<i32>(), COEF_SCALE);
            assert!(q.iter().all(|&v| v >= 0));
        }
        assert_eq!(t.w[0], [COEF_SCALE, 0, 0, 0]);
    }

    #[test]
    fn identity_rect_copies_the_image() {
        // A 4x4 image, rect = the whole image, n = 4: tensor pixel u samples u.
        let data: Vec<u8> = (0..48).map(|i| (i * 5) as u8).collect();
        let img = RgbView::new(4, 4, &data).unwrap_or_else(|_| unreachable!());
        let rect = NormRect {
            x_center: 0.5,
            y_center: 0.5,
            width: 1.0,
            height: 1.0,
            rotation: 0.0,
        };
        let map = Affine::for_rect(&rect, 4, 4, 4);
        assert_eq!(map.origin, [0.0, 0.0]);
        let mut out = vec![0.0; 48];
        warp_to_tensor(
            &img,
            &map,
            4,
            Border::Replicate,
            ValueMap {
                scale: 1.0,
                offset: 0.0,
            },
            &BilinearTable::new(),
            &mut out,
        );
        let want: Vec<f32> = data.iter().map(|&v| v as f32).collect();
        assert_eq!(out, want);
    }

    #[test]
    fn rotation_of_a_quarter_turn_maps_columns_to_rows() {
        let rect = NormRect {
            x_center: 0.5,
            y_center: 0.5,
            width: 1.0,
            height: 1.0,
            rotation: std::f32::consts::FRAC_PI_2,
        };
        let m = Affine::for_rect(&rect, 10, 10, 10);
        // Clockwise quarter turn: tensor +u points down the image.
        assert!((m.du[0]).abs() < 1e-6 && (m.du[1] - 1.0).abs() < 1e-6);
        assert!((m.dv[0] + 1.0).abs() < 1e-6 && m.dv[1].abs() < 1e-6);
        assert!((rotation_from([0.0, 0.0], [1.0, 1.0]) - std::f32::consts::FRAC_PI_4).abs() < 1e-6);
        assert!((normalize_radians(3.5 * std::f32::consts::PI) + 0.5 * std::f32::consts::PI).abs() < 1e-5);
    }
}
