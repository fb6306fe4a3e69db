//! Image pyramids for [`super::PyramidLk`], and the frame-to-frame workspace that
//! swaps previous/next pyramids.
//!
//! Memory layout: each level is row-major `u8` with a border of
//! `b = border_for(window)` pixels on every side (the window side rounded up to the
//! kernel's lane count, plus slack, so that fixed-width window rows can be read
//! anywhere a window may start); pixel `(x, y)` of the level (0-based,
//! `-b <= x < w + b`) is at `(y + b) * stride + (x + b)` with `stride = w + 2b`. The
//! border is filled by reflect-101 (`BORDER_REFLECT_101`).
//!
//! Gradients are not stored: the kernel computes the Scharr derivatives of the
//! `(window + 1)²` pixels a point needs on the fly (see `kernel.rs`), which for
//! sparse points costs far less than differentiating every level of every frame.
//! [`PyramidLevel::gradient`] gives the same values for inspection.

use image::GrayImage;

use crate::error::{Error, Result};

/// Lane count of the kernel's fixed-width row loops: window rows are processed
/// as `window.next_multiple_of(LANES)` values.
pub(crate) const LANES: usize = 8;

/// Border (px) kept around every level for window side `window`.
pub(crate) fn border_for(window: usize) -> usize {
    window.next_multiple_of(LANES) + 4 * LANES
}

/// Border columns / rows that must hold reflect-101 values: windows start at
/// `x >= -window`, bilinear reads one more pixel and the Scharr patch one more.
pub(crate) fn reach_for(window: usize) -> usize {
    window + 2
}

/// OpenCV `BORDER_REFLECT_101` index (repeated reflection, any distance).
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    while i < 0 || i >= n {
        if i < 0 {
            i = -i;
        }
        if i >= n {
            i = 2 * (n - 1) - i;
        }
    }
    i as usize
}

/// Largest border handled by [`PyramidLevel::fill_border`]'s index table.
const MAX_BORDER: usize = 128;

/// One pyramid level: padded intensities.
#[derive(Debug, Clone, Default)]
pub struct PyramidLevel {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) border: usize,
    pub(crate) stride: usize,
    pub(crate) img: Vec<u8>,
}

impl PyramidLevel {
    /// Level width in pixels (without border).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Level height in pixels (without border).
    pub fn height(&self) -> usize {
        self.height
    }

    /// Intensity at `(x, y)`, `-border <= x < width + border` (reflect-101 outside).
    pub fn pixel(&self, x: isize, y: isize) -> Option<u8> {
        self.index(x, y)?;
        let (rx, ry) = (reflect101(x, self.width), reflect101(y, self.height));
        self.index(rx as isize, ry as isize).map(|i| self.img[i])
    }

    /// Scharr gradients `(Ix, Iy)` at `(x, y)`: `[3 10 3]ᵀ ⊗ [-1 0 1]` and its
    /// transpose over the reflect-101 image, i.e. 32x the central-difference
    /// gradient; zero outside the image (OpenCV's `calcScharrDeriv` + constant border).
    /// `None` outside the stored border.
    pub fn gradient(&self, x: isize, y: isize) -> Option<(i16, i16)> {
        self.index(x, y)?;
        if x < 0 || y < 0 || x >= self.width as isize || y >= self.height as isize {
            return Some((0, 0));
        }
        let p = |dx: isize, dy: isize| self.pixel(x + dx, y + dy).unwrap_or(0) as i16;
        let ix = 3 * (p(1, -1) - p(-1, -1)) + 10 * (p(1, 0) - p(-1, 0)) + 3 * (p(1, 1) - p(-1, 1));
        let iy = 3 * (p(-1, 1) - p(-1, -1)) + 10 * (p(0, 1) - p(0, -1)) + 3 * (p(1, 1) - p(1, -1));
        Some((ix, iy))
    }

    fn index(&self, x: isize, y: isize) -> Option<usize> {
        let b = self.border as isize;
        let (px, py) = (x + b, y + b);
        if px < 0
            || py < 0
            || px >= (self.width + 2 * self.border) as isize
            || py >= (self.height + 2 * self.border) as isize
        {
            return None;
        }
        Some(py as usize * self.stride + px as usize)
    }

    fn resize(&mut self, width: usize, height: usize, border: usize) {
        self.width = width;
        self.height = height;
        self.border = border;
        self.stride = width + 2 * border;
        let n = self.stride * (height + 2 * border);
        // `resize` keeps the allocation when the size is unchanged.
        self.img.resize(n, 0);
    }

