//! Fitting the tensor model to 2D image points: pose, expression and identity.
//!
//! # Problem (Papanek 2010, sec. 3.4; Vlasic et al. 2005)
//!
//! Input: `N` image points `x_k` (pixels, 0-based, see `facecap_core::camera`), each
//! the image of model vertex `v_k`, with weights `rho_k >= 0` (0 = lost track), and the
//! camera intrinsics `K`. Unknowns: the pose `(R, t)` ([`ModelToCamera`]), the
//! database weights `w_id` (`I`) and `w_exp` (`E`) of the generative function
//! `p_k = m_k + M_k x2 (U_id^T w_id) x3 (U_exp^T w_exp)` ([`crate::model`]).
//!
//! **Projection.** Weak perspective as in the thesis: `x_k ~ c + f (R p_k + t)_xy / z`
//! with one depth `z = z_avg`, the mean depth of the points under the current pose,
//! updated at every pose step ([`Projection::WeakPerspective`]). With the pose and `z`
//! fixed the projection is *linear* in `p_k`, so each weight block has a closed form.
//! [`Projection::PerPointDepth`] uses each point's own depth `z_k` from the previous
//! pose step instead (a departure from the thesis: exact perspective at convergence,
//! same cost per sweep).
//!
//! **Cost** (model units squared; `q_k = ((x_k - c_x) z_k / f_x, (y_k - c_y) z_k / f_y)`
//! is the image point lifted to the model's scale):
//!
//! `C = sum_k rho~_k ||q_k - (R p_k + t)_xy||^2 + lambda_id ||w_id - w0_id||^2 + lambda_exp ||w_exp - w0_exp||^2`
//!
//! with `rho~_k = rho_k / sum rho` and priors `w0` (default: uniform `1/I`, `1/E`,
//! the average identity / expression).
//!
//! **One sweep** (thesis order: pose, expression, identity):
//! 1. pose by PnP on the current model points: Levenberg-Marquardt on the perspective
//!    reprojection error ([`facecap_geom::pnp::refine_pose`], weighted, at most `pose_iterations`
//!    iterations), warm-started from the state's pose, or, when the previous pose step
//!    from that same pose was rejected, from the pose that step found (same optimum,
//!    reached in one pass instead of several); then `z`; the step is accepted only if
//!    `C` does not increase;
//! 2. expression in closed form (thesis eq. 3.47):
//!    with `A` the `2N x r_exp` design (rows `sqrt(rho~_k) R_2 M_k x2 alpha`) and `y` the
//!    matching residual targets, `beta = (A^T A + lambda_exp I)^{-1} (A^T y + lambda_exp U_exp^T w0_exp)` and
//!    `w_exp = w0_exp + U_exp (beta - U_exp^T w0_exp)` (the exact minimiser over `w_exp`);
//!    or with `w_exp >= 0` ([`Method::NonNegative`]) by sequential coordinate-wise NNLS
//!    ([`facecap_geom::nnls`]) on `H = U A^T A U^T + lambda I`, `f = -(U A^T y + lambda w0)`;
//! 3. identity in the same way (thesis eq. 3.48), unless `update_identity` is off.
//!
//! Each block step minimises `C` over its block (or, for the pose, is rejected if it
//! does not decrease it), so `C` never increases between sweeps. Iteration stops when
//! the relative decrease is below `tol` or after `max_sweeps`.
//!
//! **Sequences** ([`Fitter::fit_sequence`]): one identity for all frames, one
//! expression and pose per frame, alternating as in the thesis; the cost is the sum of
//! the frames' data and expression terms plus one identity prior term.
//!
//! The per-frame call [`Fitter::solve_into`] does not allocate (tested with a counting
//! allocator).

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_geom::pnp::{refine_pose, PnpParams};
use facecap_geom::{cholesky::dot, nnls, pose};
use nalgebra::{Point2, Point3};

use crate::error::{Error, Result};
use crate::kernels;
use crate::model::TensorModel;

/// How the weights are constrained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Ridge-regularised closed form (thesis eqs. 3.47-3.48).
    Regularised,
    /// Non-negative database weights (regularised too), sequential coordinate-wise NNLS.
    NonNegative,
}

/// Projection model of the weight steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Projection {
    /// One depth `z_avg` for all points (thesis).
    WeakPerspective,
    /// Each point's own depth from the last pose step (exact perspective at convergence).
    PerPointDepth,
}

/// Parameters of the fitter.
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `lambda_id` | 1e-2 | identity prior weight (model units^2) | >= 0, finite |
/// | `lambda_exp` | 1e-2 | expression prior weight (model units^2) | >= 0, finite |
/// | `method` | `Regularised` | closed form or non-negative | |
/// | `projection` | `WeakPerspective` | weak perspective (thesis) or per-point depth | |
/// | `max_sweeps` | 30 | maximum pose/expression/identity sweeps | >= 1 |
/// | `tol` | 1e-7 | stop when the relative cost decrease falls below | >= 0, finite |
/// | `pose_iterations` | 10 | Levenberg-Marquardt iterations per pose step | >= 1 |
/// | `nnls_max_iter` | 500 | NNLS passes per block | >= 1 |
/// | `nnls_tol` | 1e-12 | NNLS KKT tolerance | >= 0, finite |
/// | `update_identity` | true | whether the identity block is updated | |
/// | `prior_id` | uniform `1/I` | `w0_id` | finite, length I |
/// | `prior_exp` | uniform `1/E` | `w0_exp` | finite, length E |
#[derive(Debug, Clone, PartialEq)]
pub struct FitParams {
    /// Identity prior weight.
    pub lambda_id: f64,
    /// Expression prior weight.
    pub lambda_exp: f64,
    /// Constraint.
    pub method: Method,
    /// Projection model.
    pub projection: Projection,
    /// Maximum sweeps.
    pub max_sweeps: usize,
    /// Relative decrease tolerance.
    pub tol: f64,
    /// LM iterations per pose step.
    pub pose_iterations: usize,
    /// NNLS passes per block.
    pub nnls_max_iter: usize,
    /// NNLS KKT tolerance.
    pub nnls_tol: f64,
    /// Update the identity block.
    pub update_identity: bool,
    /// Identity prior (None = uniform).
    pub prior_id: Option<Vec<f64>>,
    /// Expression prior (None = uniform).
    pub prior_exp: Option<Vec<f64>>,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            lambda_id: 1e-2,
            lambda_exp: 1e-2,
            method: Method::Regularised,
            projection: Projection::WeakPerspective,
            max_sweeps: 30,
            tol: 1e-7,
            pose_iterations: 10,
            nnls_max_iter: 500,
            nnls_tol: 1e-12,
            update_identity: true,
            prior_id: None,
            prior_exp: None,
        }
    }
}

