//! The seed's region method: rigid alignment first, then each facial region's shapes fitted on
//! that region's landmarks only, in order, earlier regions' weights held fixed.
//!
//! Stage 0 ("rigid") is the Umeyama similarity on the stable landmarks (the seed's rigid head
//! shapes are replaced by a proper similarity, see [`crate::basis`]). Then, for each
//! [`RegionGroup`] in order, with `L` its landmarks and `G` its shapes:
//!
//! ```text
//! min_{e_G in [0,1]}  s^2 || D_{L,G} e_G - (b'_L - D_{L,~G} e_~G) ||^2 + lambda 1^T e_G + mu ||e_G - e_prev,G||^2
//! ```
//!
//! solved exactly (box QP, Gram matrices per group precomputed). Shapes of later groups are 0
//! while earlier groups are solved, as in the seed.
//!
//! Default grouping ([`RegionGroup::automatic`]): brows (iBUG 17-26), eyes (36-47), then mouth,
//! jaw and nose (0-16, 27-35, 48-67); each shape goes to the group where its landmark deltas
//! carry the most energy. Any grouping can be passed instead.
//!
//! | param | default | meaning | range |
//! |---|---|---|---|
//! | `objective` | `l1 = 1, temporal = 0` | see [`ObjectiveParams`] | |
//! | `groups` | automatic | ordered regions (landmarks + shapes) | every shape in at most one group |
//! | `max_iterations` | 100 | QP iteration cap per group | 1-10000 |

use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};

use crate::basis::Basis2d;
use crate::error::{check_count, Error, Result};
use crate::solver::{
    check_io, ExpressionSolver, Frame2d, Model2d, ObjectiveParams, Report, Solution, SolveState, StopReason, COORDS,
};
use facecap_geom::qp::{solve_box_qp, QpOptions, QpWorkspace};

/// One region: its landmarks and the shapes solved on them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegionGroup {
    /// Name (for reports).
    pub name: String,
    /// 0-based iBUG landmark indices.
    pub landmarks: Vec<usize>,
    /// Shape indices (rig order).
    pub shapes: Vec<usize>,
}

impl RegionGroup {
    /// The default grouping (module docs) for a basis.
    pub fn automatic(basis: &Basis2d) -> Vec<RegionGroup> {
        let regions: [(&str, Vec<usize>); 3] = [
            ("brows", (17..27).collect()),
            ("eyes", (36..48).collect()),
            ("mouth_jaw_nose", (0..17).chain(27..36).chain(48..68).collect()),
        ];
        let mut groups: Vec<RegionGroup> = regions
            .iter()
            .map(|(n, l)| RegionGroup {
                name: n.to_string(),
                landmarks: l.clone(),
                shapes: Vec::new(),
            })
            .collect();
        for k in 0..basis.num_shapes() {
            let energy = |ls: &[usize]| -> f64 {
                ls.iter()
                    .filter(|&&l| basis.mapped[l])
                    .map(|&l| basis.deltas[[k, 2 * l]].powi(2) + basis.deltas[[k, 2 * l + 1]].powi(2))
                    .sum()
            };
            let mut best = 2;
            let mut best_e = -1.0;
            for (g, (_, ls)) in regions.iter().enumerate() {
                let e = energy(ls);
                if e > best_e {
                    best_e = e;
                    best = g;
                }
            }
            groups[best].shapes.push(k);
        }
        groups.retain(|g| !g.shapes.is_empty());
        groups
    }
}

/// Parameters of [`RegionSolver`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RegionParams {
    /// Objective weights.
    pub objective: ObjectiveParams,
    /// Ordered regions; `None` = [`RegionGroup::automatic`].
    pub groups: Option<Vec<RegionGroup>>,
    /// QP iteration cap per group (0 = default 100).
    pub max_iterations: usize,
}

#[derive(Debug, Clone)]
struct Group {
    shapes: Vec<usize>,
    coords: Vec<usize>,
    gram: Vec<f64>,
}

/// The region method (see module docs).
#[derive(Debug, Clone)]
pub struct RegionSolver {
    model: Model2d,
    groups: Vec<Group>,
    group_names: Vec<String>,
    objective: ObjectiveParams,
    max_iterations: usize,
    ridge: f64,
}

/// Scratch of [`RegionSolver`].
#[derive(Debug, Clone)]
pub struct RegionWorkspace {
    frame: Frame2d,
    e: Vec<f64>,
    resid: Vec<f64>,
    h: Vec<f64>,
    g: Vec<f64>,
    x: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    scratch: Vec<f64>,
    qp: QpWorkspace,
}

