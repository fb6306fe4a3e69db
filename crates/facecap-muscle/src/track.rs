//! Contraction tracking: the thesis' Algorithm 2, made automatic.
//!
//! Per frame, given 2D observations `x_k` of `K` tracked model vertices (the mapped 68
//! landmarks, optionally extra optical-flow points) and pinhole intrinsics:
//!
//! 1. **Targets, frame-to-frame difference with carried error** (thesis section 3.3). The
//!    model is moved by the *observed motion*, not fitted to absolute positions:
//!    `y_k(t) = p_k(t-1) + (x_k(t) - x_k(t-1)) + carry * e_k(t-1)`, where `p_k(t-1)` is the
//!    model's projection at the previous solution and `e_k(t-1) = y_k(t-1) - p_k(t-1)` the
//!    error left unexplained there, carried forward so that it does not accumulate as drift.
//!    At the first frame (assumed neutral, as in the thesis) `c = 0`, `theta = 0`, only the
//!    pose is solved and `y_k = p_k`: the mismatch between the actor's neutral face and the
//!    mesh is never attributed to muscles. With `carry = 1`, `y_k(t) = x_k(t) - o_k` with
//!    the first-frame offset `o_k = x_k(0) - p_k(0)`.
//! 2. **Head pose** by PnP (core's EPnP + Levenberg-Marquardt) on the static points (eye
//!    corners, nose), with the model deformed by the current contractions.
//! 3. **Jaw angle** by golden-section search on `[0, max_angle]` of the jaw point's error.
//! 4. **Contractions** by bounded minimisation on `[0, 1]^M` of
//!    `sum_k |pi(K (R P_k(c, theta) + t)) - y_k|^2 + lambda |c|^2` with analytic gradients:
//!    projected Gauss-Newton whose box-constrained quadratic sub-problems are solved
//!    exactly by projected coordinate descent, or the thesis' point-by-point scheme.
//!    * [`SolveMode::PointByPoint`] (thesis): each muscle in turn fits only its own
//!      most-displaced point(s) by a bounded 1-D Gauss-Newton; steps 3-4 and a PnP pose
//!      refinement alternate `outer_iterations` times.
//!    * [`SolveMode::Global`] (ours): steps 2-3 only initialise one joint solve over all
//!      points of head pose (6, free), jaw angle (bounded) and contractions (bounded);
//!      the pose block is eliminated by its Schur complement each iteration. The joint
//!      solve removes the pose/muscle coupling that the alternation leaves (muscles also
//!      move the "static" points slightly: the cheek pulls the outer eye corners).
//!
//! Because the posed point is `P_k = A_k(theta) (B_k + sum_i c_i D_ik) + b_k(theta)` with
//! `A_k = (1 - w_k) I + w_k R_theta`, `b_k = w_k (pivot - R_theta pivot)`, the camera-space
//! point is *linear* in `c` for a fixed pose and jaw: `X_k = X0_k + sum_i c_i G_ik`,
//! `G_ik = R A_k D_ik`. The Jacobian row of muscle `i` is `dpi/dX (X_k) G_ik`, and
//! `dX_k/dtheta = R w_k [a]_x R_theta (P_m,k - pivot)`.
//!
//! Units: pixels (0-based, centre of the top-left pixel at (0, 0)), radians, mesh units.
//!
//! | parameter | default | meaning | range |
//! |---|---|---|---|
//! | `mode` | `Global` | contraction solver | `Global`, `PointByPoint` |
//! | `gn_iterations` | 15 | Gauss-Newton iterations per solve | >= 1 |
//! | `qp_sweeps` | 30 | coordinate-descent sweeps per sub-problem | >= 1 |
//! | `regularisation` | 0.25 | `lambda`, px^2 per unit contraction^2 | >= 0 |
//! | `outer_iterations` | 2 | pose / jaw / contraction alternations | >= 1 |
//! | `jaw_tolerance` | 1e-5 | golden-section bracket width (rad) | > 0 |
//! | `carry` | 1.0 | fraction of the error carried to the next frame | [0, 1] |
//! | `first_frame_neutral` | true | frame 0 is neutral (thesis) | |

use nalgebra::{Point2, Point3, Rotation3, Unit, Vector2, Vector3};

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmark_map::LandmarkMap;
use facecap_geom::golden::golden_section;
use facecap_geom::pnp::{apply_pose_step, point_jacobian, refine_pose, solve_pnp, PnpParams};

use crate::error::{Error, Result};
use crate::rig::MuscleRig;

