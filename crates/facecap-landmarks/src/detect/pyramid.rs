//! dlib's image pyramids for the HOG detector, reproduced to the bit.
//!
//! * `pyramid_down<6>`: each level is `floor(5 * rows / 6) x floor(5 * cols / 6)`
//!   pixels, made by dlib's bilinear `resize_image` (the 8-bit greyscale SIMD path:
//!   float weights, `(u8)(value + 0.5)` rounding, 4-column blocks, scalar tail with
//!   truncation). A point `p` of a level maps to `p' = (p - 0.3) * 5/6` on the next.
//! * `pyramid_down<2>` up-sampling (used by `detector(img, upsample)`): the output is
//!   `rect_up(get_rect(img))` sized, i.e. `(2 * rows + 1) x (2 * cols + 2)`, filled by
//!   the same resize; rectangles map back with `p' = p / 2 - (1.25, 0.75)`.
//!
//! Pixel convention: pixel `(x, y)` has its centre at `(x, y)` (0-based), as in dlib.

/// A greyscale image owned by the detector workspace (row-major, `width * height`).
#[derive(Debug, Clone, Default)]
pub struct Gray {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels, row-major.
    pub data: Vec<u8>,
}

impl Gray {
    /// Resizes the buffer (keeps the allocation when large enough).
    pub fn set_size(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.resize(width * height, 0);
    }
}

/// A borrowed greyscale view.
#[derive(Debug, Clone, Copy)]
pub struct GrayView<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels, row-major, `width * height` long.
    pub data: &'a [u8],
}

impl Gray {
    /// Borrow as a view.
    pub fn view(&self) -> GrayView<'_> {
        GrayView {
            width: self.width,
            height: self.height,
            data: &self.data,
        }
    }
}

/// dlib's `drectangle -> rectangle` rounding: `floor(v + 0.5)`.
pub(crate) fn round_half_up(v: f64) -> i64 {
    (v + 0.5).floor() as i64
}

/// An inclusive integer rectangle as dlib's `rectangle` (`l, t, r, b`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DRect {
    /// Left column (inclusive).
    pub l: i64,
    /// Top row (inclusive).
    pub t: i64,
    /// Right column (inclusive).
    pub r: i64,
    /// Bottom row (inclusive).
    pub b: i64,
}

impl DRect {
    /// Width `r - l + 1` (0 when empty).
    pub fn width(&self) -> i64 {
        if self.r < self.l {
            0
        } else {
            self.r - self.l + 1
        }
    }
    /// Height `b - t + 1` (0 when empty).
    pub fn height(&self) -> i64 {
        if self.b < self.t {
            0
        } else {
            self.b - self.t + 1
        }
    }
    /// Area in pixels (0 when empty).
    pub fn area(&self) -> i64 {
        self.width() * self.height()
    }
    /// Intersection (may be empty).
    pub fn intersect(&self, o: &DRect) -> DRect {
        DRect {
            l: self.l.max(o.l),
            t: self.t.max(o.t),
            r: self.r.min(o.r),
            b: self.b.min(o.b),
        }
    }
    /// Smallest rectangle containing both (dlib's `a + b`).
    pub fn union_box(&self, o: &DRect) -> DRect {
        DRect {
            l: self.l.min(o.l),
            t: self.t.min(o.t),
            r: self.r.max(o.r),
            b: self.b.max(o.b),
        }
    }
}

/// `pyramid_down<6>::rect_up(rect, levels)`, rounded back to integers.
pub(crate) fn rect_up6(rect: DRect, levels: usize) -> DRect {
    let up = |mut v: f64| {
        for _ in 0..levels {
            v = v * (6.0 / 5.0) + 0.3;
        }
        v
    };
    DRect {
        l: round_half_up(up(rect.l as f64)),
        t: round_half_up(up(rect.t as f64)),
        r: round_half_up(up(rect.r as f64)),
        b: round_half_up(up(rect.b as f64)),
    }
}

/// `pyramid_down<6>::rect_down(rect)` (one level), rounded.
pub(crate) fn rect_down6(rect: DRect) -> DRect {
    let down = |v: f64| (v - 0.3) * (5.0 / 6.0);
    DRect {
        l: round_half_up(down(rect.l as f64)),
        t: round_half_up(down(rect.t as f64)),
        r: round_half_up(down(rect.r as f64)),
        b: round_half_up(down(rect.b as f64)),
    }
}

