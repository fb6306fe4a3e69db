//! The solver trait and the types every method shares.
//!
//! # The objective (all methods)
//! For observed landmarks `o_j` (pixels, 0-based, y down), mapped landmarks `j`, weights
//! `e in [0, 1]^n`, previous frame's weights `e_prev`:
//!
//! ```text
//! f(e) = sum_j || proj_j(e) - o_j ||^2  +  lambda * sum_i e_i  +  mu * || e - e_prev ||^2
//! ```
//!
//! (`|e_i| = e_i` on the box.) Units: px^2. `proj_j` is, for the 2D methods, the similarity
//! `s R (n_j + D_j e) + t` of the frontal 2D basis fitted on the stable landmarks (Umeyama), and,
//! for the 3D method, the perspective projection of the posed 3D landmark. The temporal term is
//! active only when the state holds a previous frame.

use facecap_core::camera::ModelToCamera;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::Point2;

use crate::basis::{flatten_landmarks, Basis2d, Similarity2d};
use crate::error::{check_range, Error, Result};

/// Parameters of the shared objective.
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `l1` | 1.0 | `lambda`, weight of `sum e_i` (px^2 per unit weight) | `[0, 1e9]` |
/// | `temporal` | 0.0 | `mu`, weight of `||e - e_prev||^2` (px^2 per unit weight^2) | `[0, 1e9]` |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectiveParams {
    /// L1 weight `lambda`.
    pub l1: f64,
    /// Temporal weight `mu`.
    pub temporal: f64,
}

impl Default for ObjectiveParams {
    fn default() -> Self {
        ObjectiveParams { l1: 1.0, temporal: 0.0 }
    }
}

impl ObjectiveParams {
    /// Validates the ranges in the table.
    pub fn validate(&self) -> Result<()> {
        check_range("l1", self.l1, 0.0, 1e9)?;
        check_range("temporal", self.temporal, 0.0, 1e9)?;
        Ok(())
    }
}

/// Why a solve stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// Optimality conditions (KKT) hold to the tolerance.
    Converged,
    /// The relative decrease of the objective fell below the tolerance (3D alternation).
    SmallDecrease,
    /// BOBYQA's trust region reached `rho_end` (its normal stop).
    RhoEnd,
    /// The iteration or evaluation cap was reached first.
    MaxIterations,
    /// Closed-form method: no iteration.
    ClosedForm,
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Report {
    /// Outer iterations (QP iterations, BOBYQA passes' evaluations, alternations).
    pub iterations: usize,
    /// Objective evaluations (BOBYQA) or inner QP iterations (others).
    pub evaluations: usize,
    /// Final objective value `f(e)` (px^2), see module docs.
    pub cost: f64,
    /// Why it stopped.
    pub stop: StopReason,
}

/// Warm-start state carried between frames.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveState {
    /// Previous frame's weights (start point and temporal-term anchor).
    pub weights: Vec<f64>,
    /// Previous frame's pose (3D method).
    pub pose: Option<ModelToCamera>,
    /// False before the first frame (no temporal term, cold start).
    pub has_previous: bool,
}

impl SolveState {
    /// A fresh state for `n` shapes (cold start at `e = 0`).
    pub fn new(n: usize) -> Self {
        SolveState {
            weights: vec![0.0; n],
            pose: None,
            has_previous: false,
        }
    }

    /// Forgets the previous frame (e.g. after a tracking loss).
    pub fn reset(&mut self) {
        self.weights.fill(0.0);
        self.pose = None;
        self.has_previous = false;
    }
}

/// The per-frame output.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Blendshape weights in `[0, 1]`, rig order.
    pub weights: Vec<f64>,
    /// Head pose (3D method), model to camera.
    pub pose: Option<ModelToCamera>,
    /// Image-from-model similarity (2D methods).
    pub similarity: Option<Similarity2d>,
    /// The model's landmarks in pixels (NaN where unmapped).
    pub fitted: [Point2<f64>; NUM_LANDMARKS],
}

impl Solution {
    /// An empty solution for `n` shapes.
    pub fn new(n: usize) -> Self {
        Solution {
            weights: vec![0.0; n],
            pose: None,
            similarity: None,
            fitted: [Point2::new(f64::NAN, f64::NAN); NUM_LANDMARKS],
        }
    }

