//! Felzenszwalb HOG ("fHOG") features exactly as dlib's `extract_fhog_features`
//! (`dlib/image_transforms/fhog.h`), for 8-bit greyscale images.
//!
//! Felzenszwalb, Girshick, McAllester, Ramanan, "Object Detection with
//! Discriminatively Trained Part Based Models", IEEE TPAMI 32(9), 2010.
//!
//! For every pixel `(x, y)` with `1 <= x < visible_w`, `1 <= y < visible_h`
//! (`visible_* = min(cells * cell_size, size) - 1`):
//!
//! * gradient `g = (I[y][x+1] - I[y][x-1], I[y+1][x] - I[y-1][x])` (integers),
//!   magnitude `v = sqrt(|g|^2)` (f32);
//! * orientation bin `o` in `0..18`: the argmax over the 9 unit directions
//!   `u_k` (dlib's 4-decimal table) of `max(u_k . g, -(u_k . g))`, `o = k` for the
//!   positive and `k + 9` for the negative side, first strict maximum wins, `o = 0`
//!   when `g = 0`;
//! * `v` is split bilinearly into the 4 cells around the pixel: with
//!   `xp = (x + 0.5) / cell - 0.5`, `ix = floor(xp)`, `vx0 = xp - ix`, `vx1 = 1 - vx0`
//!   (same for y), cell `(ix, iy)` gets `vx1 vy1 v`, `(ix + 1, iy)` gets `vx0 vy1 v`,
//!   etc. (18-bin histogram per cell).
//!
//! Per cell, energy `N = sum_{k<9} (h_k + h_{k+9})^2`. For each output cell the 4
//! 2x2-cell blocks containing it give `nn_j = 0.2 sqrt(sum of 4 energies + 1e-4)`,
//! `n_j = 0.1 / nn_j`. Features (31 per cell):
//!
//! * `0..18`: `sum_j min(h_o, nn_j) n_j` (contrast sensitive, clipped at 0.2 after
//!   normalisation and scaled by 1/2);
//! * `18..27`: the same with `h_o + h_{o+9}` (contrast insensitive);
//! * `27..31`: `0.4714 sum_o min(h_o, nn_j) n_j` for block `j` (texture).
//!
//! The output of an image with `cells_h x cells_w` cells
//! (`cells = (int)(size / cell + 0.5)`) has `(cells_h - 2) x (cells_w - 2)` feature
//! cells, placed at offset `((fh - 1) / 2, (fw - 1) / 2)` inside planes of
//! `(cells_h - 2 + fh - 1) x (cells_w - 2 + fw - 1)` whose border is zero, where
//! `fh x fw` is the filter size (the detector's fHOG window). Cell `(0, 0)` of the
//! features is centred at pixel `cell + 1 + cell/2 - 0.5`... see
//! [`super::scan::fhog_to_image`] for the exact mapping dlib uses.
//!
//! Bit-exactness: dlib evaluates pixels in 8-wide SIMD blocks and a scalar tail
//! which associate the bilinear weights differently (`vy * (vx * v)` versus
//! `(vy * vx) * v`), sums 4 block lanes as `(a0 + a1) + (a2 + a3)` (`_mm_dp_ps`), and
//! accumulates histograms in raster order. We reproduce all of that, so our features
//! equal dlib's to the bit (IEEE f32, no fused multiply-add).

/// Number of fHOG planes.
pub const PLANES: usize = 31;

/// dlib's orientation table (unit vectors at 20 degree steps, 4 decimals).
const DIRECTIONS: [[f32; 2]; 9] = [
    [1.0000, 0.0000],
    [0.9397, 0.3420],
    [0.7660, 0.6428],
    [0.500, 0.8660],
    [0.1736, 0.9848],
    [-0.1736, 0.9848],
    [-0.5000, 0.8660],
    [-0.7660, 0.6428],
    [-0.9397, 0.3420],
];

/// Normalisation floor added to the block energies.
const EPS: f32 = 0.0001;
/// Truncation level of the normalised histograms (Felzenszwalb's 0.2).
const TRUNC: f32 = 0.2;
/// Scale of the normalised features (dlib's 0.1 = 0.5 * 0.2).
const NORM_SCALE: f32 = 0.1;
/// Texture feature scale `2 * 0.2357`.
const TEXTURE_SCALE: f32 = (2.0 * 0.2357) as f32;