/// 0-based iBUG landmarks used for the head pose: eye corners and the nose.
pub const STATIC_LANDMARKS: [usize; 13] = [36, 39, 42, 45, 27, 28, 29, 30, 31, 32, 33, 34, 35];
/// 0-based iBUG landmark of the jaw point (chin); 57 is used when it is unmapped.
pub const JAW_LANDMARK: usize = 8;

/// Contraction solver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolveMode {
    /// All contractions at once from all points (projected Gauss-Newton).
    Global,
    /// Thesis: each muscle from its own point(s), one after the other.
    PointByPoint,
}

/// Tracking parameters (see the module table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackParams {
    /// Contraction solver.
    pub mode: SolveMode,
    /// Gauss-Newton iterations per contraction solve.
    pub gn_iterations: usize,
    /// Coordinate-descent sweeps per quadratic sub-problem.
    pub qp_sweeps: usize,
    /// Tikhonov weight on the contractions (px^2).
    pub regularisation: f64,
    /// Pose / jaw / contraction alternations per frame.
    pub outer_iterations: usize,
    /// Golden-section tolerance (rad).
    pub jaw_tolerance: f64,
    /// Carried-error fraction.
    pub carry: f64,
    /// Treat frame 0 as neutral.
    pub first_frame_neutral: bool,
    /// PnP settings.
    pub pnp: PnpParams,
}

impl Default for TrackParams {
    fn default() -> Self {
        TrackParams {
            mode: SolveMode::Global,
            gn_iterations: 15,
            qp_sweeps: 30,
            regularisation: 0.25,
            outer_iterations: 2,
            jaw_tolerance: 1e-5,
            carry: 1.0,
            first_frame_neutral: true,
            pnp: PnpParams::default(),
        }
    }
}

impl TrackParams {
    /// Validates every field.
    ///
    /// # Errors
    /// Names the parameter and its range.
    pub fn validate(&self) -> Result<()> {
        for (n, v) in [
            ("gn_iterations", self.gn_iterations),
            ("qp_sweeps", self.qp_sweeps),
            ("outer_iterations", self.outer_iterations),
        ] {
            if v == 0 {
                return Err(Error::invalid(n, v, ">= 1"));
            }
        }
        if !(self.regularisation.is_finite() && self.regularisation >= 0.0) {
            return Err(Error::invalid("regularisation", self.regularisation, "finite and >= 0"));
        }
        if !(self.jaw_tolerance.is_finite() && self.jaw_tolerance > 0.0) {
            return Err(Error::invalid("jaw_tolerance", self.jaw_tolerance, "finite and > 0"));
        }
        if !(self.carry.is_finite() && (0.0..=1.0).contains(&self.carry)) {
            return Err(Error::invalid("carry", self.carry, "in [0, 1]"));
        }
        self.pnp.validate()?;
        Ok(())
    }
}

/// The tracked subset of a rig: `K` vertices with dense per-muscle deltas.
#[derive(Debug, Clone)]
pub struct TrackModel {
    names: Vec<String>,
    vertices: Vec<u32>,
    base: Vec<Point3<f64>>,
    /// Muscle-major: `deltas[i * K + k]`.
    deltas: Vec<Vector3<f64>>,
    jaw_w: Vec<f64>,
    pivot: Point3<f64>,
    axis: Unit<Vector3<f64>>,
    max_jaw: f64,
    static_points: Vec<usize>,
    jaw_points: Vec<usize>,
    muscle_points: Vec<Vec<usize>>,
    landmark_of_point: Vec<Option<usize>>,
}

