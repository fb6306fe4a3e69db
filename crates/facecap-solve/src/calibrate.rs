//! The subject's own neutral face, fitted in 3D over many frames.
//!
//! A generic rig's neutral is not the subject's face: without calibration the solver reports
//! the difference (a wider mouth, higher brows, a longer nose) as expression on every frame.
//! [`fit_subject`] estimates a per-landmark 3D offset field `delta` (model frame, rig units)
//! so that the rig's neutral `n_j + delta_j` is the subject's resting face:
//!
//! 1. solve a subsample of the frames (at most [`SubjectParams::max_frames`], evenly spaced)
//!    with the current neutral, giving each frame a head pose and weights;
//! 2. take the *resting* frames: after the first pass, the `rest_fraction` of frames with the
//!    least total expression `sum_i e_i` (expressions come and go; rest is what most frames
//!    share);
//! 3. update the offsets so those frames, **at zero expression** and their solved poses, land
//!    on the tracked landmarks: per landmark the linearised least squares
//!
//!    ```text
//!    min_d  mean_f || J_fj d + r_fj ||^2 / s_f  +  alpha_xy (d_x^2 + d_y^2) + alpha_z d_z^2
//!    ```
//!
//!    with `r_fj` the reprojection residual of `n_j + delta_j` at frame `f`'s pose, `J_fj`
//!    its Jacobian with respect to a model-frame offset, `s_f = (IOD_f / 100 px)^2` (so the
//!    terms are in percent of the inter-ocular distance, whatever the face size), and the
//!    depth damped harder than the image-plane directions (depth is seen only through head
//!    rotation);
//! 4. repeat from 1 (`iterations` times).
//!
//! Holding the resting frames at zero expression is what separates identity from
//! expression: fitting offsets and weights jointly on every frame lets whichever explains a
//! landmark first keep it (measured: a generic-rig `browDown = 1` on a resting face stays 1).
//! The fit is the multi-frame analogue of eos's and the Papanek thesis' identity fitting, on
//! a free offset field with a ridge prior, so it works for any rig.

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::{eye_aspect_ratio, Landmarks68, EYES, NUM_LANDMARKS};
use nalgebra::{Matrix2x3, Matrix3, Point3, Vector2, Vector3};

use crate::error::{check_count, check_range, Error, Result};
use crate::exact3d::{Exact3dParams, Exact3dSolver, ShapePriors};
use crate::rig::BlendshapeRig;
use crate::solver::{ExpressionSolver, ObjectiveParams, Solution, SolveState};

/// Parameters of [`fit_subject`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `max_frames` | 150 | frames used per pass (evenly spaced over the clip) | 1-100000 |
/// | `iterations` | 3 | solve / refit passes | 1-20 |
/// | `rest_fraction` | 0.8 | share of the frames taken as resting after the first pass | (0, 1] |
/// | `alpha_xy` | 5.0 | ridge on the image-plane offset (% IOD)^2 per unit^2 | `[0, 1e9]` |
/// | `alpha_z` | 500.0 | ridge on the depth offset | `[0, 1e9]` |
/// | `identity_ridge` | 1.0 | ridge on the identity coefficients (unit-variance modes), (% IOD)^2 | `[0, 1e9]` |
/// | `residual_offsets` | true | with identity modes, also fit the offset field on what they leave | |
/// | `mouth_closed` | (0.0, 0.3) | the mouth and chin points' neutral is fitted on the frames whose mouth opening lies between these quantiles | as `eye_open` |
/// | `eye_typical` | 0.5 | of each eye's open-eye frames, the share whose solved expression lies closest to the clip's typical one | (0, 1], or `None`: all of them |
/// | `mouth_typical` | 0.5 | of those closed-mouth frames, the share whose solved expression lies closest to the clip's typical one | (0, 1], or `None`: all of them |
/// | `shape_ridge` | 8.0 | ridge on the offsets along the rig's mouth, jaw and eye shapes, units of `alpha_xy` | `[0, 1e9]` |
/// | `eye_open` | (0.5, 0.95) | the lid points' neutral is fitted on the frames whose eye opening lies between these quantiles | `0 <= lo < hi <= 1`, or `None`: the resting frames |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubjectParams {
    /// Frames per pass.
    pub max_frames: usize,
    /// Passes.
    pub iterations: usize,
    /// Resting share.
    pub rest_fraction: f64,
    /// Image-plane ridge.
    pub alpha_xy: f64,
    /// Depth ridge.
    pub alpha_z: f64,
    /// Ridge on the identity coefficients (used only with identity modes).
    pub identity_ridge: f64,
    /// With identity modes: also fit the per-landmark offsets on the residual.
    pub residual_offsets: bool,
    /// Quantiles of the per-eye opening (lid distance over the eye-corner distance, from the tracked points) that
    /// pick the frames the four lid points of that eye are fitted on. Blinks, half-closed eyes
    /// and downward glances (the upper lid follows the eyeball down) lower the opening on
    /// many frames that otherwise count as resting; fitted on them, the neutral eye is
    /// half-closed and an ordinary open eye reads as `eyeWide` (measured on
    /// liveportrait_d3: eyeWide >= 0.95 on 19 % of the frames, mean 0.45, where MediaPipe's
    /// stays near 0). `None` fits the eye points on the resting frames like the rest.
    pub eye_open: Option<(f64, f64)>,
    /// Quantiles of the mouth opening (inner-lip gap over the outer eye corners' distance, from the
    /// tracked points) that pick the frames the mouth points (iBUG 48-67) and the chin's
    /// contour points (4-12) are fitted on. The subject's neutral has the lips together (as
    /// ARKit's); in speech most frames that count as resting have the lips apart, and fitted
    /// on them the neutral mouth is half open: small openings then read as 0 (`jawOpen` is
    /// clamped) and closed lips as `mouthClose` + `mouthShrugLower` (measured on
    /// liveportrait_d6: `jawOpen` 0.00 where MediaPipe's is 0.15-0.20; docs/expressions.md,
    /// "The neutral mouth"). `None` fits the mouth on the resting frames like the rest.
    pub mouth_closed: Option<(f64, f64)>,
    /// Of the closed-mouth frames ([`SubjectParams::mouth_closed`]), the share kept for the
    /// mouth and chin points in each pass: those whose solved weights lie closest (L1) to
    /// the clip's typical expression, the per-shape median over the sampled frames. Lips
    /// are also together in a smile, a pucker or a press, and a clip that holds one for a
    /// while put it into the neutral mouth: every resting frame then read as its opposite
    /// (measured on the synthetic clip, whose smile covers 40 % of the frames: resting
    /// `mouthFrown` 0.15-0.28, smile peak 0.47 for 0.7; docs/expressions.md, "The neutral
    /// mouth's frames"). The median is the expression most frames share, whatever the
    /// current neutral, so the choice does not inherit the neutral's own bias. `None`
    /// keeps every closed-mouth frame.
    pub mouth_typical: Option<f64>,
    /// The same choice for the lid points: of each eye's open-eye frames
    /// ([`SubjectParams::eye_open`]), the share whose solved weights lie closest to the
    /// clip's typical expression (a squint or a wide-eyed stare held for a while stays
    /// out of the neutral lids). `None` keeps every open-eye frame.
    pub eye_typical: Option<f64>,
    /// Ridge on the offsets' components along the rig's mouth, jaw and eye shapes
    /// ([`RIDGED_SHAPE_PREFIXES`]; each shape's landmark displacement at unit length), in
    /// the units of `alpha_xy`. What the resting, closed-lip and open-eye frames share that
    /// looks like an expression (lips pressed or rolled in, a held smile, narrowed lids)
    /// stays an expression instead of becoming the subject's neutral; what no such shape
    /// makes is as free as before. Measured on the five shared clips and the synthetic clip
    /// (docs/expressions.md, "The neutral's expression-shaped part"): 8 raises mean r 0.770
    /// -> 0.780 (built-in) and 0.781 -> 0.787 (ICT) and keeps the synthetic RMSE at 0.082;
    /// above it the synthetic clip's smiling photo starts to read as a smile. 0 turns it
    /// off; rigs without ARKit-named shapes are not affected.
    pub shape_ridge: f64,
}

