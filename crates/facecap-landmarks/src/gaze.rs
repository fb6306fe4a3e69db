//! Iris (pupil) centre per eye from the grey frame and the 6 dlib eye landmarks, and a
//! mapping of the gaze offsets to the eight ARKit `eyeLook*` weights.
//!
//! The 68 iBUG points carry no iris, so gaze has to come from the image. Per eye:
//!
//! 1. **Eye frame.** With the outer corner `O` and the inner corner `I` (subject's right
//!    eye: 36 / 39, image left; subject's left eye: 45 / 42, image right) and the corner
//!    distance `L = |I - O|`, a point of the eye is `p = O + L (u a + v n)` with
//!    `a = (I - O) / L` and `n` the unit normal of `a` that points *down the face*
//!    (`n = (-a_y, a_x)` for the right eye, `(a_y, -a_x)` for the left, so `n` is image-down
//!    for an upright face whatever the eye). `u` = 0 at the outer corner, 1 at the inner
//!    corner; `v` > 0 below the corner axis; both in units of `L`.
//! 2. **Patch.** The region `u ∈ [-PATCH_U_MARGIN, 1 + PATCH_U_MARGIN]`,
//!    `v ∈ [-PATCH_V_HALF, PATCH_V_HALF]` is sampled bilinearly into a fixed
//!    `patch_width x patch_height` grid (square samples of `du = dv`), so the work per eye
//!    does not depend on the face size.
//! 3. **Mask.** Samples inside the polygon of the 6 landmarks (36-41 / 42-47, in landmark
//!    order), each vertex pushed `mask_margin · L` away from the polygon's centroid.
//! 4. **Darkness.** With `lo` / `hi` the `low_percentile` / `high_percentile` of the masked
//!    intensities, `t = lo + threshold_level (hi - lo)`, the weight of a masked sample is
//!    `D(p) = max(0, t - I(p))` (0 outside the mask): the iris and pupil, darker than the
//!    sclera and the lid skin, carry the weight.
//! 5. **Centre.** The mode of the darkness density smoothed by an isotropic Gaussian of
//!    standard deviation `kernel_sigma · L`, found by mean shift
//!    (Comaniciu & Meer 2002): start at the darkness centroid of the mask,
//!    `c ← Σ D(p) g(p - c) p / Σ D(p) g(p - c)`, `iterations` steps or until the step is
//!    below 0.01 samples. The Gaussian is separable, so one step costs two short tables
//!    of `exp` and one pass over the patch. The result is continuous (sub-pixel) by
//!    construction.
//!
//! Departures: gradient-based centre localisation (Timm & Barth 2011) was the other
//! candidate; on the 480x480 shared clips the eye is ~40 px wide and half-covered by the
//! lids, where the iris boundary gives few reliable gradients, while the darkness mode
//! is cheap and stable (measured figures: `docs/gaze.md`).
//!
//! Validity ([`EyeStatus`]): the eye must be at least `min_eye_width_px` wide, open
//! (`opening = (|p37 - p41| + |p38 - p40|) / (2 L)`, the eye aspect ratio, at least
//! `min_opening`), the masked patch inside the image, its contrast `hi - lo` at least
//! `min_contrast` grey levels, and the centre inside the (dilated) eye polygon. An
//! invalid eye is a value, not an error: degenerate, non-finite or out-of-image
//! landmarks never panic.
//!
//! # Coordinates
//!
//! Image pixels with the centre of the top-left pixel at (0, 0), as
//! [`Landmarks68`](facecap_core::landmarks::Landmarks68).
//!
//! # Example
//!
//! ```
//! use facecap_core::landmarks::Landmarks68;
//! use facecap_landmarks::gaze::{IrisEstimator, IrisFrame, IrisParams};
//! use image::GrayImage;
//!
//! let est = IrisEstimator::new(IrisParams::default())?;
//! let mut ws = est.new_workspace();
//! let mut out = IrisFrame::default();
//! let gray = GrayImage::new(64, 64); // a real frame in practice
//! let lm = Landmarks68::default(); // from the tracker in practice
//! let report = est.estimate_into(&gray, &lm, &mut ws, &mut out)?;
//! assert_eq!(report.valid_eyes, 0); // degenerate landmarks: both eyes invalid, no panic
//! assert!(!out.right.valid() && !out.left.valid());
//! # Ok::<(), facecap_landmarks::Error>(())
//! ```

use facecap_core::landmarks::Landmarks68;
use image::GrayImage;
use nalgebra::{Point2, Vector2};

use crate::error::{Error, Result};

/// Patch extent beyond each eye corner along the corner axis, in units of the corner
/// distance (the dilated polygon must fit inside the patch).
pub const PATCH_U_MARGIN: f64 = 0.15;
/// Half the patch extent across the corner axis, in units of the corner distance (eye
/// openings above 0.6 are not human).
pub const PATCH_V_HALF: f64 = 0.45;
/// Mean shift stops when a step is shorter than this, in patch samples.
const MEAN_SHIFT_EPS: f64 = 1e-2;

/// Landmark indices of one eye: outer corner, upper lid (outer, inner), inner corner,
/// lower lid (inner, outer) — the iBUG order walked around the eye.
const RIGHT_EYE: [usize; 6] = [36, 37, 38, 39, 40, 41];
/// Subject's left eye (image right) in the same order: 45 outer, 44 / 43 upper, 42
/// inner, 47 / 46 lower.
const LEFT_EYE: [usize; 6] = [45, 44, 43, 42, 47, 46];

