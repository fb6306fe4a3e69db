//! PCA method that works: PCA of the expression shapes, closed-form projection, and a bounded
//! least-squares map from PCA coefficients back to blendshape weights.
//!
//! `D^T` (`136 x n`, columns = shape deltas at the mapped landmarks) has the thin SVD
//! `U S V^T`. We keep the `k` leading components holding `energy` (default 99.9 %) of
//! `sum S_i^2` (uncentred: the neutral is the natural origin of expression deltas), `U_k` (`136 x k`).
//!
//! Per frame: align (Umeyama), project the model-frame target `b'` in closed form,
//! `c = U_k^T b'` (k numbers), then map back to weights by the bounded problem
//!
//! ```text
//! min_{e in [0,1]^n}  s^2 || P e - c ||^2 + lambda 1^T e + mu ||e - e_prev||^2,   P = U_k^T D^T  (k x n)
//! ```
//!
//! solved exactly (box QP, `P^T P` precomputed). The seed's PCA attempt lacked this map (it
//! inverted unbounded coefficients), so its meshes did not look right; with bounds and the L1
//! term the weights stay in the rig's valid range. Reported cost is the full 2D objective.
//!
//! | param | default | meaning | range |
//! |---|---|---|---|
//! | `objective` | `l1 = 1, temporal = 0` | see [`ObjectiveParams`] | |
//! | `energy` | 0.999 | fraction of squared singular values kept | (0, 1] |

use facecap_core::landmarks::Landmarks68;
use nalgebra::DMatrix;

use crate::basis::Basis2d;
use crate::error::{check_range, Error, Result};
use crate::solver::{
    check_io, ExpressionSolver, Frame2d, Model2d, ObjectiveParams, Report, Solution, SolveState, StopReason, COORDS,
};
use facecap_geom::qp::{solve_box_qp, QpOptions, QpWorkspace};

/// Parameters of [`PcaSolver`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcaParams {
    /// Objective weights.
    pub objective: ObjectiveParams,
    /// Energy kept.
    pub energy: f64,
}

impl Default for PcaParams {
    fn default() -> Self {
        PcaParams {
            objective: ObjectiveParams::default(),
            energy: 0.999,
        }
    }
}

/// The PCA method (see module docs).
#[derive(Debug, Clone)]
pub struct PcaSolver {
    model: Model2d,
    objective: ObjectiveParams,
    /// `k x 136` row-major.
    components: Vec<f64>,
    /// `k x n` row-major.
    p: Vec<f64>,
    /// `P^T P`, `n x n`.
    gram: Vec<f64>,
    k: usize,
    ridge: f64,
}

/// Scratch of [`PcaSolver`].
#[derive(Debug, Clone)]
pub struct PcaWorkspace {
    frame: Frame2d,
    /// The PCA coefficients of the last frame (`k`).
    pub coefficients: Vec<f64>,
    h: Vec<f64>,
    g: Vec<f64>,
    x: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    scratch: Vec<f64>,
    qp: QpWorkspace,
}

