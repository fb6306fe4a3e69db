//! # facecap-core
//!
//! Shared vocabulary of the facecap workspace: the iBUG 68-point landmark scheme,
//! face boxes, meshes with morph targets, pinhole cameras, rigid poses that name the
//! frames they map between, the one error type, atomic file writing, model-cache and
//! shared-data paths, model checksums and landmark-to-vertex maps.
//!
//! File formats (video, images, glTF, OBJ, CSV, landmark files) live in `facecap-io`,
//! shared geometry and small dense solvers (PnP, alignment, Cholesky, box QP, NNLS,
//! Delaunay) in `facecap-geom`; both build on this crate. Algorithm crates
//! (`facecap-landmarks`, `facecap-solve`, `facecap-tensor`, `facecap-muscle`,
//! `facecap-mesh`) depend on these three and never on each other; only
//! `facecap-pipeline` composes them.
//!
//! ## Coordinate conventions
//! * **Pixels**: `(x, y)` with the *centre* of the top-left pixel at `(0, 0)`,
//!   x to the right, y down (dlib / OpenCV convention). iBUG `.pts` files use
//!   1-based coordinates (MATLAB convention) and are converted on read/write.
//! * **Model space**: right-handed, +Y up, +Z out of the face, units of the source mesh.
//! * **Camera space**: right-handed, +X right, +Y down, +Z forward (OpenCV convention).
//!
//! ```
//! use facecap_core::landmarks::{Landmarks68, Region};
//! let lm = Landmarks68::from_fn(|i| (i as f64, 2.0 * i as f64));
//! assert_eq!(Region::Jaw.indices().len(), 17);
//! assert!((lm.interocular_distance() - ((9.0f64 * 9.0 + 18.0 * 18.0).sqrt())).abs() < 1e-12);
//! ```

pub mod error;
pub mod landmarks;

pub use error::{Error, Result};
pub mod atomic;
pub mod camera;
pub mod checksum;
pub mod landmark_map;
pub mod mesh;
pub mod paths;
