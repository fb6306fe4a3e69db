//! BlazeFace short-range face detection, decoded as MediaPipe's face detector graph does
//! (`face_detector_graph.cc` with `SsdAnchorsCalculator`, `TensorsToDetectionsCalculator`,
//! weighted `NonMaxSuppressionCalculator` and `DetectionProjectionCalculator`).
//!
//! 1. The whole image, padded to a square (zero border, aspect kept), is sampled to the
//!    128 x 128 input with values in [-1, 1] (see [`crate::roi`]).
//! 2. 896 anchors: a 16 x 16 grid (stride 8) with 2 anchors per cell and an 8 x 8 grid
//!    (strides 16, three layers) with 6 per cell; centres `((x + 0.5) / fw, (y + 0.5) / fh)`,
//!    fixed size 1.
//! 3. Per anchor: score `sigmoid(clamp(logit, -100, 100))`, kept when `>= min_score`;
//!    box centre `raw[0..2] / 128 + anchor`, size `raw[2..4] / 128`, six keypoints
//!    `raw[4 + 2k..] / 128 + anchor` (right eye, left eye, nose tip, mouth, right ear,
//!    left ear; "right" as seen by the subject).
//! 4. Weighted NMS: the best remaining detection absorbs every detection whose IoU with it
//!    exceeds `min_suppression` (itself included); box corners and keypoints become the
//!    score-weighted means, the score stays the best one's.
//! 5. Tensor coordinates are mapped back to normalised image coordinates.

use crate::roi::{Affine, BilinearTable, Border, NormRect, RgbView, ValueMap};
use crate::tflite::{Interpreter, Workspace};
use crate::{Error, Result};

/// Detector input size.
pub const DETECTOR_INPUT: usize = 128;
/// The least score a detection of [`FaceDetector::detect_small_into`] keeps (or
/// `min_score`, if higher). The search looks at the image 16 times instead of once, so a
/// face-like pattern is more often seen: on two group photos of dlib's face data set the
/// 13 annotated faces scored 0.84-0.98 and the only other detections (on a guitar)
/// 0.52-0.54 (`tests/small_faces.rs`).
pub const SMALL_FACE_MIN_SCORE: f32 = 0.75;
/// Number of anchors of the short-range model.
pub const NUM_ANCHORS: usize = 896;
/// Values per anchor in the regressor output (box 4 + 6 keypoints x 2).
pub const NUM_COORDS: usize = 16;
/// Keypoints per detection.
pub const NUM_KEYPOINTS: usize = 6;
/// `score_clipping_thresh` of MediaPipe's options.
const SCORE_CLIP: f32 = 100.0;
/// Anchor layout: (feature map size, anchors per cell).
const ANCHOR_GRIDS: [(usize, usize); 2] = [(16, 2), (8, 6)];

/// One detected face in normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Detection {
    /// Confidence in [0, 1].
    pub score: f32,
    /// Left edge (fraction of image width).
    pub xmin: f32,
    /// Top edge (fraction of image height).
    pub ymin: f32,
    /// Width (fraction of image width).
    pub width: f32,
    /// Height (fraction of image height).
    pub height: f32,
    /// Keypoints (x, y), normalised: right eye, left eye, nose tip, mouth centre,
    /// right ear tragion, left ear tragion ("right" of the subject).
    pub keypoints: [[f32; 2]; NUM_KEYPOINTS],
}

impl Detection {
    fn iou(&self, o: &Detection) -> f32 {
        let ix = (self.xmin + self.width).min(o.xmin + o.width) - self.xmin.max(o.xmin);
        let iy = (self.ymin + self.height).min(o.ymin + o.height) - self.ymin.max(o.ymin);
        if ix <= 0.0 || iy <= 0.0 {
            return 0.0;
        }
        let inter = ix * iy;
        let union = self.width * self.height + o.width * o.height - inter;
        if union > 0.0 {
            inter / union
        } else {
            0.0
        }
    }

    /// The landmark region MediaPipe derives from a detection: the box, rotated so the
    /// eye keypoints are level, scaled by `scale` (1.5 in MediaPipe's graph; not made
    /// square). `w`, `h`: image size in pixels (the rotation is measured in pixels).
    pub fn to_rect(&self, w: usize, h: usize, scale: f32) -> NormRect {
        let [r, l] = [self.keypoints[0], self.keypoints[1]];
        let rotation =
            crate::roi::rotation_from([r[0] * w as f32, r[1] * h as f32], [l[0] * w as f32, l[1] * h as f32]);
        NormRect {
            x_center: self.xmin + self.width / 2.0,
            y_center: self.ymin + self.height / 2.0,
            width: self.width * scale,
            height: self.height * scale,
            rotation,
        }
    }
}

