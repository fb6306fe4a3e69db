//! # facecap-solve
//!
//! Blendshape expression solvers: per frame, find weights `e in [0, 1]^n` that make a
//! blendshape rig (`B = B0 + sum e_i B_i`) match 68 tracked landmarks, as in the King 2017
//! thesis (the "seed"), plus exact solvers that beat it.
//!
//! | method | type | model | what it solves |
//! |---|---|---|---|
//! | `bobyqa` | [`BobyqaSolver`] | 2D, similarity-aligned | the seed's all-in-one BOBYQA (Powell 2009) with L1 term |
//! | `region` | [`RegionSolver`] | 2D | the seed's region method: rigid, then brows, eyes, mouth/jaw |
//! | `pca` | [`PcaSolver`] | 2D | PCA projection + bounded map back to weights |
//! | `exact` | [`ExactSolver`] | 2D | the same objective as `bobyqa`, solved exactly (box QP) |
//! | `exact3d` | [`Exact3dSolver`] | 3D, perspective | joint head pose + weights |
//!
//! All share the objective of [`solver`] (px^2: landmark residual, L1, optional temporal term),
//! the [`ExpressionSolver`] trait (`X::new(model, params)`, `workspace()`,
//! `solve_into(&input, &mut ws, &mut state, &mut out) -> Report`) and allocate nothing per frame
//! after the workspace is built (tested with a counting allocator).
//!
//! ```
//! use facecap_solve::{BlendshapeRig, Basis2d, ExactSolver, ExactParams, ExpressionSolver, Solution, SolveState};
//! use facecap_core::landmarks::Landmarks68;
//! let rig = BlendshapeRig::synthetic(8, 1);
//! let basis = Basis2d::frontal(&rig);
//! let solver = ExactSolver::new(&basis, ExactParams::default()).unwrap();
//! // landmarks of the rig posed with weight 0.5 on shape 2, drawn at 20 px per model unit
//! let mut e = vec![0.0; 8];
//! e[2] = 0.5;
//! let lm = Landmarks68::from_fn(|l| {
//!     let p = rig.landmark(l, &e);
//!     (320.0 + 20.0 * p.x, 240.0 - 20.0 * p.y)
//! });
//! let (mut ws, mut state, mut out) = (solver.workspace(), SolveState::new(8), Solution::new(8));
//! let report = solver.solve_into(&lm, &mut ws, &mut state, &mut out).unwrap();
//! assert!((out.weights[2] - 0.5).abs() < 0.01);
//! assert!(out.reprojection_error(&lm) < 0.1);
//! # let _ = report;
//! ```

pub mod basis;
pub mod bobyqa;
pub mod bobyqa_solver;
pub mod calibrate;
pub mod contour;
pub mod dense;
pub mod error;
pub mod exact;
pub mod exact3d;
pub mod observability;
pub mod pca;
pub mod region;
pub mod rig;
pub mod solver;
pub mod synth;

pub use basis::{Basis2d, Shape2dExample, Shapes2d, Similarity2d};
pub use bobyqa_solver::{BobyqaParams, BobyqaSolver};
pub use calibrate::{fit_subject, fit_subject_with_identity, IdentityModes, SubjectFit, SubjectParams};
pub use contour::{ContourCandidates, ContourLine, ContourParams};
pub use error::{Error, Result};
pub use exact::{ExactParams, ExactSolver};
pub use exact3d::{DensePoints, Exact3dParams, Exact3dSolver, ShapePriors};
pub use pca::{PcaParams, PcaSolver};
pub use region::{RegionGroup, RegionParams, RegionSolver};
pub use rig::BlendshapeRig;
pub use solver::{ExpressionSolver, ObjectiveParams, Report, Solution, SolveState, StopReason};

/// The five methods by name (`exact`, `exact3d`, `bobyqa`, `region`, `pca`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// [`ExactSolver`].
    Exact,
    /// [`Exact3dSolver`].
    Exact3d,
    /// [`BobyqaSolver`].
    Bobyqa,
    /// [`RegionSolver`].
    Region,
    /// [`PcaSolver`].
    Pca,
}

impl Method {
    /// All methods.
    pub const ALL: [Method; 5] = [
        Method::Exact,
        Method::Exact3d,
        Method::Bobyqa,
        Method::Region,
        Method::Pca,
    ];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Exact => "exact",
            Method::Exact3d => "exact3d",
            Method::Bobyqa => "bobyqa",
            Method::Region => "region",
            Method::Pca => "pca",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| Error::invalid("method", s, "one of exact, exact3d, bobyqa, region, pca"))
    }
}

/// Any of the five solvers with default parameters (plus `objective`), for callers that pick the
/// method at run time (the CLI).
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)]
pub enum AnySolver {
    /// See [`ExactSolver`].
    Exact(ExactSolver),
    /// See [`Exact3dSolver`].
    Exact3d(Exact3dSolver),
    /// See [`BobyqaSolver`].
    Bobyqa(BobyqaSolver),
    /// See [`RegionSolver`].
    Region(RegionSolver),
    /// See [`PcaSolver`].
    Pca(PcaSolver),
}

/// Workspace of [`AnySolver`].
#[derive(Debug, Clone)]
pub enum AnyWorkspace {
    /// Exact.
    Exact(exact::ExactWorkspace),
    /// Exact 3D.
    Exact3d(Box<exact3d::Exact3dWorkspace>),
    /// BOBYQA.
    Bobyqa(Box<bobyqa_solver::BobyqaWorkspace>),
    /// Region.
    Region(region::RegionWorkspace),
    /// PCA.
    Pca(pca::PcaWorkspace),
}

