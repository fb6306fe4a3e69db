//! # facecap-muscle
//!
//! A face driven by a few physiological parameters (muscle contractions in `[0, 1]` and the
//! jaw angle) and tracked from single-camera video, after S. Mramornov's 2015 thesis
//! (muscle deformers of Waters 1987 with the wrinkles of Bui et al. 2004; the thesis'
//! Algorithm 1 for retargeting and Algorithm 2 for tracking).
//!
//! * [`deform`]: linear, parallel (sheet) and sphincter deformers, each equation documented.
//! * [`set`]: the JSON muscle-set format with validation.
//! * [`rig`]: a mesh with precomputed displacement fields; allocation-free posing.
//! * [`defaults`]: the thesis' 11 muscles placed from 68 landmarks on any mesh.
//! * [`retarget`]: Algorithm 1 (same topology) and retargeting across topologies.
//! * [`track`]: Algorithm 2 made automatic: head pose by PnP, jaw by golden-section search,
//!   contractions by projected Gauss-Newton on `[0, 1]` (global or point-by-point).
//!
//! ```
//! use facecap_muscle::{deform::*, set::*, rig::MuscleRig};
//! use nalgebra::{Point3, Vector3};
//! let set = MuscleSet::from_json_str(r#"{"muscles": [{"name": "m", "type": "linear",
//!     "origin": [0,0,0], "insertion": [1,0,0], "rs": 1, "rf": 2, "k": 0.2}]}"#).unwrap();
//! let pts = vec![Point3::new(1.0, 0.0, 0.0), Point3::new(3.0, 0.0, 0.0)];
//! let rig = MuscleRig::new(&set, &pts, &[Vector3::z(); 2]).unwrap();
//! let mut out = pts.clone();
//! rig.pose_into(&[0.5], 0.0, &mut out).unwrap();
//! assert!((out[0].x - 0.9).abs() < 1e-12); // pulled towards the origin by c * K
//! assert_eq!(out[1], pts[1]);               // outside Rf: unmoved
//! ```

// Index loops over several parallel buffers read better than zipped iterators here.
#![allow(clippy::needless_range_loop)]

pub mod defaults;
pub mod deform;
pub mod error;
pub mod retarget;
pub mod rig;
pub mod set;
pub mod synthetic;
pub mod track;

pub use error::{Error, Result};
