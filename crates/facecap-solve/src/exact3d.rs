//! 3D-aware solve (ours): perspective camera, joint head pose and blendshape weights.
//!
//! Objective (px^2), over the rotation `R`, translation `t` (model units) and `e in [0,1]^n`:
//!
//! ```text
//! F(R, t, e) = sum_j || pi(R X_j(e) + t) - o_j ||^2 + lambda 1^T e + mu ||e - e_prev||^2,
//! X_j(e) = n_j + sum_i e_i d_ij,     pi(x, y, z) = (fx x / z + cx, fy y / z + cy)
//! ```
//!
//! with the rig in model space (+Y up) and the camera in OpenCV convention (+Y down, +Z
//! forward), see [`facecap_core::camera`]. Head rotation is explained by `R`, not by "tilt"
//! shapes (the seed's 2D rotation failure).
//!
//! # Method
//! 1. Start: the previous frame's pose and weights (warm start), else an affine-camera fit
//!    (linear least squares of a `2 x 4` projection, rows orthonormalised, depth from its scale).
//! 2. Rigid update: `pose_iterations` Levenberg-Marquardt steps on the 6 pose parameters
//!    (left-multiplied rotation increment `exp([w]x) R`, `t + dt`), weights fixed: the
//!    shared pose refinement [`facecap_geom::pnp::refine_pose`], whose Jacobian
//!    ([`facecap_geom::pnp::point_jacobian`]) and update ([`facecap_geom::pnp::apply_pose_step`])
//!    the joint step below uses too.
//! 3. Bounded QP: the projection is linearised at the current pose and weights,
//!    `r(z) = r_0 + A_p dp + A_e (e' - e)`, and the convex box QP in `z = (dp, e')` (pose increments
//!    unbounded, `e' in [0,1]^n`) is solved exactly ([`facecap_geom::qp`]). With `joint = false` only `e'`
//!    is free (pure alternation). The step is accepted with a backtracking search on `F`.
//! 4. Repeat 2-3 until the relative decrease of `F` is below `tol` (reported as
//!    [`StopReason::SmallDecrease`]) or `max_alternations` is reached ([`StopReason::MaxIterations`]).
//! 5. Jaw contour (rigs with [`crate::BlendshapeRig::contour`] candidates): before step 2
//!    the points of iBUG 0-16 are chosen on the rig's silhouette under the starting pose
//!    ([`crate::contour`]); after step 4 they are chosen again under the solved pose, and
//!    when one moved by more than 0.25 px the frame is solved once more from there.
//!
//! | param | default | meaning | range |
//! |---|---|---|---|
//! | `objective` | `l1 = 1, temporal = 0` | see [`ObjectiveParams`] | |
//! | `camera` | required | pinhole intrinsics (px); CLI default `fx = fy = max(W, H)`, centre | |
//! | `max_alternations` | 50 | outer iterations | 1-10000 |
//! | `pose_iterations` | 2 | LM steps of the rigid update per alternation | 0-100 |
//! | `tol` | 1e-5 | relative decrease that stops | (0, 1) |
//!
//! `tol`: from 1e-9 to 1e-5 the mean number of alternations per frame falls from 9.9 to 6.8
//! on liveportrait_d6 (whole capture 0.957 of the wall time) while no weight of the five
//! shared clips moves by more than 0.0005 (built-in and ICT rigs; docs/expressions.md).
//! | `joint` | true | pose increments free in the QP step | |

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::{Isometry3, Matrix4, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3, Vector4};

use crate::contour::silhouette_index;
use crate::error::{check_count, check_range, Error, Result};
use crate::rig::BlendshapeRig;
use crate::solver::{check_io, ExpressionSolver, ObjectiveParams, Report, Solution, SolveState, StopReason};
use facecap_geom::pnp::{apply_pose_step, point_jacobian, refine_pose, PnpParams};
use facecap_geom::qp::{solve_box_qp, QpOptions, QpWorkspace};

/// Parameters of [`Exact3dSolver`] (table in the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exact3dParams {
    /// Objective weights.
    pub objective: ObjectiveParams,
    /// Camera intrinsics.
    pub camera: Intrinsics,
    /// Outer iterations.
    pub max_alternations: usize,
    /// LM steps per rigid update.
    pub pose_iterations: usize,
    /// Relative-decrease stop (see the module table).
    pub tol: f64,
    /// Free pose increments in the QP step.
    pub joint: bool,
}

impl Exact3dParams {
    /// Defaults for a camera.
    pub fn new(camera: Intrinsics) -> Self {
        Exact3dParams {
            objective: ObjectiveParams::default(),
            camera,
            max_alternations: 50,
            pose_iterations: 2,
            tol: 1e-5,
            joint: true,
        }
    }

    fn validate(&self) -> Result<()> {
        self.objective.validate()?;
        let c = &self.camera;
        Intrinsics::new(c.fx, c.fy, c.cx, c.cy)?;
        check_count("max_alternations", self.max_alternations, 1, 10000)?;
        check_count("pose_iterations", self.pose_iterations, 0, 100)?;
        check_range("tol", self.tol, 0.0, 1.0)?;
        if self.tol <= 0.0 || self.tol >= 1.0 {
            return Err(Error::invalid("tol", self.tol, "in (0, 1)"));
        }
        Ok(())
    }
}

const POSE: usize = 6;
/// Smallest depth (model units) a landmark may have in front of the camera.
const MIN_DEPTH: f64 = 1e-6;
/// Initial damping of the rigid update's Levenberg-Marquardt (relative to the diagonal):
/// small, since the pose is warm-started near its optimum.
const RIGID_DAMPING0: f64 = 1e-6;
/// Backtracking halvings of the QP step.
const MAX_HALVINGS: usize = 30;
/// A weight above this counts as active for the exclusive pairs.
const EXCLUSIVE_EPS: f64 = 1e-3;

/// Most shapes [`Exact3dSolver::pose_points`] lists as on (beyond, it tests every shape
/// at every point).
const ACTIVE_MAX: usize = 64;

/// `(IOD / 100 px)^2` of the observed landmarks (1 when the eye corners are unusable).
fn prior_scale(input: &Landmarks68) -> f64 {
    let d = (input.points[36] - input.points[45]).norm();
    if d.is_finite() && d > 1.0 {
        (d / 100.0).powi(2)
    } else {
        1.0
    }
}

/// The 3D-aware solver (see module docs).
#[derive(Debug, Clone)]
pub struct Exact3dSolver {
    names: Vec<String>,
    n: usize,
    /// Mapped landmark indices.
    idx: Vec<usize>,
    /// Neutral points of `idx`.
    neutral: Vec<Vector3<f64>>,
    /// Deltas `[j][k]` of `idx`, row-major `m x n`.
    deltas: Vec<Vector3<f64>>,
    params: Exact3dParams,
    ridge: f64,
    /// Per-shape and per-landmark terms (all neutral by default).
    priors: ShapePriors,
    /// `sqrt` of the point weight of each mapped landmark (`idx` order), then of each
    /// dense point.
    sqrt_w: Vec<f64>,
    /// Index of each dense point's observation in the dense input (see [`DensePoints`]);
    /// `neutral`, `deltas` and `sqrt_w` hold the dense points after the `idx` ones.
    dense_sources: Vec<usize>,
    /// Contour landmarks whose point follows the pose ([`crate::contour`]).
    contour: Vec<ContourSlot>,
    /// Contour slot of each mapped landmark (`idx` order; [`NO_SLOT`]: none).
    slot_of: Vec<usize>,
}