/// Why a fit stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// Relative cost decrease below `tol`.
    Converged,
    /// `max_sweeps` reached.
    MaxSweeps,
}

/// Outcome of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitReport {
    /// Sweeps done.
    pub sweeps: usize,
    /// Cost after the first pose step.
    pub initial_cost: f64,
    /// Cost at the end.
    pub final_cost: f64,
    /// Largest cost increase seen between consecutive sweeps (<= 0 up to rounding).
    pub max_increase: f64,
    /// Why it stopped.
    pub stop: Stop,
    /// Weighted RMS perspective reprojection error of the fitted points, pixels.
    pub rms_px: f64,
}

/// Per-frame input.
#[derive(Debug, Clone, Copy)]
pub struct FitInput<'a> {
    /// Image points (pixels), one per fitter vertex.
    pub image: &'a [Point2<f64>],
    /// Point weights (0 = ignore, e.g. a lost track), one per fitter vertex.
    pub weights: &'a [f64],
    /// Camera intrinsics.
    pub intrinsics: Intrinsics,
}

/// Warm-startable per-frame state.
#[derive(Debug, Clone, PartialEq)]
pub struct FitState {
    /// Identity database weights (`I`).
    pub w_id: Vec<f64>,
    /// Expression database weights (`E`).
    pub w_exp: Vec<f64>,
    /// Current pose (`None` = not initialised: the first pose step initialises it).
    pub pose: Option<ModelToCamera>,
    /// Depth used by the projection for each point (model units).
    pub depth: Vec<f64>,
}

/// Scratch buffers of the fitter (sized once by [`Fitter::workspace`]).
#[derive(Debug, Clone)]
pub struct FitWorkspace {
    alpha: Vec<f64>,
    beta: Vec<f64>,
    ab: Vec<f64>,
    pts: Vec<Point3<f64>>,
    /// Expression design rows: `[N][2][rp]` (two image rows per weighted point,
    /// contiguous, zero-padded to `rp = r_exp` rounded up to a multiple of 8), and each
    /// point's weight `w_k / sum w`.
    design: Vec<f64>,
    design_w: Vec<f64>,
    /// `rp x rp` scratch for the blocked `A^T W A` of [`kernels::syrk_points`].
    hpad: Vec<f64>,
    syrk_scratch: Vec<f64>,
    /// Model points as `[N][3]` (output of [`kernels::points`]).
    pflat: Vec<f64>,
    h: Vec<f64>,
    g: Vec<f64>,
    hdb: Vec<f64>,
    fdb: Vec<f64>,
    tmp: Vec<f64>,
    grad: Vec<f64>,
    /// Scratch of the NNLS support polish ([`nnls::solve_polished_into`]).
    nnls_scratch: Vec<f64>,
    sol: Vec<f64>,
    depth_backup: Vec<f64>,
    /// Per point, the core contracted with the identity modes: `[N][3][r_exp]`.
    texp: Vec<f64>,
    /// Per point, the core contracted with the expression modes and rotated by the
    /// pose rotation `R` (`ws.rtid_rot`): `[N][3][rp_id]` (rows 0 and 1 are the
    /// identity design rows).
    rtid: Vec<f64>,
    rtid_rot: [f64; 9],
    /// Per point: the weight `w_k / sum w` (0 = unused) and the two residual targets.
    pw: Vec<f64>,
    py: Vec<f64>,
    /// The weights `pts` were computed for (valid when `pts_valid`): a warm-started
    /// call on an unchanged state skips recomputing the points.
    pts_w_id: Vec<f64>,
    pts_w_exp: Vec<f64>,
    pts_valid: bool,
    /// The last rejected pose step: the state pose it started from and the pose its
    /// refinement found (the warm start of the next refinement from that state pose).
    pose_memo: Option<(ModelToCamera, ModelToCamera)>,
}