/// The orientation bin of gradient `(gx, gy)`, dlib's procedure.
pub(crate) fn orientation_bin(gx: f32, gy: f32) -> u8 {
    let mut best_dot = 0f32;
    let mut best_o = 0u8;
    for (o, d) in DIRECTIONS.iter().enumerate() {
        let dot = d[0] * gx + d[1] * gy;
        if dot > best_dot {
            best_dot = dot;
            best_o = o as u8;
        } else if -dot > best_dot {
            best_dot = -dot;
            best_o = o as u8 + 9;
        }
    }
    best_o
}

/// Orientation bins for every 8-bit gradient, indexed `(gy + 255) * 511 + gx + 255`.
#[derive(Debug, Clone)]
pub struct BinTable {
    bins: Vec<u8>,
}

impl Default for BinTable {
    fn default() -> Self {
        Self::new()
    }
}

impl BinTable {
    const SIDE: usize = 511;

    /// Builds the 511 x 511 table (261 KB) with [`orientation_bin`].
    pub fn new() -> Self {
        let mut bins = vec![0u8; Self::SIDE * Self::SIDE];
        for gy in -255i32..=255 {
            for gx in -255i32..=255 {
                bins[((gy + 255) as usize) * Self::SIDE + (gx + 255) as usize] = orientation_bin(gx as f32, gy as f32);
            }
        }
        BinTable { bins }
    }

    #[inline(always)]
    fn get(&self, gx: i32, gy: i32) -> u8 {
        let i = ((gy + 255) as usize) * Self::SIDE + (gx + 255) as usize;
        self.bins.get(i).copied().unwrap_or(0)
    }
}

/// The 31-plane feature image of one pyramid level, padded for a `fh x fw` filter.
#[derive(Debug, Clone, Default)]
pub struct FhogImage {
    /// Plane width (`hog_w + fw - 1`, or 0 when the image is too small).
    pub width: usize,
    /// Plane height (`hog_h + fh - 1`, or 0).
    pub height: usize,
    /// `31 * height * width` values, plane-major then row-major.
    pub data: Vec<f32>,
}

impl FhogImage {
    /// One plane (`height * width` values).
    pub fn plane(&self, i: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[i * n..(i + 1) * n]
    }
}

/// Scratch memory of the feature extractor (histograms, energies, per-column weights).
#[derive(Debug, Clone, Default)]
pub struct FhogScratch {
    hist: Vec<f32>,
    norm: Vec<f32>,
    col_ix: Vec<usize>,
    col_w0: Vec<f32>,
    col_w1: Vec<f32>,
    /// Per row of pixels: orientation-table index of every pixel's gradient.
    row_idx: Vec<u32>,
    /// Per row of pixels: the four bilinear votes of every pixel (`v11, v01, v10, v00`).
    row_votes: Vec<[f32; 4]>,
}

/// Geometry of the fHOG computation for an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FhogGeometry {
    pub cells_w: usize,
    pub cells_h: usize,
    pub hog_w: usize,
    pub hog_h: usize,
    pub visible_w: usize,
    pub visible_h: usize,
}

pub(crate) fn geometry(width: usize, height: usize, cell: usize) -> FhogGeometry {
    let cells_h = ((height as f32) / (cell as f32) + 0.5) as usize;
    let cells_w = ((width as f32) / (cell as f32) + 0.5) as usize;
    let hog_h = cells_h.saturating_sub(2);
    let hog_w = cells_w.saturating_sub(2);
    let visible_h = (cells_h * cell).min(height) as i64 - 1;
    let visible_w = (cells_w * cell).min(width) as i64 - 1;
    FhogGeometry {
        cells_w,
        cells_h,
        hog_w,
        hog_h,
        visible_w: visible_w.max(0) as usize,
        visible_h: visible_h.max(0) as usize,
    }
}