/// No contour slot.
const NO_SLOT: usize = usize::MAX;

/// A contour point moving more than this (px) after a solve re-solves the frame.
const CONTOUR_RESOLVE_PX: f64 = 0.25;

/// One contour landmark's candidates in the solver (see [`crate::contour::ContourLine`]).
#[derive(Debug, Clone)]
struct ContourSlot {
    /// Point index (`idx` order).
    point: usize,
    /// Index of the mapped vertex among the candidates.
    anchor: usize,
    /// Silhouette level (the mapped vertex's frontal facing).
    tau: f64,
    /// Candidate positions minus the mapped vertex's.
    offsets: Vec<Vector3<f64>>,
    /// Candidate normals.
    normals: Vec<Vector3<f64>>,
    /// Candidate deltas, row-major `candidates x n`.
    deltas: Vec<Vector3<f64>>,
}

/// The chosen contour points of a frame (in [`Exact3dWorkspace`]).
#[derive(Debug, Clone)]
struct ContourWork {
    /// Per slot: the chosen point minus the mapped vertex (model units).
    offset: Vec<Vector3<f64>>,
    /// Per slot: the chosen fractional candidate index.
    index: Vec<f64>,
    /// Per slot: the chosen point's deltas, row-major `slots x n`.
    deltas: Vec<Vector3<f64>>,
    /// Scratch: facings along a line.
    facing: Vec<f64>,
}

/// Extra model points of the 3D solve beyond the 68 iBUG landmarks (e.g. the face mesh's
/// points on the rig, [`crate::dense::DenseMap::points`]): each one's neutral position and
/// per-shape deltas (rig units), the index of its observation in the dense input, and the
/// weight of its squared residual (the 68 landmarks keep their [`ShapePriors::point_weights`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DensePoints {
    sources: Vec<usize>,
    neutral: Vec<Vector3<f64>>,
    /// `[j][k]`, row-major `m x n`.
    deltas: Vec<Vector3<f64>>,
    n: usize,
    weight: f64,
}

impl DensePoints {
    /// Checks sizes (`deltas` is `sources.len() x n`, row-major), finiteness and the
    /// weight (`[0, 1e6]`).
    ///
    /// # Errors
    /// Mismatched sizes, a non-finite coordinate or a weight out of range.
    pub fn new(
        sources: Vec<usize>,
        neutral: Vec<Vector3<f64>>,
        deltas: Vec<Vector3<f64>>,
        n: usize,
        weight: f64,
    ) -> Result<Self> {
        let m = sources.len();
        if neutral.len() != m || deltas.len() != m * n {
            return Err(Error::DimensionMismatch {
                what: "dense points (neutral, deltas)".into(),
                expected: m * (n + 1),
                got: neutral.len() + deltas.len(),
            });
        }
        check_range("dense point weight", weight, 0.0, 1e6)?;
        if neutral.iter().chain(&deltas).any(|v| !v.iter().all(|x| x.is_finite())) {
            return Err(Error::rig("dense points", "non-finite coordinate"));
        }
        Ok(DensePoints {
            sources,
            neutral,
            deltas,
            n,
            weight,
        })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.sources.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.sources.is_empty()
    }

    /// Observation index of each point in the dense input.
    pub fn sources(&self) -> &[usize] {
        &self.sources
    }

    /// Neutral positions.
    pub fn neutral(&self) -> &[Vector3<f64>] {
        &self.neutral
    }

    /// Per-shape deltas, row-major `len() x n`.
    pub fn deltas(&self) -> &[Vector3<f64>] {
        &self.deltas
    }

    /// The residual weight.
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// The same points with another residual weight (clamped to `[0, 1e6]`).
    pub fn with_weight(mut self, weight: f64) -> Self {
        self.weight = if weight.is_finite() {
            weight.clamp(0.0, 1e6)
        } else {
            0.0
        };
        self
    }

    /// Adds `offset(p)` to each neutral position `p` (non-finite offsets are ignored).
    pub fn shift_neutral(&mut self, offset: impl Fn(&Vector3<f64>) -> Vector3<f64>) {
        for p in &mut self.neutral {
            let o = offset(p);
            if o.iter().all(|x| x.is_finite()) {
                *p += o;
            }
        }
    }
}

/// Per-shape and per-landmark terms of the 3D objective beyond [`ObjectiveParams`]:
///
/// ```text
/// F += s * sum_i ridge_i e_i^2,   s = (IOD / 100 px)^2
/// ```
///
/// (`IOD` = the observed distance of the outer eye corners 36 and 45, so the prior means the
/// same on small and large faces), `e_i = 0` for `fixed` shapes, each landmark's squared
/// residual multiplied by `point_weights[l]`, and for each `exclusive` pair `(a, b)` at most
/// one of the two is non-zero: when both are after a solve, the smaller one is held at 0 and
/// the frame is solved again (up to [`MAX_EXCLUSIVE_ROUNDS`] rounds). For each `coupled`
/// pair `(child, parent)` the child acts only together with its parent, `w_child <=
/// w_parent` (ARKit's `mouthClose` closes the lips of an open jaw: alone it would lift the
/// lower lip of a closed mouth): the solver's own variables are `z_parent = w_parent -
/// w_child` and `z_child = w_child`, each in `[0, 1]`, the child's column moving the points
/// by both shapes' deltas (`w_parent` is clamped to 1); the ridge and the temporal term
/// act on those variables.
///
/// [`ShapePriors::neutral`] changes nothing; [`crate::observability::default_priors`] is the
/// measured default for a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapePriors {
    /// Quadratic prior per shape (px^2 at IOD = 100 px per unit weight^2), `>= 0`.
    pub ridge: Vec<f64>,
    /// Shapes held at 0.
    pub fixed: Vec<bool>,
    /// Multiplier of the objective's temporal weight per shape, `[0, 1e6]` (1: as given;
    /// fast actions such as blinks take less, so the temporal term does not delay them).
    pub temporal: Vec<f64>,
    /// Shape pairs that must not both be active.
    pub exclusive: Vec<(usize, usize)>,
    /// `(child, parent)`: the child is active only with the parent, `w_child <= w_parent`.
    /// A child has one parent and is no one's parent.
    pub coupled: Vec<(usize, usize)>,
    /// Weight of each landmark's squared residual, `[0, 1e6]`.
    pub point_weights: [f64; NUM_LANDMARKS],
}

/// Re-solves allowed by the exclusive pairs of [`ShapePriors`].
pub const MAX_EXCLUSIVE_ROUNDS: usize = 3;

impl ShapePriors {
    /// No prior, nothing fixed, every landmark weight 1 (the plain objective).
    pub fn neutral(n: usize) -> Self {
        ShapePriors {
            ridge: vec![0.0; n],
            fixed: vec![false; n],
            temporal: vec![1.0; n],
            exclusive: Vec::new(),
            coupled: Vec::new(),
            point_weights: [1.0; NUM_LANDMARKS],
        }
    }

