//! [`super::FaceFinder`] / [`super::ShapeRegressor`] for this crate's dlib-compatible
//! HOG detector and ERT shape predictor.

use facecap_core::landmarks::Rect;
use image::GrayImage;
use nalgebra::Point2;

use super::{FaceFinder, ShapeRegressor};
use crate::detect::{DetectWorkspace, Detection, FaceDetector};
use crate::error::Result;
use crate::ert::{ErtWorkspace, ShapePredictor};

/// Detector workspace plus its detection list.
#[derive(Debug, Default)]
pub struct DetectorWs {
    ws: DetectWorkspace,
    dets: Vec<Detection>,
}

impl FaceFinder for FaceDetector {
    type Workspace = DetectorWs;

    fn new_workspace(&self) -> DetectorWs {
        DetectorWs {
            ws: FaceDetector::new_workspace(self),
            dets: Vec::with_capacity(16),
        }
    }

    fn find_faces(&self, img: &GrayImage, ws: &mut DetectorWs, out: &mut Vec<Rect>) -> Result<()> {
        self.detect_into(img, &mut ws.ws, &mut ws.dets)?;
        out.clear();
        out.extend(ws.dets.iter().map(|d| d.rect));
        Ok(())
    }
}

impl ShapeRegressor for ShapePredictor {
    type Workspace = ErtWorkspace;

    fn new_workspace(&self) -> ErtWorkspace {
        ShapePredictor::new_workspace(self)
    }

    fn mean_shape(&self) -> &[f32] {
        ShapePredictor::mean_shape(self)
    }

    fn predict(&self, img: &GrayImage, rect: &Rect, ws: &mut ErtWorkspace, out: &mut [Point2<f64>]) -> Result<()> {
        self.predict_into(img, rect, ws, out)
    }

    fn predict_from_shape(
        &self,
        img: &GrayImage,
        rect: &Rect,
        initial: &[Point2<f64>],
        ws: &mut ErtWorkspace,
        out: &mut [Point2<f64>],
    ) -> Result<()> {
        self.predict_from_shape_into(img, rect, initial, ws, out)
    }
}