/// Computes the padded fHOG image of `img` (`width x height`, row-major) into `out`.
/// `fw x fh` is the filter (fHOG window) size the padding is made for.
#[allow(clippy::too_many_arguments)] // image + geometry + reusable buffers, all needed
pub(crate) fn extract(
    img: &[u8],
    width: usize,
    height: usize,
    cell: usize,
    fw: usize,
    fh: usize,
    table: &BinTable,
    scratch: &mut FhogScratch,
    out: &mut FhogImage,
) {
    let g = geometry(width, height, cell);
    if g.cells_w == 0 || g.cells_h == 0 || g.hog_w == 0 || g.hog_h == 0 {
        out.width = 0;
        out.height = 0;
        out.data.clear();
        return;
    }
    let hist_w = g.cells_w + 2;
    let hist_h = g.cells_h + 2;
    scratch.hist.clear();
    scratch.hist.resize(hist_w * hist_h * 18, 0.0);

    // Per-column bilinear weights and association mode.
    scratch.col_ix.clear();
    scratch.col_w0.clear();
    scratch.col_w1.clear();
    let cs = cell as f32;
    for x in 0..g.visible_w.max(1) {
        let xp = ((x as f64 + 0.5) / cell as f64 - 0.5) as f32;
        let ix = xp.floor();
        let w0 = xp - ix;
        let w1 = (1.0 - f64::from(w0)) as f32;
        // histogram column of the left cell, already shifted by the +1 border
        scratch.col_ix.push((ix as i64 + 1) as usize);
        scratch.col_w0.push(w0);
        scratch.col_w1.push(w1);
    }
    let _ = cs;
    // dlib's SIMD blocks cover x = 1, 9, 17, ... while x < visible_w - 7.
    let simd_end = {
        let mut x = 1i64;
        while x < g.visible_w as i64 - 7 {
            x += 8;
        }
        x.max(1) as usize
    };

    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        if g.visible_w > V3_LANES {
            pulp::Simd::vectorize(
                v3,
                HistV3 {
                    v3,
                    img,
                    width,
                    cell,
                    g,
                    simd_end,
                    table,
                    scratch,
                },
            );
            finish(g, fw, fh, scratch, out, true);
            return;
        }
    }

    let hist = &mut scratch.hist;
    for y in 1..g.visible_h {
        let (vy0, vy1, hy) = row_weights(y, cell);
        let row0 = &mut hist[hy * hist_w * 18..(hy + 2) * hist_w * 18];
        let (r_top, r_bot) = row0.split_at_mut(hist_w * 18);
        let up = &img[(y - 1) * width..y * width];
        let mid = &img[y * width..(y + 1) * width];
        let dn = &img[(y + 1) * width..(y + 2) * width];
        for x in 1..g.visible_w {
            let gx = i32::from(mid[x + 1]) - i32::from(mid[x - 1]);
            let gy = i32::from(dn[x]) - i32::from(up[x]);
            let v = ((gx * gx + gy * gy) as f32).sqrt();
            let o = usize::from(table.get(gx, gy));
            let hx = scratch.col_ix[x];
            let vx0 = scratch.col_w0[x];
            let vx1 = scratch.col_w1[x];
            let (v11, v01, v10, v00) = if x < simd_end {
                let a1 = vx1 * v;
                let a0 = vx0 * v;
                (vy1 * a1, vy0 * a1, vy1 * a0, vy0 * a0)
            } else {
                (vy1 * vx1 * v, vy0 * vx1 * v, vy1 * vx0 * v, vy0 * vx0 * v)
            };
            r_top[hx * 18 + o] += v11;
            r_bot[hx * 18 + o] += v01;
            r_top[(hx + 1) * 18 + o] += v10;
            r_bot[(hx + 1) * 18 + o] += v00;
        }
    }

    finish(g, fw, fh, scratch, out, true);
}

/// Vertical bilinear weights `(vy0, vy1)` of pixel row `y` and the histogram row of
/// its upper cell (shifted by the +1 border).
#[inline(always)]
fn row_weights(y: usize, cell: usize) -> (f32, f32, usize) {
    let yp = ((y as f32 as f64 + 0.5) / (cell as f32 as f64) - 0.5) as f32;
    let iy = yp.floor();
    let vy0 = yp - iy;
    let vy1 = (1.0 - f64::from(vy0)) as f32;
    (vy0, vy1, (iy as i64 + 1) as usize)
}

/// f32 lanes of an AVX register.
#[cfg(target_arch = "x86_64")]
const V3_LANES: usize = 8;