/// Settings of [`IrisEstimator`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `patch_width` | 48 | samples along the corner axis (the patch spans `1 + 2·PATCH_U_MARGIN` corner distances) | 16..=256 |
/// | `mask_margin` | 0.03 | polygon dilation, in corner distances | 0..=0.3 |
/// | `low_percentile` | 0.05 | `lo` of the masked intensities | 0..1, < `high_percentile` |
/// | `high_percentile` | 0.95 | `hi` of the masked intensities | 0..=1 |
/// | `threshold_level` | 0.5 | `t = lo + level (hi - lo)` | (0, 1] |
/// | `kernel_sigma` | 0.15 | Gaussian of the mean shift, in corner distances (iris radius ~0.2) | 0.02..=1 |
/// | `iterations` | 10 | maximum mean-shift steps | 1..=100 |
/// | `min_eye_width_px` | 8 | corner distance below which the eye is [`EyeStatus::TooSmall`] | >= 2 |
/// | `min_opening` | 0.12 | eye aspect ratio below which the eye is [`EyeStatus::Closed`] | 0..1 |
/// | `min_contrast` | 20 | `hi - lo` in grey levels below which the eye is [`EyeStatus::LowContrast`] | 0..=255 |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IrisParams {
    /// Samples along the corner axis.
    pub patch_width: usize,
    /// Polygon dilation in corner distances.
    pub mask_margin: f64,
    /// Percentile of the masked intensities taken as the dark level.
    pub low_percentile: f64,
    /// Percentile of the masked intensities taken as the bright level.
    pub high_percentile: f64,
    /// Darkness threshold between the two levels.
    pub threshold_level: f64,
    /// Mean-shift Gaussian standard deviation in corner distances.
    pub kernel_sigma: f64,
    /// Maximum mean-shift steps.
    pub iterations: usize,
    /// Minimum corner distance in pixels.
    pub min_eye_width_px: f64,
    /// Minimum eye aspect ratio.
    pub min_opening: f64,
    /// Minimum `hi - lo` in grey levels.
    pub min_contrast: f64,
}

impl Default for IrisParams {
    fn default() -> Self {
        IrisParams {
            patch_width: 48,
            mask_margin: 0.03,
            low_percentile: 0.05,
            high_percentile: 0.95,
            threshold_level: 0.5,
            kernel_sigma: 0.15,
            iterations: 10,
            min_eye_width_px: 8.0,
            min_opening: 0.12,
            min_contrast: 20.0,
        }
    }
}

fn check(name: &'static str, v: f64, ok: bool, expected: &str) -> Result<()> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name,
            value: v.to_string(),
            expected: expected.into(),
        })
    }
}

impl IrisParams {
    /// Checks every field against the table of [`IrisParams`].
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the first bad field.
    pub fn validate(&self) -> Result<()> {
        let pw = self.patch_width;
        check("patch_width", pw as f64, (16..=256).contains(&pw), "16..=256")?;
        let m = self.mask_margin;
        check("mask_margin", m, (0.0..=0.3).contains(&m), "0..=0.3")?;
        let lo = self.low_percentile;
        check("low_percentile", lo, (0.0..1.0).contains(&lo), "0 <= p < 1")?;
        let hi = self.high_percentile;
        check("high_percentile", hi, hi > lo && hi <= 1.0, "low_percentile < p <= 1")?;
        let t = self.threshold_level;
        check("threshold_level", t, t > 0.0 && t <= 1.0, "0 < level <= 1")?;
        let s = self.kernel_sigma;
        check("kernel_sigma", s, (0.02..=1.0).contains(&s), "0.02..=1")?;
        let it = self.iterations;
        check("iterations", it as f64, (1..=100).contains(&it), "1..=100")?;
        let w = self.min_eye_width_px;
        check("min_eye_width_px", w, w >= 2.0, ">= 2")?;
        let o = self.min_opening;
        check("min_opening", o, (0.0..1.0).contains(&o), "0 <= opening < 1")?;
        let c = self.min_contrast;
        check("min_contrast", c, (0.0..=255.0).contains(&c), "0..=255")
    }
}

/// Which eye, in the subject's terms (ARKit naming: `Left` = the subject's left eye,
/// image right in a non-mirrored frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Eye {
    /// Subject's right eye, iBUG 36-41 (image left).
    Right,
    /// Subject's left eye, iBUG 42-47 (image right).
    Left,
}

/// Why an eye estimate is (in)valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EyeStatus {
    /// The centre is usable.
    Valid,
    /// Not estimated yet (the default).
    #[default]
    NotRun,
    /// A landmark of the eye is NaN or infinite.
    NotFinite,
    /// Corner distance below `min_eye_width_px` (includes coincident corners).
    TooSmall,
    /// Eye aspect ratio below `min_opening`.
    Closed,
    /// Part of the masked eye region lies outside the image.
    OutOfImage,
    /// Masked intensities span less than `min_contrast` grey levels.
    LowContrast,
    /// No darkness weight, or the centre fell outside the eye polygon.
    Implausible,
}

/// The estimate for one eye. Fields other than `status`, `width_px` and `opening` are
/// meaningful only when [`EyeEstimate::valid`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EyeEstimate {
    /// Iris centre in image pixels (top-left pixel centre = (0, 0)).
    pub centre: Point2<f64>,
    /// Along the outer -> inner corner axis: 0 at the outer corner, 1 at the inner one.
    pub u: f64,
    /// Across the axis, positive down the face, in corner distances.
    pub v: f64,
    /// Eye aspect ratio: mean upper-lower lid distance / corner distance.
    pub opening: f64,
    /// Corner distance in pixels.
    pub width_px: f64,
    /// In [0, 1]: `min(1, contrast / (2 min_contrast)) · min(1, opening / (2 min_opening))`
    /// for a valid eye, 0 otherwise.
    pub confidence: f64,
    /// Validity and the reason for invalidity.
    pub status: EyeStatus,
}

impl Default for EyeEstimate {
    fn default() -> Self {
        EyeEstimate {
            centre: Point2::origin(),
            u: f64::NAN,
            v: f64::NAN,
            opening: f64::NAN,
            width_px: f64::NAN,
            confidence: 0.0,
            status: EyeStatus::NotRun,
        }
    }
}