    /// Checks sizes and ranges against `n` shapes.
    pub fn validate(&self, n: usize) -> Result<()> {
        if self.ridge.len() != n || self.fixed.len() != n || self.temporal.len() != n {
            return Err(Error::DimensionMismatch {
                what: "shape priors (ridge, fixed, temporal)".into(),
                expected: n,
                got: self.ridge.len().min(self.fixed.len()).min(self.temporal.len()),
            });
        }
        for &t in &self.temporal {
            check_range("temporal", t, 0.0, 1e6)?;
        }
        for &r in &self.ridge {
            check_range("ridge", r, 0.0, 1e12)?;
        }
        for &w in &self.point_weights {
            check_range("point_weights", w, 0.0, 1e6)?;
        }
        for &(a, b) in &self.exclusive {
            if a >= n || b >= n || a == b {
                return Err(Error::invalid(
                    "exclusive",
                    format!("({a}, {b})"),
                    format!("two different shape indices < {n}"),
                ));
            }
        }
        for (i, &(c, p)) in self.coupled.iter().enumerate() {
            let again = self.coupled[..i].iter().any(|&(c2, _)| c2 == c);
            let chained = self.coupled.iter().any(|&(_, p2)| p2 == c);
            if c >= n || p >= n || c == p || again || chained {
                return Err(Error::invalid(
                    "coupled",
                    format!("({c}, {p})"),
                    format!("two different shape indices < {n}, each child once and no child a parent"),
                ));
            }
        }
        Ok(())
    }
}

/// `rows` of per-shape deltas (`n` per row) with each coupled child's column moved by its
/// parent's too (`sign` 1) or back (`sign` -1): the solver's variables of [`ShapePriors`].
fn couple_columns(rows: &mut [Vector3<f64>], n: usize, coupled: &[(usize, usize)], sign: f64) {
    if n == 0 || coupled.is_empty() {
        return;
    }
    for row in rows.chunks_exact_mut(n) {
        for &(c, p) in coupled {
            let d = row[p] * sign;
            row[c] += d;
        }
    }
}

/// Scratch of [`Exact3dSolver`].
#[derive(Debug, Clone)]
pub struct Exact3dWorkspace {
    /// Posed model points (model frame), `m`.
    posed: Vec<Vector3<f64>>,
    /// Observations of mapped points, `2m`.
    obs: Vec<f64>,
    /// Residuals, `2m`.
    r: Vec<f64>,
    /// Points in this frame's solve (the mapped landmarks, plus the dense points when
    /// observed).
    m: usize,
    /// Jacobian `2m x (6 + n)` row-major.
    a: Vec<f64>,
    h: Vec<f64>,
    g: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    z: Vec<f64>,
    e: Vec<f64>,
    e_trial: Vec<f64>,
    /// This frame's effective ridge per shape (`s * ridge_i`).
    rho: Vec<f64>,
    /// The rigid step's correspondences: posed model points, observations, point weights.
    rigid_model: Vec<Point3<f64>>,
    rigid_image: Vec<Point2<f64>>,
    rigid_w: Vec<f64>,
    /// The chosen contour points.
    cw: ContourWork,
    qp: QpWorkspace,
}

#[derive(Debug, Clone, Copy)]
struct Pose {
    r: Rotation3<f64>,
    t: Vector3<f64>,
}

impl Pose {
    fn to_model_to_camera(self) -> ModelToCamera {
        ModelToCamera(Isometry3::from_parts(
            Translation3::from(self.t),
            UnitQuaternion::from_rotation_matrix(&self.r),
        ))
    }

    fn from_model_to_camera(p: &ModelToCamera) -> Self {
        Pose {
            r: p.0.rotation.to_rotation_matrix(),
            t: p.0.translation.vector,
        }
    }

    fn step(&self, dp: &[f64], alpha: f64) -> Pose {
        let step = [dp[0], dp[1], dp[2], dp[3], dp[4], dp[5]];
        Pose::from_model_to_camera(&apply_pose_step(&self.to_model_to_camera(), &step, alpha))
    }
}

/// The solver's contour slots from the rig's candidates and mesh (none without either,
/// or when the mesh's targets do not match the rig's shapes).
fn contour_slots(rig: &BlendshapeRig, idx: &[usize]) -> Vec<ContourSlot> {
    let (Some(cand), Some(mesh)) = (&rig.contour, &rig.mesh) else {
        return Vec::new();
    };
    let n = rig.num_shapes();
    if mesh.targets.len() != n {
        return Vec::new();
    }
    let nv = mesh.base.positions.len();
    let mut out = Vec::new();
    for line in &cand.lines {
        let Some(point) = idx.iter().position(|&l| l == line.landmark) else {
            continue;
        };
        let k = line.vertices.len();
        if k < 2
            || line.anchor >= k
            || line.offsets.len() != k
            || line.normals.len() != k
            || line.vertices.iter().any(|&v| v as usize >= nv)
        {
            continue;
        }
        let mut deltas = Vec::with_capacity(k * n);
        for &v in &line.vertices {
            for t in &mesh.targets {
                let d = t
                    .deltas
                    .get(v as usize)
                    .copied()
                    .unwrap_or_else(nalgebra::Vector3::zeros);
                deltas.push(Vector3::new(f64::from(d.x), f64::from(d.y), f64::from(d.z)));
            }
        }
        if line
            .offsets
            .iter()
            .chain(&line.normals)
            .chain(&deltas)
            .any(|v| !v.iter().all(|x| x.is_finite()))
        {
            continue;
        }
        out.push(ContourSlot {
            point,
            anchor: line.anchor,
            tau: line.frontal_facing(),
            offsets: line.offsets.clone(),
            normals: line.normals.clone(),
            deltas,
        });
    }
    out
}

impl Exact3dSolver {
    /// Validates parameters and extracts the mapped landmarks of the rig; the contour
    /// landmarks with candidates in `rig.contour` follow the pose ([`crate::contour`]).
    pub fn new(rig: &BlendshapeRig, params: Exact3dParams) -> Result<Self> {
        params.validate()?;
        let n = rig.num_shapes();
        if n == 0 {
            return Err(Error::rig("3D rig", "no shapes"));
        }
        let idx: Vec<usize> = (0..NUM_LANDMARKS).filter(|&l| rig.mapped[l]).collect();
        if idx.len() < 6 {
            return Err(Error::rig(
                "3D rig",
                format!("{} mapped landmarks; at least 6 needed", idx.len()),
            ));
        }
        let neutral: Vec<Vector3<f64>> = idx
            .iter()
            .map(|&l| Vector3::new(rig.neutral[[l, 0]], rig.neutral[[l, 1]], rig.neutral[[l, 2]]))
            .collect();
        let mut deltas = Vec::with_capacity(idx.len() * n);
        let mut maxnorm = 0.0f64;
        for &l in &idx {
            for k in 0..n {
                let d = Vector3::new(rig.deltas[[k, l, 0]], rig.deltas[[k, l, 1]], rig.deltas[[k, l, 2]]);
                maxnorm = maxnorm.max(d.norm_squared());
                deltas.push(d);
            }
        }
        if neutral
            .iter()
            .chain(deltas.iter())
            .any(|v| !v.iter().all(|x| x.is_finite()))
        {
            return Err(Error::rig("3D rig", "non-finite coordinate"));
        }
        let sqrt_w = vec![1.0; idx.len()];
        let contour = contour_slots(rig, &idx);
        let mut slot_of = vec![NO_SLOT; idx.len()];
        for (s, c) in contour.iter().enumerate() {
            slot_of[c.point] = s;
        }
        Ok(Exact3dSolver {
            contour,
            slot_of,
            dense_sources: Vec::new(),
            names: rig.names.clone(),
            n,
            idx,
            neutral,
            deltas,
            sqrt_w,
            params,
            ridge: 1e-12 * maxnorm.max(1e-300),
            priors: ShapePriors::neutral(n),
        })
    }

