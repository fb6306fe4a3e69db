//! All-in-one BOBYQA, as in the seed (King 2017 thesis, after Powell 2009, "The BOBYQA
//! algorithm for bound constrained optimization without derivatives", Cambridge NA2009/06).
//!
//! The objective of [`crate::solver`] (2D similarity-aligned, L1 and optional temporal term)
//! is minimised over `e in [0, 1]^n` by the derivative-free BOBYQA with `npt = 2n + 1`
//! interpolation points, in two passes: `rho` 0.075 -> 0.01, then again from the pass-1
//! result with `rho` 0.075 -> 0.005 (as the seed, and as the dlib anchor
//! `shared/anchors/bench_bobyqa_fit.py` times `dlib::find_min_bobyqa`).
//!
//! Implementation: our own BOBYQA, [`crate::bobyqa::Bobyqa`] (Powell 2009 port, flat arrays
//! allocated once in the workspace, no allocation per solve). We evaluate the
//! objective through the precomputed Gram matrix, `f(e) = s^2 (e^T G e - 2 e^T D b' + b'^T b')
//! + ...`, O(n^2) per evaluation instead of O(136 n) (same values to rounding; tested).
//!
//! | param | default | meaning | range |
//! |---|---|---|---|
//! | `objective` | `l1 = 1, temporal = 0` | see [`ObjectiveParams`] | |
//! | `npt` | `2n + 1` | interpolation points | `n + 2 ..= (n+1)(n+2)/2` |
//! | `rho_begin` | 0.075 | initial trust radius | (0, 0.5] |
//! | `rho_end` | `[0.01, 0.005]` | final radius of pass 1 and 2 | (0, rho_begin] |
//! | `max_evals` | 30000 | evaluation cap per pass | > npt |
//! | `warm_start` | false | start from the previous frame (else `e = 0`, as the seed) | |
//! | `alignments` | 1 | align/solve passes (see [`crate::exact`]) | 1-10 |

use facecap_core::landmarks::Landmarks68;

use crate::basis::Basis2d;
use crate::bobyqa::{Bobyqa, BobyqaRun, BobyqaStop};
use crate::error::{check_count, check_range, Error, Result};
use crate::solver::{
    check_io, ExpressionSolver, Frame2d, Model2d, ObjectiveParams, Report, Solution, SolveState, StopReason, COORDS,
};

/// Parameters of [`BobyqaSolver`] (table in the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BobyqaParams {
    /// Objective weights.
    pub objective: ObjectiveParams,
    /// Interpolation points; `None` = `2n + 1`.
    pub npt: Option<usize>,
    /// Initial trust-region radius.
    pub rho_begin: f64,
    /// Final radius of pass 1 and pass 2.
    pub rho_end: [f64; 2],
    /// Evaluation cap per pass.
    pub max_evals: usize,
    /// Start from the previous frame's weights.
    pub warm_start: bool,
    /// Align/solve passes.
    pub alignments: usize,
}

impl Default for BobyqaParams {
    fn default() -> Self {
        BobyqaParams {
            objective: ObjectiveParams::default(),
            npt: None,
            rho_begin: 0.075,
            rho_end: [0.01, 0.005],
            max_evals: 30000,
            warm_start: false,
            alignments: 1,
        }
    }
}

impl BobyqaParams {
    fn validate(&self, n: usize) -> Result<usize> {
        self.objective.validate()?;
        let npt = self.npt.unwrap_or(2 * n + 1);
        check_count("npt", npt, n + 2, (n + 1) * (n + 2) / 2)?;
        check_range("rho_begin", self.rho_begin, 1e-12, 0.5)?;
        check_range("rho_end[0]", self.rho_end[0], 1e-12, self.rho_begin)?;
        check_range("rho_end[1]", self.rho_end[1], 1e-12, self.rho_begin)?;
        check_count("max_evals", self.max_evals, npt + 1, 100_000_000)?;
        check_count("alignments", self.alignments, 1, 10)?;
        Ok(npt)
    }
}

/// The seed's all-in-one BOBYQA solver.
#[derive(Debug, Clone)]
pub struct BobyqaSolver {
    model: Model2d,
    params: BobyqaParams,
    npt: usize,
}

/// Scratch of [`BobyqaSolver`]: the two BOBYQA engines (their buffers are allocated once here).
#[derive(Debug, Clone)]
pub struct BobyqaWorkspace {
    frame: Frame2d,
    engine: Bobyqa,
    dtb: Vec<f64>,
    x: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    scratch: Vec<f64>,
}

/// `f(e)` through the Gram matrix (see module docs).
#[allow(clippy::too_many_arguments)]
pub(crate) fn gram_objective(
    gram: &[f64],
    dtb: &[f64],
    bb: f64,
    s2: f64,
    l1: f64,
    mu: f64,
    prev: &[f64],
    e: &[f64],
) -> f64 {
    let n = e.len();
    let mut quad = 0.0;
    let mut lin = 0.0;
    let mut sum = 0.0;
    let mut temp = 0.0;
    for i in 0..n {
        let row = &gram[i * n..(i + 1) * n];
        let ge: f64 = row.iter().zip(e).map(|(a, b)| a * b).sum();
        quad += e[i] * ge;
        lin += e[i] * dtb[i];
        sum += e[i];
        let d = e[i] - prev[i];
        temp += d * d;
    }
    s2 * (quad - 2.0 * lin + bb) + l1 * sum + mu * temp
}