impl RegionSolver {
    /// Validates the grouping (landmarks in range, shapes in range and in at most one group).
    pub fn new(basis: &Basis2d, params: RegionParams) -> Result<Self> {
        params.objective.validate()?;
        let max_iterations = if params.max_iterations == 0 {
            100
        } else {
            params.max_iterations
        };
        check_count("max_iterations", max_iterations, 1, 10000)?;
        let model = Model2d::new(basis)?;
        let n = model.n;
        let spec = params.groups.unwrap_or_else(|| RegionGroup::automatic(basis));
        let mut used = vec![false; n];
        let mut groups = Vec::new();
        let mut names = Vec::new();
        for g in &spec {
            if let Some(&l) = g.landmarks.iter().find(|&&l| l >= NUM_LANDMARKS) {
                return Err(Error::invalid(
                    "region landmark",
                    format!("{l} in group {:?}", g.name),
                    "0..=67",
                ));
            }
            for &k in &g.shapes {
                if k >= n {
                    return Err(Error::invalid(
                        "region shape",
                        format!("{k} in group {:?}", g.name),
                        format!("0..{n}"),
                    ));
                }
                if used[k] {
                    return Err(Error::invalid(
                        "region shape",
                        format!("{k} in group {:?}", g.name),
                        "each shape in at most one group",
                    ));
                }
                used[k] = true;
            }
            if g.shapes.is_empty() {
                continue;
            }
            let coords: Vec<usize> = g
                .landmarks
                .iter()
                .filter(|&&l| model.mapped[l])
                .flat_map(|&l| [2 * l, 2 * l + 1])
                .collect();
            let m = g.shapes.len();
            let mut gram = vec![0.0; m * m];
            for (a, &ka) in g.shapes.iter().enumerate() {
                for (b, &kb) in g.shapes.iter().enumerate() {
                    gram[a * m + b] = coords
                        .iter()
                        .map(|&c| model.deltas[ka * COORDS + c] * model.deltas[kb * COORDS + c])
                        .sum();
                }
            }
            groups.push(Group {
                shapes: g.shapes.clone(),
                coords,
                gram,
            });
            names.push(g.name.clone());
        }
        let maxdiag = (0..n).map(|i| model.gram[i * n + i]).fold(0.0f64, f64::max);
        Ok(RegionSolver {
            model,
            groups,
            group_names: names,
            objective: params.objective,
            max_iterations,
            ridge: crate::exact::RIDGE_REL * maxdiag.max(1e-300),
        })
    }

    /// Names of the groups, in solve order.
    pub fn group_names(&self) -> &[String] {
        &self.group_names
    }
}

impl ExpressionSolver for RegionSolver {
    type Workspace = RegionWorkspace;

    fn num_shapes(&self) -> usize {
        self.model.n
    }

    fn names(&self) -> &[String] {
        &self.model.names
    }

    fn workspace(&self) -> RegionWorkspace {
        let n = self.model.n;
        let m = self.groups.iter().map(|g| g.shapes.len()).max().unwrap_or(0);
        RegionWorkspace {
            frame: Frame2d::new(),
            e: vec![0.0; n],
            resid: vec![0.0; COORDS],
            h: vec![0.0; m * m],
            g: vec![0.0; m],
            x: vec![0.0; m],
            lo: vec![0.0; m],
            hi: vec![1.0; m],
            scratch: vec![0.0; COORDS],
            qp: QpWorkspace::new(m),
        }
    }

    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut RegionWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        let md = &self.model;
        let n = md.n;
        check_io(n, input, state, out)?;
        let obj = &self.objective;
        let mu = if state.has_previous { obj.temporal } else { 0.0 };
        ws.e.fill(0.0);
        md.prepare(input, &ws.e, &mut ws.frame)?;
        let s2 = ws.frame.sim.scale * ws.frame.sim.scale;
        let opts = QpOptions {
            max_iterations: self.max_iterations,
            ..QpOptions::default()
        };
        let mut inner = 0;
        let mut converged = true;
        for grp in &self.groups {
            // residual of the current (partial) fit: b' - D e
            md.pose(&ws.e, &mut ws.scratch);
            for c in 0..COORDS {
                ws.resid[c] = ws.frame.target[c] - (ws.scratch[c] - md.neutral[c]);
            }
            let m = grp.shapes.len();
            for (a, &ka) in grp.shapes.iter().enumerate() {
                // D_G^T (resid + D_G e_G): e_G is 0 here (each shape solved once)
                let r: f64 = grp
                    .coords
                    .iter()
                    .map(|&c| md.deltas[ka * COORDS + c] * ws.resid[c])
                    .sum();
                ws.g[a] = 2.0 * s2 * r + 2.0 * mu * state.weights[ka] - obj.l1;
                for b in 0..m {
                    ws.h[a * m + b] = 2.0 * s2 * grp.gram[a * m + b];
                }
                ws.h[a * m + a] += 2.0 * mu + self.ridge * s2;
                ws.x[a] = state.weights[ka];
            }
            let o = solve_box_qp(
                &ws.h[..m * m],
                &ws.g[..m],
                &ws.lo[..m],
                &ws.hi[..m],
                &mut ws.x[..m],
                &opts,
                &mut ws.qp,
            );
            inner += o.iterations;
            converged &= o.converged;
            for (a, &ka) in grp.shapes.iter().enumerate() {
                ws.e[ka] = ws.x[a];
            }
        }
        let prev = if mu > 0.0 { Some(state.weights.as_slice()) } else { None };
        let cost = md.cost(&ws.e, &ws.frame, obj, prev, &mut ws.scratch);
        out.weights.copy_from_slice(&ws.e);
        out.similarity = Some(ws.frame.sim);
        out.pose = None;
        md.fitted(&ws.e, &ws.frame.sim, &mut ws.scratch, &mut out.fitted);
        state.weights.copy_from_slice(&ws.e);
        state.has_previous = true;
        Ok(Report {
            iterations: self.groups.len(),
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