    /// The same solver with per-shape and per-landmark terms (see [`ShapePriors`]).
    ///
    /// # Errors
    /// When the priors do not fit the rig or are out of range.
    pub fn with_priors(mut self, priors: ShapePriors) -> Result<Self> {
        priors.validate(self.n)?;
        for (w, &l) in self.sqrt_w.iter_mut().zip(&self.idx) {
            *w = priors.point_weights[l].sqrt();
        }
        let n = self.n;
        couple_columns(&mut self.deltas, n, &self.priors.coupled, -1.0);
        couple_columns(&mut self.deltas, n, &priors.coupled, 1.0);
        for slot in &mut self.contour {
            couple_columns(&mut slot.deltas, n, &self.priors.coupled, -1.0);
            couple_columns(&mut slot.deltas, n, &priors.coupled, 1.0);
        }
        self.priors = priors;
        Ok(self)
    }

    /// The same solver with extra model points (see [`DensePoints`]), used by
    /// [`Exact3dSolver::solve_dense_into`] when their observations are given. Replaces
    /// any dense points set before.
    ///
    /// # Errors
    /// Points made for a rig with another number of shapes.
    pub fn with_dense(mut self, points: DensePoints) -> Result<Self> {
        if points.n != self.n {
            return Err(Error::DimensionMismatch {
                what: "dense points' shapes".into(),
                expected: self.n,
                got: points.n,
            });
        }
        let m0 = self.idx.len();
        self.neutral.truncate(m0);
        self.deltas.truncate(m0 * self.n);
        self.sqrt_w.truncate(m0);
        self.neutral.extend_from_slice(&points.neutral);
        let count = points.len();
        let mut deltas = points.deltas;
        couple_columns(&mut deltas, self.n, &self.priors.coupled, 1.0);
        self.deltas.extend_from_slice(&deltas);
        self.sqrt_w.extend(std::iter::repeat(points.weight.sqrt()).take(count));
        self.dense_sources = points.sources;
        Ok(self)
    }

    /// Number of dense points (0 without [`Exact3dSolver::with_dense`]).
    pub fn num_dense(&self) -> usize {
        self.dense_sources.len()
    }

    /// Number of mapped iBUG landmarks.
    pub fn num_landmarks(&self) -> usize {
        self.idx.len()
    }

    /// For a solved frame (`weights`, `pose`), the model-space offset of each dense point
    /// that would put its projection on its observation in `dense` at the point's depth
    /// (the image-plane residual back-projected and rotated into the model frame). `None`
    /// when the sizes do not fit, an observation is not finite or a point is behind the
    /// camera.
    pub fn dense_offsets(
        &self,
        dense: &[[f32; 3]],
        weights: &[f64],
        pose: &ModelToCamera,
    ) -> Option<Vec<Vector3<f64>>> {
        if weights.len() != self.n || self.dense_sources.iter().any(|&s| s >= dense.len()) {
            return None;
        }
        let m0 = self.idx.len();
        let mut posed = vec![Vector3::zeros(); self.neutral.len()];
        let p = Pose::from_model_to_camera(pose);
        let mut cw = self.contour_work();
        self.select_contour(&p, &mut cw);
        self.pose_points(&cw, &self.to_variables(weights), &mut posed);
        let k = &self.params.camera;
        let rt = p.r.inverse();
        let mut out = Vec::with_capacity(self.dense_sources.len());
        for (j, &s) in self.dense_sources.iter().enumerate() {
            let c = p.r * posed[m0 + j] + p.t;
            let (u, v) = (f64::from(dense[s][0]), f64::from(dense[s][1]));
            if c.z <= MIN_DEPTH || !u.is_finite() || !v.is_finite() {
                return None;
            }
            let target = Vector3::new((u - k.cx) * c.z / k.fx, (v - k.cy) * c.z / k.fy, c.z);
            out.push(rt * (target - c));
        }
        Some(out)
    }

    /// Adds `offsets[j]` to dense point `j`'s neutral (e.g. the subject's neutral at the
    /// dense points, from [`Exact3dSolver::dense_offsets`] over resting frames). Ignored
    /// when the size is not the number of dense points or an offset is not finite.
    pub fn shift_dense(&mut self, offsets: &[Vector3<f64>]) {
        let m0 = self.idx.len();
        if offsets.len() != self.dense_sources.len() || offsets.iter().any(|o| !o.iter().all(|x| x.is_finite())) {
            return;
        }
        for (p, o) in self.neutral[m0..].iter_mut().zip(offsets) {
            *p += o;
        }
    }

    /// The priors in use.
    pub fn priors(&self) -> &ShapePriors {
        &self.priors
    }

    /// The camera.
    pub fn camera(&self) -> &Intrinsics {
        &self.params.camera
    }

    /// The solver's variables to rig weights in place (`ShapePriors::coupled`: each
    /// parent's weight is its own variable plus its children's, at most 1).
    fn to_weights(&self, e: &mut [f64]) {
        for &(c, p) in &self.priors.coupled {
            e[p] = (e[p] + e[c]).min(1.0);
        }
    }

    /// Rig weights to the solver's variables (the inverse of [`Self::to_weights`]; a
    /// child above its parent counts as much as the parent).
    fn to_variables(&self, w: &[f64]) -> Vec<f64> {
        let mut z = w.to_vec();
        for &(c, p) in &self.priors.coupled {
            z[c] = w[c].min(w[p]);
        }
        for &(c, p) in &self.priors.coupled {
            z[p] -= z[c];
        }
        z
    }

    fn pose_points(&self, cw: &ContourWork, e: &[f64], out: &mut [Vector3<f64>]) {
        // the shapes that are on, listed once: the per-point loop then runs over them
        // without a test per shape (same shapes, same order, so the same sums)
        let mut on = [(0usize, 0.0f64); ACTIVE_MAX];
        let mut count = 0;
        for (k, &w) in e.iter().enumerate() {
            if w != 0.0 {
                if count == ACTIVE_MAX {
                    count = usize::MAX;
                    break;
                }
                on[count] = (k, w);
                count += 1;
            }
        }
        if count == usize::MAX {
            self.pose_points_all(cw, e, out);
            return;
        }
        let on = &on[..count];
        let n = self.n;
        if self.contour.is_empty() {
            // no contour slot: every point is the rig's own
            for (j, o) in out.iter_mut().enumerate() {
                let d = &self.deltas[j * n..(j + 1) * n];
                let mut p = self.neutral[j];
                for &(k, w) in on {
                    p += d[k] * w;
                }
                *o = p;
            }
            return;
        }
        for (j, o) in out.iter_mut().enumerate() {
            let mut p = self.point_neutral(cw, j);
            let d = self.point_deltas(cw, j);
            for &(k, w) in on {
                p += d[k] * w;
            }
            *o = p;
        }
    }

    /// [`Exact3dSolver::pose_points`] testing each shape at each point (for more than
    /// [`ACTIVE_MAX`] shapes on).
    fn pose_points_all(&self, cw: &ContourWork, e: &[f64], out: &mut [Vector3<f64>]) {
        for (j, o) in out.iter_mut().enumerate() {
            let mut p = self.point_neutral(cw, j);
            for (&d, &w) in self.point_deltas(cw, j).iter().zip(e) {
                if w != 0.0 {
                    p += d * w;
                }
            }
            *o = p;
        }
    }

    /// Neutral of point `j` (the chosen contour candidate for a contour slot).
    #[inline]
    fn point_neutral(&self, cw: &ContourWork, j: usize) -> Vector3<f64> {
        match self.slot_of.get(j) {
            Some(&s) if s != NO_SLOT => self.neutral[j] + cw.offset[s],
            _ => self.neutral[j],
        }
    }