impl EyeEstimate {
    /// `status == EyeStatus::Valid`.
    pub fn valid(&self) -> bool {
        self.status == EyeStatus::Valid
    }
}

/// Both eyes of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IrisFrame {
    /// Subject's right eye (iBUG 36-41, image left).
    pub right: EyeEstimate,
    /// Subject's left eye (iBUG 42-47, image right).
    pub left: EyeEstimate,
}

impl IrisFrame {
    /// The estimate of one eye.
    pub fn eye(&self, eye: Eye) -> &EyeEstimate {
        match eye {
            Eye::Right => &self.right,
            Eye::Left => &self.left,
        }
    }
}

/// What [`IrisEstimator::estimate_into`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IrisReport {
    /// Eyes with a valid estimate (0, 1 or 2).
    pub valid_eyes: usize,
    /// Mean-shift steps taken, summed over the eyes that reached it.
    pub iterations: usize,
}

/// Scratch buffers of [`IrisEstimator`]; make one per thread with
/// [`IrisEstimator::new_workspace`] and reuse it every frame (no allocation per frame).
#[derive(Debug, Clone)]
pub struct IrisWorkspace {
    width: usize,
    height: usize,
    patch: Vec<f32>,
    mask: Vec<bool>,
    values: Vec<f32>,
    weights: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    spans: Vec<(usize, usize)>,
}

/// Iris-centre estimator (see the module docs for the method). `Send + Sync`, immutable.
#[derive(Debug, Clone)]
pub struct IrisEstimator {
    params: IrisParams,
    width: usize,
    height: usize,
}

impl IrisEstimator {
    /// Validates the parameters and fixes the patch size.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (see [`IrisParams::validate`]).
    pub fn new(params: IrisParams) -> Result<Self> {
        params.validate()?;
        let width = params.patch_width;
        let du = (1.0 + 2.0 * PATCH_U_MARGIN) / (width - 1) as f64;
        let height = ((2.0 * PATCH_V_HALF / du).round() as usize + 1) | 1;
        Ok(IrisEstimator { params, width, height })
    }

    /// The parameters.
    pub fn params(&self) -> &IrisParams {
        &self.params
    }

    /// Patch size `(width, height)` in samples.
    pub fn patch_size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// A workspace sized for this estimator.
    pub fn new_workspace(&self) -> IrisWorkspace {
        let n = self.width * self.height;
        IrisWorkspace {
            width: self.width,
            height: self.height,
            patch: vec![0.0; n],
            mask: vec![false; n],
            values: Vec::with_capacity(n),
            weights: vec![0.0; n],
            gx: vec![0.0; self.width],
            gy: vec![0.0; self.height],
            spans: vec![(1, 0); self.height],
        }
    }

    /// Estimates both iris centres of one frame into `out`.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when `ws` was made by an estimator with another patch
    /// size. Invalid eyes are not errors: see [`EyeEstimate::status`].
    pub fn estimate_into(
        &self,
        gray: &GrayImage,
        landmarks: &Landmarks68,
        ws: &mut IrisWorkspace,
        out: &mut IrisFrame,
    ) -> Result<IrisReport> {
        if ws.width != self.width || ws.height != self.height {
            return Err(Error::DimensionMismatch {
                what: "iris workspace patch samples".into(),
                expected: self.width * self.height,
                got: ws.width * ws.height,
            });
        }
        let mut report = IrisReport::default();
        for eye in [Eye::Right, Eye::Left] {
            let (est, iters) = self.estimate_eye(gray, landmarks, eye, ws);
            report.iterations += iters;
            report.valid_eyes += usize::from(est.valid());
            match eye {
                Eye::Right => out.right = est,
                Eye::Left => out.left = est,
            }
        }
        Ok(report)
    }

