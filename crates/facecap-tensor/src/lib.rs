//! # facecap-tensor
//!
//! A multilinear identity x expression face model after Vlasic et al. 2005 as used by
//! Papanek 2010: a corresponded database becomes a data tensor ([`tensor`]), the
//! Gram-matrix HOSVD gives a core tensor and mode matrices ([`model`]), the model is
//! fitted to 2D image points frame by frame or over a sequence ([`fit`], regularised
//! closed form or non-negative least squares by `facecap_geom::nnls`), and expression transfer
//! combines fitted weights ([`transfer`]) with 2D reanimation by Poisson seamless
//! cloning ([`poisson`], Perez et al. 2003).
//!
//! This crate takes 2D points and meshes; it never depends on the landmark crate.
//!
//! ```
//! use facecap_tensor::tensor::DataTensor;
//! use facecap_tensor::model::{HosvdParams, TensorModel};
//! use nalgebra::Point3;
//! // 3 identities x 2 expressions of a 4-vertex "face".
//! let ids = vec!["a".to_string(), "b".into(), "c".into()];
//! let exps = vec!["neutral".to_string(), "smile".into()];
//! let d = DataTensor::from_cells(ids, exps, 4, vec![], |i, e| {
//!     Ok((0..4).map(|v| Point3::new(v as f64, i as f64 * 0.1, e as f64 * (v as f64 + 1.0))).collect())
//! }).unwrap();
//! let (model, _report) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
//! // Unit weights give database face (identity 1, expression 1) back.
//! let f = model.generate(&[0.0, 1.0, 0.0], &[0.0, 1.0]).unwrap();
//! assert!((f[3 * 2 + 2] - 3.0).abs() < 1e-9);
//! ```

pub mod error;
pub mod features;
pub mod fit;
mod kernels;
pub mod model;
pub mod poisson;
pub mod reanimate;
pub mod synth;
pub mod tensor;
pub mod transfer;
pub mod video_fit;

pub use error::{Error, Result};