    /// Fills the innermost `reach` border columns and rows by reflect-101
    /// (`BORDER_REFLECT_101`). Pixels farther out are only ever read into lanes
    /// whose weight or gradient is zero (see `kernel.rs`), so they stay as they are.
    fn fill_border(&mut self, reach: usize) {
        let (w, h, b, s) = (self.width, self.height, self.border, self.stride);
        let reach = reach.min(b).min(MAX_BORDER);
        // Source column (padded index) of every filled left / right border column.
        let mut left = [0usize; MAX_BORDER];
        let mut right = [0usize; MAX_BORDER];
        for k in 0..reach {
            left[k] = b + reflect101(-(k as isize) - 1, w);
            right[k] = b + reflect101((w + k) as isize, w);
        }
        let (left, right) = (&left[..reach], &right[..reach]);
        for y in b..b + h {
            let row = &mut self.img[y * s..(y + 1) * s];
            for (k, &src) in left.iter().enumerate() {
                row[b - 1 - k] = row[src];
            }
            for (k, &src) in right.iter().enumerate() {
                row[b + w + k] = row[src];
            }
        }
        // Rows above and below (whole padded rows).
        for k in 0..reach {
            let src = (b + reflect101(-(k as isize) - 1, h)) * s;
            self.img.copy_within(src..src + s, (b - 1 - k) * s);
            let src = (b + reflect101((h + k) as isize, h)) * s;
            self.img.copy_within(src..src + s, (b + h + k) * s);
        }
    }
}

/// A Gaussian pyramid (level 0 = full resolution).
#[derive(Debug, Clone, Default)]
pub struct Pyramid {
    levels: Vec<PyramidLevel>,
    used: usize,
    /// Vertical pass buffer of `pyr_down` (one row of source columns).
    tmp: Vec<u32>,
}

impl Pyramid {
    /// Number of levels built (0 before the first build).
    pub fn levels(&self) -> usize {
        self.used
    }

    /// Level `l`, if built.
    pub fn level(&self, l: usize) -> Option<&PyramidLevel> {
        if l < self.used {
            self.levels.get(l)
        } else {
            None
        }
    }

    pub(crate) fn lvl(&self, l: usize) -> &PyramidLevel {
        &self.levels[l]
    }

    /// Builds the pyramid of `img` in place (no allocation when sizes repeat).
    pub fn build(&mut self, img: &GrayImage, window: usize, max_level: usize) {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let border = border_for(window);
        let reach = reach_for(window);
        if self.levels.len() < max_level + 1 {
            self.levels.resize_with(max_level + 1, PyramidLevel::default);
        }
        // Level 0: copy with border.
        {
            let l0 = &mut self.levels[0];
            l0.resize(w, h, border);
            let (b, s) = (l0.border, l0.stride);
            let src = img.as_raw();
            for (y, row) in src.chunks_exact(w).take(h).enumerate() {
                l0.img[(y + b) * s + b..(y + b) * s + b + w].copy_from_slice(row);
            }
            l0.fill_border(reach);
        }
        let mut used = 1;
        let (mut cw, mut ch) = (w, h);
        for level in 1..=max_level {
            let (nw, nh) = (cw.div_ceil(2), ch.div_ceil(2));
            // OpenCV stops when the next level would be no larger than the window.
            if nw <= window || nh <= window {
                break;
            }
            let (lo, hi) = self.levels.split_at_mut(level);
            let src = &lo[level - 1];
            let dst = &mut hi[0];
            dst.resize(nw, nh, border);
            pyr_down(src, dst, &mut self.tmp);
            dst.fill_border(reach);
            used += 1;
            cw = nw;
            ch = nh;
        }
        self.used = used;
    }
}

/// `(even, odd)` source-column sums stored in one `u32` through a `u16` view.
#[inline(always)]
fn halves(v: u32) -> (u32, u32) {
    if cfg!(target_endian = "little") {
        (v & 0xffff, v >> 16)
    } else {
        (v >> 16, v & 0xffff)
    }
}