    /// Mean Euclidean distance (px) between `fitted` and `observed` over the landmarks where
    /// `fitted` is finite.
    pub fn reprojection_error(&self, observed: &Landmarks68) -> f64 {
        let (mut s, mut c) = (0.0, 0usize);
        for (f, o) in self.fitted.iter().zip(observed.points.iter()) {
            if f.x.is_finite() && f.y.is_finite() {
                s += (f - o).norm();
                c += 1;
            }
        }
        if c == 0 {
            f64::NAN
        } else {
            s / c as f64
        }
    }
}

/// One expression solver (the five methods implement it).
pub trait ExpressionSolver: Send + Sync {
    /// Per-thread scratch buffers.
    type Workspace;
    /// Number of blendshapes solved for.
    fn num_shapes(&self) -> usize;
    /// Blendshape names.
    fn names(&self) -> &[String];
    /// A workspace sized for this solver (allocates; do it once).
    fn workspace(&self) -> Self::Workspace;
    /// Solves one frame. `state` is read as the warm start and updated with this frame's result.
    ///
    /// # Errors
    /// [`Error::Input`] for non-finite landmarks or degenerate alignment;
    /// [`Error::DimensionMismatch`] when `state`/`out` were made for another shape count.
    fn solve_into(
        &self,
        input: &Landmarks68,
        ws: &mut Self::Workspace,
        state: &mut SolveState,
        out: &mut Solution,
    ) -> Result<Report>;
}

pub(crate) fn check_io(n: usize, input: &Landmarks68, state: &SolveState, out: &Solution) -> Result<()> {
    if !input.is_finite() {
        return Err(Error::Input {
            reason: "a landmark coordinate is NaN or infinite".into(),
        });
    }
    for (what, got) in [
        ("state weights", state.weights.len()),
        ("solution weights", out.weights.len()),
    ] {
        if got != n {
            return Err(Error::DimensionMismatch {
                what: what.into(),
                expected: n,
                got,
            });
        }
    }
    Ok(())
}

/// Precomputed 2D model shared by the 2D methods: basis flattened row-major and its Gram matrix.
#[derive(Debug, Clone)]
pub(crate) struct Model2d {
    pub names: Vec<String>,
    pub n: usize,
    pub neutral: Vec<f64>,
    /// `n x 136`, zero rows for unmapped landmarks.
    pub deltas: Vec<f64>,
    pub mapped: [bool; NUM_LANDMARKS],
    pub stable: [bool; NUM_LANDMARKS],
    /// `D^T D` over mapped coordinates, `n x n`.
    pub gram: Vec<f64>,
}

/// Per-frame 2D data: observations, alignment and the model-frame target `b'`.
#[derive(Debug, Clone)]
pub(crate) struct Frame2d {
    pub obs: Vec<f64>,
    pub posed: Vec<f64>,
    pub target: Vec<f64>,
    pub sim: Similarity2d,
}

impl Frame2d {
    pub fn new() -> Self {
        Frame2d {
            obs: vec![0.0; 2 * NUM_LANDMARKS],
            posed: vec![0.0; 2 * NUM_LANDMARKS],
            target: vec![0.0; 2 * NUM_LANDMARKS],
            sim: Similarity2d::identity(),
        }
    }
}

pub(crate) const COORDS: usize = 2 * NUM_LANDMARKS;

/// Dot product with four independent partial sums (differs from a left-to-right sum only by
/// rounding).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = (acc[0] + acc[2]) + (acc[1] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

impl Model2d {
    pub fn new(basis: &Basis2d) -> Result<Self> {
        let n = basis.num_shapes();
        if n == 0 {
            return Err(Error::rig("2D basis", "no shapes"));
        }
        if basis.deltas.dim() != (n, COORDS) || basis.neutral.len() != COORDS {
            return Err(Error::DimensionMismatch {
                what: "2D basis deltas (n x 136)".into(),
                expected: n * COORDS,
                got: basis.deltas.len(),
            });
        }
        if basis.neutral.iter().chain(basis.deltas.iter()).any(|v| !v.is_finite()) {
            return Err(Error::rig("2D basis", "non-finite coordinate"));
        }
        let mut deltas = vec![0.0; n * COORDS];
        let mut neutral = vec![0.0; COORDS];
        for l in 0..NUM_LANDMARKS {
            if !basis.mapped[l] {
                continue;
            }
            for c in 0..2 {
                neutral[2 * l + c] = basis.neutral[2 * l + c];
                for k in 0..n {
                    deltas[k * COORDS + 2 * l + c] = basis.deltas[[k, 2 * l + c]];
                }
            }
        }
        let mut gram = vec![0.0; n * n];
        for a in 0..n {
            for b in a..n {
                let v: f64 = deltas[a * COORDS..(a + 1) * COORDS]
                    .iter()
                    .zip(&deltas[b * COORDS..(b + 1) * COORDS])
                    .map(|(x, y)| x * y)
                    .sum();
                gram[a * n + b] = v;
                gram[b * n + a] = v;
            }
        }
        let mut stable = basis.stable;
        for (s, m) in stable.iter_mut().zip(basis.mapped.iter()) {
            *s &= *m;
        }
        Ok(Model2d {
            names: basis.names.clone(),
            n,
            neutral,
            deltas,
            mapped: basis.mapped,
            stable,
            gram,
        })
    }