impl TrackModel {
    /// Builds the tracked subset. `vertices`: the `K` mesh vertices observed per frame;
    /// `static_points` (>= 4) and `jaw_points` index into `vertices`;
    /// `points_per_muscle` (>= 1): how many of each muscle's most displaced points it uses
    /// in [`SolveMode::PointByPoint`].
    ///
    /// # Errors
    /// Indices out of range, fewer than 4 static points, `points_per_muscle == 0`.
    pub fn new(
        rig: &MuscleRig,
        vertices: &[u32],
        static_points: &[usize],
        jaw_points: &[usize],
        points_per_muscle: usize,
    ) -> Result<Self> {
        let n = rig.base().len();
        let k = vertices.len();
        if let Some(v) = vertices.iter().find(|v| **v as usize >= n) {
            return Err(Error::invalid("tracked vertex", v, format!("< {n}")));
        }
        if static_points.len() < 4 {
            return Err(Error::invalid("static point count", static_points.len(), ">= 4"));
        }
        if let Some(i) = static_points.iter().chain(jaw_points).find(|i| **i >= k) {
            return Err(Error::invalid("static/jaw point index", i, format!("< {k}")));
        }
        if points_per_muscle == 0 {
            return Err(Error::invalid("points_per_muscle", 0, ">= 1"));
        }
        let m = rig.num_muscles();
        let mut deltas = vec![Vector3::zeros(); m * k];
        let mut slot = vec![usize::MAX; n];
        for (kk, &v) in vertices.iter().enumerate() {
            slot[v as usize] = kk;
        }
        // Duplicate vertices keep every slot: fill through a per-vertex loop.
        for (i, f) in rig.fields().iter().enumerate() {
            for (&v, d) in f.indices.iter().zip(&f.deltas) {
                if slot[v as usize] != usize::MAX {
                    for (kk, &vv) in vertices.iter().enumerate() {
                        if vv == v {
                            deltas[i * k + kk] = *d;
                        }
                    }
                }
            }
        }
        let mut jaw_w = vec![0.0; k];
        let (pivot, axis, max_jaw) = match rig.jaw() {
            Some(j) => {
                for (&v, &w) in j.indices.iter().zip(&j.weights) {
                    for (kk, &vv) in vertices.iter().enumerate() {
                        if vv == v {
                            jaw_w[kk] = w;
                        }
                    }
                }
                (j.pivot, j.axis, j.max_angle)
            }
            None => (Point3::origin(), Vector3::x_axis(), 0.0),
        };
        let muscle_points = (0..m)
            .map(|i| {
                let mut order: Vec<usize> = (0..k).filter(|kk| deltas[i * k + kk].norm() > 0.0).collect();
                order.sort_by(|a, b| deltas[i * k + b].norm().total_cmp(&deltas[i * k + a].norm()));
                order.truncate(points_per_muscle);
                order
            })
            .collect();
        Ok(TrackModel {
            names: rig.names().to_vec(),
            vertices: vertices.to_vec(),
            base: vertices.iter().map(|&v| rig.base()[v as usize]).collect(),
            deltas,
            jaw_w,
            pivot,
            axis,
            max_jaw,
            static_points: static_points.to_vec(),
            jaw_points: jaw_points.to_vec(),
            muscle_points,
            landmark_of_point: vec![None; k],
        })
    }

    /// The usual model: the mapped landmarks (in landmark order) then `extra` vertices
    /// (e.g. optical-flow points). Static points are [`STATIC_LANDMARKS`], the jaw point
    /// [`JAW_LANDMARK`] (57 if unmapped).
    ///
    /// # Errors
    /// Fewer than 4 static landmarks mapped, no jaw point, bad vertex ids.
    pub fn from_landmarks(rig: &MuscleRig, map: &LandmarkMap, extra: &[u32], points_per_muscle: usize) -> Result<Self> {
        map.validate(rig.base().len())?;
        let mut vertices = Vec::new();
        let mut lm_of = Vec::new();
        let mut slot_of_lm = [None; 68];
        for (i, v) in map.mapped() {
            slot_of_lm[i] = Some(vertices.len());
            vertices.push(v);
            lm_of.push(Some(i));
        }
        vertices.extend_from_slice(extra);
        lm_of.extend(extra.iter().map(|_| None));
        let stat: Vec<usize> = STATIC_LANDMARKS.iter().filter_map(|&i| slot_of_lm[i]).collect();
        let jaw = slot_of_lm[JAW_LANDMARK]
            .or(slot_of_lm[57])
            .ok_or(Error::MissingLandmark {
                landmark: JAW_LANDMARK,
                purpose: "the jaw point (57 is the fallback)",
            })?;
        let mut model = Self::new(rig, &vertices, &stat, &[jaw], points_per_muscle)?;
        model.landmark_of_point = lm_of;
        Ok(model)
    }

    /// Number of tracked points `K`.
    pub fn num_points(&self) -> usize {
        self.base.len()
    }
    /// Number of muscles `M`.
    pub fn num_muscles(&self) -> usize {
        self.names.len()
    }
    /// Muscle names.
    pub fn names(&self) -> &[String] {
        &self.names
    }
    /// Mesh vertex of each tracked point.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }
    /// The iBUG landmark of each tracked point (None for extra points).
    pub fn landmark_of_point(&self) -> &[Option<usize>] {
        &self.landmark_of_point
    }
    /// Largest jaw angle.
    pub fn max_jaw(&self) -> f64 {
        self.max_jaw
    }
    /// Static (pose) points.
    pub fn static_points(&self) -> &[usize] {
        &self.static_points
    }
    /// Each muscle's points for the point-by-point solver.
    pub fn muscle_points(&self) -> &[Vec<usize>] {
        &self.muscle_points
    }