/// The histogram pass on AVX2, bit-identical to the scalar loop of [`extract`]: per
/// row of pixels, gradients, magnitudes, orientation-table indices and the four
/// bilinear votes 8 pixels at a time in dlib's 8-pixel blocks (the same float
/// operations in the same order, no fused multiply-add), dlib's scalar tail as
/// scalar code, then the votes added into the histograms pixel by pixel in raster
/// order (so every histogram bin sums the same values in the same order).
#[cfg(target_arch = "x86_64")]
struct HistV3<'a> {
    v3: pulp::x86::V3,
    img: &'a [u8],
    width: usize,
    cell: usize,
    g: FhogGeometry,
    simd_end: usize,
    table: &'a BinTable,
    scratch: &'a mut FhogScratch,
}

/// Eight bytes from `s[at..]` widened to `i32` lanes.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn ld8_u8(v3: pulp::x86::V3, s: &[u8], at: usize) -> pulp::i32x8 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&s[at..at + V3_LANES]);
    let q: pulp::u8x16 = bytemuck::cast([u64::from_le_bytes(b), 0]);
    v3.convert_u8x16_to_i32x8(q)
}

/// Eight floats from `s[at..]` as one vector.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn ld8_f32(s: &[f32], at: usize) -> pulp::f32x8 {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&s[at..at + V3_LANES]))
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for HistV3<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        use pulp::Simd as _;
        let HistV3 {
            v3,
            img,
            width,
            cell,
            g,
            simd_end,
            table,
            scratch,
        } = self;
        let hist_w = g.cells_w + 2;
        let vis_w = g.visible_w;
        scratch.row_idx.clear();
        scratch.row_idx.resize(2 * vis_w, 0);
        scratch.row_votes.clear();
        scratch.row_votes.resize(2 * vis_w, [0.0; 4]);
        if g.visible_h < 2 {
            return;
        }
        let side = BinTable::SIDE as i32;
        let c255 = v3.splat_i32x8(255);
        let cside = v3.splat_i32x8(side);
        // The scatter runs two streams of pixels interleaved (two chains of dependent
        // additions instead of one): at step `t` the left part (pixels `1..m`) of row
        // `t` and the right part (`m..`) of row `t - 1`. Only the one or two cells
        // around pixel `m` get votes from both parts (right pixels up to `m + 16`, left
        // pixels from `m - 17`); the right stream reaches them within its first 17
        // pixels, the left stream after `m - 18` pixels, so with `m >= 48` every bin
        // still receives its votes in raster order (left of row t - 1, right of row
        // t - 1, left of row t, ...).
        let m = if vis_w >= 96 { vis_w / 2 } else { vis_w };
        let row_len = hist_w * 18;
        for t in 1..=g.visible_h {
            if t < g.visible_h {
                let y = t;
                let (vy0, vy1, _) = row_weights(y, cell);
                let up = &img[(y - 1) * width..y * width];
                let mid = &img[y * width..(y + 1) * width];
                let dn = &img[(y + 1) * width..(y + 2) * width];
                let half = (y & 1) * vis_w;
                let idx = &mut scratch.row_idx[half..half + vis_w];
                let votes = &mut scratch.row_votes[half..half + vis_w];
                let (w0, w1) = (&scratch.col_w0[..], &scratch.col_w1[..]);
                let (svy0, svy1) = (v3.splat_f32x8(vy0), v3.splat_f32x8(vy1));
                // dlib's 8-pixel blocks
                let mut x = 1;
                while x < simd_end {
                    let gx = v3.sub_i32s(ld8_u8(v3, mid, x + 1), ld8_u8(v3, mid, x - 1));
                    let gy = v3.sub_i32s(ld8_u8(v3, dn, x), ld8_u8(v3, up, x));
                    let m2 = v3.add_i32s(v3.mul_i32s(gx, gx), v3.mul_i32s(gy, gy));
                    let v = v3.sqrt_f32x8(v3.convert_i32x8_to_f32x8(m2));
                    let ti = v3.add_i32s(v3.mul_i32s(v3.add_i32s(gy, c255), cside), v3.add_i32s(gx, c255));
                    let ti: [u32; V3_LANES] = bytemuck::cast(ti);
                    idx[x..x + V3_LANES].copy_from_slice(&ti);
                    let a1 = v3.mul_f32s(ld8_f32(w1, x), v);
                    let a0 = v3.mul_f32s(ld8_f32(w0, x), v);
                    let v11: [f32; V3_LANES] = bytemuck::cast(v3.mul_f32s(svy1, a1));
                    let v01: [f32; V3_LANES] = bytemuck::cast(v3.mul_f32s(svy0, a1));
                    let v10: [f32; V3_LANES] = bytemuck::cast(v3.mul_f32s(svy1, a0));
                    let v00: [f32; V3_LANES] = bytemuck::cast(v3.mul_f32s(svy0, a0));
                    for k in 0..V3_LANES {
                        votes[x + k] = [v11[k], v01[k], v10[k], v00[k]];
                    }
                    x += V3_LANES;
                }
                // dlib's scalar tail (other association of the weights)
                for x in simd_end..vis_w {
                    let gx = i32::from(mid[x + 1]) - i32::from(mid[x - 1]);
                    let gy = i32::from(dn[x]) - i32::from(up[x]);
                    let v = ((gx * gx + gy * gy) as f32).sqrt();
                    idx[x] = ((gy + 255) * side + gx + 255) as u32;
                    let (vx0, vx1) = (w0[x], w1[x]);
                    votes[x] = [vy1 * vx1 * v, vy0 * vx1 * v, vy1 * vx0 * v, vy0 * vx0 * v];
                }
            }
            // the votes: left part of row t, right part of row t - 1
            let bins = &table.bins[..];
            let col_ix = &scratch.col_ix[..];
            let (idx, votes) = (&scratch.row_idx[..], &scratch.row_votes[..]);
            let hist = &mut scratch.hist[..];
            let stream = |y: usize, from: usize, to: usize| {
                let half = (y & 1) * vis_w;
                let base = row_weights(y, cell).2 * row_len;
                (
                    base,
                    &col_ix[from..to],
                    &idx[half + from..half + to],
                    &votes[half + from..half + to],
                )
            };
            let vote = |hist: &mut [f32], base: usize, hx: usize, i: u32, v: [f32; 4]| {
                let at = base + hx * 18 + usize::from(bins[i as usize]);
                hist[at] += v[0];
                hist[at + row_len] += v[1];
                hist[at + 18] += v[2];
                hist[at + row_len + 18] += v[3];
            };
            let left = if t < g.visible_h {
                stream(t, 1, m)
            } else {
                stream(t - 1, 1, 1)
            };
            let right = if t >= 2 {
                stream(t - 1, m, vis_w)
            } else {
                stream(t, m, m)
            };
            let both = left.1.len().min(right.1.len());
            for k in 0..both {
                vote(hist, left.0, left.1[k], left.2[k], left.3[k]);
                vote(hist, right.0, right.1[k], right.2[k], right.3[k]);
            }
            for k in both..left.1.len() {
                vote(hist, left.0, left.1[k], left.2[k], left.3[k]);
            }
            for k in both..right.1.len() {
                vote(hist, right.0, right.1[k], right.2[k], right.3[k]);
            }
        }
    }
}