    /// Per-shape deltas of point `j` (the chosen contour candidate's for a contour slot).
    #[inline]
    fn point_deltas<'a>(&'a self, cw: &'a ContourWork, j: usize) -> &'a [Vector3<f64>] {
        let n = self.n;
        match self.slot_of.get(j) {
            Some(&s) if s != NO_SLOT => &cw.deltas[s * n..(s + 1) * n],
            _ => &self.deltas[j * n..(j + 1) * n],
        }
    }

    /// Chooses each contour slot's point on the silhouette under `pose` (see
    /// [`crate::contour`]). Returns the largest move of a chosen point (model units).
    fn select_contour(&self, pose: &Pose, cw: &mut ContourWork) -> f64 {
        let n = self.n;
        let mut moved = 0.0f64;
        for (s, slot) in self.contour.iter().enumerate() {
            let k = slot.normals.len();
            let f = &mut cw.facing[..k];
            let base = self.neutral[slot.point];
            // cosine between a normal and the direction to the camera (perspective)
            let facing = |r: &Rotation3<f64>, x: Vector3<f64>, n: &Vector3<f64>| {
                let c = r * x + pose.t;
                let d = c.norm();
                if d > 0.0 {
                    -(r * n).dot(&c) / d
                } else {
                    0.0
                }
            };
            for ((fc, nc), oc) in f.iter_mut().zip(&slot.normals).zip(&slot.offsets) {
                *fc = facing(&pose.r, base + oc, nc);
            }
            let x = silhouette_index(f, slot.anchor, slot.tau).clamp(0.0, (k - 1) as f64);
            let i0 = (x.floor() as usize).min(k - 1);
            let i1 = (i0 + 1).min(k - 1);
            let a = x - i0 as f64;
            let off = slot.offsets[i0] * (1.0 - a) + slot.offsets[i1] * a;
            moved = moved.max((off - cw.offset[s]).norm());
            cw.offset[s] = off;
            cw.index[s] = x;
            let (d0, d1) = (&slot.deltas[i0 * n..(i0 + 1) * n], &slot.deltas[i1 * n..(i1 + 1) * n]);
            for ((o, p), q) in cw.deltas[s * n..(s + 1) * n].iter_mut().zip(d0).zip(d1) {
                *o = p * (1.0 - a) + q * a;
            }
        }
        moved
    }

    /// A contour state at the mapped vertices (nothing chosen yet).
    fn contour_work(&self) -> ContourWork {
        let n = self.n;
        let longest = self.contour.iter().map(|c| c.normals.len()).max().unwrap_or(0);
        let mut deltas = Vec::with_capacity(self.contour.len() * n);
        for c in &self.contour {
            deltas.extend_from_slice(&c.deltas[c.anchor * n..(c.anchor + 1) * n]);
        }
        ContourWork {
            offset: vec![Vector3::zeros(); self.contour.len()],
            index: self.contour.iter().map(|c| c.anchor as f64).collect(),
            deltas,
            facing: vec![0.0; longest],
        }
    }

    /// Number of contour landmarks whose correspondence follows the pose (0 when the rig
    /// has no contour candidates).
    pub fn num_contour(&self) -> usize {
        self.contour.len()
    }

    /// After a solve with `ws`: each contour landmark's chosen point as an offset from the
    /// landmark's neutral (model frame), `(landmark, offset)`.
    pub fn contour_offsets(&self, ws: &Exact3dWorkspace) -> Vec<(usize, Vector3<f64>)> {
        self.contour
            .iter()
            .zip(&ws.cw.offset)
            .map(|(c, o)| (self.idx[c.point], *o))
            .collect()
    }

    /// After a solve with `ws`: each contour landmark's chosen position along its
    /// candidate line, in candidates from the mapped vertex (`+`: towards the back),
    /// `(landmark, steps)`.
    pub fn contour_steps(&self, ws: &Exact3dWorkspace) -> Vec<(usize, f64)> {
        self.contour
            .iter()
            .zip(&ws.cw.index)
            .map(|(c, &x)| (self.idx[c.point], x - c.anchor as f64))
            .collect()
    }

    /// `F` at (pose, e); `+inf` if a point is behind the camera.
    #[allow(clippy::too_many_arguments)]
    fn cost(
        &self,
        cw: &ContourWork,
        pose: &Pose,
        e: &[f64],
        ws_posed: &mut [Vector3<f64>],
        obs: &[f64],
        rho: &[f64],
        prev: Option<&[f64]>,
    ) -> f64 {
        self.pose_points(cw, e, ws_posed);
        let k = &self.params.camera;
        let mut f = 0.0;
        for (j, x) in ws_posed.iter().enumerate() {
            let c = pose.r * x + pose.t;
            if c.z <= MIN_DEPTH {
                return f64::INFINITY;
            }
            let u = k.fx * c.x / c.z + k.cx - obs[2 * j];
            let v = k.fy * c.y / c.z + k.cy - obs[2 * j + 1];
            let w = self.sqrt_w[j] * self.sqrt_w[j];
            f += w * (u * u + v * v);
        }
        let obj = &self.params.objective;
        f += obj.l1 * e.iter().sum::<f64>();
        f += rho.iter().zip(e).map(|(r, x)| r * x * x).sum::<f64>();
        if let Some(p) = prev {
            let t = &self.priors.temporal;
            f += obj.temporal
                * e.iter()
                    .zip(p)
                    .zip(t)
                    .map(|((a, b), w)| w * (a - b) * (a - b))
                    .sum::<f64>();
        }
        f
    }

    /// Residuals and Jacobian (`2m x (6+n)`) at (pose, e). False if a point is behind the camera.
    fn linearise(&self, pose: &Pose, ws: &mut Exact3dWorkspace) -> bool {
        let n = self.n;
        let cols = POSE + n;
        let k = &self.params.camera;
        let e = &ws.e;
        let m = ws.m;
        self.pose_points(&ws.cw, e, &mut ws.posed[..m]);
        for (j, x) in ws.posed[..m].iter().enumerate() {
            let rx = pose.r * x;
            let c = rx + pose.t;
            if c.z <= MIN_DEPTH {
                return false;
            }
            let sw = self.sqrt_w[j];
            // Pixel, d pi / d c and d pi / d (w, t) (rows scaled by the point weight).
            let jac = point_jacobian(k, &rx, &c);
            ws.r[2 * j] = sw * (jac.pixel[0] - ws.obs[2 * j]);
            ws.r[2 * j + 1] = sw * (jac.pixel[1] - ws.obs[2 * j + 1]);
            let (ru, rv) = (2 * j * cols, (2 * j + 1) * cols);
            for a in 0..POSE {
                ws.a[ru + a] = sw * jac.d_pose[0][a];
                ws.a[rv + a] = sw * jac.d_pose[1][a];
            }
            let [ju, jv] = jac.d_point;
            let dj = self.point_deltas(&ws.cw, j);
            for (kk, dk) in dj.iter().enumerate() {
                let d = pose.r * dk;
                ws.a[ru + POSE + kk] = sw * (ju[0] * d.x + ju[2] * d.z);
                ws.a[rv + POSE + kk] = sw * (jv[1] * d.y + jv[2] * d.z);
            }
        }
        true
    }