/// `pyramid_down<2>::rect_down(rect, levels)`, rounded: maps boxes found on an
/// up-sampled image back to the input image.
pub(crate) fn rect_down2(rect: DRect, levels: u32) -> DRect {
    let down = |mut x: f64, off: f64| {
        for _ in 0..levels {
            x = x / 2.0 - off;
        }
        x
    };
    DRect {
        l: round_half_up(down(rect.l as f64, 1.25)),
        t: round_half_up(down(rect.t as f64, 0.75)),
        r: round_half_up(down(rect.r as f64, 1.25)),
        b: round_half_up(down(rect.b as f64, 0.75)),
    }
}

/// Size `(width, height)` of the `pyramid_down<6>` level below an image of this size.
pub(crate) fn down6_size(width: usize, height: usize) -> (usize, usize) {
    ((5 * width) / 6, (5 * height) / 6)
}

/// Size of `pyramid_up` (via `pyramid_down<2>`) of an image of this size:
/// `rect_up((0, 0, w - 1, h - 1))` rounded, plus one.
pub(crate) fn up2_size(width: usize, height: usize) -> (usize, usize) {
    if width == 0 || height == 0 {
        return (0, 0);
    }
    let r = round_half_up(((width as f64 - 1.0) + 1.25) * 2.0);
    let b = round_half_up(((height as f64 - 1.0) + 0.75) * 2.0);
    ((r + 1).max(0) as usize, (b + 1).max(0) as usize)
}

/// Per-column tables of [`resize_bilinear_with`] (kept between calls so that no
/// allocation happens after the first frame of a given size).
#[derive(Debug, Clone, Default)]
pub struct ResizeScratch {
    /// Left source column of every output column of dlib's SIMD part.
    left: Vec<u32>,
    /// Horizontal fraction of every such column, and `1 - frac`.
    frac: Vec<f32>,
    inv: Vec<f32>,
    /// Per block of 8 output columns: first source byte and the byte shuffle that
    /// picks the 8 left (low half) and 8 right (high half) neighbours from the 16
    /// source bytes starting there, or `None` when they do not fit.
    blocks: Vec<Option<(u32, [u8; 16])>>,
}

/// dlib's bilinear `resize_image` for 8-bit greyscale images (same input and output
/// pixel type), bit-exact: see the module docs. `out` must already have its size.
/// 8 output pixels at a time on AVX2 (the same float operations in the same order,
/// so bit-identical), else scalar code; `scratch` keeps the column tables.
pub(crate) fn resize_bilinear_with(input: GrayView<'_>, out: &mut Gray, scratch: &mut ResizeScratch) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        if input.width > 0 && input.height > 0 && out.width > 0 && out.height > 0 {
            pulp::Simd::vectorize(
                v3,
                ResizeV3 {
                    v3,
                    input,
                    out,
                    scratch,
                },
            );
            return;
        }
    }
    let _ = scratch;
    resize_bilinear_scalar(input, out);
}

/// dlib's resize as scalar code, one output pixel at a time (the reference of the
/// vector version).
pub(crate) fn resize_bilinear_scalar(input: GrayView<'_>, out: &mut Gray) {
    let (in_w, in_h) = (input.width, input.height);
    let (out_w, out_h) = (out.width, out.height);
    if out_w == 0 || out_h == 0 || in_w == 0 || in_h == 0 {
        return;
    }
    let x_scale = (in_w as f64 - 1.0) / (out_w.saturating_sub(1).max(1) as f64);
    let y_scale = (in_h as f64 - 1.0) / (out_h.saturating_sub(1).max(1) as f64);
    let src = input.data;
    let mut y = -y_scale;
    for r in 0..out_h {
        y += y_scale;
        let top = y.floor() as usize;
        let bottom = (top + 1).min(in_h - 1);
        let tb_frac = y - top as f64;
        let row_t = &src[top * in_w..(top + 1) * in_w];
        let row_b = &src[bottom * in_w..(bottom + 1) * in_w];
        let orow = &mut out.data[r * out_w..(r + 1) * out_w];

        // SIMD part: 4 columns at a time, float arithmetic.
        let x0 = -4.0 * x_scale;
        let tbf = tb_frac as f32;
        let inv_tbf = (1.0 - tb_frac) as f32;
        let step = (4.0 * x_scale) as f32;
        let mut lanes = [
            x0 as f32,
            (x0 + x_scale) as f32,
            (x0 + 2.0 * x_scale) as f32,
            (x0 + 3.0 * x_scale) as f32,
        ];
        let mut c = 0usize;
        loop {
            let mut left = [0usize; 4];
            let mut frac = [0f32; 4];
            for k in 0..4 {
                lanes[k] += step;
                // _mm_cvttps_epi32: truncation (values are >= 0 here)
                let li = lanes[k] as i32;
                left[k] = li.max(0) as usize;
                frac[k] = lanes[k] - li as f32;
            }
            if left[3] + 1 >= in_w || c + 4 > out_w {
                // dlib breaks when the right neighbour of lane 3 leaves the image; the
                // second test only guards our slice indexing (dlib's images always
                // satisfy it before the first one fires for these scales).
                break;
            }
            for k in 0..4 {
                let inv = 1.0 - frac[k];
                let tlf = inv_tbf * inv;
                let trf = inv_tbf * frac[k];
                let blf = tbf * inv;
                let brf = tbf * frac[k];
                let tl = f32::from(row_t[left[k]]);
                let tr = f32::from(row_t[left[k] + 1]);
                let bl = f32::from(row_b[left[k]]);
                let br = f32::from(row_b[left[k] + 1]);
                let v = tlf * tl + trf * tr + blf * bl + brf * br;
                orow[c + k] = (f64::from(v) + 0.5) as u8;
            }
            c += 4;
        }
        scalar_tail(row_t, row_b, in_w, x_scale, tb_frac, c, orow);
    }
}