/// The fitter: a tensor model restricted to the fitted vertices (immutable, `Send + Sync`).
#[derive(Debug, Clone)]
pub struct Fitter {
    params: FitParams,
    vertices: Vec<u32>,
    /// `[N][3][ceil(r_id / 4)][r_exp][4]` (per point and coordinate, the core slice in
    /// panels of four identity modes, [`kernels::pack_point`]), stored in `f32` to halve the memory traffic of the contractions (all arithmetic
    /// is in `f64`; see "Precision" in the module docs).
    core: Vec<f32>,
    /// `[N][3]`
    mean: Vec<f64>,
    /// `(I, r_id)` row-major.
    u_id: Vec<f64>,
    /// `(E, r_exp)` row-major.
    u_exp: Vec<f64>,
    ni: usize,
    ne: usize,
    r_id: usize,
    r_exp: usize,
    prior_id: Vec<f64>,
    prior_exp: Vec<f64>,
    alpha0: Vec<f64>,
    beta0: Vec<f64>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Block {
    Id,
    Exp,
}

impl FitParams {
    /// Validates ranges (see the parameter table).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self, ni: usize, ne: usize) -> Result<()> {
        for (n, v) in [
            ("lambda_id", self.lambda_id),
            ("lambda_exp", self.lambda_exp),
            ("tol", self.tol),
            ("nnls_tol", self.nnls_tol),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(n, v, "a finite number >= 0"));
            }
        }
        for (n, v) in [
            ("max_sweeps", self.max_sweeps),
            ("pose_iterations", self.pose_iterations),
            ("nnls_max_iter", self.nnls_max_iter),
        ] {
            if v == 0 {
                return Err(Error::invalid(n, v, ">= 1"));
            }
        }
        for (n, p, len) in [("prior_id", &self.prior_id, ni), ("prior_exp", &self.prior_exp, ne)] {
            if let Some(p) = p {
                if p.len() != len {
                    return Err(Error::dim(n, len, p.len()));
                }
                if p.iter().any(|x| !x.is_finite()) {
                    return Err(Error::invalid(n, "non-finite entry", "finite weights"));
                }
            }
        }
        Ok(())
    }
}