    /// Affine-camera initial pose for weights `e` (module docs, step 1).
    fn initial_pose(&self, ws: &mut Exact3dWorkspace) -> Result<Pose> {
        let np = ws.m;
        self.pose_points(&ws.cw, &ws.e, &mut ws.posed[..np]);
        let k = &self.params.camera;
        let mut m = Matrix4::<f64>::zeros();
        let (mut bu, mut bv) = (Vector4::<f64>::zeros(), Vector4::<f64>::zeros());
        for (j, x) in ws.posed[..np].iter().enumerate() {
            let h = Vector4::new(x.x, x.y, x.z, 1.0);
            m += h * h.transpose();
            bu += h * ws.obs[2 * j];
            bv += h * ws.obs[2 * j + 1];
        }
        let degenerate = || Error::Input {
            reason: "landmarks too degenerate for the initial pose".into(),
        };
        let chol = m.cholesky().ok_or_else(degenerate)?;
        let pu = chol.solve(&bu);
        let pv = chol.solve(&bv);
        let a1 = Vector3::new(pu[0], pu[1], pu[2]) / k.fx;
        let a2 = Vector3::new(pv[0], pv[1], pv[2]) / k.fy;
        let (n1, n2) = (a1.norm(), a2.norm());
        if !(n1 > 0.0 && n2 > 0.0 && n1.is_finite() && n2.is_finite()) {
            return Err(degenerate());
        }
        let r1 = a1 / n1;
        let r2 = a2 - r1 * r1.dot(&a2);
        let r2n = r2.norm();
        if r2n <= 0.0 || r2n.is_nan() {
            return Err(degenerate());
        }
        let r2 = r2 / r2n;
        let r3 = r1.cross(&r2);
        let rm = nalgebra::Matrix3::from_rows(&[r1.transpose(), r2.transpose(), r3.transpose()]);
        let z = 2.0 / (n1 + n2);
        let t = Vector3::new((pu[3] - k.cx) * z / k.fx, (pv[3] - k.cy) * z / k.fy, z);
        Ok(Pose {
            r: Rotation3::from_matrix_unchecked(rm),
            t,
        })
    }

    /// The rigid update (weights fixed): `pose_iterations` iterations of the shared
    /// Levenberg-Marquardt pose refinement ([`facecap_geom::pnp::refine_pose`]) on the
    /// landmark-weighted reprojection error, kept when it lowers `F`. Returns the new cost.
    fn rigid_update(&self, pose: &mut Pose, cost: f64, prev: Option<&[f64]>, ws: &mut Exact3dWorkspace) -> f64 {
        if self.params.pose_iterations == 0 {
            return cost;
        }
        let m = ws.m;
        self.pose_points(&ws.cw, &ws.e, &mut ws.posed[..m]);
        for (j, x) in ws.posed[..m].iter().enumerate() {
            ws.rigid_model[j] = Point3::from(*x);
            ws.rigid_image[j] = Point2::new(ws.obs[2 * j], ws.obs[2 * j + 1]);
            ws.rigid_w[j] = self.sqrt_w[j] * self.sqrt_w[j];
        }
        let lm = PnpParams {
            max_iterations: self.params.pose_iterations,
            initial_damping: RIGID_DAMPING0,
            ..PnpParams::default()
        };
        let mut refined = pose.to_model_to_camera();
        let k = &self.params.camera;
        if refine_pose(
            &mut refined,
            k,
            &ws.rigid_model[..m],
            &ws.rigid_image[..m],
            Some(&ws.rigid_w[..m]),
            &lm,
        )
        .is_err()
        {
            return cost;
        }
        let trial = Pose::from_model_to_camera(&refined);
        let c = self.cost(&ws.cw, &trial, &ws.e, &mut ws.posed[..m], &ws.obs, &ws.rho, prev);
        if c < cost {
            *pose = trial;
            c
        } else {
            cost
        }
    }
}

impl ExpressionSolver for Exact3dSolver {
    type Workspace = Exact3dWorkspace;

    fn num_shapes(&self) -> usize {
        self.n
    }

    fn names(&self) -> &[String] {
        &self.names
    }

    fn workspace(&self) -> Exact3dWorkspace {
        let m = self.neutral.len();
        let n = self.n;
        let cols = POSE + n;
        let mut lo = vec![f64::NEG_INFINITY; cols];
        let mut hi = vec![f64::INFINITY; cols];
        lo[POSE..].fill(0.0);
        hi[POSE..].fill(1.0);
        Exact3dWorkspace {
            posed: vec![Vector3::zeros(); m],
            m: self.idx.len(),
            obs: vec![0.0; 2 * m],
            r: vec![0.0; 2 * m],
            a: vec![0.0; 2 * m * cols],
            h: vec![0.0; cols * cols],
            g: vec![0.0; cols],
            lo,
            hi,
            z: vec![0.0; cols],
            e: vec![0.0; n],
            e_trial: vec![0.0; n],
            rho: vec![0.0; n],
            rigid_model: vec![Point3::origin(); m],
            rigid_image: vec![Point2::origin(); m],
            rigid_w: vec![0.0; m],
            cw: self.contour_work(),
            qp: QpWorkspace::new(cols),
        }
    }

    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut Exact3dWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        self.solve_dense_into(input, None, ws, state, out)
    }
}