    /// Muscle-posed point before the jaw: `B_k + sum_i c_i D_ik`.
    fn muscled(&self, k: usize, c: &[f64]) -> Point3<f64> {
        let kk = self.base.len();
        let mut p = self.base[k];
        for (i, &ci) in c.iter().enumerate() {
            p += self.deltas[i * kk + k] * ci;
        }
        p
    }

    /// Posed model point `k` (model space).
    pub fn point(&self, k: usize, c: &[f64], jaw: f64) -> Point3<f64> {
        let pm = self.muscled(k, c);
        let w = self.jaw_w[k];
        if w == 0.0 || jaw == 0.0 {
            return pm;
        }
        let r = Rotation3::from_axis_angle(&self.axis, jaw);
        pm + (self.pivot + r * (pm - self.pivot) - pm) * w
    }

    /// Projection of point `k` and its analytic derivatives with respect to every
    /// contraction (`dc[i]`) and the jaw angle (returned second). `None` when the point is
    /// behind the camera.
    pub fn project_with_jacobian(
        &self,
        k: usize,
        pose: &ModelToCamera,
        intr: &Intrinsics,
        c: &[f64],
        jaw: f64,
        dc: &mut [Vector2<f64>],
    ) -> Option<(Point2<f64>, Vector2<f64>)> {
        let kk = self.base.len();
        let pm = self.muscled(k, c);
        let w = self.jaw_w[k];
        let rj = Rotation3::from_axis_angle(&self.axis, jaw);
        let a = Rotation3::identity().matrix() * (1.0 - w) + rj.matrix() * w;
        let p = pm + (self.pivot + rj * (pm - self.pivot) - pm) * w;
        let rc = pose.0.rotation.to_rotation_matrix();
        let x = pose.transform(&p);
        let proj = intr.project(&x)?;
        let dpi = point_jacobian(intr, &(rc * p.coords), &x.coords).d_point_matrix();
        for (i, d) in dc.iter_mut().enumerate().take(self.names.len()) {
            *d = dpi * (rc.matrix() * (a * self.deltas[i * kk + k]));
        }
        let dtheta = rc.matrix() * (self.axis.cross(&(rj * (pm - self.pivot))) * w);
        Some((proj, dpi * dtheta))
    }
}

/// Per-frame observations.
#[derive(Debug, Clone, Copy)]
pub struct TrackInput<'a> {
    /// One 2D point per tracked point (pixels).
    pub points: &'a [Point2<f64>],
    /// Optional confidence per point (0 = lost this frame; default all 1).
    pub weights: Option<&'a [f64]>,
}

/// Warm-start and carried state between frames.
#[derive(Debug, Clone)]
pub struct TrackState {
    /// Contractions of the last frame.
    pub contractions: Vec<f64>,
    /// Jaw angle of the last frame.
    pub jaw: f64,
    /// Head pose of the last frame (None before the first).
    pub pose: Option<ModelToCamera>,
    prev_obs: Vec<Point2<f64>>,
    prev_proj: Vec<Point2<f64>>,
    carried: Vec<Vector2<f64>>,
    frames: u64,
}

impl TrackState {
    /// Fresh state for `model`.
    pub fn new(model: &TrackModel) -> Self {
        let k = model.num_points();
        TrackState {
            contractions: vec![0.0; model.num_muscles()],
            jaw: 0.0,
            pose: None,
            prev_obs: vec![Point2::origin(); k],
            prev_proj: vec![Point2::origin(); k],
            carried: vec![Vector2::zeros(); k],
            frames: 0,
        }
    }
    /// Frames processed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

/// Scratch buffers (built once per model).
#[derive(Debug, Clone)]
pub struct TrackWorkspace {
    targets: Vec<Point2<f64>>,
    w: Vec<f64>,
    x0: Vec<Point3<f64>>,
    g: Vec<Vector3<f64>>,
    jac: Vec<Vector2<f64>>,
    hpb: Vec<nalgebra::Vector6<f64>>,
    h: Vec<f64>,
    grad: Vec<f64>,
    step: Vec<f64>,
    trial: Vec<f64>,
    stat_model: Vec<Point3<f64>>,
    stat_image: Vec<Point2<f64>>,
}

impl TrackWorkspace {
    /// Buffers for `model`.
    pub fn new(model: &TrackModel) -> Self {
        let (k, m) = (model.num_points(), model.num_muscles());
        TrackWorkspace {
            targets: vec![Point2::origin(); k],
            w: vec![1.0; k],
            x0: vec![Point3::origin(); k],
            g: vec![Vector3::zeros(); m * k],
            jac: vec![Vector2::zeros(); m + 1],
            hpb: vec![nalgebra::Vector6::zeros(); m + 1],
            h: vec![0.0; (m + 1) * (m + 1)],
            grad: vec![0.0; m + 1],
            step: vec![0.0; m + 1],
            trial: vec![0.0; m + 1],
            stat_model: Vec::with_capacity(model.static_points.len()),
            stat_image: Vec::with_capacity(model.static_points.len()),
        }
    }
}

/// Per-frame result.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackOutput {
    /// Contractions in `[0, 1]`, one per muscle.
    pub contractions: Vec<f64>,
    /// Jaw angle (rad).
    pub jaw: f64,
    /// Head pose.
    pub pose: ModelToCamera,
}