    fn estimate_eye(
        &self,
        gray: &GrayImage,
        lm: &Landmarks68,
        eye: Eye,
        ws: &mut IrisWorkspace,
    ) -> (EyeEstimate, usize) {
        let p = &self.params;
        let idx = match eye {
            Eye::Right => RIGHT_EYE,
            Eye::Left => LEFT_EYE,
        };
        let pts: [Point2<f64>; 6] = idx.map(|i| lm.points[i]);
        let mut est = EyeEstimate::default();
        let Some(EyeFrame { o, a, n, l, poly }) = eye_frame(&pts, eye, p, &mut est) else {
            return (est, 0);
        };
        // sample the patch, only where the mask is (row by row, between the polygon's
        // outermost crossings of the row)
        let (w, h) = (self.width, self.height);
        let step = (1.0 + 2.0 * PATCH_U_MARGIN) / (w - 1) as f64;
        let v0 = -step * ((h - 1) / 2) as f64;
        let u0 = -PATCH_U_MARGIN;
        let (iw, ih) = (gray.width() as usize, gray.height() as usize);
        let img = gray.as_raw();
        ws.values.clear();
        let mut outside = false;
        for r in 0..h {
            let v = v0 + step * r as f64;
            let mut xs = [0.0f64; 6];
            let nx = row_crossings(&poly, v, &mut xs);
            ws.spans[r] = (1, 0);
            if nx < 2 {
                continue;
            }
            let (xmin, xmax) = xs[..nx]
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            let cmin = ((xmin - u0) / step).floor().max(0.0) as usize;
            let cmax = (((xmax - u0) / step).ceil().max(0.0) as usize).min(w - 1);
            ws.spans[r] = (cmin, cmax);
            for c in cmin..=cmax {
                let u = u0 + step * c as f64;
                let k = r * w + c;
                // even-odd rule, as `point_in_polygon`
                let inside = xs[..nx].iter().filter(|&&x| u < x).count() % 2 == 1;
                ws.mask[k] = inside;
                ws.patch[k] = 0.0;
                if !inside {
                    continue;
                }
                let q = o + (a * u + n * v) * l;
                match bilinear(img, iw, ih, q.x, q.y) {
                    Some(val) => {
                        ws.patch[k] = val;
                        ws.values.push(val);
                    }
                    None => outside = true,
                }
            }
        }
        if outside {
            est.status = EyeStatus::OutOfImage;
            return (est, 0);
        }
        let m = ws.values.len();
        if m < 4 {
            est.status = EyeStatus::Implausible;
            return (est, 0);
        }
        let lo = select(&mut ws.values, p.low_percentile);
        let hi = select(&mut ws.values, p.high_percentile);
        let contrast = f64::from(hi - lo);
        if contrast < p.min_contrast {
            est.status = EyeStatus::LowContrast;
            return (est, 0);
        }
        let t = lo + (p.threshold_level as f32) * (hi - lo);
        // darkness weights and their centroid (mean-shift start)
        let (mut sw, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
        for r in 0..h {
            let (cmin, cmax) = ws.spans[r];
            let (mut rw, mut rx) = (0.0f32, 0.0f32);
            for c in cmin..=cmax.min(w - 1) {
                let k = r * w + c;
                let d = if ws.mask[k] { (t - ws.patch[k]).max(0.0) } else { 0.0 };
                ws.weights[k] = d;
                rw += d;
                rx += d * c as f32;
            }
            sw += f64::from(rw);
            sx += f64::from(rx);
            sy += f64::from(rw) * r as f64;
        }
        if sw.is_nan() || sw <= 0.0 {
            est.status = EyeStatus::Implausible;
            return (est, 0);
        }
        let (mut cx, mut cy) = (sx / sw, sy / sw);
        let sigma = p.kernel_sigma / step;
        let inv2s2 = 1.0 / (2.0 * sigma * sigma);
        let mut iters = 0;
        for _ in 0..p.iterations {
            iters += 1;
            for (c, g) in ws.gx.iter_mut().enumerate() {
                let d = c as f64 - cx;
                *g = (-d * d * inv2s2).exp() as f32;
            }
            for (r, g) in ws.gy.iter_mut().enumerate() {
                let d = r as f64 - cy;
                *g = (-d * d * inv2s2).exp() as f32;
            }
            let (mut sw, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
            for r in 0..h {
                let (cmin, cmax) = ws.spans[r];
                if cmin > cmax {
                    continue;
                }
                let row = &ws.weights[r * w + cmin..=r * w + cmax.min(w - 1)];
                let (mut rw, mut rx) = (0.0f32, 0.0f32);
                for (j, (&d, &g)) in row.iter().zip(&ws.gx[cmin..]).enumerate() {
                    let wd = d * g;
                    rw += wd;
                    rx += wd * (cmin + j) as f32;
                }
                let gy = f64::from(ws.gy[r]);
                sw += f64::from(rw) * gy;
                sx += f64::from(rx) * gy;
                sy += f64::from(rw) * gy * r as f64;
            }
            if sw.is_nan() || sw <= 0.0 {
                break;
            }
            let (nx, ny) = (sx / sw, sy / sw);
            let moved = ((nx - cx).powi(2) + (ny - cy).powi(2)).sqrt();
            cx = nx;
            cy = ny;
            if moved < MEAN_SHIFT_EPS {
                break;
            }
        }
        let u = u0 + step * cx;
        let v = v0 + step * cy;
        if !point_in_polygon(&poly, u, v) {
            est.status = EyeStatus::Implausible;
            return (est, iters);
        }
        est.u = u;
        est.v = v;
        est.centre = o + (a * u + n * v) * l;
        est.confidence = (contrast / (2.0 * p.min_contrast.max(1e-9))).min(1.0)
            * (est.opening / (2.0 * p.min_opening.max(1e-9))).min(1.0);
        est.status = EyeStatus::Valid;
        (est, iters)
    }
}

/// The `q`-quantile (nearest rank) of `values`, reordering them.
fn select(values: &mut [f32], q: f64) -> f32 {
    let n = values.len();
    let k = ((q * (n - 1) as f64).round() as usize).min(n - 1);
    let (_, v, _) = values.select_nth_unstable_by(k, f32::total_cmp);
    *v
}

/// Bilinear sample at `(x, y)`, `None` outside `[0, w-1] x [0, h-1]`.
fn bilinear(img: &[u8], w: usize, h: usize, x: f64, y: f64) -> Option<f32> {
    if !(x >= 0.0 && y >= 0.0 && x <= (w as f64 - 1.0) && y <= (h as f64 - 1.0)) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let px = |xx: usize, yy: usize| f32::from(img[yy * w + xx]);
    let top = px(x0, y0) + fx * (px(x1, y0) - px(x0, y0));
    let bot = px(x0, y1) + fx * (px(x1, y1) - px(x0, y1));
    Some(top + fy * (bot - top))
}

/// The `u` of every crossing of the polygon's edges with the row `v` (same formula and
/// edge test as [`point_in_polygon`], so a sample is inside exactly when an odd number of
/// crossings lie to its right); returns how many.
fn row_crossings(poly: &[[f64; 2]; 6], y: f64, xs: &mut [f64; 6]) -> usize {
    let mut n = 0;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (xi, yi) = (poly[i][0], poly[i][1]);
        let (xj, yj) = (poly[j][0], poly[j][1]);
        if (yi > y) != (yj > y) {
            xs[n] = (xj - xi) * (y - yi) / (yj - yi) + xi;
            n += 1;
        }
        j = i;
    }
    n
}

/// Even-odd rule for a closed polygon (the reference of the row-span mask).
fn point_in_polygon(poly: &[[f64; 2]; 6], x: f64, y: f64) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (xi, yi) = (poly[i][0], poly[i][1]);
        let (xj, yj) = (poly[j][0], poly[j][1]);
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// One eye's estimate from an iris centre measured by a landmark model (the face mesh's
/// iris landmarks) instead of the grey frame: the eye frame `(u, v)`, the opening and the
/// validity rules of [`IrisEstimator`] (`NotFinite`, `TooSmall`, `Closed`, and
/// `Implausible` for a centre outside the eye polygon dilated by `mask_margin`), without
/// the image tests (contrast, image bounds), which have no meaning here.
///
/// `contour` is the eye's outline in the iBUG walk order: outer corner, upper lid (outer,
/// inner), inner corner, lower lid (inner, outer); `centre` is the iris centre; both in
/// image pixels. `confidence` is `min(1, opening / (2 min_opening))` for a valid eye.
/// Never panics; non-finite input gives an invalid eye.
pub fn eye_from_centre(contour: &[Point2<f64>; 6], centre: Point2<f64>, eye: Eye, params: &IrisParams) -> EyeEstimate {
    let mut est = EyeEstimate::default();
    if !centre.x.is_finite() || !centre.y.is_finite() {
        est.status = EyeStatus::NotFinite;
        return est;
    }
    let Some(frame) = eye_frame(contour, eye, params, &mut est) else {
        return est;
    };
    let [u, v] = frame.uv(centre);
    if !point_in_polygon(&frame.poly, u, v) {
        est.status = EyeStatus::Implausible;
        return est;
    }
    est.centre = centre;
    est.u = u;
    est.v = v;
    est.confidence = (est.opening / (2.0 * params.min_opening.max(1e-9))).min(1.0);
    est.status = EyeStatus::Valid;
    est
}

/// An eye's own frame, from its six outline points (iBUG walk order): origin `o` at the
/// outer corner, unit axis `a` to the inner corner, unit normal `n` towards the upper lid,
/// the width `l` in pixels, and the outline in (u, v) = eye widths along (a, n), dilated
/// about its centroid by `mask_margin`.
struct EyeFrame {
    o: Point2<f64>,
    a: Vector2<f64>,
    n: Vector2<f64>,
    l: f64,
    poly: [[f64; 2]; 6],
}

impl EyeFrame {
    /// A point in the eye's (u, v).
    fn uv(&self, q: Point2<f64>) -> [f64; 2] {
        let d = q - self.o;
        [d.dot(&self.a) / self.l, d.dot(&self.n) / self.l]
    }
}

/// The validity rules both eye estimators share (`NotFinite`, `TooSmall`, `Closed`) and
/// the eye's frame; sets `est.width_px`, `est.opening` and, for an invalid eye,
/// `est.status` (then `None`).
fn eye_frame(pts: &[Point2<f64>; 6], eye: Eye, p: &IrisParams, est: &mut EyeEstimate) -> Option<EyeFrame> {
    if pts.iter().any(|q| !q.x.is_finite() || !q.y.is_finite()) {
        est.status = EyeStatus::NotFinite;
        return None;
    }
    let (o, i) = (pts[0], pts[3]);
    let axis = i - o;
    let l = axis.norm();
    est.width_px = l;
    if l.is_nan() || l < p.min_eye_width_px {
        est.status = EyeStatus::TooSmall;
        return None;
    }
    let a = axis / l;
    let n = match eye {
        Eye::Right => Vector2::new(-a.y, a.x),
        Eye::Left => Vector2::new(a.y, -a.x),
    };
    est.opening = facecap_core::landmarks::eye_aspect_ratio(pts);
    if est.opening < p.min_opening {
        est.status = EyeStatus::Closed;
        return None;
    }
    let mut frame = EyeFrame {
        o,
        a,
        n,
        l,
        poly: [[0.0; 2]; 6],
    };
    // the outline in (u, v), dilated about its centroid
    let mut poly = pts.map(|q| frame.uv(q));
    let cu = poly.iter().map(|q| q[0]).sum::<f64>() / 6.0;
    let cv = poly.iter().map(|q| q[1]).sum::<f64>() / 6.0;
    for q in &mut poly {
        let (du, dv) = (q[0] - cu, q[1] - cv);
        let r = (du * du + dv * dv).sqrt();
        if r > 0.0 {
            q[0] += du / r * p.mask_margin;
            q[1] += dv / r * p.mask_margin;
        }
    }
    frame.poly = poly;
    Some(frame)
}

/// ARKit names of the weights [`gaze_weights`] returns, in its order.
pub const GAZE_WEIGHT_NAMES: [&str; 8] = [
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeLookDownLeft",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeLookDownRight",
];

/// One eye's resting `(u, v)` (see [`EyeEstimate`]), e.g. the median over a clip of the
/// valid estimates ([`GazeRest::median_of`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EyeRest {
    /// Resting `u`.
    pub u: f64,
    /// Resting `v`.
    pub v: f64,
}