impl Default for SubjectParams {
    fn default() -> Self {
        SubjectParams {
            max_frames: 150,
            iterations: 3,
            rest_fraction: 0.8,
            alpha_xy: 5.0,
            alpha_z: 500.0,
            identity_ridge: 1.0,
            residual_offsets: true,
            eye_open: Some((0.5, 0.95)),
            mouth_closed: Some((0.0, 0.3)),
            mouth_typical: Some(0.5),
            eye_typical: Some(0.5),
            shape_ridge: 8.0,
        }
    }
}

impl SubjectParams {
    /// Checks the table's ranges.
    pub fn validate(&self) -> Result<()> {
        check_count("max_frames", self.max_frames, 1, 100_000)?;
        check_count("iterations", self.iterations, 1, 20)?;
        check_range("rest_fraction", self.rest_fraction, 1e-6, 1.0)?;
        check_range("alpha_xy", self.alpha_xy, 0.0, 1e9)?;
        check_range("alpha_z", self.alpha_z, 0.0, 1e9)?;
        check_range("identity_ridge", self.identity_ridge, 0.0, 1e9)?;
        check_range("shape_ridge", self.shape_ridge, 0.0, 1e9)?;
        for (name, share) in [("mouth_typical", self.mouth_typical), ("eye_typical", self.eye_typical)] {
            if let Some(q) = share {
                check_range(name, q, 1e-6, 1.0)?;
            }
        }
        for (name, q) in [("eye_open", self.eye_open), ("mouth_closed", self.mouth_closed)] {
            if let Some((lo, hi)) = q {
                check_range(name, lo, 0.0, 1.0)?;
                check_range(name, hi, 0.0, 1.0)?;
                if lo >= hi {
                    return Err(Error::InvalidParameter {
                        name,
                        value: format!("({lo}, {hi})"),
                        expected: "lower quantile below the upper".into(),
                    });
                }
            }
        }
        Ok(())
    }
}

/// The fitted subject.
#[derive(Debug, Clone)]
pub struct SubjectFit {
    /// The rig with the subject's neutral landmarks (`neutral + offsets`); deltas unchanged.
    pub rig: BlendshapeRig,
    /// Per-landmark offsets (model frame, rig units; zero where unmapped), identity
    /// modes included.
    pub offsets: [Vector3<f64>; NUM_LANDMARKS],
    /// Fitted identity coefficients (empty without identity modes).
    pub identity: Vec<f64>,
    /// Frames solved per pass.
    pub frames_used: usize,
    /// Resting frames of the last pass (the ones the offsets were fitted on).
    pub rest_frames: usize,
    /// Frames the mouth and chin points were fitted on in the last pass (closed lips,
    /// typical expression); `None` when they were fitted on the resting frames.
    pub mouth_frames: Option<usize>,
    /// Mean offset length (rig units).
    pub mean_offset: f64,
    /// Mean total expression `sum_i e_i` of the solved frames before calibration (the
    /// first pass, on the generic rig).
    pub mean_expression_before: f64,
    /// The same on the last pass (the rig of all passes but the last refit). The frames are
    /// not solved once more on the final rig: that would cost a whole pass for a report
    /// figure, and the clip is solved on it anyway.
    pub mean_expression_last_pass: f64,
}

/// A linear identity model on the rig's topology (for example ICT FaceKit's 100 PCA modes),
/// at the rig's 68 landmarks: `neutral_j + sum_m beta_m b_mj`, modes scaled to unit variance.
#[derive(Debug, Clone)]
pub struct IdentityModes {
    /// Mode names.
    pub names: Vec<String>,
    /// `b_mj`, `[mode][landmark][xyz]`.
    pub deltas: ndarray::Array3<f64>,
}

impl IdentityModes {
    /// The landmark deltas of an identity model read as a rig (its morph targets are the
    /// modes; the landmark map must be the expression rig's).
    ///
    /// # Errors
    /// When the model's mapped landmarks differ from the rig's or a delta is not finite.
    pub fn from_rig(identity: &BlendshapeRig, rig: &BlendshapeRig) -> Result<Self> {
        if identity.mapped != rig.mapped {
            return Err(Error::rig("identity modes", "mapped landmarks differ from the rig's"));
        }
        if identity.deltas.iter().any(|v| !v.is_finite()) {
            return Err(Error::rig("identity modes", "non-finite delta"));
        }
        Ok(IdentityModes {
            names: identity.names.clone(),
            deltas: identity.deltas.clone(),
        })
    }

    /// Number of modes.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// True without modes.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    fn mode(&self, m: usize, l: usize) -> Vector3<f64> {
        Vector3::new(self.deltas[[m, l, 0]], self.deltas[[m, l, 1]], self.deltas[[m, l, 2]])
    }
}