impl TrackOutput {
    /// Zeroed output for `model`.
    pub fn new(model: &TrackModel) -> Self {
        TrackOutput {
            contractions: vec![0.0; model.num_muscles()],
            jaw: 0.0,
            pose: ModelToCamera::identity(),
        }
    }
}

/// What happened in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackReport {
    /// Gauss-Newton iterations over all contraction solves.
    pub gn_iterations: usize,
    /// RMS distance (px) between the targets and the posed model's projections.
    pub rms_px: f64,
    /// RMS PnP error on the static points (px).
    pub pose_rms_px: f64,
    /// Points used (weight > 0).
    pub points_used: usize,
    /// True for the first frame (neutral: pose only).
    pub neutral_frame: bool,
}

/// The tracker: an immutable model plus validated parameters.
#[derive(Debug, Clone)]
pub struct MuscleTracker {
    model: TrackModel,
    params: TrackParams,
    intr: Intrinsics,
}

impl MuscleTracker {
    /// Validates and stores.
    ///
    /// # Errors
    /// Invalid parameters or intrinsics.
    pub fn new(model: TrackModel, intr: Intrinsics, params: TrackParams) -> Result<Self> {
        params.validate()?;
        Intrinsics::new(intr.fx, intr.fy, intr.cx, intr.cy)?;
        Ok(MuscleTracker { model, params, intr })
    }

    /// The model.
    pub fn model(&self) -> &TrackModel {
        &self.model
    }
    /// The parameters.
    pub fn params(&self) -> &TrackParams {
        &self.params
    }