/// Output pixels per vector block of [`ResizeV3`].
#[cfg(target_arch = "x86_64")]
const V3_LANES: usize = 8;

/// The AVX2 resize: per image, dlib's SIMD-part column positions (they do not depend
/// on the row) and byte shuffles gathering each block's neighbours; per row, the
/// weights and the blend 8 columns at a time with separate multiplies and adds in
/// dlib's order, and `(u8)(v + 0.5)` computed exactly in f32 (`trunc(v)` plus one
/// when `v - trunc(v) >= 0.5`, clamped to 0..=255); dlib's scalar tail as scalar code.
#[cfg(target_arch = "x86_64")]
struct ResizeV3<'a, 'b> {
    v3: pulp::x86::V3,
    input: GrayView<'a>,
    out: &'b mut Gray,
    scratch: &'b mut ResizeScratch,
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for ResizeV3<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        use pulp::Simd as _;
        let ResizeV3 {
            v3,
            input,
            out,
            scratch,
        } = self;
        let (in_w, in_h) = (input.width, input.height);
        let (out_w, out_h) = (out.width, out.height);
        let x_scale = (in_w as f64 - 1.0) / (out_w.saturating_sub(1).max(1) as f64);
        let y_scale = (in_h as f64 - 1.0) / (out_h.saturating_sub(1).max(1) as f64);

        // dlib's SIMD columns: the lane positions of `resize_bilinear_scalar`
        scratch.left.clear();
        scratch.frac.clear();
        scratch.inv.clear();
        let x0 = -4.0 * x_scale;
        let step = (4.0 * x_scale) as f32;
        let mut lanes = [
            x0 as f32,
            (x0 + x_scale) as f32,
            (x0 + 2.0 * x_scale) as f32,
            (x0 + 3.0 * x_scale) as f32,
        ];
        let mut c_end = 0usize;
        loop {
            let mut left = [0usize; 4];
            let mut frac = [0f32; 4];
            for k in 0..4 {
                lanes[k] += step;
                let li = lanes[k] as i32;
                left[k] = li.max(0) as usize;
                frac[k] = lanes[k] - li as f32;
            }
            if left[3] + 1 >= in_w || c_end + 4 > out_w {
                break;
            }
            for k in 0..4 {
                scratch.left.push(left[k] as u32);
                scratch.frac.push(frac[k]);
                scratch.inv.push(1.0 - frac[k]);
            }
            c_end += 4;
        }
        let n_blocks = c_end / V3_LANES;
        scratch.blocks.clear();
        for b in 0..n_blocks {
            let l = &scratch.left[b * V3_LANES..(b + 1) * V3_LANES];
            let base = l[0] as usize;
            let fits = l.iter().all(|&v| (v as usize) >= base && v as usize + 1 - base < 16) && base + 16 <= in_w;
            scratch.blocks.push(fits.then(|| {
                let mut mask = [0u8; 16];
                for k in 0..V3_LANES {
                    mask[k] = (l[k] as usize - base) as u8;
                    mask[V3_LANES + k] = (l[k] as usize + 1 - base) as u8;
                }
                (base as u32, mask)
            }));
        }