/// A square region of the image the detector samples to its input, in pixels (the
/// project's convention: centre of the top-left pixel = (0, 0)); parts outside the image
/// read as 0, MediaPipe's letterbox.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Centre x.
    pub cx: f32,
    /// Centre y.
    pub cy: f32,
    /// Side length.
    pub side: f32,
}

impl Window {
    /// The whole `w x h` image padded to a square around its centre (MediaPipe's input).
    pub fn whole(w: usize, h: usize) -> Window {
        Window {
            cx: w as f32 / 2.0,
            cy: h as f32 / 2.0,
            side: w.max(h) as f32,
        }
    }

    /// The windows of [`FaceDetector::detect_small_into`]: side a third of the long side,
    /// placed evenly along each axis at most two thirds of a side apart, first and last
    /// flush with the image's edges (one centred window where the image is narrower).
    pub fn tiles(w: usize, h: usize) -> impl Iterator<Item = Window> {
        let side = w.max(h) as f32 / 3.0;
        let along = move |len: f32| {
            let room = len - side;
            let steps = if room > 0.0 {
                (room / (side * 2.0 / 3.0)).ceil().max(1.0) as usize
            } else {
                0
            };
            (0..=steps).map(move |i| {
                if steps == 0 {
                    len / 2.0
                } else {
                    side / 2.0 + room * i as f32 / steps as f32
                }
            })
        };
        along(h as f32).flat_map(move |cy| along(w as f32).map(move |cx| Window { cx, cy, side }))
    }
}

/// Detector settings.
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `min_score` | 0.5 | minimum detection confidence (`min_face_detection_confidence`) | [0, 1] |
/// | `min_suppression` | 0.5 | IoU above which detections merge (`min_suppression_threshold`) | [0, 1] |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorParams {
    /// Minimum detection confidence.
    pub min_score: f32,
    /// IoU above which detections are merged.
    pub min_suppression: f32,
}

impl Default for DetectorParams {
    fn default() -> Self {
        DetectorParams {
            min_score: 0.5,
            min_suppression: 0.5,
        }
    }
}

pub(crate) fn check_unit(name: &'static str, v: f32) -> Result<()> {
    if !(0.0..=1.0).contains(&v) {
        return Err(Error::InvalidParameter {
            name,
            value: v.to_string(),
            expected: "a number in [0, 1]".into(),
        });
    }
    Ok(())
}

impl DetectorParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        check_unit("min_score", self.min_score)?;
        check_unit("min_suppression", self.min_suppression)
    }
}

/// The face detector: BlazeFace model, anchors, settings. Immutable, `Send + Sync`.
#[derive(Debug, Clone)]
pub struct FaceDetector {
    model: Interpreter,
    anchors: Vec<[f32; 2]>,
    params: DetectorParams,
    table: BilinearTable,
}

/// Per-thread buffers of a [`FaceDetector`].
#[derive(Debug, Clone)]
pub struct DetectorWorkspace {
    model: Workspace,
    nms: NmsScratch,
}

#[derive(Debug, Clone)]
struct NmsScratch {
    raw: Vec<(f32, usize)>,
    candidates: Vec<Detection>,
    remained: Vec<usize>,
    next: Vec<usize>,
}

/// The anchor centres of the short-range model, in MediaPipe's order.
pub fn anchors() -> Vec<[f32; 2]> {
    let mut a = Vec::with_capacity(NUM_ANCHORS);
    for (fm, per_cell) in ANCHOR_GRIDS {
        for y in 0..fm {
            for x in 0..fm {
                for _ in 0..per_cell {
                    a.push([(x as f32 + 0.5) / fm as f32, (y as f32 + 0.5) / fm as f32]);
                }
            }
        }
    }
    a
}

impl FaceDetector {
    /// Wraps a loaded BlazeFace short-range model.
    ///
    /// # Errors
    /// [`Error::Model`] when the model's input or outputs are not BlazeFace short
    /// range's (`[1,128,128,3]` -> `[1,896,16]`, `[1,896,1]`);
    /// [`Error::InvalidParameter`] for out-of-range settings.
    pub fn new(model: Interpreter, params: DetectorParams) -> Result<Self> {
        params.validate()?;
        let ok = model.input_shape(0) == Some(&[1, DETECTOR_INPUT, DETECTOR_INPUT, 3][..])
            && model.output_shape(0) == Some(&[1, NUM_ANCHORS, NUM_COORDS][..])
            && model.output_shape(1) == Some(&[1, NUM_ANCHORS, 1][..]);
        if !ok {
            return Err(Error::Model {
                reason: "not a BlazeFace short-range model (expected [1,128,128,3] -> [1,896,16], [1,896,1])".into(),
            });
        }
        Ok(FaceDetector {
            model,
            anchors: anchors(),
            params,
            table: BilinearTable::new(),
        })
    }