/// Per-subject resting gaze of both eyes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeRest {
    /// Subject's right eye.
    pub right: EyeRest,
    /// Subject's left eye.
    pub left: EyeRest,
}

impl GazeRest {
    /// Per eye the median `u` and `v` of the valid estimates; `None` when an eye has no
    /// valid estimate. Allocates (meant for a calibration pass, not per frame).
    pub fn median_of(frames: &[IrisFrame]) -> Option<GazeRest> {
        let med = |eye: Eye| -> Option<EyeRest> {
            let mut us: Vec<f64> = Vec::new();
            let mut vs: Vec<f64> = Vec::new();
            for f in frames.iter().map(|f| f.eye(eye)).filter(|e| e.valid()) {
                us.push(f.u);
                vs.push(f.v);
            }
            Some(EyeRest {
                u: median(&mut us)?,
                v: median(&mut vs)?,
            })
        };
        Some(GazeRest {
            right: med(Eye::Right)?,
            left: med(Eye::Left)?,
        })
    }
}

/// Where the iris centre rests across the eye when the eye looks straight ahead in the
/// head: `u` = 0.46 eye widths from the outer corner, a little outside the corners' midpoint.
/// Measured with the mesh front end on the five shared clips, whose subjects mostly face and
/// look at the camera: the median `u` of seven of the ten eyes lies 0.44-0.50 (the midpoint
/// is 0.5; liveportrait_d18's right eye 0.40, liveportrait_d6's eyes 0.55 and 0.61). The
/// clip median alone takes a subject who looks inwards all along (d6 converges: MediaPipe's
/// `eyeLookInRight` is 0.68 on average there) for a straight gaze (docs/gaze.md, "The
/// straight gaze").
pub const STRAIGHT_AHEAD_U: f64 = 0.46;

