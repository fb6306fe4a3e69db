//! Face detection with dlib's frontal face detector (HOG features + linear SVM),
//! reimplemented in pure Rust and matching dlib's output.
//!
//! # What it computes
//!
//! dlib's `get_frontal_face_detector()` is an `object_detector<scan_fhog_pyramid<
//! pyramid_down<6>>>` with 5 sub-detectors (front, left, right, front rotated left and
//! right), each a linear SVM over 31-dimensional fHOG features (Felzenszwalb et al.,
//! TPAMI 2010; Dalal & Triggs, CVPR 2005) in an 80 x 80 pixel window (10 x 10 cells
//! of 8 pixels). For an image `I`:
//!
//! 1. (optional) up-sample `upsample` times by 2 (dlib's `pyramid_up`, bilinear);
//! 2. image pyramid `I_0 = I`, `I_{l+1} = down_{5/6}(I_l)` (dlib `pyramid_down<6>`,
//!    bit-exact bilinear resize) while the next level is at least 64 x 64 pixels;
//! 3. fHOG of every level ([`fhog`], bit-exact);
//! 4. for each sub-detector `d` and level `l`, the window score
//!    `s = <w_d, fhog window>` ([`scan`]; separable SVD approximation of the filters
//!    exactly as dlib builds it); candidates are windows with
//!    `s >= b_d + adjust_threshold`, confidence `s - b_d`;
//! 5. the window's rectangle in the input image: the 10 x 10 cell window centred at
//!    cell `(r, c)` is mapped by dlib's `fhog_to_image` then `rect_up` through `l`
//!    pyramid levels (`p -> 1.2 p + 0.3` per level) and rounded;
//! 6. greedy non-maximum suppression in order of decreasing confidence: a candidate
//!    is dropped when it overlaps an accepted box, i.e. `|A ∩ B| / |bbox(A ∪ B)| >
//!    0.330` or `|A ∩ B| / |A| > 0.789` or `|A ∩ B| / |B| > 0.789` (the thresholds
//!    are read from the model file);
//! 7. boxes found on an up-sampled image map back with `p -> p / 2 - (1.25, 0.75)`.
//!
//! Output boxes are in 0-based pixel coordinates of the input (centre of the top-left
//! pixel is `(0, 0)`); [`Detection::rect`] is `Rect::from_dlib(l, t, r, b)` of dlib's
//! inclusive rectangle, so `rect.to_dlib()` returns dlib's numbers. The result is
//! sorted largest box first (ties: higher score first).
//!
//! # Where we depart from dlib
//!
//! * Greyscale input only (dlib also accepts RGB and then takes the per-pixel colour
//!   channel with the strongest gradient; convert to grey first).
//! * No allocation per frame after the first frame of a given size (dlib allocates
//!   its pyramids and feature images on every call); orientation bins come from a
//!   precomputed 511 x 511 table; levels can run in parallel ([`Par::Rayon`]) with
//!   identical results.
//! * [`DetectorParams::min_size`] drops final boxes smaller than a side length
//!   (dlib has no such option; default 0 keeps everything).
//!
//! # Parameters
//!
//! | name | default | meaning | range |
//! |---|---|---|---|
//! | `upsample` | `Times(0)` | `Times(n)`: the image is doubled n times before detection (dlib's `detector(img, n)`); `Auto`: dlib's `detector(img, 1)` with the finest levels scanned only when needed ([`Upsample`]) | `Times(0..=4)`, `Auto` |
//! | `adjust_threshold` | 0.0 | added to every sub-detector threshold (negative finds more) | finite |
//! | `min_size` | 0 | smallest accepted box side in input pixels | any |
//! | `par` | `Par::Seq` | run pyramid levels sequentially or on the rayon pool | |
//!
//! # Example
//!
//! ```no_run
//! use facecap_landmarks::detect::{FaceDetector, DetectorParams, Upsample};
//! # fn main() -> facecap_landmarks::Result<()> {
//! let detector = FaceDetector::default_model()?.with_params(DetectorParams { upsample: Upsample::Auto, ..Default::default() })?;
//! let mut ws = detector.new_workspace();
//! let img = image::GrayImage::new(640, 480);
//! let faces = detector.detect(&img, &mut ws)?;
//! assert!(faces.is_empty());
//! # Ok(()) }
//! ```
//!
//! The model file is `dlib_frontal_face_detector.svm`, written by
//! `scripts/export_dlib_hog.py` (dlib-bin from PyPI) into the model folder; see
//! `docs/detection.md`.