impl AnySolver {
    /// Builds `method` for `rig` (2D methods use [`Basis2d::frontal`]); `camera` is used by
    /// `exact3d` only.
    pub fn new(
        method: Method,
        rig: &BlendshapeRig,
        camera: facecap_core::camera::Intrinsics,
        objective: ObjectiveParams,
    ) -> Result<Self> {
        let basis = Basis2d::frontal(rig);
        Ok(match method {
            Method::Exact => AnySolver::Exact(ExactSolver::new(
                &basis,
                ExactParams {
                    objective,
                    ..Default::default()
                },
            )?),
            Method::Exact3d => AnySolver::Exact3d(Exact3dSolver::new(
                rig,
                Exact3dParams {
                    objective,
                    ..Exact3dParams::new(camera)
                },
            )?),
            Method::Bobyqa => AnySolver::Bobyqa(BobyqaSolver::new(
                &basis,
                BobyqaParams {
                    objective,
                    ..Default::default()
                },
            )?),
            Method::Region => AnySolver::Region(RegionSolver::new(
                &basis,
                RegionParams {
                    objective,
                    ..Default::default()
                },
            )?),
            Method::Pca => AnySolver::Pca(PcaSolver::new(
                &basis,
                PcaParams {
                    objective,
                    ..Default::default()
                },
            )?),
        })
    }
}

impl AnySolver {
    /// Applies per-shape priors (see [`ShapePriors`]) to the 3D method; the 2D methods
    /// have no such terms and are returned unchanged.
    ///
    /// # Errors
    /// When the priors do not fit the rig.
    pub fn with_priors(self, priors: ShapePriors) -> Result<Self> {
        Ok(match self {
            AnySolver::Exact3d(s) => AnySolver::Exact3d(s.with_priors(priors)?),
            other => other,
        })
    }

    /// Adds dense points (see [`DensePoints`]) to the 3D method; the 2D methods are
    /// returned unchanged.
    ///
    /// # Errors
    /// When the points do not fit the rig.
    pub fn with_dense(self, points: DensePoints) -> Result<Self> {
        Ok(match self {
            AnySolver::Exact3d(s) => AnySolver::Exact3d(s.with_dense(points)?),
            other => other,
        })
    }

    /// Number of points the solve uses when the dense input is given: the mapped
    /// landmarks plus the dense points of the 3D method (the landmarks alone otherwise).
    pub fn num_points(&self) -> usize {
        match self {
            AnySolver::Exact3d(s) => s.num_landmarks() + s.num_dense(),
            _ => NUM_POINTS_2D,
        }
    }

    /// [`ExpressionSolver::solve_into`] with the dense input (e.g. the face mesh's points),
    /// used by the 3D method's dense points ([`Exact3dSolver::solve_dense_into`]) and
    /// ignored by the others.
    ///
    /// # Errors
    /// As [`ExpressionSolver::solve_into`].
    pub fn solve_dense_into(
        &self,
        input: &facecap_core::landmarks::Landmarks68,
        dense: Option<&[[f32; 3]]>,
        ws: &mut AnyWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        match (self, ws) {
            (AnySolver::Exact3d(s), AnyWorkspace::Exact3d(w)) => s.solve_dense_into(input, dense, w, state, out),
            (s, w) => s.solve_into(input, w, state, out),
        }
    }
}

/// Points of the 2D methods (the 68 landmarks).
const NUM_POINTS_2D: usize = facecap_core::landmarks::NUM_LANDMARKS;

impl ExpressionSolver for AnySolver {
    type Workspace = AnyWorkspace;

    fn num_shapes(&self) -> usize {
        match self {
            AnySolver::Exact(s) => s.num_shapes(),
            AnySolver::Exact3d(s) => s.num_shapes(),
            AnySolver::Bobyqa(s) => s.num_shapes(),
            AnySolver::Region(s) => s.num_shapes(),
            AnySolver::Pca(s) => s.num_shapes(),
        }
    }

    fn names(&self) -> &[String] {
        match self {
            AnySolver::Exact(s) => s.names(),
            AnySolver::Exact3d(s) => s.names(),
            AnySolver::Bobyqa(s) => s.names(),
            AnySolver::Region(s) => s.names(),
            AnySolver::Pca(s) => s.names(),
        }
    }

    fn workspace(&self) -> AnyWorkspace {
        match self {
            AnySolver::Exact(s) => AnyWorkspace::Exact(s.workspace()),
            AnySolver::Exact3d(s) => AnyWorkspace::Exact3d(Box::new(s.workspace())),
            AnySolver::Bobyqa(s) => AnyWorkspace::Bobyqa(Box::new(s.workspace())),
            AnySolver::Region(s) => AnyWorkspace::Region(s.workspace()),
            AnySolver::Pca(s) => AnyWorkspace::Pca(s.workspace()),
        }
    }

    fn solve_into(
        &self,
        input: &facecap_core::landmarks::Landmarks68,
        ws: &mut AnyWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        match (self, ws) {
            (AnySolver::Exact(s), AnyWorkspace::Exact(w)) => s.solve_into(input, w, state, out),
            (AnySolver::Exact3d(s), AnyWorkspace::Exact3d(w)) => s.solve_into(input, w, state, out),
            (AnySolver::Bobyqa(s), AnyWorkspace::Bobyqa(w)) => s.solve_into(input, w, state, out),
            (AnySolver::Region(s), AnyWorkspace::Region(w)) => s.solve_into(input, w, state, out),
            (AnySolver::Pca(s), AnyWorkspace::Pca(w)) => s.solve_into(input, w, state, out),
            _ => Err(Error::invalid(
                "workspace",
                "of another method",
                "the workspace made by this solver",
            )),
        }
    }
}
