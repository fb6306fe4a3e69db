//! Exact bounded 2D solver (ours): the seed's objective solved exactly as a box QP.
//!
//! With the similarity `(s, R, t)` fixed (Umeyama on the stable points), the objective of
//! [`crate::solver`] is
//!
//! ```text
//! f(e) = s^2 ||D e - b'||^2 + lambda 1^T e + mu ||e - e_prev||^2,    e in [0, 1]^n
//!      = 1/2 e^T H e - g^T e + const,
//! H = 2 (s^2 G + mu I),   G = D^T D  (n x n, precomputed once in `new`),
//! g = 2 s^2 D b' + 2 mu e_prev - lambda 1,
//! ```
//!
//! with `D` the `136 x n` delta matrix and `b' = sim^-1(o) - neutral`. Per frame only `D b'`
//! (136 n flops) and the box QP ([`facecap_geom::qp`], exact active-set method, warm-started from the
//! previous frame's weights and active set) are computed. The alignment is then refitted on the
//! posed shape and the QP re-solved (`alignments` passes).
//!
//! Per-frame savings (same result): with `mu = 0`, `H = s^2 (2 G + ridge I)`, so the QP's
//! Cholesky factor of the free block is carried over from the previous pass or frame and
//! rescaled by the ratio of the `s^2` instead of recomputed ([`facecap_geom::qp::solve_box_qp_reuse`];
//! the workspace remembers which solver and `s^2` it belongs to). The first alignment reuses the
//! posed shape of the previous weights kept in the workspace. The reported cost is
//! `q(e) - (ridge s^2 / 2) |e|^2 + s^2 b'^T b' + mu |e_prev|^2` from the QP value, O(n).
//!
//! | param | default | meaning | range |
//! |---|---|---|---|
//! | `objective` | `l1 = 1, temporal = 0` | see [`ObjectiveParams`] | |
//! | `alignments` | 2 | align/solve passes (pass 2+ aligns the posed shape) | 1-10 |
//! | `max_iterations` | 100 | QP iteration cap | 1-10000 |
//! | `kkt_tol` | 1e-10 | relative KKT tolerance | (0, 1e-2] |

use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::Point2;

use crate::basis::{flatten_landmarks, Basis2d};
use crate::error::{check_count, check_range, Result};
use crate::solver::{
    check_io, ExpressionSolver, Frame2d, Model2d, ObjectiveParams, Report, Solution, SolveState, StopReason,
};
use facecap_geom::qp::{solve_box_qp_reuse, QpOptions, QpWorkspace};

/// Relative ridge added to the QP Hessian's diagonal so that shapes invisible at the landmarks
/// (e.g. eye-gaze shapes) keep the reduced Hessian positive definite. Negligible otherwise.
pub(crate) const RIDGE_REL: f64 = 1e-12;

/// Parameters of [`ExactSolver`] (table in the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExactParams {
    /// Objective weights.
    pub objective: ObjectiveParams,
    /// Align/solve passes.
    pub alignments: usize,
    /// QP iteration cap.
    pub max_iterations: usize,
    /// Relative KKT tolerance.
    pub kkt_tol: f64,
}

impl Default for ExactParams {
    fn default() -> Self {
        ExactParams {
            objective: ObjectiveParams::default(),
            alignments: 2,
            max_iterations: 100,
            kkt_tol: 1e-10,
        }
    }
}

impl ExactParams {
    /// Validates the table's ranges.
    pub fn validate(&self) -> Result<()> {
        self.objective.validate()?;
        check_count("alignments", self.alignments, 1, 10)?;
        check_count("max_iterations", self.max_iterations, 1, 10000)?;
        if self.kkt_tol <= 0.0 {
            return Err(crate::Error::invalid(
                "kkt_tol",
                self.kkt_tol,
                "a finite number in (0, 0.01]",
            ));
        }
        check_range("kkt_tol", self.kkt_tol, 0.0, 1e-2)?;
        Ok(())
    }
}

/// The exact bounded 2D solver (see module docs).
#[derive(Debug, Clone)]
pub struct ExactSolver {
    pub(crate) model: Model2d,
    params: ExactParams,
    ridge: f64,
    /// Identifies the Gram matrix for the QP factor reuse (clones share it, and their matrix).
    id: u64,
}

static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Scratch buffers of [`ExactSolver`].
#[derive(Debug, Clone)]
pub struct ExactWorkspace {
    pub(crate) frame: Frame2d,
    h: Vec<f64>,
    g: Vec<f64>,
    dtb: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    x: Vec<f64>,
    /// Weights whose posed shape `frame.posed` holds after a solve (`posed_valid`): the next
    /// frame's first alignment starts from the previous weights and reuses it.
    posed_w: Vec<f64>,
    posed_valid: bool,
    /// `(solver id, s^2)` of the last QP solved with `mu = 0`, whose factor `qp` keeps.
    qp_last: Option<(u64, f64)>,
    qp: QpWorkspace,
}