    /// Buffers for one thread.
    pub fn workspace(&self) -> DetectorWorkspace {
        DetectorWorkspace {
            model: self.model.workspace(),
            nms: NmsScratch {
                raw: Vec::with_capacity(NUM_ANCHORS),
                candidates: Vec::with_capacity(NUM_ANCHORS),
                remained: Vec::with_capacity(NUM_ANCHORS),
                next: Vec::with_capacity(NUM_ANCHORS),
            },
        }
    }

    /// The settings.
    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    /// Detects faces; `out` receives them best first (cleared first).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another detector.
    pub fn detect_into(&self, img: &RgbView<'_>, ws: &mut DetectorWorkspace, out: &mut Vec<Detection>) -> Result<()> {
        ws.nms.candidates.clear();
        self.candidates_in(img, Window::whole(img.width, img.height), self.params.min_score, ws)?;
        self.suppress(&mut ws.nms, out);
        Ok(())
    }

    /// Detects faces too small for [`FaceDetector::detect_into`]: the model runs on
    /// overlapping square windows of a third of the image's long side ([`Window::tiles`]),
    /// each sampled to the model's 128 x 128 input, and the windows' detections scoring at
    /// least [`SMALL_FACE_MIN_SCORE`] are merged by the same weighted NMS; `out` receives
    /// them best first (cleared first).
    ///
    /// BlazeFace short range is made for faces near the camera: on the whole image it
    /// misses faces narrower than about a tenth of the long side (MediaPipe's FaceLandmarker
    /// finds no face in four of the shared annotated photos, faces 84-142 px wide in
    /// 817-1864 px images, which dlib's HOG detector finds). In a window of a third of the
    /// long side such a face is three times larger. A window holds every face up to a third
    /// of its side whole (the windows overlap by a third), so together with the whole-image
    /// pass faces from about 4 % of the long side up are found. Cost: one model run per
    /// window (16 on a square image, 12 on a 16:9 one).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another detector.
    pub fn detect_small_into(
        &self,
        img: &RgbView<'_>,
        ws: &mut DetectorWorkspace,
        out: &mut Vec<Detection>,
    ) -> Result<()> {
        ws.nms.candidates.clear();
        let min_score = self.params.min_score.max(SMALL_FACE_MIN_SCORE);
        for window in Window::tiles(img.width, img.height) {
            self.candidates_in(img, window, min_score, ws)?;
        }
        self.suppress(&mut ws.nms, out);
        Ok(())
    }

    /// Runs the model on `window` and appends its detections scoring at least `min_score`,
    /// in normalised image coordinates, to the workspace's candidates.
    fn candidates_in(
        &self,
        img: &RgbView<'_>,
        window: Window,
        min_score: f32,
        ws: &mut DetectorWorkspace,
    ) -> Result<()> {
        let (w, h) = (img.width, img.height);
        let roi = NormRect {
            x_center: window.cx / w as f32,
            y_center: window.cy / h as f32,
            width: window.side / w as f32,
            height: window.side / h as f32,
            rotation: 0.0,
        };
        let map = Affine::for_rect(&roi, w, h, DETECTOR_INPUT);
        let input = self.model.input_mut(&mut ws.model, 0)?;
        crate::roi::warp_to_tensor(
            img,
            &map,
            DETECTOR_INPUT,
            Border::Zero,
            ValueMap::SIGNED,
            &self.table,
            input,
        );
        self.model.run(&mut ws.model)?;
        let reg = self.model.output(&ws.model, 0)?;
        let cls = self.model.output(&ws.model, 1)?;
        self.decode(reg, cls, window, min_score, (w, h), &mut ws.nms);
        Ok(())
    }

