//! The 500-point fitting problem shared by the `tensor_fit_sweep_500pts` bench and the
//! `sweep_profile` example: a synthetic 56 x 7 x 5090 model, every tenth vertex projected
//! through a fixed pose with a 0.1-unit offset, unit weights.

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_tensor::fit::FitInput;
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use nalgebra::{Point2, Point3, Vector3};

/// Model, fitted vertices, their image points, weights and camera.
pub struct SweepProblem {
    pub model: TensorModel,
    pub vertices: Vec<u32>,
    pub image: Vec<Point2<f64>>,
    pub weights: Vec<f64>,
    pub intrinsics: Intrinsics,
}

impl SweepProblem {
    /// Builds the problem (HOSVD of the synthetic database included).
    pub fn new() -> Self {
        let d = synth::database(5090, 56, 7, 2).unwrap();
        let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
        let vertices: Vec<u32> = (0..500).map(|k| k * 10).collect();
        let k = Intrinsics::new(900.0, 900.0, 320.0, 240.0).unwrap();
        let pose = ModelToCamera::from_rvec_tvec(Vector3::new(0.1, -0.2, 0.0), Vector3::new(0.0, 0.0, 60.0));
        let f = model.generate(&[1.0 / 56.0; 56], &[1.0 / 7.0; 7]).unwrap();
        let image = vertices
            .iter()
            .map(|&v| {
                let v = v as usize;
                pose.project(&k, &Point3::new(f[3 * v] + 0.1, f[3 * v + 1], f[3 * v + 2]))
                    .unwrap()
            })
            .collect();
        SweepProblem {
            model,
            vertices,
            image,
            weights: vec![1.0; 500],
            intrinsics: k,
        }
    }

    /// The fitter's input.
    pub fn input(&self) -> FitInput<'_> {
        FitInput {
            image: &self.image,
            weights: &self.weights,
            intrinsics: self.intrinsics,
        }
    }
}