impl PcaSolver {
    /// Computes the PCA basis and the map-back Gram matrix.
    pub fn new(basis: &Basis2d, params: PcaParams) -> Result<Self> {
        params.objective.validate()?;
        check_range("energy", params.energy, 1e-9, 1.0)?;
        let model = Model2d::new(basis)?;
        let n = model.n;
        let dt = DMatrix::from_fn(COORDS, n, |r, c| model.deltas[c * COORDS + r]);
        let svd = dt.svd(true, false);
        let u = svd.u.ok_or_else(|| Error::Numerical {
            operation: "PCA (SVD)",
            reason: "no left singular vectors".into(),
        })?;
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
        let total: f64 = svd.singular_values.iter().map(|s| s * s).sum();
        if total <= 0.0 || total.is_nan() {
            return Err(Error::rig(
                "PCA basis",
                "all expression deltas are zero at the mapped landmarks",
            ));
        }
        let mut k = 0;
        let mut acc = 0.0;
        for &i in &order {
            acc += svd.singular_values[i].powi(2);
            k += 1;
            if acc >= params.energy * total {
                break;
            }
        }
        let mut components = vec![0.0; k * COORDS];
        for (r, &i) in order.iter().take(k).enumerate() {
            for c in 0..COORDS {
                components[r * COORDS + c] = u[(c, i)];
            }
        }
        let mut p = vec![0.0; k * n];
        for r in 0..k {
            for j in 0..n {
                p[r * n + j] = (0..COORDS)
                    .map(|c| components[r * COORDS + c] * model.deltas[j * COORDS + c])
                    .sum();
            }
        }
        let mut gram = vec![0.0; n * n];
        for a in 0..n {
            for b in 0..n {
                gram[a * n + b] = (0..k).map(|r| p[r * n + a] * p[r * n + b]).sum();
            }
        }
        let maxdiag = (0..n).map(|i| gram[i * n + i]).fold(0.0f64, f64::max);
        Ok(PcaSolver {
            model,
            objective: params.objective,
            components,
            p,
            gram,
            k,
            ridge: crate::exact::RIDGE_REL * maxdiag.max(1e-300),
        })
    }

    /// Number of PCA components kept.
    pub fn num_components(&self) -> usize {
        self.k
    }
}

impl ExpressionSolver for PcaSolver {
    type Workspace = PcaWorkspace;

    fn num_shapes(&self) -> usize {
        self.model.n
    }

    fn names(&self) -> &[String] {
        &self.model.names
    }

    fn workspace(&self) -> PcaWorkspace {
        let n = self.model.n;
        PcaWorkspace {
            frame: Frame2d::new(),
            coefficients: vec![0.0; self.k],
            h: vec![0.0; n * n],
            g: vec![0.0; n],
            x: vec![0.0; n],
            lo: vec![0.0; n],
            hi: vec![1.0; n],
            scratch: vec![0.0; COORDS],
            qp: QpWorkspace::new(n),
        }
    }

    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut PcaWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        let md = &self.model;
        let n = md.n;
        check_io(n, input, state, out)?;
        let obj = &self.objective;
        let mu = if state.has_previous { obj.temporal } else { 0.0 };
        ws.x.fill(0.0);
        md.prepare(input, &ws.x, &mut ws.frame)?;
        let s2 = ws.frame.sim.scale * ws.frame.sim.scale;
        for r in 0..self.k {
            ws.coefficients[r] = self.components[r * COORDS..(r + 1) * COORDS]
                .iter()
                .zip(&ws.frame.target)
                .map(|(a, b)| a * b)
                .sum();
        }
        for i in 0..n {
            let ptc: f64 = (0..self.k).map(|r| self.p[r * n + i] * ws.coefficients[r]).sum();
            ws.g[i] = 2.0 * s2 * ptc + 2.0 * mu * state.weights[i] - obj.l1;
            for j in 0..n {
                ws.h[i * n + j] = 2.0 * s2 * self.gram[i * n + j];
            }
            ws.h[i * n + i] += 2.0 * mu + self.ridge * s2;
        }
        ws.x.copy_from_slice(&state.weights);
        let o = solve_box_qp(
            &ws.h,
            &ws.g,
            &ws.lo,
            &ws.hi,
            &mut ws.x,
            &QpOptions::default(),
            &mut ws.qp,
        );
        let prev = if mu > 0.0 { Some(state.weights.as_slice()) } else { None };
        let cost = md.cost(&ws.x, &ws.frame, obj, prev, &mut ws.scratch);
        out.weights.copy_from_slice(&ws.x);
        out.similarity = Some(ws.frame.sim);
        out.pose = None;
        md.fitted(&ws.x, &ws.frame.sim, &mut ws.scratch, &mut out.fitted);
        state.weights.copy_from_slice(&ws.x);
        state.has_previous = true;
        Ok(Report {
            iterations: 1,
            evaluations: o.iterations,
            cost,
            stop: if o.converged {
                StopReason::Converged
            } else {
                StopReason::MaxIterations
            },
        })
    }
}