/// Energies, normalisation and output planes (shared by the fast and the reference
/// extractor; `vector`: the AVX2 feature pass where available, else scalar code).
fn finish(g: FhogGeometry, fw: usize, fh: usize, scratch: &mut FhogScratch, out: &mut FhogImage, vector: bool) {
    let hist_w = g.cells_w + 2;
    let hist = &scratch.hist;
    let norm = &mut scratch.norm;
    norm.clear();
    norm.resize(g.cells_w * g.cells_h, 0.0);
    for r in 0..g.cells_h {
        for c in 0..g.cells_w {
            let h = &hist[((r + 1) * hist_w + c + 1) * 18..((r + 1) * hist_w + c + 2) * 18];
            let mut n = 0f32;
            for o in 0..9 {
                let s = h[o] + h[o + 9];
                n += s * s;
            }
            norm[r * g.cells_w + c] = n;
        }
    }

    let pw = g.hog_w + fw - 1;
    let ph = g.hog_h + fh - 1;
    let plane = pw * ph;
    out.width = pw;
    out.height = ph;
    out.data.clear();
    out.data.resize(PLANES * plane, 0.0);
    let off_r = (fh - 1) / 2;
    let off_c = (fw - 1) / 2;
    let cw = g.cells_w;
    let geo = FeatureGeometry {
        hist_w,
        cw,
        pw,
        plane,
        off_r,
        off_c,
    };
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new().filter(|_| vector) {
        pulp::Simd::vectorize(
            v3,
            FeaturesV3 {
                v3,
                g,
                geo,
                hist,
                norm,
                out: &mut out.data,
            },
        );
        return;
    }
    let _ = vector;
    for y in 0..g.hog_h {
        for x in 0..g.hog_w {
            cell_features(&geo, hist, norm, &mut out.data, y, x);
        }
    }
}