// Index loops below mirror dlib's loops one to one (bit-exact emulation), so they stay.
#![allow(clippy::needless_range_loop)]

pub mod fhog;
pub mod model;
pub mod pyramid;
pub mod scan;

use std::path::Path;

use facecap_core::landmarks::Rect;
use image::GrayImage;
use rayon::prelude::*;

use crate::error::{Error, Result};
pub use model::HogModel;
use pyramid::{DRect, Gray, GrayView};
use scan::FilterBank;

/// File name of the exported dlib frontal face detector in the model folder.
pub const DLIB_FRONTAL_MODEL: &str = "dlib_frontal_face_detector.svm";

/// Largest accepted `upsample` (each step quadruples the pixel count).
pub const MAX_UPSAMPLE: u32 = 4;

/// How to run the per-level work.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Par {
    /// On the calling thread.
    #[default]
    Seq,
    /// Pyramid levels on rayon's global pool (results identical to `Seq`).
    Rayon,
}

/// How often the image is doubled before detection.
///
/// `Times(n)` is dlib's `detector(img, n)` exactly. `Auto` gives what dlib's examples
/// get with `detector(img, 1)` at a cost close to `Times(0)` on large images:
///
/// * the image is doubled once and the pyramid of the doubled image is built exactly
///   as dlib builds it;
/// * the finest levels, whose 80 x 80 detection window covers less than
///   [`AUTO_MIN_FACE_FRACTION`] of the input's shorter side (and less than
///   [`AUTO_ALWAYS_FACE_SIDE`] pixels), are skipped at first: on a 375-pixel-high
///   photo every level is scanned (faces from 40 px), on a 480-pixel frame the finest
///   one is skipped (faces from 48 px), from about 700 px up the four finest (faces
///   from 83 px, about what `Times(0)` finds; those four levels hold 77 % of the
///   doubled pyramid's pixels);
/// * when the scanned levels find no face, the skipped levels are scanned too and the
///   result is exactly dlib's `detector(img, 1)`.
///
/// Every box `Auto` returns is one of the boxes dlib's `detector(img, 1)` reports
/// unless a skipped small box would have suppressed it (dlib's overlap rule also drops
/// a larger box that mostly covers a higher-scoring small one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Upsample {
    /// Double the image this many times (0..=[`MAX_UPSAMPLE`]), as dlib does.
    Times(u32),
    /// The automatic rule above.
    Auto,
}

/// `Upsample::Auto` scans a level of the doubled pyramid first when its detection
/// window is at least this fraction of the input's shorter side ...
pub const AUTO_MIN_FACE_FRACTION: f64 = 0.1;

/// ... or at least this many input pixels (the smallest face `Times(0)` can find).
pub const AUTO_ALWAYS_FACE_SIDE: f64 = 80.0;

impl std::fmt::Display for Upsample {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Upsample::Times(n) => write!(f, "{n}"),
            Upsample::Auto => f.write_str("auto"),
        }
    }
}

impl std::str::FromStr for Upsample {
    type Err = Error;

    /// `"auto"` or a whole number `0..=MAX_UPSAMPLE`.
    fn from_str(s: &str) -> Result<Self> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("auto") {
            return Ok(Upsample::Auto);
        }
        let bad = || Error::InvalidParameter {
            name: "upsample",
            value: s.to_string(),
            expected: format!("auto or 0..={MAX_UPSAMPLE}"),
        };
        let n: u32 = t.parse().map_err(|_| bad())?;
        if n > MAX_UPSAMPLE {
            return Err(bad());
        }
        Ok(Upsample::Times(n))
    }
}

/// Detection parameters (see the module table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorParams {
    /// 2x up-samplings before detection (dlib's second argument), or the automatic rule.
    pub upsample: Upsample,
    /// Added to each sub-detector threshold; 0 reproduces dlib's default.
    pub adjust_threshold: f64,
    /// Boxes with a side shorter than this many input pixels are dropped.
    pub min_size: u32,
    /// Sequential or rayon-parallel over pyramid levels.
    pub par: Par,
}