impl Fitter {
    /// Restricts `model` to `vertices` (the model vertex of each image point).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a bad parameter, an empty or out-of-range vertex list.
    pub fn new(model: &TensorModel, vertices: &[u32], params: FitParams) -> Result<Self> {
        let (ni, ne) = (model.num_identities(), model.num_expressions());
        params.validate(ni, ne)?;
        if vertices.len() < 4 {
            return Err(Error::invalid("number of fitted vertices", vertices.len(), ">= 4"));
        }
        let nv = model.num_vertices();
        if let Some(v) = vertices.iter().find(|&&v| v as usize >= nv) {
            return Err(Error::invalid("fitted vertex", v, format!("< {nv}")));
        }
        let (r_id, r_exp) = (model.rank_id(), model.rank_exp());
        let mut core = Vec::with_capacity(vertices.len() * 3 * kernels::panel_len(r_id, r_exp));
        let mut mean = Vec::with_capacity(vertices.len() * 3);
        for &v in vertices {
            let p = 3 * v as usize;
            // Panel layout of `kernels` (groups of four identity modes, each with all
            // expression modes): both contractions read contiguous 4-wide vectors.
            // f32 storage (deliberate rounding, see the module docs).
            #[allow(clippy::cast_possible_truncation)]
            kernels::pack_point(&mut core, r_id, r_exp, |c, e, j| model.core[[p + c, j, e]] as f32);
            mean.extend_from_slice(&[model.mean[p], model.mean[p + 1], model.mean[p + 2]]);
        }
        let prior_id = params.prior_id.clone().unwrap_or_else(|| vec![1.0 / ni as f64; ni]);
        let prior_exp = params.prior_exp.clone().unwrap_or_else(|| vec![1.0 / ne as f64; ne]);
        let mut alpha0 = vec![0.0; r_id];
        let mut beta0 = vec![0.0; r_exp];
        model.id_modes_into(&prior_id, &mut alpha0);
        model.exp_modes_into(&prior_exp, &mut beta0);
        Ok(Fitter {
            params,
            vertices: vertices.to_vec(),
            core,
            mean,
            u_id: model.u_id.iter().copied().collect(),
            u_exp: model.u_exp.iter().copied().collect(),
            ni,
            ne,
            r_id,
            r_exp,
            prior_id,
            prior_exp,
            alpha0,
            beta0,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &FitParams {
        &self.params
    }

    /// The fitted model vertices.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// A fresh state: weights at the priors, no pose.
    pub fn initial_state(&self) -> FitState {
        FitState {
            w_id: self.prior_id.clone(),
            w_exp: self.prior_exp.clone(),
            pose: None,
            depth: vec![1.0; self.vertices.len()],
        }
    }

    /// Scratch buffers for this fitter.
    pub fn workspace(&self) -> FitWorkspace {
        let n = self.vertices.len();
        let r = self.r_id.max(self.r_exp);
        let rp = pad8(r);
        let d = self.ni.max(self.ne);
        FitWorkspace {
            alpha: vec![0.0; self.r_id],
            beta: vec![0.0; self.r_exp],
            ab: vec![0.0; kernels::panel_len(self.r_id, self.r_exp)],
            pts: vec![Point3::origin(); n],
            design: vec![0.0; 2 * n * pad8(self.r_exp)],
            design_w: vec![0.0; n],
            hpad: vec![0.0; rp * rp],
            syrk_scratch: vec![0.0; kernels::syrk_scratch_len(rp)],
            pflat: vec![0.0; 3 * n],
            h: vec![0.0; r * r],
            g: vec![0.0; r],
            hdb: vec![0.0; d * d],
            fdb: vec![0.0; d],
            tmp: vec![0.0; d * r],
            grad: vec![0.0; d],
            nnls_scratch: vec![0.0; nnls::polish_scratch_len(d)],
            sol: vec![0.0; d.max(r)],
            depth_backup: vec![0.0; n],
            texp: vec![0.0; n * 3 * self.r_exp],
            rtid: vec![0.0; n * 3 * pad8(self.r_id)],
            rtid_rot: [0.0; 9],
            pw: vec![0.0; n],
            py: vec![0.0; 2 * n],
            pts_w_id: vec![0.0; self.ni],
            pts_w_exp: vec![0.0; self.ne],
            pts_valid: false,
            pose_memo: None,
        }
    }

    fn check_input(&self, input: &FitInput, state: &FitState) -> Result<()> {
        let n = self.vertices.len();
        if input.image.len() != n {
            return Err(Error::dim("image point count", n, input.image.len()));
        }
        if input.weights.len() != n {
            return Err(Error::dim("point weight count", n, input.weights.len()));
        }
        if state.w_id.len() != self.ni || state.w_exp.len() != self.ne || state.depth.len() != n {
            return Err(Error::dim(
                "fit state size (use Fitter::initial_state)",
                self.ni + self.ne + n,
                state.w_id.len() + state.w_exp.len() + state.depth.len(),
            ));
        }
        let mut used = 0;
        for (x, &w) in input.image.iter().zip(input.weights) {
            if !(w.is_finite() && w >= 0.0) {
                return Err(Error::invalid("point weight", w, "a finite number >= 0"));
            }
            if w > 0.0 {
                if !(x.x.is_finite() && x.y.is_finite()) {
                    return Err(Error::invalid("image point", format!("({}, {})", x.x, x.y), "finite"));
                }
                used += 1;
            }
        }
        if used < 4 {
            return Err(Error::invalid("number of points with weight > 0", used, ">= 4"));
        }
        Ok(())
    }

    /// Mode coordinates `alpha = U_id^T w_id`, `beta = U_exp^T w_exp` into `ws`.
    fn update_modes(&self, state: &FitState, ws: &mut FitWorkspace) {
        mat_t_vec(&self.u_id, self.ni, self.r_id, &state.w_id, &mut ws.alpha);
        mat_t_vec(&self.u_exp, self.ne, self.r_exp, &state.w_exp, &mut ws.beta);
    }

    /// Model points for the state's weights into `ws.pts` (and the modes).
    fn update_points(&self, state: &FitState, ws: &mut FitWorkspace) {
        self.update_modes(state, ws);
        // p = m + <core_row, alpha kron beta>: one long contiguous dot per coordinate.
        kernels::pack_ab(&ws.alpha, &ws.beta, &mut ws.ab);
        kernels::points(&self.core, &self.mean, &ws.ab, &mut ws.pflat);
        for (p, q) in ws.pts.iter_mut().zip(ws.pflat.chunks_exact(3)) {
            *p = Point3::new(q[0], q[1], q[2]);
        }
        self.record_points(state, ws);
    }

    /// Notes that `ws.pts` hold the points of the state's weights.
    fn record_points(&self, state: &FitState, ws: &mut FitWorkspace) {
        ws.pts_w_id.copy_from_slice(&state.w_id);
        ws.pts_w_exp.copy_from_slice(&state.w_exp);
        ws.pts_valid = true;
    }

    /// `ws.pts` for the state's weights: recomputed unless they already are.
    fn ensure_points(&self, state: &FitState, ws: &mut FitWorkspace) {
        if !(ws.pts_valid && ws.pts_w_id == state.w_id && ws.pts_w_exp == state.w_exp) {
            self.update_points(state, ws);
        }
    }

    /// `texp[k][c] = alpha^T C_kc` (the core of point `k`, coordinate `c`, contracted
    /// with the identity modes) for every point; `ws.alpha` must be current.
    fn contract_exp(&self, ws: &mut FitWorkspace) {
        kernels::contract_exp(&self.core, &ws.alpha, self.r_exp, &mut ws.texp);
    }

    /// `ws.pts` from a contraction (`texp` with `beta`, or the rotated `rtid` with
    /// `alpha`): the same points as [`Self::update_points`] (up to rounding) at a
    /// fraction of the cost.
    fn points_from(&self, block: Block, ws: &mut FitWorkspace) {
        match block {
            Block::Exp => pulp::Arch::new().dispatch(PointsFrom {
                t: &ws.texp,
                w: &ws.beta,
                mean: &self.mean,
                pts: &mut ws.pts,
            }),
            Block::Id => pulp::Arch::new().dispatch(PointsFromRot {
                t: &ws.rtid,
                rp: pad8(self.r_id),
                rot: ws.rtid_rot,
                w: &ws.alpha,
                mean: &self.mean,
                pts: &mut ws.pts,
            }),
        }
    }

    /// Data term for the points in `ws.pts`.
    fn data_cost(&self, input: &FitInput, pose: &ModelToCamera, depth: &[f64], pts: &[Point3<f64>]) -> f64 {
        let k = &input.intrinsics;
        let sw: f64 = input.weights.iter().sum();
        let rm = *pose.0.rotation.to_rotation_matrix().matrix();
        let t = pose.0.translation.vector;
        let mut e = 0.0;
        for (((p, x), &w), &z) in pts.iter().zip(input.image).zip(input.weights).zip(depth) {
            if w > 0.0 {
                let xc = rm * p.coords + t;
                let qx = (x.x - k.cx) * z / k.fx;
                let qy = (x.y - k.cy) * z / k.fy;
                e += w * ((qx - xc.x).powi(2) + (qy - xc.y).powi(2));
            }
        }
        e / sw
    }

    fn prior_cost(&self, state: &FitState, with_id: bool) -> f64 {
        let p_exp: f64 = state
            .w_exp
            .iter()
            .zip(&self.prior_exp)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        let mut c = self.params.lambda_exp * p_exp;
        if with_id {
            let p_id: f64 = state
                .w_id
                .iter()
                .zip(&self.prior_id)
                .map(|(a, b)| (a - b).powi(2))
                .sum();
            c += self.params.lambda_id * p_id;
        }
        c
    }

    /// The cost `C` of the module docs for a state with a pose.
    ///
    /// # Errors
    /// As [`Self::solve_into`]; [`Error::InvalidParameter`] when the state has no pose.
    pub fn cost(&self, input: &FitInput, state: &FitState, ws: &mut FitWorkspace) -> Result<f64> {
        self.check_input(input, state)?;
        let pose = state
            .pose
            .ok_or_else(|| Error::invalid("state pose", "None", "an initialised pose"))?;
        self.update_points(state, ws);
        Ok(self.data_cost(input, &pose, &state.depth, &ws.pts) + self.prior_cost(state, true))
    }

    fn set_depth(&self, input: &FitInput, pose: &ModelToCamera, pts: &[Point3<f64>], depth: &mut [f64]) {
        for (d, p) in depth.iter_mut().zip(pts) {
            *d = pose.transform(p).z;
        }
        if self.params.projection == Projection::WeakPerspective {
            let (mut s, mut sw) = (0.0, 0.0);
            for (d, &w) in depth.iter().zip(input.weights) {
                if w > 0.0 {
                    s += w * d;
                    sw += w;
                }
            }
            let z = s / sw;
            depth.iter_mut().for_each(|d| *d = z);
        }
    }

    /// Pose step; `ws.pts` must hold the current points. Returns the new data cost.
    fn pose_step(&self, input: &FitInput, state: &mut FitState, ws: &mut FitWorkspace) -> Result<()> {
        let old = state.pose;
        let mut cand = match (old, ws.pose_memo) {
            // The previous refinement from this very pose was rejected: start where it
            // ended (the same optimum, reached in one pass instead of several).
            (Some(p), Some((from, to))) if from == p => to,
            (Some(p), _) => p,
            (None, _) => pose::init_scaled_orthographic(&ws.pts, input.image, input.weights, &input.intrinsics)?,
        };
        let lm = PnpParams {
            max_iterations: self.params.pose_iterations,
            ..PnpParams::default()
        };
        refine_pose(
            &mut cand,
            &input.intrinsics,
            &ws.pts,
            input.image,
            Some(input.weights),
            &lm,
        )?;
        match old {
            None => {
                self.set_depth(input, &cand, &ws.pts, &mut state.depth);
                state.pose = Some(cand);
                ws.pose_memo = None;
            }
            Some(old_pose) => {
                let before = self.data_cost(input, &old_pose, &state.depth, &ws.pts);
                ws.depth_backup.copy_from_slice(&state.depth);
                self.set_depth(input, &cand, &ws.pts, &mut state.depth);
                let after = self.data_cost(input, &cand, &state.depth, &ws.pts);
                if after <= before {
                    state.pose = Some(cand);
                    ws.pose_memo = None;
                } else {
                    state.depth.copy_from_slice(&ws.depth_backup);
                    ws.pose_memo = Some((old_pose, cand));
                }
            }
        }
        Ok(())
    }

    /// Adds `scale * (A^T A, A^T y)` of one frame for `block` into `ws.h`, `ws.g`
    /// (upper triangle of `h` only). The other block's modes must be in `ws.alpha`/`ws.beta`;
    /// for the expression block `ws.texp` must be current.
    ///
    /// Expression block: the design rows of all weighted points are written contiguously
    /// into `ws.design` (`A^T y` is summed on the way). Identity block: the contraction
    /// with `beta` is done here, rotated by `R` ([`kernels::contract_id_rot`], rows 0 and
    /// 1 are the design rows, `A^T y` summed on the way) into `ws.rtid`. Then `A^T W A`
    /// is formed by [`kernels::syrk_points`], a register-tiled update over the row pairs.
    fn accumulate(&self, block: Block, input: &FitInput, state: &FitState, ws: &mut FitWorkspace, scale: f64) {
        let Some(pose) = state.pose else { return };
        let r = match block {
            Block::Id => self.r_id,
            Block::Exp => self.r_exp,
        };
        let rp = pad8(r);
        let rot = pose.0.rotation.to_rotation_matrix();
        let rm = rot.matrix();
        let t = pose.0.translation.vector;
        let sw: f64 = input.weights.iter().sum();
        let hpad = &mut ws.hpad[..rp * rp];
        hpad.iter_mut().for_each(|v| *v = 0.0);
        match block {
            Block::Exp => {
                let m = pulp::Arch::new().dispatch(DesignRows {
                    tall: &ws.texp,
                    mean: &self.mean,
                    input,
                    depth: &state.depth,
                    rm: *rm,
                    t,
                    scale: scale / sw,
                    r,
                    rp,
                    design: &mut ws.design,
                    design_w: &mut ws.design_w,
                    g: &mut ws.g[..r],
                });
                kernels::syrk_points(&ws.design, 2 * rp, rp, &ws.design_w[..m], &mut ws.syrk_scratch, hpad);
            }
            Block::Id => {
                let k = &input.intrinsics;
                let scale = scale / sw;
                for (((((x, &w), &z), m3), pw), py) in input
                    .image
                    .iter()
                    .zip(input.weights)
                    .zip(&state.depth)
                    .zip(self.mean.chunks_exact(3))
                    .zip(ws.pw.iter_mut())
                    .zip(ws.py.chunks_exact_mut(2))
                {
                    if w > 0.0 {
                        let qx = (x.x - k.cx) * z / k.fx;
                        let qy = (x.y - k.cy) * z / k.fy;
                        *pw = scale * w;
                        py[0] = qx - (rm[(0, 0)] * m3[0] + rm[(0, 1)] * m3[1] + rm[(0, 2)] * m3[2] + t.x);
                        py[1] = qy - (rm[(1, 0)] * m3[0] + rm[(1, 1)] * m3[1] + rm[(1, 2)] * m3[2] + t.y);
                    } else {
                        *pw = 0.0;
                        py[0] = 0.0;
                        py[1] = 0.0;
                    }
                }
                let rot9 = std::array::from_fn(|q| rm[(q / 3, q % 3)]);
                kernels::contract_id_rot(
                    &self.core,
                    &ws.beta,
                    r,
                    rp,
                    &rot9,
                    &ws.py,
                    &ws.pw,
                    &mut ws.rtid,
                    &mut ws.g[..r],
                );
                ws.rtid_rot = rot9;
                kernels::syrk_points(&ws.rtid, 3 * rp, rp, &ws.pw, &mut ws.syrk_scratch, hpad);
            }
        }
        let h = &mut ws.h[..r * r];
        for i in 0..r {
            for (hv, pv) in h[i * r + i..(i + 1) * r].iter_mut().zip(&hpad[i * rp + i..i * rp + r]) {
                *hv += pv;
            }
        }
    }

    /// Solves the block from `ws.h` (upper triangle of `A^T A`) and `ws.g` with prior
    /// weight `lambda`, writing the database weights `w`.
    fn solve_block(&self, block: Block, lambda: f64, w: &mut [f64], ws: &mut FitWorkspace) -> Result<()> {
        let (u, d, r, prior, mode_prior) = match block {
            Block::Id => (&self.u_id, self.ni, self.r_id, &self.prior_id, &self.alpha0),
            Block::Exp => (&self.u_exp, self.ne, self.r_exp, &self.prior_exp, &self.beta0),
        };
        let h = &mut ws.h[..r * r];
        for i in 0..r {
            for j in 0..i {
                h[i * r + j] = h[j * r + i];
            }
        }
        match self.params.method {
            Method::Regularised => {
                let sol = &mut ws.sol[..r];
                for i in 0..r {
                    h[i * r + i] += lambda;
                    sol[i] = ws.g[i] + lambda * mode_prior[i];
                }
                facecap_geom::cholesky::solve(h, r, sol).map_err(|j| Error::Numerical {
                    operation: "fit normal equations",
                    reason: format!("matrix not positive definite at pivot {j} (use lambda > 0 or more points)"),
                })?;
                // w = w0 + U (beta - beta0)
                for (row, (wv, p)) in w.iter_mut().zip(prior).enumerate() {
                    let mut acc = *p;
                    for k in 0..r {
                        acc += u[row * r + k] * (sol[k] - mode_prior[k]);
                    }
                    *wv = acc;
                }
            }
            Method::NonNegative => {
                // H_db = U H U^T + lambda I ; f = -(U g + lambda w0)
                pulp::Arch::new().dispatch(Uhu {
                    u,
                    h,
                    d,
                    r,
                    lambda,
                    tmp: &mut ws.tmp[..d * r],
                    hdb: &mut ws.hdb[..d * d],
                });
                let fdb = &mut ws.fdb[..d];
                for i in 0..d {
                    fdb[i] = -(dot(&u[i * r..(i + 1) * r], &ws.g[..r]) + lambda * prior[i]);
                }
                nnls::solve_polished_into(
                    &ws.hdb[..d * d],
                    fdb,
                    w,
                    &mut ws.grad[..d],
                    &mut ws.nnls_scratch,
                    self.params.nnls_max_iter,
                    self.params.nnls_tol,
                );
            }
        }
        Ok(())
    }

    fn clear_normal(&self, block: Block, ws: &mut FitWorkspace) {
        let r = match block {
            Block::Id => self.r_id,
            Block::Exp => self.r_exp,
        };
        ws.h[..r * r].iter_mut().for_each(|v| *v = 0.0);
        ws.g[..r].iter_mut().for_each(|v| *v = 0.0);
    }

    /// Expression step; leaves the new points in `ws.pts` and the modes current.
    fn exp_step(&self, input: &FitInput, state: &mut FitState, ws: &mut FitWorkspace) -> Result<()> {
        self.update_modes(state, ws);
        self.contract_exp(ws);
        self.clear_normal(Block::Exp, ws);
        self.accumulate(Block::Exp, input, state, ws, 1.0);
        let mut w = std::mem::take(&mut state.w_exp);
        let res = self.solve_block(Block::Exp, self.params.lambda_exp, &mut w, ws);
        state.w_exp = w;
        res?;
        mat_t_vec(&self.u_exp, self.ne, self.r_exp, &state.w_exp, &mut ws.beta);
        self.points_from(Block::Exp, ws);
        self.record_points(state, ws);
        Ok(())
    }

    /// Identity step of one frame; leaves the new points in `ws.pts`. `ws.alpha` and
    /// `ws.beta` must be current.
    fn id_step(&self, input: &FitInput, state: &mut FitState, ws: &mut FitWorkspace) -> Result<()> {
        self.clear_normal(Block::Id, ws);
        self.accumulate(Block::Id, input, state, ws, 1.0);
        let mut w = std::mem::take(&mut state.w_id);
        let res = self.solve_block(Block::Id, self.params.lambda_id, &mut w, ws);
        state.w_id = w;
        res?;
        mat_t_vec(&self.u_id, self.ni, self.r_id, &state.w_id, &mut ws.alpha);
        self.points_from(Block::Id, ws);
        self.record_points(state, ws);
        Ok(())
    }

    /// Cost of the state for the points already in `ws.pts`.
    fn cost_of_points(&self, input: &FitInput, state: &FitState, ws: &FitWorkspace, with_id: bool) -> f64 {
        match state.pose {
            Some(p) => self.data_cost(input, &p, &state.depth, &ws.pts) + self.prior_cost(state, with_id),
            None => f64::INFINITY,
        }
    }

    /// Fits one frame, warm-started from `state`. Does not allocate.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] for wrong input or state sizes,
    /// [`Error::InvalidParameter`] for non-finite points, negative weights or fewer than 4
    /// weighted points; [`Error::Numerical`] for degenerate geometry.
    pub fn solve_into(&self, input: &FitInput, ws: &mut FitWorkspace, state: &mut FitState) -> Result<FitReport> {
        self.check_input(input, state)?;
        self.ensure_points(state, ws);
        self.pose_step(input, state, ws)?;
        // ws.pts holds the points of the state's weights from here on: every step
        // below updates them from its own contraction.
        let mut cost = self.cost_of_points(input, state, ws, true);
        let initial = cost;
        let mut max_increase = f64::NEG_INFINITY;
        let mut stop = Stop::MaxSweeps;
        let mut sweeps = 0;
        for s in 0..self.params.max_sweeps {
            sweeps = s + 1;
            if s > 0 {
                self.pose_step(input, state, ws)?;
            }
            self.exp_step(input, state, ws)?;
            if self.params.update_identity {
                self.id_step(input, state, ws)?;
            }
            let new = self.cost_of_points(input, state, ws, true);
            max_increase = max_increase.max(new - cost);
            let rel = (cost - new) / cost.max(1e-300);
            cost = new;
            if rel <= self.params.tol {
                stop = Stop::Converged;
                break;
            }
        }
        let rms_px = state
            .pose
            .map(|p| pose::reprojection_rms(&ws.pts, input.image, input.weights, &input.intrinsics, &p))
            .unwrap_or(f64::NAN);
        Ok(FitReport {
            sweeps,
            initial_cost: initial,
            final_cost: cost,
            max_increase,
            stop,
            rms_px,
        })
    }

    fn cost_inner(&self, input: &FitInput, state: &FitState, ws: &mut FitWorkspace, with_id: bool) -> f64 {
        self.update_points(state, ws);
        match state.pose {
            Some(p) => self.data_cost(input, &p, &state.depth, &ws.pts) + self.prior_cost(state, with_id),
            None => f64::INFINITY,
        }
    }

    /// Fits a sequence: one identity shared by all frames (written to every state's
    /// `w_id`), one expression and pose per frame. `states` must have one entry per frame;
    /// the identity is taken from `states[0]` at the start.
    ///
    /// # Errors
    /// As [`Self::solve_into`]; [`Error::DimensionMismatch`] when `states` and `frames` differ in length.
    pub fn fit_sequence(
        &self,
        frames: &[FitInput],
        states: &mut [FitState],
        ws: &mut FitWorkspace,
    ) -> Result<FitReport> {
        if frames.len() != states.len() {
            return Err(Error::dim("number of frame states", frames.len(), states.len()));
        }
        if frames.is_empty() {
            return Err(Error::invalid("number of frames", 0, ">= 1"));
        }
        for (f, s) in frames.iter().zip(states.iter()) {
            self.check_input(f, s)?;
        }
        let w_id0 = states[0].w_id.clone();
        for s in states.iter_mut() {
            s.w_id.copy_from_slice(&w_id0);
        }
        let seq_cost = |states: &[FitState], ws: &mut FitWorkspace| -> f64 {
            let mut c = 0.0;
            for (f, s) in frames.iter().zip(states) {
                c += self.cost_inner(f, s, ws, false);
            }
            let p_id: f64 = states[0]
                .w_id
                .iter()
                .zip(&self.prior_id)
                .map(|(a, b)| (a - b).powi(2))
                .sum();
            c + self.params.lambda_id * p_id
        };
        for (f, s) in frames.iter().zip(states.iter_mut()) {
            self.update_points(s, ws);
            self.pose_step(f, s, ws)?;
        }
        let mut cost = seq_cost(states, ws);
        let initial = cost;
        let mut max_increase = f64::NEG_INFINITY;
        let mut stop = Stop::MaxSweeps;
        let mut sweeps = 0;
        let mut w_id = w_id0;
        for s_i in 0..self.params.max_sweeps {
            sweeps = s_i + 1;
            for (f, s) in frames.iter().zip(states.iter_mut()) {
                if s_i > 0 {
                    self.update_points(s, ws);
                    self.pose_step(f, s, ws)?;
                }
                self.exp_step(f, s, ws)?;
            }
            if self.params.update_identity {
                self.clear_normal(Block::Id, ws);
                for (f, s) in frames.iter().zip(states.iter()) {
                    self.update_modes(s, ws);
                    self.accumulate(Block::Id, f, s, ws, 1.0);
                }
                self.solve_block(Block::Id, self.params.lambda_id, &mut w_id, ws)?;
                for s in states.iter_mut() {
                    s.w_id.copy_from_slice(&w_id);
                }
            }
            let new = seq_cost(states, ws);
            max_increase = max_increase.max(new - cost);
            let rel = (cost - new) / cost.max(1e-300);
            cost = new;
            if rel <= self.params.tol {
                stop = Stop::Converged;
                break;
            }
        }
        let mut rms = 0.0;
        for (f, s) in frames.iter().zip(states.iter()) {
            self.update_points(s, ws);
            if let Some(p) = s.pose {
                rms += pose::reprojection_rms(&ws.pts, f.image, f.weights, &f.intrinsics, &p).powi(2);
            }
        }
        Ok(FitReport {
            sweeps,
            initial_cost: initial,
            final_cost: cost,
            max_increase,
            stop,
            rms_px: (rms / frames.len() as f64).sqrt(),
        })
    }

    /// The fitted model points of the last [`Self::solve_into`] state (for reprojection).
    pub fn points_into(&self, state: &FitState, ws: &mut FitWorkspace, out: &mut Vec<Point3<f64>>) {
        self.update_points(state, ws);
        out.clear();
        out.extend_from_slice(&ws.pts);
    }
}

/// The design rows of one frame (see [`Fitter::accumulate`]) as a [`pulp::WithSimd`]
/// operation, so that the loops are compiled for the dispatched CPU level.
struct DesignRows<'a> {
    tall: &'a [f64],
    mean: &'a [f64],
    input: &'a FitInput<'a>,
    depth: &'a [f64],
    rm: nalgebra::Matrix3<f64>,
    t: nalgebra::Vector3<f64>,
    /// `scale / sum w`.
    scale: f64,
    r: usize,
    rp: usize,
    design: &'a mut [f64],
    design_w: &'a mut [f64],
    g: &'a mut [f64],
}

impl pulp::WithSimd for DesignRows<'_> {
    /// Number of weighted points written.
    type Output = usize;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> usize {
        let DesignRows {
            tall,
            mean,
            input,
            depth,
            rm,
            t,
            scale,
            r,
            rp,
            design,
            design_w,
            g,
        } = self;
        let k = &input.intrinsics;
        let (a00, a01, a02) = (rm[(0, 0)], rm[(0, 1)], rm[(0, 2)]);
        let (a10, a11, a12) = (rm[(1, 0)], rm[(1, 1)], rm[(1, 2)]);
        let mut m = 0;
        for (idx, ((x, &w), &z)) in input.image.iter().zip(input.weights).zip(depth).enumerate() {
            if w <= 0.0 {
                continue;
            }
            let wk = scale * w;
            // The core of this point contracted with the fixed block (precomputed).
            let tcon = &tall[3 * idx * r..3 * (idx + 1) * r];
            let (t0s, rest) = tcon.split_at(r);
            let (t1s, t2s) = rest.split_at(r);
            let m3 = [mean[3 * idx], mean[3 * idx + 1], mean[3 * idx + 2]];
            let qx = (x.x - k.cx) * z / k.fx;
            let qy = (x.y - k.cy) * z / k.fy;
            let y0 = qx - (a00 * m3[0] + a01 * m3[1] + a02 * m3[2] + t.x);
            let y1 = qy - (a10 * m3[0] + a11 * m3[1] + a12 * m3[2] + t.y);
            let (r0, r1) = design[2 * m * rp..2 * (m + 1) * rp].split_at_mut(rp);
            for (((((o0, o1), &t0), &t1), &t2), gv) in r0
                .iter_mut()
                .zip(r1.iter_mut())
                .zip(t0s)
                .zip(t1s)
                .zip(t2s)
                .zip(g.iter_mut())
            {
                let (v0, v1) = (a00 * t0 + a01 * t1 + a02 * t2, a10 * t0 + a11 * t1 + a12 * t2);
                *o0 = v0;
                *o1 = v1;
                *gv += (wk * v0) * y0 + (wk * v1) * y1;
            }
            r0[r..].iter_mut().for_each(|v| *v = 0.0);
            r1[r..].iter_mut().for_each(|v| *v = 0.0);
            design_w[m] = wk;
            m += 1;
        }
        m
    }
}

/// `pts[k][c] = mean[k][c] + <t[k][c], w>` as a [`pulp::WithSimd`] operation.
struct PointsFrom<'a> {
    t: &'a [f64],
    w: &'a [f64],
    mean: &'a [f64],
    pts: &'a mut [Point3<f64>],
}