/// Strides and offsets of the feature computation.
#[derive(Debug, Clone, Copy)]
struct FeatureGeometry {
    hist_w: usize,
    cw: usize,
    pw: usize,
    plane: usize,
    off_r: usize,
    off_c: usize,
}

/// The 31 features of output cell `(y, x)`.
#[inline(always)]
fn cell_features(geo: &FeatureGeometry, hist: &[f32], norm: &[f32], out: &mut [f32], y: usize, x: usize) {
    let FeatureGeometry {
        hist_w,
        cw,
        pw,
        plane,
        off_r,
        off_c,
    } = *geo;
    let yy = y + off_r;
    let nrm = |r: usize, c: usize| norm[r * cw + c];
    // dlib's 4 lanes: blocks below-right, above-right, below-left, above-left
    let s = [
        nrm(y + 1, x + 1) + nrm(y + 1, x + 2) + nrm(y + 2, x + 1) + nrm(y + 2, x + 2) + EPS,
        nrm(y, x + 1) + nrm(y, x + 2) + nrm(y + 1, x + 1) + nrm(y + 1, x + 2) + EPS,
        nrm(y + 1, x) + nrm(y + 1, x + 1) + nrm(y + 2, x) + nrm(y + 2, x + 1) + EPS,
        nrm(y, x) + nrm(y, x + 1) + nrm(y + 1, x) + nrm(y + 1, x + 1) + EPS,
    ];
    let nn = s.map(|v| TRUNC * v.sqrt());
    let n = nn.map(|v| NORM_SCALE / v);
    let h = &hist[((y + 2) * hist_w + x + 2) * 18..((y + 2) * hist_w + x + 3) * 18];
    let xx = x + off_c;
    let idx = yy * pw + xx;
    let mut t = [0f32; 4];
    for o in (0..18).step_by(3) {
        let mut sums = [[0f32; 4]; 3];
        for (k, s3) in sums.iter_mut().enumerate() {
            for j in 0..4 {
                s3[j] = h[o + k].min(nn[j]) * n[j];
            }
            out[(o + k) * plane + idx] = (s3[0] + s3[1]) + (s3[2] + s3[3]);
        }
        for j in 0..4 {
            t[j] += sums[0][j] + sums[1][j] + sums[2][j];
        }
    }
    for o in 0..9 {
        let hv = h[o] + h[o + 9];
        let mut s4 = [0f32; 4];
        for j in 0..4 {
            s4[j] = hv.min(nn[j]) * n[j];
        }
        out[(18 + o) * plane + idx] = (s4[0] + s4[1]) + (s4[2] + s4[3]);
    }
    for j in 0..4 {
        out[(27 + j) * plane + idx] = t[j] * TEXTURE_SCALE;
    }
}