impl Default for DetectorParams {
    /// dlib's own default, `detector(img)` = `detector(img, 0)`; the `facecap` commands
    /// use [`Upsample::Auto`] unless told otherwise.
    fn default() -> Self {
        DetectorParams {
            upsample: Upsample::Times(0),
            adjust_threshold: 0.0,
            min_size: 0,
            par: Par::Seq,
        }
    }
}

impl DetectorParams {
    /// Checks ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming `upsample` or `adjust_threshold`.
    pub fn validate(&self) -> Result<()> {
        if let Upsample::Times(n) = self.upsample {
            if n > MAX_UPSAMPLE {
                return Err(Error::InvalidParameter {
                    name: "upsample",
                    value: n.to_string(),
                    expected: format!("0..={MAX_UPSAMPLE} or auto"),
                });
            }
        }
        if !self.adjust_threshold.is_finite() {
            return Err(Error::InvalidParameter {
                name: "adjust_threshold",
                value: self.adjust_threshold.to_string(),
                expected: "a finite number".into(),
            });
        }
        Ok(())
    }
}

/// One detected face.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// The face box (0-based pixels; `rect.to_dlib()` gives dlib's rectangle).
    pub rect: Rect,
    /// dlib's detection confidence: window score minus the sub-detector threshold.
    pub score: f64,
}

/// A candidate window before non-max suppression.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    score: f64,
    detector: usize,
    rect: DRect,
}

/// Per-level buffers.
#[derive(Debug, Clone, Default)]
struct LevelWs {
    feats: fhog::FhogImage,
    fscratch: fhog::FhogScratch,
    sscratch: scan::ScanScratch,
    hits: Vec<scan::Hit>,
    cands: Vec<Candidate>,
}

/// Reusable memory of [`FaceDetector::detect`]: image pyramid, feature images,
/// score images, candidate lists. Create with [`FaceDetector::new_workspace`]; after
/// the first frame of a given size no further allocation happens.
#[derive(Debug, Clone, Default)]
pub struct DetectWorkspace {
    up: [Gray; 2],
    pyr: Vec<Gray>,
    resize: pyramid::ResizeScratch,
    levels: Vec<LevelWs>,
    all: Vec<Candidate>,
    kept: Vec<Candidate>,
}

/// dlib's frontal HOG face detector (or any `scan_fhog_pyramid<pyramid_down<6>>`
/// detector file). Immutable, `Send + Sync`.
#[derive(Debug, Clone)]
pub struct FaceDetector {
    model: HogModel,
    banks: Vec<FilterBank>,
    table: fhog::BinTable,
    params: DetectorParams,
}

impl FaceDetector {
    /// Builds a detector from a parsed model.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for bad `params`.
    pub fn new(model: HogModel, params: DetectorParams) -> Result<Self> {
        params.validate()?;
        let banks = model
            .weights
            .iter()
            .map(|w| FilterBank::new(w, model.fhog_window_width, model.fhog_window_height))
            .collect();
        Ok(FaceDetector {
            model,
            banks,
            table: fhog::BinTable::new(),
            params,
        })
    }

    /// Loads a detector file written by `scripts/export_dlib_hog.py` (dlib's
    /// `fhog_object_detector.save`), with default parameters.
    ///
    /// # Errors
    /// I/O errors and [`Error::Model`] for malformed files.
    pub fn from_file(path: &Path) -> Result<Self> {
        // A file scripts/setup.sh installed (or a copy of it) must match its checksum.
        facecap_core::checksum::verify_model_file(path, None)?;
        Self::new(HogModel::from_file(path)?, DetectorParams::default())
    }

    /// Loads [`DLIB_FRONTAL_MODEL`] from `facecap_core::paths::model_dir()`.
    ///
    /// # Errors
    /// [`Error::Model`] telling to run `scripts/setup.sh` when the file is missing.
    pub fn default_model() -> Result<Self> {
        let dir = facecap_core::paths::model_dir().ok_or_else(|| Error::Model {
            path: DLIB_FRONTAL_MODEL.into(),
            reason: "no model folder known (set FACECAP_MODELS or HOME), then run scripts/setup.sh".into(),
        })?;
        let path = dir.join(DLIB_FRONTAL_MODEL);
        if !path.is_file() {
            return Err(Error::Model {
                path,
                reason: "face detector model not found: run scripts/setup.sh (it exports dlib's frontal \
                         face detector with scripts/export_dlib_hog.py)"
                    .into(),
            });
        }
        Self::from_file(&path)
    }