    /// `neutral + D^T e` into `out` (136).
    pub fn pose(&self, e: &[f64], out: &mut [f64]) {
        out.copy_from_slice(&self.neutral);
        for (k, &w) in e.iter().enumerate() {
            if w != 0.0 {
                for (o, d) in out.iter_mut().zip(&self.deltas[k * COORDS..(k + 1) * COORDS]) {
                    *o += w * d;
                }
            }
        }
    }

    /// Aligns the model posed with `e_align` to the observations and fills `frame.target`
    /// with `b' = sim^-1(o) - neutral` (zero where unmapped).
    pub fn prepare(&self, input: &Landmarks68, e_align: &[f64], frame: &mut Frame2d) -> Result<()> {
        flatten_landmarks(input, &mut frame.obs);
        self.pose(e_align, &mut frame.posed);
        self.align_posed(frame)
    }

    /// As [`Model2d::prepare`] with `frame.obs` and `frame.posed` already filled.
    pub fn align_posed(&self, frame: &mut Frame2d) -> Result<()> {
        let sim = Similarity2d::fit(&frame.posed, &frame.obs, &self.stable).ok_or_else(|| Error::Input {
            reason: "the stable landmarks coincide; cannot align".into(),
        })?;
        frame.sim = sim;
        for l in 0..NUM_LANDMARKS {
            if self.mapped[l] {
                let (x, y) = sim.apply_inverse(frame.obs[2 * l], frame.obs[2 * l + 1]);
                frame.target[2 * l] = x - self.neutral[2 * l];
                frame.target[2 * l + 1] = y - self.neutral[2 * l + 1];
            } else {
                frame.target[2 * l] = 0.0;
                frame.target[2 * l + 1] = 0.0;
            }
        }
        Ok(())
    }

    /// `D b'` into `out` (n).
    pub fn dtb(&self, target: &[f64], out: &mut [f64]) {
        for (k, o) in out.iter_mut().enumerate() {
            *o = dot(&self.deltas[k * COORDS..(k + 1) * COORDS], target);
        }
    }

    /// The full objective (px^2) at `e` for a prepared frame.
    pub fn cost(
        &self,
        e: &[f64],
        frame: &Frame2d,
        obj: &ObjectiveParams,
        prev: Option<&[f64]>,
        scratch: &mut [f64],
    ) -> f64 {
        self.pose(e, scratch);
        let s2 = frame.sim.scale * frame.sim.scale;
        let mut f = 0.0;
        for l in 0..NUM_LANDMARKS {
            if self.mapped[l] {
                for c in 0..2 {
                    let r = scratch[2 * l + c] - self.neutral[2 * l + c] - frame.target[2 * l + c];
                    f += r * r;
                }
            }
        }
        f *= s2;
        f += obj.l1 * e.iter().sum::<f64>();
        if let Some(p) = prev {
            f += obj.temporal * e.iter().zip(p).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
        }
        f
    }

    /// Fitted landmarks in pixels.
    pub fn fitted(&self, e: &[f64], sim: &Similarity2d, scratch: &mut [f64], out: &mut [Point2<f64>; NUM_LANDMARKS]) {
        self.pose(e, scratch);
        for l in 0..NUM_LANDMARKS {
            out[l] = if self.mapped[l] {
                let (x, y) = sim.apply(scratch[2 * l], scratch[2 * l + 1]);
                Point2::new(x, y)
            } else {
                Point2::new(f64::NAN, f64::NAN)
            };
        }
    }
}