/// A solved frame: pose, weights, and the chosen contour points (offsets from their
/// landmarks' neutral, see [`Exact3dSolver::contour_offsets`]).
type SolvedSample = (
    facecap_core::camera::ModelToCamera,
    Vec<f64>,
    Vec<(usize, Vector3<f64>)>,
);

/// Solves `frames` in order with `solver` (warm-started), returning poses and weights.
/// Per value: whether it lies between the `lo` and `hi` quantiles of the finite values
/// (never, for a non-finite value or when none is finite).
fn within_quantiles(values: &[f64], (lo, hi): (f64, f64)) -> Vec<bool> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    if sorted.is_empty() {
        return vec![false; values.len()];
    }
    let q = |t: f64| sorted[((sorted.len() - 1) as f64 * t).round() as usize];
    let (a, b) = (q(lo), q(hi));
    values.iter().map(|&v| v.is_finite() && v >= a && v <= b).collect()
}

/// Per frame, the L1 distance of its solved weights from the per-shape median of every
/// solved frame's weights (the clip's typical expression); NaN for an unsolved frame.
fn distance_to_typical(solved: &[Option<SolvedSample>]) -> Vec<f64> {
    let weights: Vec<&Vec<f64>> = solved.iter().flatten().map(|(_, w, _)| w).collect();
    let n = weights.first().map_or(0, |w| w.len());
    let mut column = Vec::with_capacity(weights.len());
    let median: Vec<f64> = (0..n)
        .map(|k| {
            column.clear();
            column.extend(weights.iter().filter_map(|w| w.get(k).copied()));
            column.sort_by(f64::total_cmp);
            column.get(column.len() / 2).copied().unwrap_or(0.0)
        })
        .collect();
    solved
        .iter()
        .map(|s| match s {
            Some((_, w, _)) => w.iter().zip(&median).map(|(a, b)| (a - b).abs()).sum(),
            None => f64::NAN,
        })
        .collect()
}

/// Of the frames marked in `among`, the `share` closest to the typical expression
/// (`distance` from [`distance_to_typical`]); unsolved frames are never taken.
fn typical_among(among: &[bool], distance: &[f64], share: f64) -> Vec<bool> {
    let marked: Vec<f64> = among
        .iter()
        .zip(distance)
        .map(|(&m, &d)| if m { d } else { f64::NAN })
        .collect();
    within_quantiles(&marked, (0.0, share))
}

/// The mouth's points (iBUG), fitted on the closed-mouth frames.
const MOUTH: std::ops::Range<usize> = 48..68;
/// The chin's contour points, which the jaw carries with the mouth.
const CHIN: std::ops::RangeInclusive<usize> = 4..=12;

/// Inner-lip gap (iBUG 61-67, 62-66, 63-65) over the distance of the outer eye corners
/// (36-45). Not over the mouth's width, which a smile stretches: smiling frames would read
/// as more closed than resting ones.
fn mouth_opening(l: &Landmarks68) -> f64 {
    let p = &l.points;
    let gap = [(61, 67), (62, 66), (63, 65)]
        .iter()
        .map(|&(a, b)| (p[a] - p[b]).norm())
        .sum::<f64>()
        / 3.0;
    gap / (p[36] - p[45]).norm()
}

/// ARKit name prefixes of the shapes whose directions [`SubjectParams::shape_ridge`]
/// holds the neutral's offsets back from: the mouth's, the jaw's and the eyes' (the brows',
/// cheeks' and nose's were measured and left out, docs/expressions.md "The neutral's
/// expression-shaped part").
pub const RIDGED_SHAPE_PREFIXES: &[&str] = &["mouth", "jaw", "eye"];

/// Each shape of `rig` named with one of `prefixes`: its landmark displacement over the
/// mapped landmarks, `[l * 3 + axis]`, scaled to unit length (shapes that move no mapped
/// landmark are left out).
fn shape_directions(rig: &BlendshapeRig, prefixes: &[&str]) -> Vec<nalgebra::DVector<f64>> {
    let mut out = Vec::new();
    for (k, name) in rig.names.iter().enumerate() {
        if !prefixes.iter().any(|p| name.starts_with(p)) {
            continue;
        }
        let mut u = nalgebra::DVector::<f64>::zeros(3 * NUM_LANDMARKS);
        for l in (0..NUM_LANDMARKS).filter(|&l| rig.mapped[l]) {
            for c in 0..3 {
                u[3 * l + c] = rig.deltas[[k, l, c]];
            }
        }
        let norm = u.norm();
        if norm > 1e-12 && norm.is_finite() {
            out.push(u / norm);
        }
    }
    out
}

/// One pass's offset update with [`SubjectParams::shape_ridge`]: the per-landmark
/// systems `(a_l + damp) d_l = b_l` joined into one, plus `ridge * sum_k (u_k . (o + d))^2`
/// over the shape directions `u_k`, with `o` the offsets so far (so the ridge holds the
/// whole offset, not the step, back from each direction).
fn solve_offsets_along_span(
    a: &[Matrix3<f64>; NUM_LANDMARKS],
    b: &[Vector3<f64>; NUM_LANDMARKS],
    damp: Matrix3<f64>,
    span: &[nalgebra::DVector<f64>],
    ridge: f64,
    offsets: &mut [Vector3<f64>; NUM_LANDMARKS],
    current: &mut BlendshapeRig,
) {
    let n = 3 * NUM_LANDMARKS;
    let mut lhs = nalgebra::DMatrix::<f64>::zeros(n, n);
    let mut rhs = nalgebra::DVector::<f64>::zeros(n);
    for l in 0..NUM_LANDMARKS {
        // an unmapped landmark's rows are the identity's, with a zero right-hand side
        let (m, v) = if current.mapped[l] {
            (a[l] + damp, b[l])
        } else {
            (Matrix3::identity(), Vector3::zeros())
        };
        for i in 0..3 {
            for j in 0..3 {
                lhs[(3 * l + i, 3 * l + j)] = m[(i, j)];
            }
            rhs[3 * l + i] = v[i];
        }
    }
    for u in span {
        let uo: f64 = (0..NUM_LANDMARKS)
            .map(|l| (0..3).map(|c| u[3 * l + c] * offsets[l][c]).sum::<f64>())
            .sum();
        lhs.ger(ridge, u, u, 1.0);
        rhs.axpy(-ridge * uo, u, 1.0);
    }
    let Some(ch) = lhs.cholesky() else { return };
    let d = ch.solve(&rhs);
    if !d.iter().all(|v| v.is_finite()) {
        return;
    }
    for l in (0..NUM_LANDMARKS).filter(|&l| current.mapped[l]) {
        let dl = Vector3::new(d[3 * l], d[3 * l + 1], d[3 * l + 2]);
        offsets[l] += dl;
        for c in 0..3 {
            current.neutral[[l, c]] += dl[c];
        }
    }
}