    /// The same detector with other parameters.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for bad `params`.
    pub fn with_params(mut self, params: DetectorParams) -> Result<Self> {
        params.validate()?;
        self.params = params;
        Ok(self)
    }

    /// The same detector with another [`Upsample`] rule (other parameters kept).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for `Upsample::Times(n)` with `n > MAX_UPSAMPLE`.
    pub fn with_upsample(self, upsample: Upsample) -> Result<Self> {
        let params = DetectorParams {
            upsample,
            ..self.params
        };
        self.with_params(params)
    }

    /// Current parameters.
    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    /// The parsed model.
    pub fn model(&self) -> &HogModel {
        &self.model
    }

    /// Number of sub-detectors (5 for dlib's frontal detector).
    pub fn num_sub_detectors(&self) -> usize {
        self.banks.len()
    }

    /// Number of rank-1 filter terms per sub-detector.
    pub fn separable_terms(&self) -> Vec<usize> {
        self.banks.iter().map(|b| b.terms.len()).collect()
    }

    /// A fresh workspace.
    pub fn new_workspace(&self) -> DetectWorkspace {
        DetectWorkspace::default()
    }

    /// Detects faces; see [`FaceDetector::detect_into`].
    ///
    /// # Errors
    /// As [`FaceDetector::detect_into`].
    pub fn detect(&self, img: &GrayImage, ws: &mut DetectWorkspace) -> Result<Vec<Detection>> {
        let mut out = Vec::new();
        self.detect_into(img, ws, &mut out)?;
        Ok(out)
    }

    /// Detects faces in a greyscale image into `out` (cleared first), largest box
    /// first. A frame without faces gives an empty list.
    ///
    /// # Errors
    /// None for valid images today; the `Result` is kept for future checks.
    pub fn detect_into(&self, img: &GrayImage, ws: &mut DetectWorkspace, out: &mut Vec<Detection>) -> Result<()> {
        let view = GrayView {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.as_raw(),
        };
        self.detect_view(view, ws, out)
    }