        let src = input.data;
        let half = v3.splat_f32x8(0.5);
        let one = v3.splat_f32x8(1.0);
        let zero = v3.splat_f32x8(0.0);
        let top_val = v3.splat_f32x8(255.0);
        let mut y = -y_scale;
        for r in 0..out_h {
            y += y_scale;
            let top = y.floor() as usize;
            let bottom = (top + 1).min(in_h - 1);
            let tb_frac = y - top as f64;
            let row_t = &src[top * in_w..(top + 1) * in_w];
            let row_b = &src[bottom * in_w..(bottom + 1) * in_w];
            let orow = &mut out.data[r * out_w..(r + 1) * out_w];
            let tbf = tb_frac as f32;
            let inv_tbf = (1.0 - tb_frac) as f32;
            let (stbf, sinv_tbf) = (v3.splat_f32x8(tbf), v3.splat_f32x8(inv_tbf));
            for b in 0..n_blocks {
                let c = b * V3_LANES;
                let fr: pulp::f32x8 =
                    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&scratch.frac[c..c + V3_LANES]));
                let inv: pulp::f32x8 =
                    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&scratch.inv[c..c + V3_LANES]));
                let tlf = v3.mul_f32s(sinv_tbf, inv);
                let trf = v3.mul_f32s(sinv_tbf, fr);
                let blf = v3.mul_f32s(stbf, inv);
                let brf = v3.mul_f32s(stbf, fr);
                let (tl, tr) = gather(v3, row_t, scratch.blocks[b], &scratch.left[c..c + V3_LANES]);
                let (bl, br) = gather(v3, row_b, scratch.blocks[b], &scratch.left[c..c + V3_LANES]);
                let v = v3.add_f32s(v3.mul_f32s(tlf, tl), v3.mul_f32s(trf, tr));
                let v = v3.add_f32s(v, v3.mul_f32s(blf, bl));
                let v = v3.add_f32s(v, v3.mul_f32s(brf, br));
                // (u8)(v + 0.5) exactly: trunc(v) + [v - trunc(v) >= 0.5], clamped
                let t = v3.truncate_f32x8(v);
                let up = v3.cmp_ge_f32x8(v3.sub_f32s(v, t), half);
                let rounded = v3.add_f32s(t, v3.select_f32x8(up, one, zero));
                let rounded = v3.min_f32s(v3.max_f32s(rounded, zero), top_val);
                // 0..=255 integers: two unsigned-saturating packs give the 8 bytes
                let [lo, hi]: [core::arch::x86_64::__m128i; 2] = pulp::cast(v3.convert_f32x8_to_i32x8(rounded));
                let words = v3.sse4_1._mm_packus_epi32(lo, hi);
                let bytes: [u8; 16] = pulp::cast(v3.sse2._mm_packus_epi16(words, words));
                orow[c..c + V3_LANES].copy_from_slice(&bytes[..V3_LANES]);
            }
            // SIMD-part columns past the last whole block of 8
            for c in n_blocks * V3_LANES..c_end {
                let (l, frac) = (scratch.left[c] as usize, scratch.frac[c]);
                let inv = scratch.inv[c];
                let tlf = inv_tbf * inv;
                let trf = inv_tbf * frac;
                let blf = tbf * inv;
                let brf = tbf * frac;
                let tl = f32::from(row_t[l]);
                let tr = f32::from(row_t[l + 1]);
                let bl = f32::from(row_b[l]);
                let br = f32::from(row_b[l + 1]);
                let v = tlf * tl + trf * tr + blf * bl + brf * br;
                orow[c] = (f64::from(v) + 0.5) as u8;
            }
            scalar_tail(row_t, row_b, in_w, x_scale, tb_frac, c_end, orow);
        }
    }
}

/// The 8 left and 8 right neighbours of a block of output columns (`left`: their left
/// source columns; `block`: the byte shuffle when it applies), as two vectors.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn gather(v3: pulp::x86::V3, row: &[u8], block: Option<(u32, [u8; 16])>, left: &[u32]) -> (pulp::f32x8, pulp::f32x8) {
    let pair: pulp::u8x16 = match block {
        Some((base, mask)) => {
            let base = base as usize;
            let bytes: [u8; 16] = row[base..base + 16].try_into().unwrap_or([0; 16]);
            pulp::cast(v3.ssse3._mm_shuffle_epi8(pulp::cast(bytes), pulp::cast(mask)))
        }
        None => {
            let mut bytes = [0u8; 16];
            for k in 0..V3_LANES {
                let l = left[k] as usize;
                bytes[k] = row[l];
                bytes[V3_LANES + k] = row[l + 1];
            }
            pulp::cast(bytes)
        }
    };
    let hi: pulp::u8x16 = pulp::cast(v3.sse2._mm_srli_si128::<8>(pulp::cast(pair)));
    (
        v3.convert_i32x8_to_f32x8(v3.convert_u8x16_to_i32x8(pair)),
        v3.convert_i32x8_to_f32x8(v3.convert_u8x16_to_i32x8(hi)),
    )
}