/// OpenCV `pyrDown` of the interior of `src` into the interior of `dst`
/// (sizes already set), reading the reflect-101 border of `src`.
///
/// Separable `[1 4 6 4 1]` in exact integers, vertical pass first (contiguous
/// `u16` rows: at most `16 · 255`), then horizontal (at most `16² · 255 + 128`),
/// so the result equals OpenCV's horizontal-first order bit for bit. The
/// vertical sums of source columns `2k - 2` and `2k - 1` share one `u32` (low and
/// high half), which turns the stride-2 horizontal pass into a contiguous loop.
fn pyr_down(src: &PyramidLevel, dst: &mut PyramidLevel, tmp: &mut Vec<u32>) {
    let (dw, dh) = (dst.width, dst.height);
    let (sb, ss) = (src.border, src.stride);
    debug_assert!(sb >= 3);
    // Source columns -2 ..= 2*dw + 1 (column c - 2 in half c of the u16 view).
    let pairs = dw + 2;
    let cols = 2 * pairs;
    tmp.resize(pairs, 0);
    let (db, ds) = (dst.border, dst.stride);
    for y in 0..dh {
        // Padded index of source row 2y - 2 at source column -2.
        let base = (2 * y + sb - 2) * ss + sb - 2;
        let r0 = &src.img[base..base + cols];
        let r1 = &src.img[base + ss..base + ss + cols];
        let r2 = &src.img[base + 2 * ss..base + 2 * ss + cols];
        let r3 = &src.img[base + 3 * ss..base + 3 * ss + cols];
        let r4 = &src.img[base + 4 * ss..base + 4 * ss + cols];
        let t: &mut [u16] = bytemuck::cast_slice_mut(&mut tmp[..pairs]);
        for (c, o) in t.iter_mut().enumerate() {
            *o = r0[c] as u16 + 4 * (r1[c] as u16 + r3[c] as u16) + 6 * r2[c] as u16 + r4[c] as u16;
        }
        let t: &[u32] = &tmp[..pairs];
        let out = &mut dst.img[(y + db) * ds + db..(y + db) * ds + db + dw];
        let (p0, p1, p2) = (&t[..dw], &t[1..dw + 1], &t[2..dw + 2]);
        for x in 0..dw {
            let (e0, o0) = halves(p0[x]);
            let (e1, o1) = halves(p1[x]);
            let (e2, _) = halves(p2[x]);
            let s = e0 + 4 * (o0 + o1) + 6 * e1 + e2;
            out[x] = ((s + 128) >> 8) as u8;
        }
    }
}

/// Previous/next pyramids for frame-to-frame tracking.
///
/// [`LkWorkspace::push_frame`] builds the pyramid of the new frame once into the
/// older buffer and swaps, so every frame's pyramid is built exactly once and no
/// memory is allocated once frame sizes are stable.
#[derive(Debug, Clone)]
pub struct LkWorkspace {
    window: usize,
    max_level: usize,
    prev: Pyramid,
    next: Pyramid,
    frames: usize,
}

impl LkWorkspace {
    /// An empty workspace for `lk`'s window and level count.
    pub fn new(lk: &super::PyramidLk) -> Self {
        LkWorkspace {
            window: lk.params().window,
            max_level: lk.params().max_level,
            prev: Pyramid::default(),
            next: Pyramid::default(),
            frames: 0,
        }
    }

    /// Makes the latest frame the previous one and builds the pyramid of `img` as the latest.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when `img` is smaller than 2x2... in
    /// practice: when either side is smaller than `window + 1` pixels.
    pub fn push_frame(&mut self, img: &GrayImage) -> Result<()> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let min = self.window + 1;
        if w < min || h < min {
            return Err(Error::DimensionMismatch {
                what: "frame side (must exceed the LK window)".into(),
                expected: min,
                got: w.min(h),
            });
        }
        std::mem::swap(&mut self.prev, &mut self.next);
        self.next.build(img, self.window, self.max_level);
        self.frames += 1;
        Ok(())
    }

    /// Forgets the frames (keeps the memory): the next two pushes start a new pair.
    pub fn reset(&mut self) {
        self.frames = 0;
    }

    /// Frames pushed since creation or [`LkWorkspace::reset`].
    pub fn frames_pushed(&self) -> usize {
        self.frames
    }

    /// The window side this workspace pads for.
    pub fn window(&self) -> usize {
        self.window
    }

    pub(crate) fn max_level_requested(&self) -> usize {
        self.max_level
    }

    /// The previous frame's pyramid (valid after two pushes).
    pub fn prev(&self) -> &Pyramid {
        &self.prev
    }

    /// The latest frame's pyramid.
    pub fn latest(&self) -> &Pyramid {
        &self.next
    }

    /// (previous, latest) when two frames of equal size are available.
    pub(crate) fn pair(&self) -> Option<(&Pyramid, &Pyramid)> {
        if self.frames < 2 || self.prev.levels() == 0 {
            return None;
        }
        let (a, b) = (self.prev.lvl(0), self.next.lvl(0));
        if a.width != b.width || a.height != b.height {
            return None;
        }
        Some((&self.prev, &self.next))
    }
}