impl ExactSolver {
    /// Validates the parameters and precomputes the Gram matrix.
    ///
    /// # Errors
    /// Invalid parameters (named), empty or non-finite basis.
    pub fn new(basis: &Basis2d, params: ExactParams) -> Result<Self> {
        params.validate()?;
        let model = Model2d::new(basis)?;
        let maxdiag = (0..model.n).map(|i| model.gram[i * model.n + i]).fold(0.0f64, f64::max);
        Ok(ExactSolver {
            ridge: RIDGE_REL * maxdiag.max(1e-300),
            model,
            params,
            id: NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ExactParams {
        &self.params
    }
}

impl ExpressionSolver for ExactSolver {
    type Workspace = ExactWorkspace;

    fn num_shapes(&self) -> usize {
        self.model.n
    }

    fn names(&self) -> &[String] {
        &self.model.names
    }

    fn workspace(&self) -> ExactWorkspace {
        let n = self.model.n;
        ExactWorkspace {
            frame: Frame2d::new(),
            h: vec![0.0; n * n],
            g: vec![0.0; n],
            dtb: vec![0.0; n],
            lo: vec![0.0; n],
            hi: vec![1.0; n],
            x: vec![0.0; n],
            posed_w: vec![0.0; n],
            posed_valid: false,
            qp_last: None,
            qp: QpWorkspace::new(n),
        }
    }

    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut ExactWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        let m = &self.model;
        let n = m.n;
        check_io(n, input, state, out)?;
        let obj = &self.params.objective;
        let mu = if state.has_previous { obj.temporal } else { 0.0 };
        ws.x.copy_from_slice(&state.weights);
        let opts = QpOptions {
            max_iterations: self.params.max_iterations,
            kkt_tol: self.params.kkt_tol,
        };
        let mut inner = 0;
        let mut converged = true;
        let (mut s2, mut bb, mut q) = (1.0, 0.0, 0.0);
        flatten_landmarks(input, &mut ws.frame.obs);
        if !(ws.posed_valid && ws.posed_w == state.weights) {
            m.pose(&ws.x, &mut ws.frame.posed);
        }
        for pass in 0..self.params.alignments {
            if pass > 0 {
                m.pose(&ws.x, &mut ws.frame.posed);
            }
            ws.posed_valid = false;
            m.align_posed(&mut ws.frame)?;
            s2 = ws.frame.sim.scale * ws.frame.sim.scale;
            m.dtb(&ws.frame.target, &mut ws.dtb);
            bb = ws.frame.target.iter().map(|v| v * v).sum::<f64>();
            let diag = 2.0 * mu + self.ridge * s2;
            for i in 0..n {
                let (hr, gr) = (&mut ws.h[i * n..(i + 1) * n], &m.gram[i * n..(i + 1) * n]);
                for (a, b) in hr.iter_mut().zip(gr) {
                    *a = 2.0 * s2 * b;
                }
                hr[i] += diag;
                ws.g[i] = 2.0 * s2 * ws.dtb[i] + 2.0 * mu * state.weights[i] - obj.l1;
            }
            // with mu = 0, H = s^2 (2 G + ridge I): the previous factor is reusable, scaled
            // (not on a cold start: the previous frame's working set is no guess for a new track)
            let reuse = match ws.qp_last {
                Some((id, prev_s2)) if mu == 0.0 && id == self.id && (pass > 0 || state.has_previous) => {
                    Some(s2 / prev_s2)
                }
                _ => None,
            };
            let o = solve_box_qp_reuse(&ws.h, &ws.g, &ws.lo, &ws.hi, &mut ws.x, &opts, &mut ws.qp, reuse);
            ws.qp_last = if mu == 0.0 { Some((self.id, s2)) } else { None };
            inner += o.iterations;
            converged = o.converged;
            q = o.cost;
        }
        // f = q - (ridge s^2 / 2) |x|^2 + s^2 b'^T b' + mu |e_prev|^2  (module docs), O(n)
        let (mut xx, mut pp) = (0.0, 0.0);
        for (x, p) in ws.x.iter().zip(&state.weights) {
            xx += x * x;
            pp += p * p;
        }
        let cost = q - 0.5 * self.ridge * s2 * xx + s2 * bb + mu * pp;
        m.pose(&ws.x, &mut ws.frame.posed);
        let sim = ws.frame.sim;
        for l in 0..NUM_LANDMARKS {
            out.fitted[l] = if m.mapped[l] {
                let (x, y) = sim.apply(ws.frame.posed[2 * l], ws.frame.posed[2 * l + 1]);
                Point2::new(x, y)
            } else {
                Point2::new(f64::NAN, f64::NAN)
            };
        }
        ws.posed_w.copy_from_slice(&ws.x);
        ws.posed_valid = true;
        out.weights.copy_from_slice(&ws.x);
        out.similarity = Some(sim);
        out.pose = None;
        state.weights.copy_from_slice(&ws.x);
        state.has_previous = true;
        Ok(Report {
            iterations: self.params.alignments,
            evaluations: inner,
            cost,
            stop: if converged {
                StopReason::Converged
            } else {
                StopReason::MaxIterations
            },
        })
    }
}