impl pulp::WithSimd for PointsFrom<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let r = self.w.len();
        for ((p, rows), m) in self
            .pts
            .iter_mut()
            .zip(self.t.chunks_exact(3 * r))
            .zip(self.mean.chunks_exact(3))
        {
            for c in 0..3 {
                p[c] = m[c] + dot(&rows[c * r..(c + 1) * r], self.w);
            }
        }
    }
}

/// `pts[k] = mean[k] + R^T v_k` with `v_k[i] = <t[k][i], w>` (`t`: `[N][3][rp]`, the
/// rotated contraction; `R` row-major) as a [`pulp::WithSimd`] operation.
struct PointsFromRot<'a> {
    t: &'a [f64],
    rp: usize,
    rot: [f64; 9],
    w: &'a [f64],
    mean: &'a [f64],
    pts: &'a mut [Point3<f64>],
}

impl pulp::WithSimd for PointsFromRot<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let (r, rp, rot) = (self.w.len(), self.rp, self.rot);
        for ((p, rows), m) in self
            .pts
            .iter_mut()
            .zip(self.t.chunks_exact(3 * rp))
            .zip(self.mean.chunks_exact(3))
        {
            let v: [f64; 3] = std::array::from_fn(|i| dot(&rows[i * rp..i * rp + r], self.w));
            for c in 0..3 {
                p[c] = m[c] + (rot[c] * v[0] + rot[3 + c] * v[1] + rot[6 + c] * v[2]);
            }
        }
    }
}