    fn detect_view(&self, input: GrayView<'_>, ws: &mut DetectWorkspace, out: &mut Vec<Detection>) -> Result<()> {
        out.clear();
        if input.width == 0 || input.height == 0 {
            return Ok(());
        }
        let p = self.params;
        let times = match p.upsample {
            Upsample::Times(n) => n,
            Upsample::Auto => 1,
        };
        // 1. up-sampling
        let base: GrayView<'_> = if times == 0 {
            input
        } else {
            let [a, b] = &mut ws.up;
            pyramid::up2_with(input, a, &mut ws.resize);
            for _ in 1..times {
                pyramid::up2_with(a.view(), b, &mut ws.resize);
                std::mem::swap(a, b);
            }
            ws.up[0].view()
        };
        // 2. number of levels, as dlib's create_fhog_pyramid
        let m = &self.model;
        let mut levels = 0usize;
        let mut rect = DRect {
            l: 0,
            t: 0,
            r: base.width as i64 - 1,
            b: base.height as i64 - 1,
        };
        loop {
            rect = pyramid::rect_down6(rect);
            levels += 1;
            if !(rect.width() >= m.min_pyramid_layer_width as i64
                && rect.height() >= m.min_pyramid_layer_height as i64
                && levels < m.max_pyramid_levels)
            {
                break;
            }
        }
        if ws.pyr.len() < levels {
            ws.pyr.resize_with(levels, Gray::default);
        }
        if ws.levels.len() < levels {
            ws.levels.resize_with(levels, LevelWs::default);
        }
        for l in 1..levels {
            let (prev, rest) = ws.pyr.split_at_mut(l);
            let src = if l == 1 { base } else { prev[l - 1].view() };
            pyramid::down6_with(src, &mut rest[0], &mut ws.resize);
        }
        // the levels scanned first (all of them unless `Auto` skips the finest)
        let first = match p.upsample {
            Upsample::Times(_) => 0,
            Upsample::Auto => self.auto_first_level(input.width, input.height).min(levels),
        };
        // 3-6. features, scores, candidates per level; merge and suppress
        for lw in &mut ws.levels[..first] {
            lw.cands.clear();
        }
        self.scan_levels(base, first, levels, &ws.pyr, &mut ws.levels);
        self.suppress(&ws.levels[..levels], &mut ws.all, &mut ws.kept);
        if first > 0 && ws.kept.is_empty() {
            // `Auto` found nothing: the skipped levels too, giving dlib's `detector(img, 1)`
            self.scan_levels(base, 0, first, &ws.pyr, &mut ws.levels);
            self.suppress(&ws.levels[..levels], &mut ws.all, &mut ws.kept);
        }
        // 7. back to input coordinates, size filter, largest first
        for c in &ws.kept {
            let r = if times > 0 {
                pyramid::rect_down2(c.rect, times)
            } else {
                c.rect
            };
            if r.width() < i64::from(p.min_size) || r.height() < i64::from(p.min_size) {
                continue;
            }
            out.push(Detection {
                rect: Rect::from_dlib(r.l, r.t, r.r, r.b),
                score: c.score,
            });
        }
        out.sort_by(|a, b| {
            b.rect
                .area()
                .total_cmp(&a.rect.area())
                .then(b.score.total_cmp(&a.score))
        });
        Ok(())
    }

    /// First level of the once-doubled pyramid that [`Upsample::Auto`] scans: the
    /// finest level whose detection window, in input pixels, is at least
    /// `min(AUTO_ALWAYS_FACE_SIDE, AUTO_MIN_FACE_FRACTION * shorter side)`.
    fn auto_first_level(&self, width: usize, height: usize) -> usize {
        let m = &self.model;
        let window = ((m.fhog_window_width - 2 * m.padding) * m.cell_size) as f64;
        let shorter = width.min(height) as f64;
        let wanted = (AUTO_MIN_FACE_FRACTION * shorter).min(AUTO_ALWAYS_FACE_SIDE);
        // window side in input pixels at level k: window / 2 * (6/5)^k
        let mut side = window / 2.0;
        let mut k = 0usize;
        while side < wanted && k < m.max_pyramid_levels {
            side *= 1.2;
            k += 1;
        }
        k
    }

    /// Features, scores and candidates of levels `from..to` (each level's list is
    /// replaced); levels outside the range keep their lists.
    fn scan_levels(&self, base: GrayView<'_>, from: usize, to: usize, pyr: &[Gray], levels: &mut [LevelWs]) {
        let work = |(i, lw): (usize, &mut LevelWs)| {
            let l = from + i;
            let img = if l == 0 { base } else { pyr[l].view() };
            self.process_level(l, img, lw);
        };
        match self.params.par {
            Par::Seq => levels[from..to].iter_mut().enumerate().for_each(work),
            Par::Rayon => levels[from..to].par_iter_mut().enumerate().for_each(work),
        }
    }

    /// Merges the candidates of `levels` in dlib's order (sub-detector, then level)
    /// into `all` and applies dlib's non-maximum suppression into `kept`.
    fn suppress(&self, levels: &[LevelWs], all: &mut Vec<Candidate>, kept: &mut Vec<Candidate>) {
        let m = &self.model;
        all.clear();
        for d in 0..self.banks.len() {
            for lw in levels {
                all.extend(lw.cands.iter().filter(|c| c.detector == d));
            }
        }
        all.sort_by(|a, b| b.score.total_cmp(&a.score));
        kept.clear();
        let (iou, pc) = (m.overlap_iou_thresh, m.overlap_percent_covered_thresh);
        for c in all.iter() {
            if kept.iter().any(|k| boxes_overlap(&k.rect, &c.rect, iou, pc)) {
                continue;
            }
            kept.push(*c);
        }
    }

    fn process_level(&self, level: usize, img: GrayView<'_>, lw: &mut LevelWs) {
        let m = &self.model;
        let (fw, fh) = (m.fhog_window_width, m.fhog_window_height);
        lw.cands.clear();
        fhog::extract(
            img.data,
            img.width,
            img.height,
            m.cell_size,
            fw,
            fh,
            &self.table,
            &mut lw.fscratch,
            &mut lw.feats,
        );
        if lw.feats.width == 0 {
            return;
        }
        let det_w = (fw - 2 * m.padding) as i64;
        let det_h = (fh - 2 * m.padding) as i64;
        for (d, bank) in self.banks.iter().enumerate() {
            let thresh = bank.threshold + self.params.adjust_threshold;
            lw.hits.clear();
            if scan::candidates(bank, &lw.feats, thresh, &mut lw.sscratch, &mut lw.hits).is_none() {
                continue;
            }
            let start = lw.cands.len();
            for hit in &lw.hits {
                let rect = window_rect(hit.c as i64, hit.r as i64, det_w, det_h, m.cell_size as i64, fw, fh);
                lw.cands.push(Candidate {
                    score: f64::from(hit.score) - bank.threshold,
                    detector: d,
                    rect: pyramid::rect_up6(rect, level),
                });
            }
            // dlib sorts each sub-detector's list by score before merging
            lw.cands[start..].sort_by(|a, b| b.score.total_cmp(&a.score));
        }
    }
}

