//! Image pyramids with Scharr gradients for [`super::PyramidLk`], and the
//! frame-to-frame workspace that swaps previous/next pyramids.
//!
//! Memory layout: each level is row-major with a border of `b = window` pixels on
//! every side; pixel `(x, y)` of the level (0-based, `-b <= x < w + b`) is at
//! `(y + b) * stride + (x + b)` with `stride = w + 2b`. Intensities are `u8`
//! with a reflect-101 border; gradients `Ix`, `Iy` are `i16` planes (Scharr,
//! 32x the central-difference gradient) with a zero border.

use image::GrayImage;

use crate::error::{Error, Result};

/// One pyramid level: padded intensities and gradients.
#[derive(Debug, Clone, Default)]
pub struct PyramidLevel {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) border: usize,
    pub(crate) stride: usize,
    pub(crate) img: Vec<u8>,
    pub(crate) ix: Vec<i16>,
    pub(crate) iy: Vec<i16>,
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
        self.index(x, y).map(|i| self.img[i])
    }

    /// Scharr gradients `(Ix, Iy)` at `(x, y)` (zero outside the image).
    pub fn gradient(&self, x: isize, y: isize) -> Option<(i16, i16)> {
        self.index(x, y).map(|i| (self.ix[i], self.iy[i]))
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
        self.ix.resize(n, 0);
        self.iy.resize(n, 0);
    }

    /// Fills the border of the intensity plane by reflect-101 (`BORDER_REFLECT_101`).
    fn fill_border(&mut self) {
        let (w, h, b, s) = (self.width, self.height, self.border, self.stride);
        // Left/right of every image row.
        for y in b..b + h {
            let row = &mut self.img[y * s..(y + 1) * s];
            for k in 1..=b {
                row[b - k] = row[b + k];
                row[b + w - 1 + k] = row[b + w - 1 - k];
            }
        }
        // Whole rows above and below.
        for k in 1..=b {
            let src = (b + k) * s;
            let dst = (b - k) * s;
            self.img.copy_within(src..src + s, dst);
            let src = (b + h - 1 - k) * s;
            let dst = (b + h - 1 + k) * s;
            self.img.copy_within(src..src + s, dst);
        }
    }

    /// Scharr gradients of the interior from the padded intensities (the
    /// reflect-101 border gives OpenCV's border handling); the gradient border stays zero.
    fn compute_gradients(&mut self) {
        let (w, h, b, s) = (self.width, self.height, self.border, self.stride);
        self.ix.fill(0);
        self.iy.fill(0);
        for y in 0..h {
            let r = (y + b) * s + b;
            let up = &self.img[r - s - 1..r - s + w + 1];
            let mid = &self.img[r - 1..r + w + 1];
            let dn = &self.img[r + s - 1..r + s + w + 1];
            let ix = &mut self.ix[r..r + w];
            let iy = &mut self.iy[r..r + w];
            for x in 0..w {
                let (u0, u1, u2) = (up[x] as i16, up[x + 1] as i16, up[x + 2] as i16);
                let (m0, m2) = (mid[x] as i16, mid[x + 2] as i16);
                let (d0, d1, d2) = (dn[x] as i16, dn[x + 1] as i16, dn[x + 2] as i16);
                ix[x] = 3 * (u2 - u0) + 10 * (m2 - m0) + 3 * (d2 - d0);
                iy[x] = 3 * (d0 - u0) + 10 * (d1 - u1) + 3 * (d2 - u2);
            }
        }
    }
}

/// A Gaussian pyramid with gradients (level 0 = full resolution).
#[derive(Debug, Clone, Default)]
pub struct Pyramid {
    levels: Vec<PyramidLevel>,
    used: usize,
    /// Horizontal pass buffer of `pyr_down` (src rows incl. border x dst width).
    tmp: Vec<u16>,
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
        if self.levels.len() < max_level + 1 {
            self.levels.resize_with(max_level + 1, PyramidLevel::default);
        }
        // Level 0: copy with border.
        {
            let l0 = &mut self.levels[0];
            l0.resize(w, h, window);
            let (b, s) = (l0.border, l0.stride);
            let src = img.as_raw();
            for y in 0..h {
                l0.img[(y + b) * s + b..(y + b) * s + b + w].copy_from_slice(&src[y * w..(y + 1) * w]);
            }
            l0.fill_border();
            l0.compute_gradients();
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
            dst.resize(nw, nh, window);
            pyr_down(src, dst, &mut self.tmp);
            dst.fill_border();
            dst.compute_gradients();
            used += 1;
            cw = nw;
            ch = nh;
        }
        self.used = used;
    }
}

/// OpenCV `pyrDown` of the interior of `src` into the interior of `dst`
/// (sizes already set), reading the reflect-101 border of `src` (width >= 2).
fn pyr_down(src: &PyramidLevel, dst: &mut PyramidLevel, tmp: &mut Vec<u16>) {
    let (dw, dh) = (dst.width, dst.height);
    let (sb, ss) = (src.border, src.stride);
    debug_assert!(sb >= 2);
    // Horizontal pass for source rows -2 ..= 2*dh (reads columns -2 ..= 2*dw).
    let rows = 2 * dh + 3;
    tmp.resize(rows * dw, 0);
    for r in 0..rows {
        let sy = r + sb - 2; // padded row index of source row (r - 2)
        let row = &src.img[sy * ss + sb - 2..sy * ss + sb + 2 * dw + 1];
        let out = &mut tmp[r * dw..(r + 1) * dw];
        for (x, o) in out.iter_mut().enumerate() {
            let p = &row[2 * x..2 * x + 5];
            *o = p[0] as u16 + 4 * p[1] as u16 + 6 * p[2] as u16 + 4 * p[3] as u16 + p[4] as u16;
        }
    }
    // Vertical pass with rounding: (sum + 128) >> 8.
    let (db, ds) = (dst.border, dst.stride);
    for y in 0..dh {
        let t0 = &tmp[(2 * y) * dw..(2 * y + 1) * dw];
        let t1 = &tmp[(2 * y + 1) * dw..(2 * y + 2) * dw];
        let t2 = &tmp[(2 * y + 2) * dw..(2 * y + 3) * dw];
        let t3 = &tmp[(2 * y + 3) * dw..(2 * y + 4) * dw];
        let t4 = &tmp[(2 * y + 4) * dw..(2 * y + 5) * dw];
        let out = &mut dst.img[(y + db) * ds + db..(y + db) * ds + db + dw];
        for x in 0..dw {
            let s = t0[x] as u32 + 4 * t1[x] as u32 + 6 * t2[x] as u32 + 4 * t3[x] as u32 + t4[x] as u32;
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