    /// Tracks one frame (see module docs). No allocation after the first frame.
    ///
    /// # Errors
    /// Wrong input length, non-finite observed points with weight > 0, negative weights,
    /// or a PnP failure on the first frame.
    pub fn solve_into(
        &self,
        input: &TrackInput<'_>,
        ws: &mut TrackWorkspace,
        state: &mut TrackState,
        out: &mut TrackOutput,
    ) -> Result<TrackReport> {
        let md = &self.model;
        let k = md.num_points();
        if input.points.len() != k {
            return Err(Error::DimensionMismatch {
                what: "tracked point count".into(),
                expected: k,
                got: input.points.len(),
            });
        }
        if let Some(w) = input.weights {
            if w.len() != k {
                return Err(Error::DimensionMismatch {
                    what: "point weight count".into(),
                    expected: k,
                    got: w.len(),
                });
            }
        }
        for i in 0..k {
            let w = input.weights.map_or(1.0, |w| w[i]);
            if !(w.is_finite() && w >= 0.0) {
                return Err(Error::invalid(
                    "point weight",
                    format!("point {i}: {w}"),
                    "finite and >= 0",
                ));
            }
            if w > 0.0 && !(input.points[i].x.is_finite() && input.points[i].y.is_finite()) {
                return Err(Error::invalid(
                    "tracked point",
                    format!("point {i}"),
                    "finite coordinates",
                ));
            }
            ws.w[i] = w;
        }
        // 1. Targets (difference formulation with carried error).
        let first = state.frames == 0;
        for i in 0..k {
            ws.targets[i] = if first {
                input.points[i]
            } else if ws.w[i] > 0.0 {
                state.prev_proj[i] + (input.points[i] - state.prev_obs[i]) + state.carried[i] * self.params.carry
            } else {
                state.prev_proj[i] + state.carried[i] * self.params.carry
            };
        }
        if first {
            state.contractions.iter_mut().for_each(|c| *c = 0.0);
            state.jaw = 0.0;
        }
        out.contractions.copy_from_slice(&state.contractions);
        out.jaw = state.jaw;
        // 2. Pose.
        let mut pose_rms = self.solve_pose(ws, state.pose, out)?;
        let mut gn = 0;
        let neutral = first && self.params.first_frame_neutral;
        if !neutral {
            for _ in 0..self.params.outer_iterations {
                if md.max_jaw > 0.0 {
                    out.jaw = self.solve_jaw(ws, out);
                }
                match self.params.mode {
                    SolveMode::Global => {
                        gn += self.solve_global(ws, out, &state.contractions);
                        break;
                    }
                    SolveMode::PointByPoint => gn += self.solve_point_by_point(ws, out),
                }
                pose_rms = self.solve_pose(ws, Some(out.pose), out)?;
            }
        }
        // 5. Carry.
        let (mut sse, mut used) = (0.0, 0usize);
        for i in 0..k {
            let p = out
                .pose
                .project(&self.intr, &md.point(i, &out.contractions, out.jaw))
                .unwrap_or(ws.targets[i]);
            let e = ws.targets[i] - p;
            if first {
                // y = p at the neutral frame: the offset is the identity mismatch.
                state.carried[i] = Vector2::zeros();
            } else {
                state.carried[i] = e;
            }
            if ws.w[i] > 0.0 {
                sse += e.norm_squared();
                used += 1;
                state.prev_obs[i] = input.points[i];
            }
            state.prev_proj[i] = p;
        }
        if first && !self.params.first_frame_neutral {
            for i in 0..k {
                state.carried[i] = ws.targets[i] - state.prev_proj[i];
            }
        }
        state.contractions.copy_from_slice(&out.contractions);
        state.jaw = out.jaw;
        state.pose = Some(out.pose);
        state.frames += 1;
        Ok(TrackReport {
            gn_iterations: gn,
            rms_px: if used > 0 { (sse / used as f64).sqrt() } else { f64::NAN },
            pose_rms_px: pose_rms,
            points_used: used,
            neutral_frame: neutral,
        })
    }

    /// PnP on the static points of the model posed with `out`'s contractions and jaw.
    fn solve_pose(&self, ws: &mut TrackWorkspace, init: Option<ModelToCamera>, out: &mut TrackOutput) -> Result<f64> {
        let md = &self.model;
        ws.stat_model.clear();
        ws.stat_image.clear();
        for &i in &md.static_points {
            if ws.w[i] > 0.0 {
                ws.stat_model.push(md.point(i, &out.contractions, out.jaw));
                ws.stat_image.push(ws.targets[i]);
            }
        }
        if ws.stat_model.len() < 4 {
            // Too few static points visible: keep the previous pose.
            if let Some(p) = init {
                out.pose = p;
                return Ok(f64::NAN);
            }
            return Err(Error::invalid(
                "visible static points",
                ws.stat_model.len(),
                ">= 4 on the first frame",
            ));
        }
        match init {
            Some(mut p) => {
                let rep = refine_pose(
                    &mut p,
                    &self.intr,
                    &ws.stat_model,
                    &ws.stat_image,
                    None,
                    &self.params.pnp,
                )?;
                out.pose = p;
                Ok(rep.rms_px)
            }
            None => {
                let (p, rep) = solve_pnp(&ws.stat_model, &ws.stat_image, &self.intr, None, &self.params.pnp)?;
                out.pose = p;
                Ok(rep.rms_px)
            }
        }
    }

    /// Golden-section search of the jaw angle on the jaw point(s).
    fn solve_jaw(&self, ws: &TrackWorkspace, out: &TrackOutput) -> f64 {
        let md = &self.model;
        let cost = |theta: f64| -> f64 {
            let mut s = 0.0;
            for &i in &md.jaw_points {
                if ws.w[i] > 0.0 {
                    let p = out.pose.project(&self.intr, &md.point(i, &out.contractions, theta));
                    s += p.map_or(f64::INFINITY, |p| (p - ws.targets[i]).norm_squared() * ws.w[i]);
                }
            }
            s
        };
        golden_section(cost, 0.0, md.max_jaw, self.params.jaw_tolerance)
    }