/// The image rectangle of the detection window centred at fHOG cell `(c, r)`:
/// dlib's `fhog_to_image(centered_rect(point(c, r), det_w, det_h))`.
fn window_rect(c: i64, r: i64, det_w: i64, det_h: i64, cell: i64, fw: usize, fh: usize) -> DRect {
    let l = c - det_w / 2;
    let t = r - det_h / 2;
    let rr = l + det_w - 1;
    let b = t + det_h - 1;
    let (l, t) = fhog_to_image(l, t, cell, fw, fh);
    let (rr, b) = fhog_to_image(rr, b, cell, fw, fh);
    DRect { l, t, r: rr, b }
}

/// dlib's `fhog_to_image(point, cell_size, filter_rows_padding, filter_cols_padding)`.
pub(crate) fn fhog_to_image(x: i64, y: i64, cell: i64, fw: usize, fh: usize) -> (i64, i64) {
    let px = (x + 1 - (fw as i64 - 1) / 2) * cell + 1;
    let py = (y + 1 - (fh as i64 - 1) / 2) * cell + 1;
    let half = cell / 2;
    let ox = if px >= 0 { half } else { -half };
    let oy = if py >= 0 { half } else { -half };
    (px + ox, py + oy)
}

/// dlib's `test_box_overlap` on inclusive integer rectangles.
fn boxes_overlap(a: &DRect, b: &DRect, iou_thresh: f64, covered_thresh: f64) -> bool {
    let inner = a.intersect(b).area() as f64;
    if inner == 0.0 {
        return false;
    }
    let outer = a.union_box(b).area() as f64;
    inner / outer > iou_thresh || inner / a.area() as f64 > covered_thresh || inner / b.area() as f64 > covered_thresh
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fhog_to_image_matches_dlib_quadrants() {
        // (0,0) with 10x10 padding: (0 + 1 - 4) * 8 + 1 = -23 -> -23 - 4
        assert_eq!(fhog_to_image(0, 0, 8, 10, 10), (-27, -27));
        assert_eq!(fhog_to_image(5, 5, 8, 10, 10), (17 + 4, 17 + 4));
    }

    #[test]
    fn overlap_uses_bounding_box_union() {
        let a = DRect { l: 0, t: 0, r: 9, b: 9 };
        let b = DRect {
            l: 5,
            t: 0,
            r: 14,
            b: 9,
        };
        // inner 50, bbox 150 -> 0.333 > 0.330
        assert!(boxes_overlap(&a, &b, 0.330, 0.789));
        assert!(!boxes_overlap(&a, &b, 0.34, 0.789));
    }

    #[test]
    fn upsample_parses_and_prints() {
        assert_eq!("auto".parse::<Upsample>().unwrap(), Upsample::Auto);
        assert_eq!(" 2 ".parse::<Upsample>().unwrap(), Upsample::Times(2));
        for bad in ["5", "-1", "x", "", "1.5"] {
            let e = bad.parse::<Upsample>().unwrap_err().to_string();
            assert!(e.contains("upsample"), "{bad}: {e}");
        }
        for u in [Upsample::Auto, Upsample::Times(0), Upsample::Times(4)] {
            assert_eq!(u.to_string().parse::<Upsample>().unwrap(), u);
        }
    }

    #[test]
    fn params_are_validated() {
        let bad = DetectorParams {
            upsample: Upsample::Times(9),
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        let bad = DetectorParams {
            adjust_threshold: f64::NAN,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
    }
}