    fn decode(
        &self,
        reg: &[f32],
        cls: &[f32],
        window: Window,
        min_score: f32,
        size: (usize, usize),
        ws: &mut NmsScratch,
    ) {
        let (w, h) = size;
        let n = DETECTOR_INPUT as f32;
        let side = window.side;
        // Tensor-normalised -> image-normalised coordinates.
        let to_x = |u: f32| ((u - 0.5) * side + window.cx) / w as f32;
        let to_y = |v: f32| ((v - 0.5) * side + window.cy) / h as f32;
        for (i, (&logit, a)) in cls.iter().zip(&self.anchors).enumerate() {
            let score = 1.0 / (1.0 + (-logit.clamp(-SCORE_CLIP, SCORE_CLIP)).exp());
            if score < min_score {
                continue;
            }
            let r = &reg[i * NUM_COORDS..(i + 1) * NUM_COORDS];
            let (xc, yc) = (r[0] / n + a[0], r[1] / n + a[1]);
            let (bw, bh) = (r[2] / n, r[3] / n);
            if !(bw > 0.0 && bh > 0.0) {
                continue;
            }
            let mut d = Detection {
                score,
                xmin: to_x(xc - bw / 2.0),
                ymin: to_y(yc - bh / 2.0),
                width: bw * side / w as f32,
                height: bh * side / h as f32,
                keypoints: [[0.0; 2]; NUM_KEYPOINTS],
            };
            for (k, kp) in d.keypoints.iter_mut().enumerate() {
                *kp = [to_x(r[4 + 2 * k] / n + a[0]), to_y(r[5 + 2 * k] / n + a[1])];
            }
            ws.candidates.push(d);
        }
    }

    /// Weighted NMS over the workspace's candidates; `out` receives the merged detections
    /// best first (cleared first).
    fn suppress(&self, ws: &mut NmsScratch, out: &mut Vec<Detection>) {
        // Weighted NMS over candidates sorted by score (stable: ties keep anchor order).
        ws.raw.clear();
        ws.raw
            .extend(ws.candidates.iter().enumerate().map(|(i, d)| (d.score, i)));
        ws.raw.sort_by(|a, b| b.0.total_cmp(&a.0));
        ws.remained.clear();
        ws.remained.extend(ws.raw.iter().map(|&(_, i)| i));
        out.clear();
        while let Some(&best) = ws.remained.first() {
            let top = ws.candidates[best];
            ws.next.clear();
            let (mut sx0, mut sy0, mut sx1, mut sy1, mut total) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
            let mut kps = [[0.0f32; 2]; NUM_KEYPOINTS];
            for &i in &ws.remained {
                let c = &ws.candidates[i];
                if top.iou(c) > self.params.min_suppression {
                    total += c.score;
                    sx0 += c.xmin * c.score;
                    sy0 += c.ymin * c.score;
                    sx1 += (c.xmin + c.width) * c.score;
                    sy1 += (c.ymin + c.height) * c.score;
                    for (acc, kp) in kps.iter_mut().zip(&c.keypoints) {
                        acc[0] += kp[0] * c.score;
                        acc[1] += kp[1] * c.score;
                    }
                } else {
                    ws.next.push(i);
                }
            }
            let mut d = top;
            if total > 0.0 {
                d.xmin = sx0 / total;
                d.ymin = sy0 / total;
                d.width = sx1 / total - d.xmin;
                d.height = sy1 / total - d.ymin;
                for (k, acc) in d.keypoints.iter_mut().zip(&kps) {
                    *k = [acc[0] / total, acc[1] / total];
                }
            }
            out.push(d);
            if ws.next.len() == ws.remained.len() {
                break;
            }
            std::mem::swap(&mut ws.remained, &mut ws.next);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_follow_mediapipe_layout() {
        let a = anchors();
        assert_eq!(a.len(), NUM_ANCHORS);
        assert_eq!(a[0], [0.5 / 16.0, 0.5 / 16.0]);
        assert_eq!(a[1], a[0]);
        assert_eq!(a[2], [1.5 / 16.0, 0.5 / 16.0]);
        assert_eq!(a[512], [0.5 / 8.0, 0.5 / 8.0]);
        assert_eq!(a[517], a[512]);
        assert_eq!(a[895], [7.5 / 8.0, 7.5 / 8.0]);
    }

    #[test]
    fn iou_of_known_boxes() {
        let d = |x: f32, y: f32, s: f32| Detection {
            xmin: x,
            ymin: y,
            width: s,
            height: s,
            ..Default::default()
        };
        assert!((d(0.0, 0.0, 1.0).iou(&d(0.5, 0.0, 1.0)) - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(d(0.0, 0.0, 1.0).iou(&d(2.0, 0.0, 1.0)), 0.0);
    }

    #[test]
    fn params_out_of_range_are_rejected() {
        let p = DetectorParams {
            min_score: f32::NAN,
            ..Default::default()
        };
        assert!(matches!(
            p.validate(),
            Err(Error::InvalidParameter { name: "min_score", .. })
        ));
    }
}