/// Share of the clip's own median `u` in the resting `u` of [`GazeRest::towards_straight_ahead`];
/// the rest is [`STRAIGHT_AHEAD_U`]. Any share 0-0.5 gave the same agreement with MediaPipe's
/// `eyeLookIn` / `eyeLookOut` on the shared clips (docs/gaze.md, "The straight gaze"); the
/// clip's own half keeps a subject's own eye shape and corner placement in the rest.
pub const REST_MEDIAN_SHARE: f64 = 0.5;

impl GazeRest {
    /// [`GazeRest::median_of`] with each eye's resting `u` moved towards the straight gaze:
    /// `REST_MEDIAN_SHARE · median + (1 - REST_MEDIAN_SHARE) · STRAIGHT_AHEAD_U`. `v` stays the
    /// median (the vertical rest depends on the lids' opening; a fixed `v` did not help).
    /// `None` as for [`GazeRest::median_of`].
    pub fn towards_straight_ahead(frames: &[IrisFrame]) -> Option<GazeRest> {
        let m = GazeRest::median_of(frames)?;
        let pull = |r: EyeRest| EyeRest {
            u: REST_MEDIAN_SHARE * r.u + (1.0 - REST_MEDIAN_SHARE) * STRAIGHT_AHEAD_U,
            v: r.v,
        };
        Some(GazeRest {
            right: pull(m.right),
            left: pull(m.left),
        })
    }
}

/// The median of `x` (the mean of the middle two for an even count; sorts `x`), as the
/// resting gaze takes it; `None` when `x` is empty.
pub fn median(x: &mut [f64]) -> Option<f64> {
    if x.is_empty() {
        return None;
    }
    x.sort_by(f64::total_cmp);
    let n = x.len();
    Some(if n % 2 == 1 {
        x[n / 2]
    } else {
        0.5 * (x[n / 2 - 1] + x[n / 2])
    })
}

/// Weight per unit offset of `u` / `v` from rest (weight = gain · offset, clamped to
/// [0, 1]). The defaults are fitted to MediaPipe FaceLandmarker's `eyeLook*` scores on the
/// shared clips (`docs/gaze.md`).
///
/// | name | default | meaning |
/// |---|---|---|
/// | `look_in` | 2.25 | `eyeLookIn` per unit of `+Δu` (towards the inner corner): 0.5 at 0.22 eye widths |
/// | `look_out` | 1.5 | `eyeLookOut` per unit of `-Δu`: 0.5 at 0.33 |
/// | `look_up` | 1.5 | `eyeLookUp` per unit of `-Δv`: 0.5 at 0.33 |
/// | `look_down` | 3.5 | `eyeLookDown` per unit of `+Δv`: 0.5 at 0.14 |
///
/// Each is the least-squares fit of `clamp(g · offset)` to MediaPipe's score minus its
/// clip median (clamped to [0, 1]), pooled over both eyes of the five shared clips
/// (4470 frames; `examples/gaze_eval.rs`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeGains {
    /// Gain towards the inner corner.
    pub look_in: f64,
    /// Gain towards the outer corner.
    pub look_out: f64,
    /// Gain upwards.
    pub look_up: f64,
    /// Gain downwards.
    pub look_down: f64,
}

impl Default for GazeGains {
    fn default() -> Self {
        GazeGains {
            look_in: 2.25,
            look_out: 1.5,
            look_up: 1.5,
            look_down: 3.5,
        }
    }
}

impl GazeGains {
    /// Every gain finite and >= 0.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the first bad gain.
    pub fn validate(&self) -> Result<()> {
        for (name, g) in [
            ("look_in", self.look_in),
            ("look_out", self.look_out),
            ("look_up", self.look_up),
            ("look_down", self.look_down),
        ] {
            check(name, g, g >= 0.0, "finite, >= 0")?;
        }
        Ok(())
    }
}

/// The eight ARKit gaze weights, in [`GAZE_WEIGHT_NAMES`] order, from one frame's
/// estimates and the subject's rest.
///
/// For both eyes `Δu = u - rest.u > 0` moves the iris towards the inner corner (nose):
/// `eyeLookIn = clamp(look_in · Δu)`, `eyeLookOut = clamp(-look_out · Δu)`; `Δv > 0` is
/// down: `eyeLookDown = clamp(look_down · Δv)`, `eyeLookUp = clamp(-look_up · Δv)`. So a
/// look towards the subject's left (image right) gives `eyeLookOutLeft` and
/// `eyeLookInRight`. When one eye is invalid it takes the other's offsets, mirrored in
/// `u` (the eyes move together); when both are, every weight is 0. Non-finite gains or
/// offsets give 0, never NaN.
pub fn gaze_weights(frame: &IrisFrame, rest: &GazeRest, gains: &GazeGains) -> [f64; 8] {
    gaze_weights_in_head(frame, rest, gains, HeadTurn::default())
}