/// The features of 8 neighbouring cells of a row at a time on AVX2 (one lane per
/// cell, stored contiguously into each plane), with the operations of
/// [`cell_features`] in the same order, so bit-identical; the last cells of a row
/// one at a time.
#[cfg(target_arch = "x86_64")]
struct FeaturesV3<'a> {
    v3: pulp::x86::V3,
    g: FhogGeometry,
    geo: FeatureGeometry,
    hist: &'a [f32],
    norm: &'a [f32],
    out: &'a mut [f32],
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for FeaturesV3<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        use pulp::Simd as _;
        let FeaturesV3 {
            v3,
            g,
            geo,
            hist,
            norm,
            out,
        } = self;
        let FeatureGeometry {
            hist_w,
            cw,
            pw,
            plane,
            off_r,
            off_c,
        } = geo;
        let blocks = g.hog_w / V3_LANES;
        let eps = v3.splat_f32x8(EPS);
        let trunc = v3.splat_f32x8(TRUNC);
        let scale = v3.splat_f32x8(NORM_SCALE);
        let texture = v3.splat_f32x8(TEXTURE_SCALE);
        let st = |out: &mut [f32], at: usize, v: pulp::f32x8| {
            let a: [f32; V3_LANES] = bytemuck::cast(v);
            out[at..at + V3_LANES].copy_from_slice(&a);
        };
        for y in 0..g.hog_h {
            let yy = y + off_r;
            for b in 0..blocks {
                let x = b * V3_LANES;
                let nrm = |r: usize, c: usize| ld8_f32(norm, r * cw + c);
                let add4 = |a, b2, c, d| v3.add_f32s(v3.add_f32s(v3.add_f32s(v3.add_f32s(a, b2), c), d), eps);
                let s = [
                    add4(
                        nrm(y + 1, x + 1),
                        nrm(y + 1, x + 2),
                        nrm(y + 2, x + 1),
                        nrm(y + 2, x + 2),
                    ),
                    add4(nrm(y, x + 1), nrm(y, x + 2), nrm(y + 1, x + 1), nrm(y + 1, x + 2)),
                    add4(nrm(y + 1, x), nrm(y + 1, x + 1), nrm(y + 2, x), nrm(y + 2, x + 1)),
                    add4(nrm(y, x), nrm(y, x + 1), nrm(y + 1, x), nrm(y + 1, x + 1)),
                ];
                let nn = s.map(|v| v3.mul_f32s(trunc, v3.sqrt_f32x8(v)));
                let n = nn.map(|v| v3.div_f32s(scale, v));
                let h0 = ((y + 2) * hist_w + x + 2) * 18;
                let hv = |o: usize| -> pulp::f32x8 {
                    bytemuck::cast::<[f32; 8], _>(std::array::from_fn(|k| hist[h0 + k * 18 + o]))
                };
                let feat = |h: pulp::f32x8| -> ([pulp::f32x8; 4], pulp::f32x8) {
                    let m: [pulp::f32x8; 4] = std::array::from_fn(|j| v3.mul_f32s(v3.min_f32s(h, nn[j]), n[j]));
                    (m, v3.add_f32s(v3.add_f32s(m[0], m[1]), v3.add_f32s(m[2], m[3])))
                };
                let idx = yy * pw + x + off_c;
                let mut t = [v3.splat_f32x8(0.0); 4];
                let mut h = [v3.splat_f32x8(0.0); 18];
                for (o, ho) in h.iter_mut().enumerate() {
                    *ho = hv(o);
                }
                for o in (0..18).step_by(3) {
                    let (m0, f0) = feat(h[o]);
                    let (m1, f1) = feat(h[o + 1]);
                    let (m2, f2) = feat(h[o + 2]);
                    st(out, o * plane + idx, f0);
                    st(out, (o + 1) * plane + idx, f1);
                    st(out, (o + 2) * plane + idx, f2);
                    for j in 0..4 {
                        t[j] = v3.add_f32s(t[j], v3.add_f32s(v3.add_f32s(m0[j], m1[j]), m2[j]));
                    }
                }
                for o in 0..9 {
                    let (_, f) = feat(v3.add_f32s(h[o], h[o + 9]));
                    st(out, (18 + o) * plane + idx, f);
                }
                for j in 0..4 {
                    st(out, (27 + j) * plane + idx, v3.mul_f32s(t[j], texture));
                }
            }
            for x in blocks * V3_LANES..g.hog_w {
                cell_features(&geo, hist, norm, out, y, x);
            }
        }
    }
}