impl Exact3dSolver {
    /// [`ExpressionSolver::solve_into`] with the dense points' observations too: `dense`
    /// holds the dense input (e.g. the face mesh's 478 points, pixels; `z` unused), read at
    /// each dense point's source index. Without it, or when it is too short or not finite
    /// at a used index, the frame is solved on the landmarks alone (as `solve_into`).
    ///
    /// # Errors
    /// As [`ExpressionSolver::solve_into`].
    pub fn solve_dense_into(
        &self,
        input: &Landmarks68,
        dense: Option<&[[f32; 3]]>,
        ws: &mut Exact3dWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        let n = self.n;
        check_io(n, input, state, out)?;
        let m0 = self.idx.len();
        ws.m = m0;
        if let Some(d) = dense {
            let usable = !self.dense_sources.is_empty()
                && self
                    .dense_sources
                    .iter()
                    .all(|&s| s < d.len() && d[s][0].is_finite() && d[s][1].is_finite());
            if usable {
                for (j, &s) in self.dense_sources.iter().enumerate() {
                    ws.obs[2 * (m0 + j)] = f64::from(d[s][0]);
                    ws.obs[2 * (m0 + j) + 1] = f64::from(d[s][1]);
                }
                ws.m = self.neutral.len();
            }
        }
        let obj = self.params.objective;
        let mu = if state.has_previous { obj.temporal } else { 0.0 };
        for (j, &l) in self.idx.iter().enumerate() {
            ws.obs[2 * j] = input.points[l].x;
            ws.obs[2 * j + 1] = input.points[l].y;
        }
        ws.e.copy_from_slice(&state.weights);
        let scale = prior_scale(input);
        for kk in 0..n {
            ws.rho[kk] = self.priors.ridge[kk] * scale;
            ws.hi[POSE + kk] = if self.priors.fixed[kk] { 0.0 } else { 1.0 };
            if self.priors.fixed[kk] {
                ws.e[kk] = 0.0;
            }
        }
        let prev_buf = &state.weights;
        let prev = if mu > 0.0 { Some(prev_buf.as_slice()) } else { None };
        let mut pose = match (&state.pose, state.has_previous) {
            (Some(p), true) => Pose::from_model_to_camera(p),
            _ => self.initial_pose(ws)?,
        };
        let mut cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, prev);
        if !cost.is_finite() {
            pose = self.initial_pose(ws)?;
            cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, prev);
            if !cost.is_finite() {
                return Err(Error::Input {
                    reason: "no pose puts the face in front of the camera".into(),
                });
            }
        }
        if !self.contour.is_empty() {
            self.select_contour(&pose, &mut ws.cw);
            cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, prev);
            if !cost.is_finite() {
                return Err(Error::Input {
                    reason: "no pose puts the face in front of the camera".into(),
                });
            }
        }
        let cols = POSE + n;
        let opts = QpOptions::default();
        let mut stop = StopReason::MaxIterations;
        let mut iterations = 0;
        let mut inner = 0;
        for contour_pass in 0..2 {
            if contour_pass > 0 {
                // the solve moved the pose: choose the contour points again, and solve again
                // when one moved noticeably
                let moved = self.select_contour(&pose, &mut ws.cw);
                let px = moved * self.params.camera.fx.max(self.params.camera.fy) / pose.t.z.max(MIN_DEPTH);
                if px.is_nan() || px <= CONTOUR_RESOLVE_PX {
                    break;
                }
                cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, prev);
                if !cost.is_finite() {
                    break;
                }
            }
            for round in 0..=MAX_EXCLUSIVE_ROUNDS {
                if round > 0 {
                    // an exclusive pair is active together: hold the smaller of each at 0
                    let mut changed = false;
                    for &(a, b) in &self.priors.exclusive {
                        if ws.e[a] > EXCLUSIVE_EPS && ws.e[b] > EXCLUSIVE_EPS {
                            let loser = if ws.e[a] < ws.e[b] { a } else { b };
                            ws.hi[POSE + loser] = 0.0;
                            ws.e[loser] = 0.0;
                            changed = true;
                        }
                    }
                    if !changed {
                        break;
                    }
                    cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, prev);
                }
                for _ in 0..self.params.max_alternations {
                    iterations += 1;
                    let before = cost;
                    cost = self.rigid_update(&mut pose, cost, prev, ws);
                    if !self.linearise(&pose, ws) {
                        break;
                    }
                    // H = 2 A^T A (+ 2 mu on e), g = -2 A^T c - lambda + 2 mu e_prev, c = r - A_e e
                    let rows = 2 * ws.m;
                    for row in 0..rows {
                        let mut c = ws.r[row];
                        for kk in 0..n {
                            c -= ws.a[row * cols + POSE + kk] * ws.e[kk];
                        }
                        ws.r[row] = c;
                    }
                    gram_upper(&ws.a[..rows * cols], &ws.r[..rows], cols, &mut ws.h, &mut ws.g);
                    for a in 0..cols {
                        for b in 0..a {
                            ws.h[a * cols + b] = ws.h[b * cols + a];
                        }
                    }
                    for kk in 0..n {
                        let i = POSE + kk;
                        let mu_k = mu * self.priors.temporal[kk];
                        ws.h[i * cols + i] += 2.0 * mu_k + 2.0 * ws.rho[kk] + self.ridge;
                        ws.g[i] += -obj.l1 + 2.0 * mu_k * state.weights[kk];
                    }
                    for a in 0..POSE {
                        ws.h[a * cols + a] += self.ridge;
                    }
                    ws.z[..POSE].fill(0.0);
                    ws.z[POSE..].copy_from_slice(&ws.e);
                    if !self.params.joint {
                        ws.lo[..POSE].fill(0.0);
                        ws.hi[..POSE].fill(0.0);
                    }
                    let o = solve_box_qp(&ws.h, &ws.g, &ws.lo, &ws.hi, &mut ws.z, &opts, &mut ws.qp);
                    inner += o.iterations;
                    // backtracking on F along the QP step
                    let mut alpha = 1.0;
                    let mut accepted = false;
                    for _ in 0..MAX_HALVINGS {
                        let trial_pose = pose.step(&ws.z[..POSE], alpha);
                        for kk in 0..n {
                            ws.e_trial[kk] = ws.e[kk] + alpha * (ws.z[POSE + kk] - ws.e[kk]);
                        }
                        let c = self.cost(
                            &ws.cw,
                            &trial_pose,
                            &ws.e_trial,
                            &mut ws.posed[..ws.m],
                            &ws.obs,
                            &ws.rho,
                            prev,
                        );
                        if c < cost {
                            pose = trial_pose;
                            ws.e.copy_from_slice(&ws.e_trial);
                            cost = c;
                            accepted = true;
                            break;
                        }
                        alpha *= 0.5;
                    }
                    if !accepted || before - cost <= self.params.tol * before.abs().max(1e-300) {
                        stop = StopReason::SmallDecrease;
                        break;
                    }
                }
                if self.priors.exclusive.is_empty() {
                    break;
                }
            }
            if self.contour.is_empty() {
                break;
            }
        }
        // outputs
        let k = &self.params.camera;
        self.pose_points(&ws.cw, &ws.e, &mut ws.posed[..ws.m]);
        out.fitted = [Point2::new(f64::NAN, f64::NAN); NUM_LANDMARKS];
        for (j, &l) in self.idx.iter().enumerate() {
            let c = pose.r * ws.posed[j] + pose.t;
            out.fitted[l] = Point2::new(k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy);
        }
        out.weights.copy_from_slice(&ws.e);
        self.to_weights(&mut out.weights);
        out.pose = Some(pose.to_model_to_camera());
        out.similarity = None;
        // the state keeps the solver's own variables (see `ShapePriors::coupled`)
        state.weights.copy_from_slice(&ws.e);
        state.pose = out.pose;
        state.has_previous = true;
        Ok(Report {
            iterations,
            evaluations: inner,
            cost,
            stop,
        })
    }
}

impl Exact3dSolver {
    /// The objective `F` for given weights and pose (e.g. to score another method's weights
    /// under the 3D model). `prev` enables the temporal term.
    pub fn objective(
        &self,
        input: &Landmarks68,
        weights: &[f64],
        pose: &ModelToCamera,
        prev: Option<&[f64]>,
    ) -> Result<f64> {
        if weights.len() != self.n {
            return Err(Error::DimensionMismatch {
                what: "weights".into(),
                expected: self.n,
                got: weights.len(),
            });
        }
        let mut posed = vec![Vector3::zeros(); self.idx.len()];
        let mut obs = vec![0.0; 2 * self.idx.len()];
        for (j, &l) in self.idx.iter().enumerate() {
            obs[2 * j] = input.points[l].x;
            obs[2 * j + 1] = input.points[l].y;
        }
        let scale = prior_scale(input);
        let rho: Vec<f64> = self.priors.ridge.iter().map(|r| r * scale).collect();
        let pose = Pose::from_model_to_camera(pose);
        let mut cw = self.contour_work();
        self.select_contour(&pose, &mut cw);
        let z = self.to_variables(weights);
        let prev = prev.map(|p| self.to_variables(p));
        Ok(self.cost(&cw, &pose, &z, &mut posed, &obs, &rho, prev.as_deref()))
    }

    /// The best pose for fixed weights (affine start + rigid LM to convergence) and its
    /// objective: scores another method's weights under the 3D model.
    pub fn fit_pose(&self, input: &Landmarks68, weights: &[f64]) -> Result<(ModelToCamera, f64)> {
        let mut ws = self.workspace();
        if weights.len() != self.n {
            return Err(Error::DimensionMismatch {
                what: "weights".into(),
                expected: self.n,
                got: weights.len(),
            });
        }
        ws.e.copy_from_slice(&self.to_variables(weights));
        ws.m = self.idx.len();
        for (j, &l) in self.idx.iter().enumerate() {
            ws.obs[2 * j] = input.points[l].x;
            ws.obs[2 * j + 1] = input.points[l].y;
        }
        let mut pose = self.initial_pose(&mut ws)?;
        let scale = prior_scale(input);
        for (r, p) in ws.rho.iter_mut().zip(&self.priors.ridge) {
            *r = p * scale;
        }
        let mut s = self.clone();
        s.params.pose_iterations = 50;
        let mut cost = f64::INFINITY;
        for pass in 0..2 {
            if pass > 0 && self.select_contour(&pose, &mut ws.cw) == 0.0 {
                break;
            }
            cost = self.cost(&ws.cw, &pose, &ws.e, &mut ws.posed[..ws.m], &ws.obs, &ws.rho, None);
            for _ in 0..4 {
                cost = s.rigid_update(&mut pose, cost, None, &mut ws);
            }
        }
        Ok((pose.to_model_to_camera(), cost))
    }
}