/// Solves `frames`, each from its own solution of the previous pass in `states` (one per
/// frame, kept across the passes: the rig changes little between passes, so a frame's last
/// pose and weights are a closer start than its neighbour's). A frame without one (the
/// first pass, or after a failure) starts from the frame before it, as a clip is solved.
fn solve_all(solver: &Exact3dSolver, frames: &[&Landmarks68], states: &mut [SolveState]) -> Vec<Option<SolvedSample>> {
    let n = solver.num_shapes();
    let mut ws = solver.workspace();
    let mut sol = Solution::new(n);
    let mut out = Vec::with_capacity(frames.len());
    for (i, l) in frames.iter().enumerate() {
        let Some(state) = states.get(i) else { break };
        if !state.has_previous && i > 0 {
            let before = states[i - 1].clone();
            states[i] = before;
        }
        let state = &mut states[i];
        out.push(match solver.solve_into(l, &mut ws, state, &mut sol) {
            Ok(_) => sol.pose.map(|p| (p, sol.weights.clone(), solver.contour_offsets(&ws))),
            Err(_) => {
                state.reset();
                None
            }
        });
    }
    out
}

/// Fits the subject's neutral (module docs). `objective` and `priors` are those the frames
/// will be solved with afterwards.
///
/// # Errors
/// Invalid parameters, or no frame could be solved.
pub fn fit_subject(
    rig: &BlendshapeRig,
    camera: Intrinsics,
    objective: ObjectiveParams,
    priors: &ShapePriors,
    frames: &[Landmarks68],
    params: &SubjectParams,
) -> Result<SubjectFit> {
    fit_subject_with_identity(rig, None, camera, objective, priors, frames, params)
}