    /// Fills `x0` and `g` (camera-space affine model in `c`) for the current pose and jaw.
    fn linearise(&self, ws: &mut TrackWorkspace, out: &TrackOutput) {
        let md = &self.model;
        let k = md.num_points();
        let rc = out.pose.0.rotation.to_rotation_matrix();
        let rj = Rotation3::from_axis_angle(&md.axis, out.jaw);
        for kk in 0..k {
            let w = md.jaw_w[kk];
            let a = Rotation3::identity().matrix() * (1.0 - w) + rj.matrix() * w;
            let b = (md.pivot.coords - rj * md.pivot.coords) * w;
            ws.x0[kk] = out.pose.transform(&Point3::from(a * md.base[kk].coords + b));
            for i in 0..md.num_muscles() {
                ws.g[i * k + kk] = rc.matrix() * (a * md.deltas[i * k + kk]);
            }
        }
    }

    /// Camera point `k` for contractions `c`.
    fn cam(&self, ws: &TrackWorkspace, kk: usize, c: &[f64]) -> Point3<f64> {
        let k = self.model.num_points();
        let mut x = ws.x0[kk];
        for (i, &ci) in c.iter().enumerate() {
            x += ws.g[i * k + kk] * ci;
        }
        x
    }

    /// Full cost over all points for contractions `c`, jaw `theta` and `pose`.
    fn cost_full(&self, ws: &TrackWorkspace, c: &[f64], theta: f64, pose: &ModelToCamera) -> f64 {
        let md = &self.model;
        let mut s = 0.0;
        for kk in 0..md.num_points() {
            if ws.w[kk] > 0.0 {
                s += pose
                    .project(&self.intr, &md.point(kk, c, theta))
                    .map_or(1e12, |p| (p - ws.targets[kk]).norm_squared() * ws.w[kk]);
            }
        }
        s + self.params.regularisation * c.iter().map(|v| v * v).sum::<f64>()
    }