impl BobyqaSolver {
    /// Validates parameters, precomputes the Gram matrix.
    pub fn new(basis: &Basis2d, params: BobyqaParams) -> Result<Self> {
        let model = Model2d::new(basis)?;
        let n = model.n;
        let npt = params.validate(n)?;
        Bobyqa::new(n, npt)?;
        Ok(BobyqaSolver { model, params, npt })
    }
}

impl ExpressionSolver for BobyqaSolver {
    type Workspace = BobyqaWorkspace;

    fn num_shapes(&self) -> usize {
        self.model.n
    }

    fn names(&self) -> &[String] {
        &self.model.names
    }

    fn workspace(&self) -> BobyqaWorkspace {
        let n = self.model.n;
        // `new` already built an engine with the same (n, npt): this cannot fail
        let engine = match Bobyqa::new(n, self.npt) {
            Ok(e) => e,
            Err(_) => unreachable_engine(n),
        };
        BobyqaWorkspace {
            frame: Frame2d::new(),
            engine,
            dtb: vec![0.0; n],
            x: vec![0.0; n],
            lo: vec![0.0; n],
            hi: vec![1.0; n],
            scratch: vec![0.0; COORDS],
        }
    }

    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut BobyqaWorkspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report> {
        let m = &self.model;
        let n = m.n;
        check_io(n, input, state, out)?;
        let obj = self.params.objective;
        let mu = if state.has_previous { obj.temporal } else { 0.0 };
        if self.params.warm_start {
            ws.x.copy_from_slice(&state.weights);
        } else {
            ws.x.fill(0.0);
        }
        let mut evals = 0;
        let mut stop = StopReason::RhoEnd;
        let mut f = f64::NAN;
        for _pass in 0..self.params.alignments {
            m.prepare(input, &ws.x, &mut ws.frame)?;
            let s2 = ws.frame.sim.scale * ws.frame.sim.scale;
            m.dtb(&ws.frame.target, &mut ws.dtb);
            let bb: f64 = ws.frame.target.iter().map(|v| v * v).sum();
            let (gram, dtb, prev) = (&m.gram, &ws.dtb, &state.weights);
            for rho_end in self.params.rho_end {
                let run = BobyqaRun {
                    rho_begin: self.params.rho_begin,
                    rho_end,
                    max_evals: self.params.max_evals,
                };
                let o = ws.engine.minimize(
                    |e: &[f64]| gram_objective(gram, dtb, bb, s2, obj.l1, mu, prev, e),
                    &mut ws.x,
                    &ws.lo,
                    &ws.hi,
                    &run,
                )?;
                evals += o.evaluations;
                f = o.f;
                if o.stop == BobyqaStop::MaxEvals {
                    stop = StopReason::MaxIterations;
                }
            }
        }
        let prev = if mu > 0.0 { Some(state.weights.as_slice()) } else { None };
        let cost = m.cost(&ws.x, &ws.frame, &obj, prev, &mut ws.scratch);
        debug_assert!((cost - f).abs() <= 1e-6 * (1.0 + cost.abs()) || !f.is_finite());
        out.weights.copy_from_slice(&ws.x);
        out.similarity = Some(ws.frame.sim);
        out.pose = None;
        m.fitted(&ws.x, &ws.frame.sim, &mut ws.scratch, &mut out.fitted);
        state.weights.copy_from_slice(&ws.x);
        state.has_previous = true;
        Ok(Report {
            iterations: 2 * self.params.alignments,
            evaluations: evals,
            cost,
            stop,
        })
    }
}

/// Allocation failure while building a workspace (after `new` succeeded with the same
/// configuration) leaves nothing sensible to do.
#[allow(clippy::panic)]
fn unreachable_engine(n: usize) -> Bobyqa {
    panic!("BOBYQA workspace allocation failed for n = {n}")
}

/// Two-pass BOBYQA (the passes of [`BobyqaParams`]) on any objective over the box
/// `[lo, hi]`, starting from `x` (overwritten with the result). Returns the final value and the
/// total number of evaluations. Allocates the engines on every call: for tests and one-off
/// problems; the per-frame solver keeps them in its workspace.
///
/// # Errors
/// Invalid parameters or bounds (BOBYQA needs `hi - lo >= 2 rho_begin`).
pub fn bobyqa_two_pass(
    mut f: impl FnMut(&[f64]) -> f64,
    x: &mut [f64],
    lo: &[f64],
    hi: &[f64],
    params: &BobyqaParams,
) -> Result<(f64, usize, StopReason)> {
    let n = x.len();
    if lo.len() != n || hi.len() != n {
        return Err(Error::DimensionMismatch {
            what: "bounds".into(),
            expected: n,
            got: lo.len().min(hi.len()),
        });
    }
    for i in 0..n {
        if hi[i] - lo[i] < 2.0 * params.rho_begin || (hi[i] - lo[i]).is_nan() {
            return Err(Error::invalid(
                "bounds",
                format!("[{}, {}] for variable {i}", lo[i], hi[i]),
                "hi - lo >= 2 rho_begin",
            ));
        }
    }
    let npt = params.validate(n)?;
    let mut engine = Bobyqa::new(n, npt)?;
    let (mut evals, mut fval, mut stop) = (0, f64::NAN, StopReason::RhoEnd);
    for rho_end in params.rho_end {
        let run = BobyqaRun {
            rho_begin: params.rho_begin,
            rho_end,
            max_evals: params.max_evals,
        };
        let o = engine.minimize(&mut f, x, lo, hi, &run)?;
        evals += o.evaluations;
        fval = o.f;
        if o.stop == BobyqaStop::MaxEvals {
            stop = StopReason::MaxIterations;
        }
    }
    Ok((fval, evals, stop))
}