/// dlib's scalar tail of a resized row from column `c` on (double positions, float
/// blend, truncation to u8 with clamping).
#[inline(always)]
fn scalar_tail(row_t: &[u8], row_b: &[u8], in_w: usize, x_scale: f64, tb_frac: f64, mut c: usize, orow: &mut [u8]) {
    let out_w = orow.len();
    let mut x = -x_scale + c as f64 * x_scale;
    while c < out_w {
        x += x_scale;
        let left = x.floor().max(0.0) as usize;
        let left = left.min(in_w - 1);
        let right = (left + 1).min(in_w - 1);
        let lr = (x - left as f64) as f32;
        let tl = f32::from(row_t[left]);
        let tr = f32::from(row_t[right]);
        let bl = f32::from(row_b[left]);
        let br = f32::from(row_b[right]);
        let a = (1.0 - lr) * tl + lr * tr;
        let b = (1.0 - lr) * bl + lr * br;
        let temp = ((1.0 - tb_frac) * f64::from(a) + tb_frac * f64::from(b)) as f32;
        orow[c] = temp.clamp(0.0, 255.0) as u8;
        c += 1;
    }
}

/// One `pyramid_down<6>` step (public for tests against dlib's `pyramid_down(6)`).
pub fn down6(input: GrayView<'_>, out: &mut Gray) {
    down6_with(input, out, &mut ResizeScratch::default());
}

/// [`down6`] with reusable tables.
pub(crate) fn down6_with(input: GrayView<'_>, out: &mut Gray, scratch: &mut ResizeScratch) {
    let (w, h) = down6_size(input.width, input.height);
    out.set_size(w, h);
    resize_bilinear_with(input, out, scratch);
}

/// One `pyramid_up` step (via `pyramid_down<2>`).
pub fn up2(input: GrayView<'_>, out: &mut Gray) {
    up2_with(input, out, &mut ResizeScratch::default());
}

/// [`up2`] with reusable tables.
pub(crate) fn up2_with(input: GrayView<'_>, out: &mut Gray, scratch: &mut ResizeScratch) {
    let (w, h) = up2_size(input.width, input.height);
    out.set_size(w, h);
    resize_bilinear_with(input, out, scratch);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_follow_dlib() {
        assert_eq!(down6_size(640, 480), (533, 400));
        assert_eq!(up2_size(10, 8), (22, 17));
    }

    #[test]
    fn vector_resize_equals_scalar_resize_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut scratch = ResizeScratch::default();
        for &(w, h) in &[
            (640usize, 480usize),
            (533, 400),
            (97, 71),
            (37, 23),
            (9, 9),
            (2, 5),
            (1280, 720),
        ] {
            // random pixels, and a smooth ramp with saturated areas
            for smooth in [false, true] {
                let data: Vec<u8> = (0..w * h)
                    .map(|i| {
                        if smooth {
                            ((i % w) * 3 + (i / w) * 2).min(255) as u8
                        } else {
                            rng.random::<u8>()
                        }
                    })
                    .collect();
                let input = Gray {
                    width: w,
                    height: h,
                    data,
                };
                let sizes = [down6_size(w, h), up2_size(w, h), (w / 3 + 1, h / 2 + 1), (w * 2 / 3, h)];
                for (ow, oh) in sizes {
                    let mut a = Gray::default();
                    let mut b = Gray::default();
                    a.set_size(ow, oh);
                    b.set_size(ow, oh);
                    resize_bilinear_with(input.view(), &mut a, &mut scratch);
                    resize_bilinear_scalar(input.view(), &mut b);
                    assert_eq!(a.data, b.data, "{w}x{h} -> {ow}x{oh}");
                }
            }
        }
    }

    #[test]
    fn constant_image_stays_constant() {
        let input = Gray {
            width: 37,
            height: 23,
            data: vec![77; 37 * 23],
        };
        let mut out = Gray::default();
        down6(input.view(), &mut out);
        assert!(out.data.iter().all(|&v| v == 77));
        up2(input.view(), &mut out);
        assert!(out.data.iter().all(|&v| v == 77));
    }
}