    /// One global solve: projected Gauss-Newton on the head pose (6, free), the jaw angle
    /// and the contractions (box-bounded) jointly, over all points. The pose block is
    /// eliminated by its Schur complement; the bounded block is a box QP solved by
    /// projected coordinate descent. Returns iterations.
    fn solve_global(&self, ws: &mut TrackWorkspace, out: &mut TrackOutput, _prev: &[f64]) -> usize {
        use nalgebra::{Matrix6, Vector6};
        let md = &self.model;
        let (k, m) = (md.num_points(), md.num_muscles());
        let nb = m + 1; // bounded block: contractions then jaw
        let lambda = self.params.regularisation;
        let max_jaw = md.max_jaw;
        let mut cost = self.cost_full(ws, &out.contractions, out.jaw, &out.pose);
        let mut iters = 0;
        for _ in 0..self.params.gn_iterations {
            iters += 1;
            // Normal equations: H_bb (nb x nb) in ws.h, H_pb (6 x nb) in ws.hpb, H_pp, g.
            ws.h.iter_mut().for_each(|v| *v = 0.0);
            ws.grad.iter_mut().for_each(|v| *v = 0.0);
            ws.hpb.iter_mut().for_each(|v| *v = Vector6::zeros());
            let mut hpp = Matrix6::<f64>::zeros();
            let mut gp = Vector6::<f64>::zeros();
            let rc = out.pose.0.rotation.to_rotation_matrix();
            let rj = Rotation3::from_axis_angle(&md.axis, out.jaw);
            for kk in 0..k {
                if ws.w[kk] == 0.0 {
                    continue;
                }
                let pm = md.muscled(kk, &out.contractions);
                let wj = md.jaw_w[kk];
                let a = Rotation3::identity().matrix() * (1.0 - wj) + rj.matrix() * wj;
                let p = pm + (md.pivot + rj * (pm - md.pivot) - pm) * wj;
                let rp = rc * p.coords;
                let x = Point3::from(rp + out.pose.0.translation.vector);
                let Some(proj) = self.intr.project(&x) else { continue };
                let sw = ws.w[kk].sqrt();
                let r = (proj - ws.targets[kk]) * sw;
                let pj = point_jacobian(&self.intr, &rp, &x.coords);
                let d = pj.d_point_matrix() * sw;
                for i in 0..m {
                    ws.jac[i] = d * (rc.matrix() * (a * md.deltas[i * k + kk]));
                }
                ws.jac[m] = d * (rc.matrix() * (md.axis.cross(&(rj * (pm - md.pivot))) * wj));
                // Pose: X = exp([w]) R P + t + tau  =>  dX/dw = -[R P]x, dX/dtau = I.
                let jp = pj.d_pose_matrix() * sw;
                hpp += jp.transpose() * jp;
                gp += jp.transpose() * r;
                for i in 0..nb {
                    ws.grad[i] += ws.jac[i].dot(&r);
                    ws.hpb[i] += jp.transpose() * ws.jac[i];
                    for j in i..nb {
                        ws.h[i * nb + j] += ws.jac[i].dot(&ws.jac[j]);
                    }
                }
            }
            for i in 0..m {
                ws.h[i * nb + i] += lambda;
                ws.grad[i] += lambda * out.contractions[i];
            }
            for i in 0..nb {
                for j in 0..i {
                    ws.h[i * nb + j] = ws.h[j * nb + i];
                }
            }
            // Levenberg damping of the pose block keeps it invertible.
            let damp = 1e-9 * (hpp.trace() + 1.0);
            for i in 0..6 {
                hpp[(i, i)] += damp;
            }
            let Some(hpp_inv) = hpp.try_inverse() else { break };
            // Schur complement: H_bb - H_bp H_pp^-1 H_pb, g_b - H_bp H_pp^-1 g_p.
            let hg = hpp_inv * gp;
            for i in 0..nb {
                let hi = hpp_inv * ws.hpb[i];
                ws.grad[i] -= ws.hpb[i].dot(&hg);
                for j in 0..nb {
                    ws.h[i * nb + j] -= ws.hpb[j].dot(&hi);
                }
            }
            // Box QP on the bounded block by projected coordinate descent.
            ws.step.iter_mut().for_each(|v| *v = 0.0);
            for _ in 0..self.params.qp_sweeps {
                let mut change: f64 = 0.0;
                for i in 0..nb {
                    let hii = ws.h[i * nb + i];
                    if hii <= 0.0 {
                        continue;
                    }
                    let mut gi = ws.grad[i];
                    for j in 0..nb {
                        gi += ws.h[i * nb + j] * ws.step[j];
                    }
                    let (cur, hi) = if i < m {
                        (out.contractions[i], 1.0)
                    } else {
                        (out.jaw, max_jaw)
                    };
                    let old = ws.step[i];
                    let new = (old - gi / hii).clamp(-cur, hi - cur);
                    ws.step[i] = new;
                    change = change.max((new - old).abs());
                }
                if change < 1e-10 {
                    break;
                }
            }
            let mut rhs = gp;
            for i in 0..nb {
                rhs += ws.hpb[i] * ws.step[i];
            }
            let dp = -(hpp_inv * rhs);
            // Accept with backtracking.
            let mut t = 1.0;
            let mut accepted = false;
            for _ in 0..6 {
                for i in 0..m {
                    ws.trial[i] = (out.contractions[i] + t * ws.step[i]).clamp(0.0, 1.0);
                }
                let theta = (out.jaw + t * ws.step[m]).clamp(0.0, max_jaw);
                let pose = apply_pose_step(&out.pose, &dp.into(), t);
                let c = self.cost_full(ws, &ws.trial[..m], theta, &pose);
                if c <= cost {
                    let rel = (cost - c) / cost.max(1e-300);
                    cost = c;
                    out.contractions.copy_from_slice(&ws.trial[..m]);
                    out.jaw = theta;
                    out.pose = pose;
                    accepted = rel > 1e-10;
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        iters
    }

    /// Thesis point-by-point: each muscle from its own point(s), bounded 1-D Gauss-Newton.
    fn solve_point_by_point(&self, ws: &mut TrackWorkspace, out: &mut TrackOutput) -> usize {
        self.linearise(ws, out);
        let md = &self.model;
        let k = md.num_points();
        let lambda = self.params.regularisation;
        let mut iters = 0;
        for _sweep in 0..self.params.gn_iterations.min(4) {
            for i in 0..md.num_muscles() {
                for _ in 0..3 {
                    iters += 1;
                    let (mut h, mut g) = (lambda, lambda * out.contractions[i]);
                    for &kk in &md.muscle_points[i] {
                        if ws.w[kk] == 0.0 {
                            continue;
                        }
                        let x = self.cam(ws, kk, &out.contractions);
                        let Some(p) = self.intr.project(&x) else { continue };
                        let j = point_jacobian(&self.intr, &x.coords, &x.coords).d_point_matrix() * ws.g[i * k + kk];
                        h += j.norm_squared() * ws.w[kk];
                        g += j.dot(&(p - ws.targets[kk])) * ws.w[kk];
                    }
                    if h <= 0.0 {
                        break;
                    }
                    let old = out.contractions[i];
                    out.contractions[i] = (old - g / h).clamp(0.0, 1.0);
                    if (out.contractions[i] - old).abs() < 1e-7 {
                        break;
                    }
                }
            }
        }
        iters
    }
}