/// `hdb = U H U^T + lambda I` (`U`: `d x r`, `H`: `r x r` symmetric, both row-major; the
/// upper triangle computed and mirrored) as a [`pulp::WithSimd`] operation.
struct Uhu<'a> {
    u: &'a [f64],
    h: &'a [f64],
    d: usize,
    r: usize,
    lambda: f64,
    tmp: &'a mut [f64],
    hdb: &'a mut [f64],
}

impl pulp::WithSimd for Uhu<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Uhu {
            u,
            h,
            d,
            r,
            lambda,
            tmp,
            hdb,
        } = self;
        // tmp = U H, row by row as axpys over the contiguous rows of `h`.
        for (trow, urow) in tmp.chunks_exact_mut(r).zip(u.chunks_exact(r)) {
            trow.iter_mut().for_each(|v| *v = 0.0);
            for (&ul, hrow) in urow.iter().zip(h.chunks_exact(r)) {
                for (tv, hv) in trow.iter_mut().zip(hrow) {
                    *tv += ul * hv;
                }
            }
        }
        for i in 0..d {
            for j in i..d {
                let v = dot(&tmp[i * r..(i + 1) * r], &u[j * r..(j + 1) * r]);
                hdb[i * d + j] = v;
                hdb[j * d + i] = v;
            }
            hdb[i * d + i] += lambda;
        }
    }
}

/// `r` rounded up to a multiple of 8 (row stride of the padded design rows).
fn pad8(r: usize) -> usize {
    r.div_ceil(8) * 8
}

/// `out = U^T w` for row-major `u` of shape `(rows, cols)`.
fn mat_t_vec(u: &[f64], rows: usize, cols: usize, w: &[f64], out: &mut [f64]) {
    out.iter_mut().for_each(|o| *o = 0.0);
    for r in 0..rows {
        let wr = w[r];
        for (o, uv) in out.iter_mut().zip(&u[r * cols..(r + 1) * cols]) {
            *o += uv * wr;
        }
    }
}