/// [`fit_subject`] with an identity model: each pass first fits the identity coefficients
/// `beta` jointly over the resting frames (the same linearised residuals, summed over the
/// landmarks, ridge `identity_ridge ||beta||^2`), then (with `residual_offsets`) the
/// per-landmark offsets on what the modes leave.
///
/// # Errors
/// As [`fit_subject`]; identity modes whose landmark count differs from the rig's.
pub fn fit_subject_with_identity(
    rig: &BlendshapeRig,
    identity: Option<&IdentityModes>,
    camera: Intrinsics,
    objective: ObjectiveParams,
    priors: &ShapePriors,
    frames: &[Landmarks68],
    params: &SubjectParams,
) -> Result<SubjectFit> {
    params.validate()?;
    if let Some(id) = identity {
        if id.deltas.dim() != (id.len(), NUM_LANDMARKS, 3) {
            return Err(Error::rig("identity modes", "expected [modes][68][3] deltas"));
        }
    }
    let n_id = identity.map_or(0, IdentityModes::len);
    let mut beta = vec![0.0; n_id];
    if frames.is_empty() {
        return Err(Error::Input {
            reason: "no tracked frame to fit the subject's neutral on".into(),
        });
    }
    let step = frames.len().div_ceil(params.max_frames).max(1);
    let sample: Vec<&Landmarks68> = frames.iter().step_by(step).collect();
    let mut offsets = [Vector3::<f64>::zeros(); NUM_LANDMARKS];
    let mut current = rig.clone();
    let build = |r: &BlendshapeRig| -> Result<Exact3dSolver> {
        Exact3dSolver::new(
            r,
            Exact3dParams {
                objective: ObjectiveParams {
                    temporal: 0.0,
                    ..objective
                },
                ..Exact3dParams::new(camera)
            },
        )?
        .with_priors(priors.clone())
    };
    // per eye, which sampled frames the eye's six points are fitted on
    let eye_frames: [Option<Vec<bool>>; 2] = std::array::from_fn(|e| {
        params.eye_open.map(|range| {
            let open: Vec<f64> = sample
                .iter()
                .map(|l| eye_aspect_ratio(&EYES[e].map(|i| l.points[i])))
                .collect();
            within_quantiles(&open, range)
        })
    });
    let mouth_frames: Option<Vec<bool>> = params.mouth_closed.map(|range| {
        let open: Vec<f64> = sample.iter().map(|l| mouth_opening(l)).collect();
        within_quantiles(&open, range)
    });
    let in_mouth = |l: usize| MOUTH.contains(&l) || CHIN.contains(&l);
    // the lid points (the corners stay with the resting frames: they do not open)
    let eye_of = |l: usize| match l {
        37 | 38 | 40 | 41 => Some(0),
        43 | 44 | 46 | 47 => Some(1),
        _ => None,
    };
    // the directions of the rig's mouth, jaw and eye shapes (empty without the ridge)
    let shape_span = if params.shape_ridge > 0.0 {
        shape_directions(rig, RIDGED_SHAPE_PREFIXES)
    } else {
        Vec::new()
    };
    let mut before = f64::NAN;
    let mut last_pass = f64::NAN;
    // per sampled frame, its solution of the previous pass (sized by the first solver: a
    // coupled pair is one of its variables)
    let mut states: Vec<SolveState> = Vec::new();
    let mut rest_frames = 0;
    let mut mouth_used = None;
    for pass in 0..params.iterations {
        let solver = build(&current)?;
        if states.is_empty() {
            states = vec![SolveState::new(solver.num_shapes()); sample.len()];
        }
        let solved = solve_all(&solver, &sample, &mut states);
        let energy: Vec<f64> = solved
            .iter()
            .map(|s| s.as_ref().map_or(f64::INFINITY, |(_, w, _)| w.iter().sum()))
            .collect();
        // one typical expression per pass, shared by the mouth's and the lids' choices
        let typical = if params.mouth_typical.is_some() || params.eye_typical.is_some() {
            distance_to_typical(&solved)
        } else {
            Vec::new()
        };
        let pass_mouth = match (&mouth_frames, params.mouth_typical) {
            (Some(closed), Some(share)) => Some(typical_among(closed, &typical, share)),
            (closed, _) => closed.clone(),
        };
        let pass_eyes: [Option<Vec<bool>>; 2] = std::array::from_fn(|e| match (&eye_frames[e], params.eye_typical) {
            (Some(open), Some(share)) => Some(typical_among(open, &typical, share)),
            (open, _) => open.clone(),
        });
        if let Some(m) = &pass_mouth {
            mouth_used = Some(m.iter().zip(&solved).filter(|(t, s)| **t && s.is_some()).count());
        }
        let finite: Vec<f64> = energy.iter().copied().filter(|e| e.is_finite()).collect();
        if finite.is_empty() {
            return Err(Error::Input {
                reason: "no frame could be solved for the subject's neutral".into(),
            });
        }
        let mean = finite.iter().sum::<f64>() / finite.len() as f64;
        if pass == 0 {
            before = mean;
        }
        last_pass = mean;
        let threshold = if pass == 0 {
            f64::INFINITY
        } else {
            let mut sorted = finite.clone();
            sorted.sort_by(f64::total_cmp);
            let k = ((sorted.len() as f64 * params.rest_fraction).ceil() as usize).clamp(1, sorted.len());
            sorted[k - 1]
        };
        let mut a = [Matrix3::<f64>::zeros(); NUM_LANDMARKS];
        let mut b = [Vector3::<f64>::zeros(); NUM_LANDMARKS];
        let mut used = 0usize;
        let mut count = [0usize; NUM_LANDMARKS];
        for (fi, ((obs, s), &en)) in sample.iter().zip(&solved).zip(&energy).enumerate() {
            let Some((pose, _, contour)) = s else { continue };
            let rest = en <= threshold;
            // the landmarks this frame informs
            let takes = |l: usize| match eye_of(l).and_then(|e| pass_eyes[e].as_ref()) {
                Some(open) => open[fi],
                None => match &pass_mouth {
                    Some(closed) if in_mouth(l) => closed[fi],
                    _ => rest,
                },
            };
            if !(0..NUM_LANDMARKS).any(takes) {
                continue;
            }
            let iod = (obs.points[36] - obs.points[45]).norm();
            if !(iod.is_finite() && iod > 1.0) {
                continue;
            }
            let inv_s = (100.0 / iod).powi(2);
            let rot = pose.0.rotation.to_rotation_matrix();
            let rm = rot.matrix();
            let mut ok = true;
            let mut fa = [Matrix3::<f64>::zeros(); NUM_LANDMARKS];
            let mut fb = [Vector3::<f64>::zeros(); NUM_LANDMARKS];
            for l in 0..NUM_LANDMARKS {
                if !current.mapped[l] {
                    continue;
                }
                // a contour landmark is where the solve put it on the silhouette
                let shift = contour
                    .iter()
                    .find(|(c, _)| *c == l)
                    .map_or(Vector3::zeros(), |(_, o)| *o);
                let x = Point3::new(
                    current.neutral[[l, 0]],
                    current.neutral[[l, 1]],
                    current.neutral[[l, 2]],
                ) + shift;
                let c = pose.0 * x;
                if c.z <= 1e-9 {
                    ok = false;
                    break;
                }
                let iz = 1.0 / c.z;
                let u = camera.fx * c.x * iz + camera.cx;
                let v = camera.fy * c.y * iz + camera.cy;
                let r = Vector2::new(u - obs.points[l].x, v - obs.points[l].y);
                let jc = Matrix2x3::new(
                    camera.fx * iz,
                    0.0,
                    -camera.fx * c.x * iz * iz,
                    0.0,
                    camera.fy * iz,
                    -camera.fy * c.y * iz * iz,
                );
                let j = jc * rm;
                fa[l] = j.transpose() * j * inv_s;
                fb[l] = -(j.transpose() * r) * inv_s;
            }
            if !ok {
                continue;
            }
            for l in (0..NUM_LANDMARKS).filter(|&l| takes(l)) {
                a[l] += fa[l];
                b[l] += fb[l];
                count[l] += 1;
            }
            if rest {
                used += 1;
            }
        }
        if used == 0 {
            return Err(Error::Input {
                reason: "no resting frame to fit the subject's neutral on".into(),
            });
        }
        rest_frames = used;
        for l in 0..NUM_LANDMARKS {
            let inv = 1.0 / count[l].max(1) as f64;
            a[l] *= inv;
            b[l] *= inv;
        }
        if let Some(id) = identity {
            // (sum_l B_l^T a_l B_l + lambda I) dbeta = sum_l B_l^T b_l - lambda beta
            let mut lhs = nalgebra::DMatrix::<f64>::zeros(n_id, n_id);
            let mut rhs = nalgebra::DVector::<f64>::zeros(n_id);
            let mut ab = vec![Vector3::<f64>::zeros(); n_id];
            for l in 0..NUM_LANDMARKS {
                if !current.mapped[l] {
                    continue;
                }
                for (m, v) in ab.iter_mut().enumerate() {
                    *v = a[l] * id.mode(m, l);
                    rhs[m] += id.mode(m, l).dot(&b[l]);
                }
                for m in 0..n_id {
                    let bm = id.mode(m, l);
                    for k in m..n_id {
                        lhs[(m, k)] += bm.dot(&ab[k]);
                    }
                }
            }
            for m in 0..n_id {
                for k in 0..m {
                    lhs[(m, k)] = lhs[(k, m)];
                }
                lhs[(m, m)] += params.identity_ridge;
                rhs[m] -= params.identity_ridge * beta[m];
            }
            if let Some(ch) = lhs.cholesky() {
                let db = ch.solve(&rhs);
                if db.iter().all(|v| v.is_finite()) {
                    for l in 0..NUM_LANDMARKS {
                        if !current.mapped[l] {
                            continue;
                        }
                        let d: Vector3<f64> = (0..n_id).map(|m| id.mode(m, l) * db[m]).sum();
                        offsets[l] += d;
                        b[l] -= a[l] * d;
                        for c in 0..3 {
                            current.neutral[[l, c]] += d[c];
                        }
                    }
                    for (bm, d) in beta.iter_mut().zip(db.iter()) {
                        *bm += d;
                    }
                }
            }
            if !params.residual_offsets {
                continue;
            }
        }
        let damp = Matrix3::from_diagonal(&Vector3::new(params.alpha_xy, params.alpha_xy, params.alpha_z));
        if !shape_span.is_empty() {
            solve_offsets_along_span(
                &a,
                &b,
                damp,
                &shape_span,
                params.shape_ridge,
                &mut offsets,
                &mut current,
            );
            continue;
        }
        for l in 0..NUM_LANDMARKS {
            if !current.mapped[l] {
                continue;
            }
            let lhs = a[l] + damp;
            let Some(ch) = lhs.cholesky() else { continue };
            let d = ch.solve(&b[l]);
            if d.iter().all(|v| v.is_finite()) {
                offsets[l] += d;
                for c in 0..3 {
                    current.neutral[[l, c]] += d[c];
                }
            }
        }
    }
    let mapped = (0..NUM_LANDMARKS).filter(|&l| rig.mapped[l]).count().max(1);
    Ok(SubjectFit {
        mean_offset: offsets.iter().map(|d| d.norm()).sum::<f64>() / mapped as f64,
        rig: current,
        offsets,
        identity: beta,
        frames_used: sample.len(),
        rest_frames,
        mouth_frames: mouth_used,
        mean_expression_before: before,
        mean_expression_last_pass: last_pass,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use facecap_core::camera::ModelToCamera;
    use nalgebra::{Point2, UnitQuaternion};

    /// A subject whose face differs from the rig's neutral, seen over frames that are at rest
    /// most of the time: the fitted neutral removes the identity, and the expression frames'
    /// weights come back.
    #[test]
    fn multi_frame_fit_separates_identity_from_expression() {
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let mut subject = rig.clone();
        for l in 0..NUM_LANDMARKS {
            subject.neutral[[l, 0]] += 0.6 * (l as f64 * 0.7).sin();
            subject.neutral[[l, 1]] += 0.5 * (l as f64 * 1.3).cos();
        }
        let facing = UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        let truth: Vec<Vec<f64>> = (0..60)
            .map(|f| {
                let mut w = vec![0.0; 6];
                if f % 3 == 0 {
                    w[(f / 3) % 6] = 0.7;
                }
                w
            })
            .collect();
        let frames: Vec<Landmarks68> = truth
            .iter()
            .enumerate()
            .map(|(f, w)| {
                let turn = UnitQuaternion::from_scaled_axis(Vector3::new(
                    0.1 * (f as f64 * 0.3).sin(),
                    0.3 * (f as f64 * 0.2).sin(),
                    0.05,
                ));
                let pose = ModelToCamera::from_rvec_tvec((turn * facing).scaled_axis(), Vector3::new(1.0, -2.0, 50.0));
                let pts: Vec<(f64, f64)> = (0..NUM_LANDMARKS)
                    .map(|l| {
                        let p = pose.project(&camera, &subject.landmark(l, w)).unwrap();
                        (p.x, p.y)
                    })
                    .collect();
                Landmarks68::from_slice(&pts).unwrap()
            })
            .collect();
        let objective = ObjectiveParams::default();
        let priors = ShapePriors::neutral(6);
        let rmse = |r: &BlendshapeRig| {
            let s = Exact3dSolver::new(r, Exact3dParams::new(camera)).unwrap();
            let refs: Vec<&Landmarks68> = frames.iter().collect();
            let mut states = vec![SolveState::new(6); refs.len()];
            let out = solve_all(&s, &refs, &mut states);
            let mut se = 0.0;
            for (o, w) in out.iter().zip(&truth) {
                let (_, e, _) = o.as_ref().unwrap();
                se += e.iter().zip(w).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
            }
            (se / (6 * frames.len()) as f64).sqrt()
        };
        let generic = rmse(&rig);
        // The synthetic rig's random mouth and jaw shapes narrow the lip gap of its (open)
        // neutral mouth, which the closed-mouth selection would take for closed lips; real
        // lips at rest are together and no expression closes them further. The closed-mouth
        // selection has its own test (`talking_frames_do_not_open_the_neutral_mouth`).
        let params = SubjectParams {
            mouth_closed: None,
            ..SubjectParams::default()
        };
        let fit = fit_subject(&rig, camera, objective, &priors, &frames, &params).unwrap();
        let calibrated = rmse(&fit.rig);
        assert!(fit.frames_used == 60 && fit.rest_frames >= 20, "{fit:?}");
        assert!(calibrated < 0.05, "calibrated RMSE {calibrated}, generic {generic}");
        assert!(
            calibrated < 0.5 * generic,
            "calibrated RMSE {calibrated}, generic {generic}"
        );
        // the identity itself is recovered in the image plane
        let err: f64 = (0..NUM_LANDMARKS)
            .map(|l| {
                let tx = 0.6 * (l as f64 * 0.7).sin();
                let ty = 0.5 * (l as f64 * 1.3).cos();
                (fit.offsets[l].x - tx).hypot(fit.offsets[l].y - ty)
            })
            .sum::<f64>()
            / NUM_LANDMARKS as f64;
        assert!(err < 0.06, "mean image-plane offset error {err} (offsets ~0.5)");
    }

    /// Half-closed eyes on 40 % of otherwise resting frames (blinks, downward glances) do not
    /// pull the neutral lids down: the lid points are fitted on the open-eye frames.
    #[test]
    fn half_closed_eyes_do_not_close_the_neutral_eye() {
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let facing = UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        let frames: Vec<Landmarks68> = (0..60)
            .map(|f| {
                let turn = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.2 * (f as f64 * 0.2).sin(), 0.0));
                let pose = ModelToCamera::from_rvec_tvec((turn * facing).scaled_axis(), Vector3::new(0.0, 0.0, 50.0));
                let mut pts: Vec<Point2<f64>> = (0..NUM_LANDMARKS)
                    .map(|l| pose.project(&camera, &rig.landmark(l, &[0.0; 6])).unwrap())
                    .collect();
                if f % 5 < 2 {
                    for (up, low) in [(37, 41), (38, 40), (43, 47), (44, 46)] {
                        pts[up] = pts[up] + 0.5 * (pts[low] - pts[up]);
                    }
                }
                Landmarks68::from_slice(&pts.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>()).unwrap()
            })
            .collect();
        let fit = |eye_open| fit_plain(&rig, camera, &frames, |p| p.eye_open = eye_open);
        let lid_shift = |f: &SubjectFit| [37, 38, 43, 44].iter().map(|&l| f.offsets[l].norm()).sum::<f64>() / 4.0;
        let lid_gap = neutral_distance(&rig, 37, 41);
        let (open, all) = (lid_shift(&fit(Some((0.5, 0.95)))), lid_shift(&fit(None)));
        // measured: 0.027 (open-eye frames) and 0.181 (all resting frames), lid gap 0.8
        assert!(
            open < 0.05 * lid_gap,
            "lid offset {open} (lid gap {lid_gap}, all frames {all})"
        );
        assert!(open < 0.25 * all, "lid offset {open}, all frames {all}");
    }

    /// [`fit_subject`] with the default objective and free priors on the 6-shape rig, and
    /// the default parameters changed by `set`.
    fn fit_plain(
        rig: &BlendshapeRig,
        camera: Intrinsics,
        frames: &[Landmarks68],
        set: impl FnOnce(&mut SubjectParams),
    ) -> SubjectFit {
        let mut params = SubjectParams::default();
        set(&mut params);
        let priors = ShapePriors::neutral(6);
        fit_subject(rig, camera, ObjectiveParams::default(), &priors, frames, &params).unwrap()
    }

    /// Distance between two landmarks of the rig's neutral.
    fn neutral_distance(rig: &BlendshapeRig, a: usize, b: usize) -> f64 {
        (0..3)
            .map(|c| (rig.neutral[[a, c]] - rig.neutral[[b, c]]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// 60 frames of the rig's neutral with the head turning left and right, each point
    /// first moved by `edit(frame, landmark, point)` (model frame).
    fn turning_frames(
        rig: &BlendshapeRig,
        camera: Intrinsics,
        edit: impl Fn(usize, usize, &mut Point3<f64>),
    ) -> Vec<Landmarks68> {
        let facing = UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        (0..60)
            .map(|f| {
                let turn = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.2 * (f as f64 * 0.2).sin(), 0.0));
                let pose = ModelToCamera::from_rvec_tvec((turn * facing).scaled_axis(), Vector3::new(0.0, 0.0, 50.0));
                let pts: Vec<(f64, f64)> = (0..NUM_LANDMARKS)
                    .map(|l| {
                        let mut x = rig.landmark(l, &[0.0; 6]);
                        edit(f, l, &mut x);
                        let p = pose.project(&camera, &x).unwrap();
                        (p.x, p.y)
                    })
                    .collect();
                Landmarks68::from_slice(&pts).unwrap()
            })
            .collect()
    }

    /// Speech: the lips are apart on most frames (all of them resting by expression
    /// energy). The neutral mouth is fitted on the closed-mouth frames, so it stays closed;
    /// fitted on every resting frame it opens.
    #[test]
    fn talking_frames_do_not_open_the_neutral_mouth() {
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let lip_gap = neutral_distance(&rig, 62, 66);
        let frames = turning_frames(&rig, camera, |f, l, x| {
            // 7 of 10 frames talk: lower lip and chin down by up to 0.6 of a lip gap
            let open = if f % 10 < 7 {
                0.3 + 0.3 * (f as f64 * 0.9).sin().abs()
            } else {
                0.0
            };
            if [56, 57, 58, 65, 66, 67, 7, 8, 9].contains(&l) {
                // model +Y is up
                x.y -= open * lip_gap;
            }
        });
        let fit = |mouth_closed| fit_plain(&rig, camera, &frames, |p| p.mouth_closed = mouth_closed);
        let lip_shift = |f: &SubjectFit| [65, 66, 67].iter().map(|&l| f.offsets[l].norm()).sum::<f64>() / 3.0;
        let (closed, all) = (lip_shift(&fit(Some((0.0, 0.3)))), lip_shift(&fit(None)));
        assert!(
            closed < 0.05 * lip_gap,
            "lower lip offset {closed} (lip gap {lip_gap}, all frames {all})"
        );
        assert!(closed < 0.25 * all, "lower lip offset {closed}, all frames {all}");
    }

    #[test]
    fn a_mouth_shape_held_on_most_frames_stays_an_expression() {
        // the subject holds the rig's mouth shape 2 at about 0.3 on 7 frames in 10 (lips
        // pressed through a whole talk, say); the neutral's part along that shape is what
        // the resting frames would read as its opposite
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let k = 2;
        assert!(rig.names[k].starts_with("mouth"));
        let frames = turning_frames(&rig, camera, |f, l, x| {
            let w = if f % 10 < 7 { 0.3 + 0.02 * (f as f64).sin() } else { 0.0 };
            for c in 0..3 {
                x[c] += w * rig.deltas[[k, l, c]];
            }
        });
        let along = |fit: &SubjectFit| {
            let (mut dot, mut norm) = (0.0, 0.0);
            for l in 0..NUM_LANDMARKS {
                for c in 0..3 {
                    dot += fit.offsets[l][c] * rig.deltas[[k, l, c]];
                    norm += rig.deltas[[k, l, c]].powi(2);
                }
            }
            dot / norm
        };
        // the solve's priors shrink a weakly observed shape (as the observability ridge
        // does), leaving part of it to the offsets
        let mut priors = ShapePriors::neutral(6);
        priors.ridge[k] = 1e4;
        let fit = |ridge: f64| {
            // the mouth fitted on the resting frames (the held shape may part the lips,
            // which would keep its frames out of the closed-mouth choice)
            let params = SubjectParams {
                shape_ridge: ridge,
                mouth_closed: None,
                mouth_typical: None,
                ..SubjectParams::default()
            };
            fit_subject(&rig, camera, ObjectiveParams::default(), &priors, &frames, &params).unwrap()
        };
        let free = along(&fit(0.0));
        assert!(
            free > 0.05,
            "without the ridge the neutral takes {free} of the shape held at 0.3"
        );
        // the default holds some of it back; a ridge well above the data term nearly all
        let held = along(&fit(SubjectParams::default().shape_ridge));
        assert!(
            held < 0.95 * free,
            "neutral along the shape {held}, without the ridge {free}"
        );
        let strong = along(&fit(1e3));
        assert!(
            strong.abs() < 0.1 * free,
            "neutral along the shape {strong}, without the ridge {free}"
        );
        // an offset no ridged shape makes stays free: the nose's
        let nose = turning_frames(&rig, camera, |_, l, x| {
            if (27..36).contains(&l) {
                x.y += 0.3;
            }
        });
        let nose_dy = |ridge: f64| {
            let fit = fit_plain(&rig, camera, &nose, |p| p.shape_ridge = ridge);
            (27..36).map(|l| fit.offsets[l].y).sum::<f64>() / 9.0
        };
        let (with, without) = (nose_dy(SubjectParams::default().shape_ridge), nose_dy(0.0));
        assert!(
            without > 0.1 && (with - without).abs() < 0.05 * without,
            "nose offset {with} with the ridge, {without} without"
        );
    }

    /// A smile held with the lips together on 4 frames in 10 (the mouth corners out and
    /// up): the closed-mouth frames include it, and only the typical-expression choice
    /// keeps it out of the neutral mouth.
    #[test]
    fn a_held_smile_stays_out_of_the_neutral_mouth() {
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let width = neutral_distance(&rig, 48, 54);
        let frames = turning_frames(&rig, camera, |f, l, x| {
            let smile = if f % 10 < 4 {
                0.1 + 0.05 * (f as f64).sin().abs()
            } else {
                0.0
            };
            // model +X is the subject's left, +Y up
            let side = match l {
                48 | 60 => -1.0,
                54 | 64 => 1.0,
                _ => 0.0,
            };
            x.x += side * smile * width;
            x.y += side.abs() * 0.5 * smile * width;
        });
        let fit = |mouth_typical| fit_plain(&rig, camera, &frames, |p| p.mouth_typical = mouth_typical);
        let corner_shift = |f: &SubjectFit| [48, 54, 60, 64].iter().map(|&l| f.offsets[l].norm()).sum::<f64>() / 4.0;
        let (typical, every) = (fit(Some(0.5)), fit(None));
        let (t, a) = (corner_shift(&typical), corner_shift(&every));
        assert!(
            t < 0.01 * width,
            "corner offset {t} (mouth width {width}, every closed frame {a})"
        );
        assert!(t < 0.25 * a, "corner offset {t}, every closed frame {a}");
        // about half of the closed-mouth frames (0.3 of 60)
        let (t, a) = (typical.mouth_frames.unwrap(), every.mouth_frames.unwrap());
        assert!((17..=19).contains(&a) && (a / 2..=a / 2 + 1).contains(&t), "{t} of {a}");
    }

    /// A subject built from identity modes: the joint multi-frame fit recovers the
    /// coefficients and, with the offsets off, the neutral lies in the modes' span.
    #[test]
    fn identity_modes_are_recovered_over_frames() {
        let rig = BlendshapeRig::synthetic(6, 11);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let n_id = 4;
        let mut modes = ndarray::Array3::<f64>::zeros((n_id, NUM_LANDMARKS, 3));
        for m in 0..n_id {
            for l in 0..NUM_LANDMARKS {
                let t = l as f64 * (0.37 + 0.21 * m as f64);
                modes[[m, l, 0]] = 0.3 * t.sin();
                modes[[m, l, 1]] = 0.25 * (1.7 * t).cos();
                modes[[m, l, 2]] = 0.2 * (0.9 * t).sin();
            }
        }
        let id = IdentityModes {
            names: (0..n_id).map(|m| format!("identity{m:03}")).collect(),
            deltas: modes,
        };
        let beta_true = [1.2, -0.8, 0.5, -1.5];
        let mut subject = rig.clone();
        for l in 0..NUM_LANDMARKS {
            for (m, b) in beta_true.iter().enumerate() {
                for c in 0..3 {
                    subject.neutral[[l, c]] += b * id.deltas[[m, l, c]];
                }
            }
        }
        let facing = UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        let frames: Vec<Landmarks68> = (0..60)
            .map(|f| {
                let mut w = vec![0.0; 6];
                if f % 4 == 0 {
                    w[(f / 4) % 6] = 0.6;
                }
                let turn = UnitQuaternion::from_scaled_axis(Vector3::new(
                    0.1 * (f as f64 * 0.3).sin(),
                    0.35 * (f as f64 * 0.2).sin(),
                    0.05,
                ));
                let pose = ModelToCamera::from_rvec_tvec((turn * facing).scaled_axis(), Vector3::new(1.0, -2.0, 50.0));
                let pts: Vec<(f64, f64)> = (0..NUM_LANDMARKS)
                    .map(|l| {
                        let p = pose.project(&camera, &subject.landmark(l, &w)).unwrap();
                        (p.x, p.y)
                    })
                    .collect();
                Landmarks68::from_slice(&pts).unwrap()
            })
            .collect();
        let params = SubjectParams {
            identity_ridge: 1e-3,
            residual_offsets: false,
            iterations: 5,
            ..SubjectParams::default()
        };
        let priors = ShapePriors::neutral(6);
        let fit = fit_subject_with_identity(
            &rig,
            Some(&id),
            camera,
            ObjectiveParams::default(),
            &priors,
            &frames,
            &params,
        )
        .unwrap();
        assert_eq!(fit.identity.len(), n_id);
        for (b, t) in fit.identity.iter().zip(&beta_true) {
            assert!((b - t).abs() < 0.1, "identity {:?} against {beta_true:?}", fit.identity);
        }
        // the modes' identity check and a mismatched landmark set are errors
        let mut other = rig.clone();
        other.mapped[5] = false;
        assert!(IdentityModes::from_rig(&other, &rig).is_err());
        let bad = IdentityModes {
            names: vec!["a".into()],
            deltas: ndarray::Array3::zeros((1, 3, 3)),
        };
        assert!(fit_subject_with_identity(
            &rig,
            Some(&bad),
            camera,
            ObjectiveParams::default(),
            &priors,
            &frames,
            &params
        )
        .is_err());
    }

    #[test]
    fn empty_input_and_bad_parameters_are_errors() {
        let rig = BlendshapeRig::synthetic(3, 1);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        let p = ShapePriors::neutral(3);
        assert!(fit_subject(
            &rig,
            camera,
            ObjectiveParams::default(),
            &p,
            &[],
            &SubjectParams::default()
        )
        .is_err());
        let bad = SubjectParams {
            rest_fraction: 0.0,
            ..SubjectParams::default()
        };
        let one = [Landmarks68::default()];
        assert!(fit_subject(&rig, camera, ObjectiveParams::default(), &p, &one, &bad).is_err());
        for eye_open in [(0.9, 0.5), (0.5, 0.5), (-0.1, 0.9), (0.5, f64::NAN)] {
            let bad = SubjectParams {
                eye_open: Some(eye_open),
                ..SubjectParams::default()
            };
            assert!(bad.validate().is_err(), "{eye_open:?}");
        }
        for share in [0.0, -0.5, 1.5, f64::NAN] {
            let mut bad = SubjectParams {
                mouth_typical: Some(share),
                ..SubjectParams::default()
            };
            assert!(bad.validate().is_err(), "{share}");
            (bad.mouth_typical, bad.eye_typical) = (None, Some(share));
            assert!(bad.validate().is_err(), "{share}");
        }
    }
}