/// Slow reference: a literal transcription of dlib's loops (per-pixel orientation
/// search, no tables, no precomputed weights). For tests.
pub fn extract_reference(img: &[u8], width: usize, height: usize, cell: usize, fw: usize, fh: usize) -> FhogImage {
    let mut out = FhogImage::default();
    let mut scratch = FhogScratch::default();
    let g = geometry(width, height, cell);
    if g.cells_w == 0 || g.cells_h == 0 || g.hog_w == 0 || g.hog_h == 0 {
        return out;
    }
    let hist_w = g.cells_w + 2;
    scratch.hist = vec![0.0; hist_w * (g.cells_h + 2) * 18];
    let px = |x: usize, y: usize| i32::from(img[y * width + x]);
    let mut add = |r: i64, c: i64, o: usize, v: f32| {
        let i = ((r as usize) * hist_w + c as usize) * 18 + o;
        scratch.hist[i] += v;
    };
    for y in 1..g.visible_h {
        let yp = ((y as f32 as f64 + 0.5) / (cell as f32 as f64) - 0.5) as f32;
        let iyp = yp.floor() as i64;
        let vy0 = yp - iyp as f32;
        let vy1 = (1.0 - f64::from(vy0)) as f32;
        let mut x = 1usize;
        // SIMD blocks of 8
        while (x as i64) < g.visible_w as i64 - 7 {
            for k in 0..8 {
                let xk = x + k;
                let gx = (px(xk + 1, y) - px(xk - 1, y)) as f32;
                let gy = (px(xk, y + 1) - px(xk, y - 1)) as f32;
                let v = (gx * gx + gy * gy).sqrt();
                let o = usize::from(orientation_bin(gx, gy));
                let xp = (xk as f32 + 0.5) / cell as f32 + 0.5;
                let ixp = xp as i64;
                let vx0 = xp - ixp as f32;
                let vx1 = 1.0 - vx0;
                let (a1, a0) = (vx1 * v, vx0 * v);
                add(iyp + 1, ixp, o, vy1 * a1);
                add(iyp + 2, ixp, o, vy0 * a1);
                add(iyp + 1, ixp + 1, o, vy1 * a0);
                add(iyp + 2, ixp + 1, o, vy0 * a0);
            }
            x += 8;
        }
        while x < g.visible_w {
            let gx = (px(x + 1, y) - px(x - 1, y)) as f32;
            let gy = (px(x, y + 1) - px(x, y - 1)) as f32;
            let v = (gx * gx + gy * gy).sqrt();
            let o = usize::from(orientation_bin(gx, gy));
            let xp = ((x as f64 + 0.5) / cell as f64 - 0.5) as f32;
            let ixp = xp.floor() as i64;
            let vx0 = xp - ixp as f32;
            let vx1 = (1.0 - f64::from(vx0)) as f32;
            add(iyp + 1, ixp + 1, o, vy1 * vx1 * v);
            add(iyp + 2, ixp + 1, o, vy0 * vx1 * v);
            add(iyp + 1, ixp + 2, o, vy1 * vx0 * v);
            add(iyp + 2, ixp + 2, o, vy0 * vx0 * v);
            x += 1;
        }
    }
    finish(g, fw, fh, &mut scratch, &mut out, false);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn fast_extractor_equals_reference_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let table = BinTable::new();
        let mut scratch = FhogScratch::default();
        let mut out = FhogImage::default();
        for &(w, h) in &[
            (64usize, 64usize),
            (97, 71),
            (130, 90),
            (17, 33),
            (8, 8),
            (3, 200),
            (333, 250),
            (10, 40),
            (16, 16),
            (25, 9),
            (96, 30),
            (101, 31),
            (640, 60),
            (1280, 24),
        ] {
            // random pixels (all bins, short runs) and smooth waves (long runs of equal
            // bins across cells, as in real images)
            for smooth in [false, true] {
                let img: Vec<u8> = (0..w * h)
                    .map(|i| {
                        if smooth {
                            let (x, y) = ((i % w) as f64, (i / w) as f64);
                            (127.0 + 120.0 * (x * 0.05 + y * 0.03).sin() * (y * 0.02).cos()) as u8
                        } else {
                            rng.random::<u8>()
                        }
                    })
                    .collect();
                extract(&img, w, h, 8, 10, 10, &table, &mut scratch, &mut out);
                let r = extract_reference(&img, w, h, 8, 10, 10);
                assert_eq!((out.width, out.height), (r.width, r.height), "{w}x{h}");
                assert!(
                    out.data.iter().zip(&r.data).all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{w}x{h} smooth {smooth}"
                );
            }
        }
    }

    #[test]
    fn flat_image_has_zero_features() {
        let img = vec![100u8; 80 * 80];
        let r = extract_reference(&img, 80, 80, 8, 10, 10);
        assert!(r.data.iter().all(|&v| v == 0.0));
        assert_eq!((r.width, r.height), (8 + 9, 8 + 9));
    }
}