/// `h = 2 A^T A` (the upper triangle and the diagonal; entries below it are left for the
/// caller to mirror) and `g = -2 A^T c` for the row-major `rows x cols` matrix `a` and the
/// residuals `c` (`h` and `g` are overwritten).
///
/// Every entry is the sum over the rows in row order of `(2 a_ra) a_rb` (rows whose
/// `a_ra` is 0 skipped), exactly as the plain row-by-row loop forms it
/// ([`gram_upper_reference`]), so the result is the same to the last bit; the rows are taken
/// in chunks that stay in L1 and each `(a, b)` block accumulates over a chunk in registers
/// (compiled for the CPU found at run time: AVX2 where available).
fn gram_upper(a: &[f64], c: &[f64], cols: usize, h: &mut [f64], g: &mut [f64]) {
    pulp::Arch::new().dispatch(Gram { a, c, cols, h, g });
}

struct Gram<'a> {
    a: &'a [f64],
    c: &'a [f64],
    cols: usize,
    h: &'a mut [f64],
    g: &'a mut [f64],
}

/// Rows of `A` per chunk of [`gram_upper`] (32 rows of 58 columns: 15 KiB, in L1).
const GRAM_CHUNK_ROWS: usize = 32;

impl pulp::WithSimd for Gram<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Gram { a, c, cols, h, g } = self;
        let rows = c.len().min(a.len() / cols.max(1));
        let h = &mut h[..cols * cols];
        let g = &mut g[..cols];
        h.fill(0.0);
        g.fill(0.0);
        for (ar, &cr) in a.chunks_exact(cols).zip(c).take(rows) {
            for (gv, &va) in g.iter_mut().zip(ar) {
                if va != 0.0 {
                    *gv -= 2.0 * va * cr;
                }
            }
        }
        let mut r0 = 0;
        while r0 < rows {
            let chunk = &a[r0 * cols..(r0 + GRAM_CHUNK_ROWS).min(rows) * cols];
            // four rows of H at a time (eight registers of independent sums, no spills), then the
            // last rows one at a time
            let mut i = 0;
            while i + 4 <= cols {
                let mut b0 = i;
                while b0 + 8 <= cols {
                    gram_block4::<8>(chunk, cols, i, b0, h);
                    b0 += 8;
                }
                while b0 + 4 <= cols {
                    gram_block4::<4>(chunk, cols, i, b0, h);
                    b0 += 4;
                }
                while b0 + 2 <= cols {
                    gram_block4::<2>(chunk, cols, i, b0, h);
                    b0 += 2;
                }
                if b0 < cols {
                    gram_block4::<1>(chunk, cols, i, b0, h);
                }
                i += 4;
            }
            for i in i..cols {
                let hrow = &mut h[i * cols + i..(i + 1) * cols];
                for ar in chunk.chunks_exact(cols) {
                    let va = ar[i];
                    if va == 0.0 {
                        continue;
                    }
                    let t = 2.0 * va;
                    for (hv, &x) in hrow.iter_mut().zip(&ar[i..]) {
                        *hv += t * x;
                    }
                }
            }
            r0 += GRAM_CHUNK_ROWS;
        }
    }
}

/// `h[i + k][b0 + j] += (2 a_r(i+k)) a_r(b0 + j)`, `k < 4`, `j < W`, over the rows `r` of
/// `chunk` in order, accumulated in registers. A row whose four `a_r(i+k)` are 0 is skipped;
/// otherwise a zero `a_r(i+k)` adds `+-0`, which leaves every sum as it was (a sum that
/// starts at `+0` is never `-0`), so each entry is still exactly the row loop's.
#[inline(always)]
fn gram_block4<const W: usize>(chunk: &[f64], cols: usize, i: usize, b0: usize, h: &mut [f64]) {
    let mut acc = [[0.0f64; W]; 4];
    for (k, acc) in acc.iter_mut().enumerate() {
        acc.copy_from_slice(&h[(i + k) * cols + b0..(i + k) * cols + b0 + W]);
    }
    for ar in chunk.chunks_exact(cols) {
        let (Ok(va), Ok(x)) = (
            <&[f64; 4]>::try_from(&ar[i..i + 4]),
            <&[f64; W]>::try_from(&ar[b0..b0 + W]),
        ) else {
            return;
        };
        if va[0] == 0.0 && va[1] == 0.0 && va[2] == 0.0 && va[3] == 0.0 {
            continue;
        }
        for k in 0..4 {
            let t = 2.0 * va[k];
            for j in 0..W {
                acc[k][j] += t * x[j];
            }
        }
    }
    for (k, acc) in acc.iter().enumerate() {
        h[(i + k) * cols + b0..(i + k) * cols + b0 + W].copy_from_slice(acc);
    }
}

/// The plain row-by-row form of [`gram_upper`] (tests compare the two bit for bit).
#[cfg(test)]
fn gram_upper_reference(a: &[f64], c: &[f64], cols: usize, h: &mut [f64], g: &mut [f64]) {
    h.fill(0.0);
    g.fill(0.0);
    for (ar, &cr) in a.chunks_exact(cols).zip(c) {
        for i in 0..cols {
            let va = ar[i];
            if va == 0.0 {
                continue;
            }
            g[i] -= 2.0 * va * cr;
            let hrow = &mut h[i * cols..(i + 1) * cols];
            for b in i..cols {
                hrow[b] += 2.0 * va * ar[b];
            }
        }
    }
}

#[cfg(test)]
mod gram_tests {
    use super::*;

    /// The blocked, dispatched normal equations equal the plain row loop bit for bit, for
    /// column counts around the block widths and rows with exact zeros (the built-in rig's
    /// 68-point rows are three-quarters zeros).
    #[test]
    fn blocked_gram_equals_the_row_loop_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for &(rows, cols) in &[
            (1, 1),
            (3, 5),
            (33, 7),
            (136, 58),
            (936, 58),
            (70, 17),
            (65, 24),
            (5, 13),
        ] {
            let a: Vec<f64> = (0..rows * cols)
                .map(|_| {
                    let v = next();
                    if v.abs() < 0.5 {
                        0.0
                    } else {
                        v * 1e3
                    }
                })
                .collect();
            let c: Vec<f64> = (0..rows).map(|_| next() * 10.0).collect();
            let (mut h, mut g) = (vec![f64::NAN; cols * cols], vec![f64::NAN; cols]);
            let (mut hr, mut gr) = (vec![0.0; cols * cols], vec![0.0; cols]);
            gram_upper(&a, &c, cols, &mut h, &mut g);
            gram_upper_reference(&a, &c, cols, &mut hr, &mut gr);
            for i in 0..cols {
                assert_eq!(g[i].to_bits(), gr[i].to_bits(), "g[{i}] rows {rows} cols {cols}");
                for j in i..cols {
                    let (x, y) = (h[i * cols + j], hr[i * cols + j]);
                    assert_eq!(
                        x.to_bits(),
                        y.to_bits(),
                        "h[{i}][{j}] rows {rows} cols {cols}: {x} vs {y}"
                    );
                }
            }
        }
    }
}