/// Iris offset (eye widths) that a head rotation of one radian makes at a fixed line of
/// sight: the eyes keep looking where they looked, so in the head they turn the other
/// way. The iris centre lies about an eyeball radius ([`EYEBALL_RADIUS_EYE_WIDTHS`], 0.4)
/// in front of the eyeball's centre, the eye corners the offsets are measured from about
/// 0.15 eye widths; the difference, 0.25, is what the image shows of the eye's turn in
/// the head. Measured as the ratio of the head rotation's and the iris offset's
/// coefficients in a least-squares fit of MediaPipe's `eyeLook*` scores (eye-in-head by
/// ARKit's definition) on the five shared clips: 0.19-0.37 vertically, 0.23-0.29
/// horizontally on the clips with the widest head turns (docs/gaze.md, "Head turns").
pub const HEAD_TURN_EYE_WIDTHS: f64 = 0.25;

/// A head rotation away from the subject's resting one, against the line of sight to
/// the camera (radians): pitch positive chin down and yaw positive towards the subject's
/// right, as `pose.csv`'s `Rx` and `Ry`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HeadTurn {
    /// Pitch minus the resting pitch.
    pub pitch: f64,
    /// Yaw minus the resting yaw.
    pub yaw: f64,
}

/// [`gaze_weights`] of the eyes' rotation in the head: the iris offsets less what the
/// head's turn `head` away from its rest moves them by at a fixed line of sight
/// ([`HEAD_TURN_EYE_WIDTHS`] per radian; a head pitched down with the eyes on the camera
/// looks up in the head, as ARKit's `eyeLookUp` says). A non-finite `head` counts as no
/// turn.
pub fn gaze_weights_in_head(frame: &IrisFrame, rest: &GazeRest, gains: &GazeGains, head: HeadTurn) -> [f64; 8] {
    let (pitch, yaw) = if head.pitch.is_finite() && head.yaw.is_finite() {
        (head.pitch, head.yaw)
    } else {
        (0.0, 0.0)
    };
    let k = HEAD_TURN_EYE_WIDTHS;
    // `u` grows towards each eye's inner corner: a yaw moves both irises the same way in
    // the image, so towards one eye's inner corner and the other's outer one
    let offset = |e: &EyeEstimate, r: &EyeRest, side: f64| {
        e.valid().then_some((e.u - r.u - side * k * yaw, e.v - r.v - k * pitch))
    };
    let (ro, lo) = (
        offset(&frame.right, &rest.right, -1.0),
        offset(&frame.left, &rest.left, 1.0),
    );
    let (ro, lo) = match (ro, lo) {
        (Some(r), Some(l)) => (r, l),
        (Some(r), None) => (r, (-r.0, r.1)),
        (None, Some(l)) => ((-l.0, l.1), l),
        (None, None) => return [0.0; 8],
    };
    let clamp = |x: f64| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
    let eye = |(du, dv): (f64, f64)| {
        [
            clamp(gains.look_in * du),
            clamp(-gains.look_out * du),
            clamp(-gains.look_up * dv),
            clamp(gains.look_down * dv),
        ]
    };
    let (l, r) = (eye(lo), eye(ro));
    [l[0], l[1], l[2], l[3], r[0], r[1], r[2], r[3]]
}

/// Radius of the eyeball in eye widths (corner-to-corner distances): about 12 mm over an
/// eye about 30 mm wide. The iris centre of an eye turned by `theta` sits `R sin(theta)` from
/// where it rests, so an offset of `d` eye widths is a rotation of `asin(d / R)`.
pub const EYEBALL_RADIUS_EYE_WIDTHS: f64 = 0.4;

/// Largest eye rotation [`eye_rotations`] reports (50 degrees, about the human range of
/// eye movement away from straight ahead).
pub const MAX_EYE_ROTATION: f64 = 50.0 * std::f64::consts::PI / 180.0;

