//! # facecap-geom
//!
//! Shared geometry and small dense solvers of the facecap workspace; each lives here
//! once and the algorithm crates import it from here.
//!
//! | module | holds |
//! |---|---|
//! | [`pnp`] | perspective-n-point: POSIT / EPnP initialisation, Levenberg-Marquardt pose refinement ([`pnp::refine_pose`]) |
//! | [`epnp`] | EPnP (Lepetit et al. 2009) |
//! | [`pose`] | weighted, allocation-free PnP used by the tensor fit (scaled-orthographic start, LM on the perspective error) |
//! | [`align`] | Umeyama similarity / rigid alignment in 2D and 3D |
//! | [`cholesky`] | in-place Cholesky factorisation and solve of a dense SPD matrix |
//! | [`qp`] | box-constrained convex QP (active set, projected Newton, exact reference) |
//! | [`nnls`] | non-negative least squares (projected coordinate descent with an active-set polish) |
//! | [`golden`] | golden-section search of a unimodal function |
//! | [`delaunay`] | Bowyer-Watson Delaunay triangulation of 2D points |
//! | [`tps`] | thin-plate spline `R^2 -> R` |
//! | [`harmonic`] | harmonic (membrane) interpolation of values given at some vertices of a triangle mesh |
//!
//! Errors are `facecap_core::Error` (re-exported here).

pub use facecap_core::{Error, Result};

pub mod align;
pub mod cholesky;
pub mod delaunay;
pub mod epnp;
pub mod golden;
pub mod harmonic;
pub mod nnls;
pub mod pnp;
pub mod pose;
pub mod qp;
pub mod tps;