/// Eye rotations (radians) of the eight gaze weights in [`GAZE_WEIGHT_NAMES`] order, made
/// by [`gaze_weights`] with `gains`: `[[yaw, pitch]; 2]` for the Left then the Right eye.
///
/// Each weight is turned back into its iris offset (`weight / gain`, in eye widths) and that
/// into a rotation of an eyeball of radius [`EYEBALL_RADIUS_EYE_WIDTHS`], capped at
/// [`MAX_EYE_ROTATION`]. Signs follow the head rotation of `pose.csv` / `livelink.csv`:
/// **yaw > 0 turns the eye towards the subject's right** (image left: `eyeLookOutRight`,
/// `eyeLookInLeft`), **pitch > 0 turns it down** (`eyeLookDown`). Non-finite or negative
/// weights count as 0.
///
/// ```
/// use facecap_landmarks::gaze::{eye_rotations, GazeGains};
/// // both eyes look towards the subject's right and a little down
/// let g = GazeGains::default();
/// let w = [0.3, 0.0, 0.0, 0.2, 0.0, 0.2, 0.0, 0.2]; // In/Out/Up/Down Left, then Right
/// let [[ly, lp], [ry, rp]] = eye_rotations(&w, &g);
/// assert!(ly > 0.0 && ry > 0.0 && lp > 0.0 && (lp - rp).abs() < 1e-12);
/// assert_eq!(eye_rotations(&[0.0; 8], &g), [[0.0; 2]; 2]);
/// ```
pub fn eye_rotations(weights: &[f64; 8], gains: &GazeGains) -> [[f64; 2]; 2] {
    let angle = |w: f64, gain: f64| {
        if !(w.is_finite() && w > 0.0 && gain.is_finite() && gain > 0.0) {
            return 0.0;
        }
        (w / gain / EYEBALL_RADIUS_EYE_WIDTHS)
            .min(1.0)
            .asin()
            .min(MAX_EYE_ROTATION)
    };
    let eye = |w: &[f64]| {
        let (look_in, out, up, down) = (
            angle(w[0], gains.look_in),
            angle(w[1], gains.look_out),
            angle(w[2], gains.look_up),
            angle(w[3], gains.look_down),
        );
        (look_in - out, down - up)
    };
    // Left eye: In is towards the nose, i.e. the subject's right; Right eye: Out is.
    let (l_in_out, l_pitch) = eye(&weights[0..4]);
    let (r_in_out, r_pitch) = eye(&weights[4..8]);
    [[l_in_out, l_pitch], [-r_in_out, r_pitch]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The row-crossing mask of `estimate_eye` equals the point-in-polygon reference on
    /// seeded random (also non-convex, self-intersecting) hexagons.
    #[test]
    fn row_crossings_match_point_in_polygon() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut inside_count = 0;
        for _ in 0..500 {
            let poly: [[f64; 2]; 6] =
                std::array::from_fn(|_| [rng.random_range(-0.2..1.2), rng.random_range(-0.5..0.5)]);
            for _ in 0..40 {
                let v = rng.random_range(-0.6..0.6);
                let mut xs = [0.0; 6];
                let n = row_crossings(&poly, v, &mut xs);
                for _ in 0..10 {
                    let u = rng.random_range(-0.3..1.3);
                    let fast = xs[..n].iter().filter(|&&x| u < x).count() % 2 == 1;
                    assert_eq!(fast, point_in_polygon(&poly, u, v), "{poly:?} {u} {v}");
                    inside_count += usize::from(fast);
                }
            }
        }
        assert!(inside_count > 10_000, "{inside_count}");
    }

    /// `eye_from_centre` puts a centre at known `(u, v)` of a drawn eye back at them, for
    /// both eyes and any roll, and reports closed, tiny, non-finite and outside eyes.
    #[test]
    fn eye_from_centre_recovers_known_offsets() {
        let p = IrisParams::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..200 {
            let eye = if rng.random::<bool>() { Eye::Right } else { Eye::Left };
            let roll: f64 = rng.random_range(-0.5..0.5);
            let l: f64 = rng.random_range(10.0..80.0);
            let o = Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0));
            let sign = if eye == Eye::Right { 1.0 } else { -1.0 };
            let a = Vector2::new(sign * roll.cos(), sign * roll.sin());
            let n = match eye {
                Eye::Right => Vector2::new(-a.y, a.x),
                Eye::Left => Vector2::new(a.y, -a.x),
            };
            let at = |u: f64, v: f64| o + (a * u + n * v) * l;
            // almond eye: lids at v = -0.15 / +0.15 at a third and two thirds of the way
            let contour = [
                at(0.0, 0.0),
                at(0.33, -0.15),
                at(0.66, -0.15),
                at(1.0, 0.0),
                at(0.66, 0.15),
                at(0.33, 0.15),
            ];
            let (u, v) = (rng.random_range(0.3..0.7), rng.random_range(-0.08..0.08));
            let e = eye_from_centre(&contour, at(u, v), eye, &p);
            assert!(e.valid(), "{e:?}");
            assert!((e.u - u).abs() < 1e-9 && (e.v - v).abs() < 1e-9, "{e:?} vs {u} {v}");
            assert!((e.opening - 0.3).abs() < 1e-9 && (e.width_px - l).abs() < 1e-9);
            assert!(e.confidence > 0.0 && e.confidence <= 1.0);
            // outside the lids
            assert_eq!(
                eye_from_centre(&contour, at(0.5, 0.4), eye, &p).status,
                EyeStatus::Implausible
            );
            // closed
            let shut = [
                at(0.0, 0.0),
                at(0.33, -0.02),
                at(0.66, -0.02),
                at(1.0, 0.0),
                at(0.66, 0.02),
                at(0.33, 0.02),
            ];
            assert_eq!(eye_from_centre(&shut, at(0.5, 0.0), eye, &p).status, EyeStatus::Closed);
        }
        let tiny = [Point2::new(0.0, 0.0); 6];
        assert_eq!(
            eye_from_centre(&tiny, Point2::new(0.0, 0.0), Eye::Right, &p).status,
            EyeStatus::TooSmall
        );
        let mut bad = [
            Point2::new(0.0, 0.0),
            Point2::new(3.0, -2.0),
            Point2::new(6.0, -2.0),
            Point2::new(10.0, 0.0),
            Point2::new(6.0, 2.0),
            Point2::new(3.0, 2.0),
        ];
        assert_eq!(
            eye_from_centre(&bad, Point2::new(f64::NAN, 0.0), Eye::Right, &p).status,
            EyeStatus::NotFinite
        );
        bad[2].x = f64::INFINITY;
        assert_eq!(
            eye_from_centre(&bad, Point2::new(5.0, 0.0), Eye::Right, &p).status,
            EyeStatus::NotFinite
        );
    }

    #[test]
    fn select_is_the_nearest_rank_quantile() {
        let mut v: Vec<f32> = (0..101).rev().map(|x| x as f32).collect();
        assert_eq!(select(&mut v, 0.05), 5.0);
        assert_eq!(select(&mut v, 0.95), 95.0);
        assert_eq!(select(&mut v, 1.0), 100.0);
        assert_eq!(select(&mut v, 0.0), 0.0);
    }

    #[test]
    fn bilinear_interpolates_and_rejects_outside() {
        let img = [0u8, 100, 50, 150];
        assert_eq!(bilinear(&img, 2, 2, 0.5, 0.5), Some(75.0));
        assert_eq!(bilinear(&img, 2, 2, 1.0, 1.0), Some(150.0));
        assert_eq!(bilinear(&img, 2, 2, 0.25, 0.0), Some(25.0));
        assert_eq!(bilinear(&img, 2, 2, -0.01, 0.0), None);
        assert_eq!(bilinear(&img, 2, 2, 1.01, 0.0), None);
        assert_eq!(bilinear(&img, 2, 2, f64::NAN, 0.0), None);
        assert_eq!(bilinear(&[], 0, 0, 0.0, 0.0), None);
    }
}
