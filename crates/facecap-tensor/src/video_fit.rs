//! The per-frame pass of the video fit (Papanek 2010, sec. 4.2), one frame at a time.
//!
//! A video fit has three steps. Steps 1 and 2 (first-frame alignment on the landmarks,
//! then one identity from evenly spaced frames by [`Fitter::fit_sequence`]) need every
//! frame's landmarks and are done by [`fit_identity`]. Step 3 is [`FramePass`]: per
//! frame, pose and expression with that identity fixed, warm-started from the previous
//! frame, on the landmarks plus *extra feature points* around the mouth and brows:
//!
//! * after the first fitted frame, a grid of image samples (spacing
//!   [`FramePassParams::feature_step`] px) inside the outer-lip polygon and both
//!   brow-to-upper-eyelid polygons, pushed out by `feature_margin` px, is attached to
//!   the closest *visible* model vertex of the fitted mesh
//!   ([`crate::features::closest_visible_vertices`], within `feature_max_px`); each
//!   distinct vertex becomes a feature point starting at the vertex's projection;
//! * the caller's [`FeatureTracker`] carries the points from frame to frame (the
//!   pipeline uses pyramidal Lucas-Kanade with a forward-backward check); a lost point
//!   is dropped for good (weight 0), as is a point whose reprojection error after the
//!   frame's fit exceeds `feature_drop_px` (the frame is then refitted once);
//! * when fewer than `feature_reseed` of the points of the last seeding are live, new
//!   points are seeded on the current frame (a departure from the thesis, which only
//!   drops them: without it a long clip ends with almost none).
//!
//! Live feature points share `feature_weight` times the landmarks' total weight
//! (each gets `feature_weight * L / live`, `L` = number of landmark points).
//!
//! This crate does not track images: the point tracker is the [`FeatureTracker`]
//! trait, so the pass is tested here with synthetic trackers and run on video by
//! `facecap-pipeline`.

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::Landmarks68;
use nalgebra::{Point2, Point3};

use crate::error::{Error, Result};
use crate::fit::{FitInput, FitParams, FitState, Fitter};
use crate::model::TensorModel;

/// Carries feature points from the previous frame into the current one.
pub trait FeatureTracker {
    /// Moves `points` (positions in the previous frame) to their positions in the
    /// current frame and clears `alive[j]` for every point it lost. Called once per
    /// frame that has an image, before the frame is fitted, only when there are points.
    ///
    /// # Errors
    /// When tracking fails as a whole (not for a lost point: that is `alive = false`).
    fn track(&mut self, points: &mut [Point2<f64>], alive: &mut [bool]) -> Result<()>;
}

/// A tracker that never moves the points (for still images and tests).
#[derive(Debug, Clone, Copy, Default)]
pub struct StillPoints;

impl FeatureTracker for StillPoints {
    fn track(&mut self, _points: &mut [Point2<f64>], _alive: &mut [bool]) -> Result<()> {
        Ok(())
    }
}

/// Parameters of the per-frame pass.
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `frame_sweeps` | 10 | pose/expression sweeps per frame (warm-started) | >= 1 |
/// | `feature_step` | 4 | grid spacing of the extra feature samples, px; 0 = no feature points | >= 0 |
/// | `feature_margin` | 6 | push-out of the mouth / brow polygons, px | >= 0 |
/// | `feature_max_px` | 3 | largest sample-to-vertex-projection distance, px | >= 0 |
/// | `feature_drop_px` | 6 | drop a feature point whose reprojection error exceeds this, px | >= 0 |
/// | `feature_weight` | 0.25 | total weight of the live feature points relative to the landmarks' | >= 0 |
/// | `feature_reseed` | 0.5 | seed anew below this fraction of the last seeding live | >= 0 |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePassParams {
    /// Maximum pose/expression sweeps per frame.
    pub frame_sweeps: usize,
    /// Grid spacing (pixels) of the feature samples; 0 disables feature points.
    pub feature_step: f64,
    /// Margin (pixels) by which the mouth / brow polygons are pushed out.
    pub feature_margin: f64,
    /// Largest distance (pixels) from a sample to the projection of its vertex.
    pub feature_max_px: f64,
    /// Reprojection error (pixels) above which a feature point is dropped.
    pub feature_drop_px: f64,
    /// Total weight of the live feature points relative to the landmarks'.
    pub feature_weight: f64,
    /// Re-seed when fewer than this fraction of the last seeding is live.
    pub feature_reseed: f64,
}

impl Default for FramePassParams {
    fn default() -> Self {
        FramePassParams {
            frame_sweeps: 10,
            feature_step: 4.0,
            feature_margin: 6.0,
            feature_max_px: 3.0,
            feature_drop_px: 6.0,
            feature_weight: 0.25,
            feature_reseed: 0.5,
        }
    }
}

impl FramePassParams {
    /// Checks every parameter.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter and its range.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("feature_step", self.feature_step),
            ("feature_margin", self.feature_margin),
            ("feature_max_px", self.feature_max_px),
            ("feature_drop_px", self.feature_drop_px),
            ("feature_weight", self.feature_weight),
            ("feature_reseed", self.feature_reseed),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, v, "a finite number >= 0"));
            }
        }
        if self.frame_sweeps == 0 {
            return Err(Error::invalid("frame_sweeps", 0, ">= 1"));
        }
        Ok(())
    }
}

/// Outcome of steps 1 and 2: the first fitted frame and the shared identity.
#[derive(Debug, Clone)]
pub struct IdentityFit {
    /// Position (in the frame list) of the first frame with landmarks.
    pub first_frame: usize,
    /// Sweeps and landmark RMS (px) of the first-frame alignment.
    pub first_sweeps: usize,
    /// Landmark RMS (px) of the first-frame alignment.
    pub first_rms_px: f64,
    /// Frames used for the identity.
    pub identity_frames: usize,
    /// Sweeps of the sequence fit.
    pub identity_sweeps: usize,
    /// Cost before / after the sequence fit.
    pub identity_cost: (f64, f64),
    /// Landmark RMS (px) of the sequence fit.
    pub identity_rms_px: f64,
    /// The shared identity weights.
    pub w_id: Vec<f64>,
    /// The first frame's expression weights (start of the per-frame pass).
    pub w_exp: Vec<f64>,
}

/// Steps 1 and 2 of the video fit: fits the first frame with landmarks on the landmarks
/// alone (pose, identity, expression), then one identity from `identity_frames` evenly
/// spaced frames with landmarks, started from the first frame's identity.
///
/// `frames[f]` holds frame `f`'s image points of the vertices `vertices` (`None` when
/// the frame has no landmarks).
///
/// # Errors
/// No frame with landmarks, a fit failure, or invalid parameters.
pub fn fit_identity(
    model: &TensorModel,
    vertices: &[u32],
    params: &FitParams,
    k: Intrinsics,
    frames: &[Option<Vec<Point2<f64>>>],
    identity_frames: usize,
) -> Result<IdentityFit> {
    let good: Vec<usize> = (0..frames.len()).filter(|&f| frames[f].is_some()).collect();
    let Some(&first) = good.first() else {
        return Err(Error::invalid("frames", "no frame with landmarks", "at least one"));
    };
    let ones = vec![1.0; vertices.len()];
    let align = Fitter::new(model, vertices, params.clone())?;
    let mut ws = align.workspace();
    let mut first_state = align.initial_state();
    let first_pts = frames[first].as_deref().unwrap_or_default();
    let first_rep = align.solve_into(
        &FitInput {
            image: first_pts,
            weights: &ones,
            intrinsics: k,
        },
        &mut ws,
        &mut first_state,
    )?;
    let nsel = identity_frames.clamp(1, good.len());
    let sel: Vec<usize> = (0..nsel).map(|j| good[j * good.len() / nsel]).collect();
    let inputs: Vec<FitInput> = sel
        .iter()
        .filter_map(|&f| frames[f].as_deref())
        .map(|im| FitInput {
            image: im,
            weights: &ones,
            intrinsics: k,
        })
        .collect();
    let mut seq: Vec<FitState> = (0..inputs.len())
        .map(|_| {
            let mut s = align.initial_state();
            s.w_id.clone_from(&first_state.w_id);
            s
        })
        .collect();
    let rep = align.fit_sequence(&inputs, &mut seq, &mut ws)?;
    let w_id = seq.first().map_or_else(|| first_state.w_id.clone(), |s| s.w_id.clone());
    Ok(IdentityFit {
        first_frame: first,
        first_sweeps: first_rep.sweeps,
        first_rms_px: first_rep.rms_px,
        identity_frames: inputs.len(),
        identity_sweeps: rep.sweeps,
        identity_cost: (rep.initial_cost, rep.final_cost),
        identity_rms_px: rep.rms_px,
        w_id,
        w_exp: first_state.w_exp,
    })
}

/// One frame's result of the pass.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFit {
    /// The fit, `None` when the frame had no landmarks or the fit failed.
    pub state: Option<FitState>,
    /// RMS reprojection error of the landmark points, px (NaN when not fitted).
    pub rms_landmarks: f64,
    /// RMS reprojection error of the live feature points, px.
    pub rms_features: f64,
    /// RMS reprojection error of all fitted points, px.
    pub rms_all: f64,
    /// Live feature points after the frame.
    pub live_features: usize,
    /// Why the fit failed, when it did.
    pub failure: Option<String>,
}

/// What the whole pass did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FramePassReport {
    /// Feature points seeded in total.
    pub seeded_features: usize,
    /// Number of seedings.
    pub seedings: usize,
}

/// One frame's input to [`FramePass::step`].
#[derive(Debug, Clone, Copy)]
pub struct FrameStep<'a> {
    /// Image points of the landmark vertices (`None`: no landmarks on this frame).
    pub landmark_points: Option<&'a [Point2<f64>]>,
    /// The frame's 68 landmarks (feature seeding uses the mouth and brow outlines).
    pub landmarks: Option<&'a Landmarks68>,
    /// Whether an image was available for this frame (and given to the tracker).
    pub have_image: bool,
}

/// Step 3 of the video fit (module docs): state carried from frame to frame.
#[derive(Debug)]
pub struct FramePass<'a> {
    model: &'a TensorModel,
    params: FitParams,
    pass: FramePassParams,
    k: Intrinsics,
    lm_vertices: Vec<u32>,
    w_id: Vec<f64>,
    w_exp: Vec<f64>,
    fitter: Fitter,
    ws: crate::fit::FitWorkspace,
    st: FitState,
    fv: Vec<u32>,
    fx: Vec<Point2<f64>>,
    alive: Vec<bool>,
    seeded_live: usize,
    report: FramePassReport,
    image: Vec<Point2<f64>>,
    weights: Vec<f64>,
    model_pts: Vec<Point3<f64>>,
    err: Vec<f64>,
}

impl<'a> FramePass<'a> {
    /// A pass over frames of `model` with the identity `w_id` fixed, starting from the
    /// expression `w_exp`, fitting the landmark vertices `lm_vertices` (plus feature
    /// points). `params` are the fitter's parameters (identity updates and the identity
    /// prior are turned off here; `max_sweeps` becomes `pass.frame_sweeps`).
    ///
    /// # Errors
    /// Invalid parameters or vertices.
    pub fn new(
        model: &'a TensorModel,
        lm_vertices: &[u32],
        params: &FitParams,
        pass: FramePassParams,
        k: Intrinsics,
        w_id: Vec<f64>,
        w_exp: Vec<f64>,
    ) -> Result<Self> {
        pass.validate()?;
        let params = FitParams {
            update_identity: false,
            prior_id: None,
            max_sweeps: pass.frame_sweeps,
            ..params.clone()
        };
        let fitter = Fitter::new(model, lm_vertices, params.clone())?;
        let ws = fitter.workspace();
        let mut st = fitter.initial_state();
        st.w_id.clone_from(&w_id);
        st.w_exp.clone_from(&w_exp);
        Ok(FramePass {
            model,
            params,
            pass,
            k,
            lm_vertices: lm_vertices.to_vec(),
            w_id,
            w_exp,
            fitter,
            ws,
            st,
            fv: Vec::new(),
            fx: Vec::new(),
            alive: Vec::new(),
            seeded_live: 0,
            report: FramePassReport::default(),
            image: Vec::new(),
            weights: Vec::new(),
            model_pts: Vec::new(),
            err: Vec::new(),
        })
    }

    /// Whether the pass uses feature points (and so wants images).
    pub fn uses_features(&self) -> bool {
        self.pass.feature_step > 0.0
    }

    /// The live feature points' image positions (for drawing).
    pub fn feature_points(&self) -> impl Iterator<Item = &Point2<f64>> {
        self.fx.iter().zip(&self.alive).filter(|(_, &a)| a).map(|(p, _)| p)
    }

    /// Seedings and points so far.
    pub fn report(&self) -> FramePassReport {
        self.report
    }

    /// One frame: carries the feature points with `tracker` (when the frame has an
    /// image), fits pose and expression, drops outlying feature points (refitting once)
    /// and seeds new ones when too few are left.
    ///
    /// # Errors
    /// Tracker failures and seeding failures (a failed *fit* is a value:
    /// [`FrameFit::state`] is `None` and [`FrameFit::failure`] says why).
    pub fn step(&mut self, input: FrameStep<'_>, tracker: &mut dyn FeatureTracker) -> Result<FrameFit> {
        let not_fitted = |failure: Option<String>, live: usize| FrameFit {
            state: None,
            rms_landmarks: f64::NAN,
            rms_features: f64::NAN,
            rms_all: f64::NAN,
            live_features: live,
            failure,
        };
        if self.uses_features() {
            if input.have_image {
                if !self.fv.is_empty() {
                    tracker.track(&mut self.fx, &mut self.alive)?;
                    for (p, a) in self.fx.iter().zip(self.alive.iter_mut()) {
                        if !(p.x.is_finite() && p.y.is_finite()) {
                            *a = false;
                        }
                    }
                }
            } else {
                // No image (the video ended before the landmark records): no more points.
                self.alive.iter_mut().for_each(|a| *a = false);
            }
        }
        let Some(lp) = input.landmark_points else {
            return Ok(not_fitted(None, self.live()));
        };
        let (nl, nf) = (self.lm_vertices.len(), self.fv.len());
        if lp.len() != nl {
            return Err(Error::DimensionMismatch {
                what: "landmark points of a frame".into(),
                expected: nl,
                got: lp.len(),
            });
        }
        self.image.clear();
        self.image.extend_from_slice(lp);
        self.image.extend_from_slice(&self.fx);
        self.weights.clear();
        self.weights.resize(nl, 1.0);
        let n_alive = self.live();
        let fw = if n_alive > 0 {
            self.pass.feature_weight * nl as f64 / n_alive as f64
        } else {
            0.0
        };
        self.weights
            .extend(self.alive.iter().map(|&a| if a { fw } else { 0.0 }));
        self.err.resize(nl + nf, 0.0);
        let mut failure = None;
        for attempt in 0..2 {
            let input = FitInput {
                image: &self.image,
                weights: &self.weights,
                intrinsics: self.k,
            };
            if let Err(e) = self.fitter.solve_into(&input, &mut self.ws, &mut self.st) {
                self.st.pose = None;
                failure = Some(e.to_string());
                break;
            }
            // Per-point reprojection errors; drop feature outliers and refit once.
            let Some(pose) = self.st.pose else { break };
            self.fitter.points_into(&self.st, &mut self.ws, &mut self.model_pts);
            for (e, (p, x)) in self.err.iter_mut().zip(self.model_pts.iter().zip(&self.image)) {
                *e = pose.project(&self.k, p).map_or(f64::INFINITY, |q| (q - x).norm());
            }
            let mut dropped = 0;
            for j in 0..nf {
                if self.alive[j] && self.err[nl + j] > self.pass.feature_drop_px {
                    self.alive[j] = false;
                    self.weights[nl + j] = 0.0;
                    dropped += 1;
                }
            }
            if dropped == 0 || attempt == 1 {
                break;
            }
        }
        if failure.is_some() {
            return Ok(not_fitted(failure, self.live()));
        }
        let rms = |r: std::ops::Range<usize>| -> f64 {
            let (mut s, mut c) = (0.0, 0usize);
            for i in r {
                if self.weights[i] > 0.0 {
                    s += self.err[i] * self.err[i];
                    c += 1;
                }
            }
            if c > 0 {
                (s / c as f64).sqrt()
            } else {
                f64::NAN
            }
        };
        let out = FrameFit {
            state: Some(self.st.clone()),
            rms_landmarks: rms(0..nl),
            rms_features: rms(nl..nl + nf),
            rms_all: rms(0..nl + nf),
            live_features: self.live(),
            failure: None,
        };
        let want_seed = self.uses_features()
            && input.have_image
            && (self.report.seedings == 0
                || (out.live_features as f64) < self.pass.feature_reseed * self.seeded_live as f64);
        if let (true, Some(lm)) = (want_seed, input.landmarks) {
            self.seed(lm)?;
        }
        Ok(out)
    }

    fn live(&self) -> usize {
        self.alive.iter().filter(|&&a| a).count()
    }

    /// Keeps the live points and adds new ones seeded on this frame's fit.
    fn seed(&mut self, lm: &Landmarks68) -> Result<()> {
        let (vs, start) = seed_features(self.model, &self.st, &self.k, lm, &self.pass, &self.lm_vertices)?;
        if vs.is_empty() {
            return Ok(());
        }
        let mut keep_v = Vec::new();
        let mut keep_x = Vec::new();
        for j in 0..self.fv.len() {
            if self.alive[j] {
                keep_v.push(self.fv[j]);
                keep_x.push(self.fx[j]);
            }
        }
        let used: std::collections::HashSet<u32> = keep_v.iter().copied().collect();
        let mut added = 0;
        for (v, x) in vs.into_iter().zip(start) {
            if !used.contains(&v) {
                keep_v.push(v);
                keep_x.push(x);
                added += 1;
            }
        }
        self.fv = keep_v;
        self.fx = keep_x;
        self.alive = vec![true; self.fv.len()];
        self.report.seeded_features += added;
        self.report.seedings += 1;
        self.seeded_live = self.fv.len();
        let (w_id, w_exp, pose) = (self.st.w_id.clone(), self.st.w_exp.clone(), self.st.pose);
        let mut vertices = self.lm_vertices.clone();
        vertices.extend_from_slice(&self.fv);
        self.fitter = Fitter::new(self.model, &vertices, self.params.clone())?;
        self.ws = self.fitter.workspace();
        let mut st = self.fitter.initial_state();
        st.w_id = w_id;
        st.w_exp = w_exp;
        st.pose = pose;
        self.st = st;
        Ok(())
    }

    /// The identity and starting expression the pass was made with.
    pub fn start_weights(&self) -> (&[f64], &[f64]) {
        (&self.w_id, &self.w_exp)
    }
}

/// Outer-lip polygon (48-59) and brow-to-upper-eyelid polygons of both brows.
fn feature_regions(l: &Landmarks68) -> [Vec<Point2<f64>>; 3] {
    let p = &l.points;
    let pick = |ids: &[usize]| ids.iter().map(|&i| p[i]).collect::<Vec<_>>();
    [
        pick(&[48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59]),
        pick(&[17, 18, 19, 20, 21, 39, 38, 37, 36]),
        pick(&[22, 23, 24, 25, 26, 45, 44, 43, 42]),
    ]
}

/// Feature points of a frame: distinct visible model vertices (not in `exclude`) under
/// image samples around the mouth and brows, and where they project.
fn seed_features(
    model: &TensorModel,
    state: &FitState,
    k: &Intrinsics,
    lm: &Landmarks68,
    o: &FramePassParams,
    exclude: &[u32],
) -> Result<(Vec<u32>, Vec<Point2<f64>>)> {
    let Some(pose) = state.pose else {
        return Ok((Vec::new(), Vec::new()));
    };
    let verts: Vec<Point3<f64>> = model
        .generate_points(&state.w_id, &state.w_exp)?
        .iter()
        .map(|p| p.cast())
        .collect();
    let mut samples = Vec::new();
    for poly in feature_regions(lm) {
        samples.extend(crate::features::grid_samples_in_polygon(
            &poly,
            o.feature_margin,
            o.feature_step,
        ));
    }
    let hits = crate::features::closest_visible_vertices(&verts, &pose, k, &samples, o.feature_max_px)?;
    let mut seen: std::collections::HashSet<u32> = exclude.iter().copied().collect();
    let mut vs = Vec::new();
    let mut pts = Vec::new();
    for v in hits.into_iter().flatten() {
        if seen.insert(v) {
            if let Some(x) = pose.project(k, &verts[v as usize]) {
                vs.push(v);
                pts.push(x);
            }
        }
    }
    Ok((vs, pts))
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::fit::Projection;
    use crate::model::HosvdParams;
    use facecap_core::camera::ModelToCamera;
    use nalgebra::Vector3;

    struct Scene {
        model: TensorModel,
        vertices: Vec<u32>,
        k: Intrinsics,
    }

    fn scene() -> Scene {
        let d = crate::synth::database(400, 5, 4, 3).unwrap();
        let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
        Scene {
            model,
            vertices: (0..60).map(|k| (k * 6) as u32).collect(),
            k: Intrinsics::new(900.0, 900.0, 319.5, 239.5).unwrap(),
        }
    }

    fn params() -> FitParams {
        FitParams {
            lambda_id: 1e-9,
            lambda_exp: 1e-9,
            projection: Projection::PerPointDepth,
            max_sweeps: 200,
            tol: 1e-14,
            ..Default::default()
        }
    }

    fn project(s: &Scene, w_id: &[f64], w_exp: &[f64], pose: &ModelToCamera, vs: &[u32]) -> Vec<Point2<f64>> {
        let f = s.model.generate_points(w_id, w_exp).unwrap();
        vs.iter()
            .map(|&v| pose.project(&s.k, &f[v as usize].cast()).unwrap())
            .collect()
    }

    fn pose(f: usize) -> ModelToCamera {
        ModelToCamera::from_rvec_tvec(Vector3::new(0.02 * f as f64, -0.1, 0.01), Vector3::new(0.2, -0.1, 60.0))
    }

    /// Landmarks whose mouth and brow outlines are boxes around the projected face, so
    /// that feature samples land on model vertices.
    fn outline_landmarks(pts: &[Point2<f64>]) -> Landmarks68 {
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for p in pts {
            x0 = x0.min(p.x);
            x1 = x1.max(p.x);
            y0 = y0.min(p.y);
            y1 = y1.max(p.y);
        }
        let corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)];
        Landmarks68::from_fn(|i| corners[i % 4])
    }

    #[test]
    fn identity_and_expressions_are_recovered_without_features() {
        let s = scene();
        let w_id = vec![0.1, 0.5, 0.2, 0.1, 0.1];
        let exps = [
            vec![0.7, 0.1, 0.1, 0.1],
            vec![0.1, 0.6, 0.2, 0.1],
            vec![0.25, 0.25, 0.25, 0.25],
        ];
        let frames: Vec<Option<Vec<Point2<f64>>>> = (0..6)
            .map(|f| (f != 2).then(|| project(&s, &w_id, &exps[f % 3], &pose(f), &s.vertices)))
            .collect();
        let id = fit_identity(&s.model, &s.vertices, &params(), s.k, &frames, 5).unwrap();
        assert_eq!(id.first_frame, 0);
        assert_eq!(id.identity_frames, 5);
        let pass_params = FramePassParams {
            feature_step: 0.0,
            frame_sweeps: 200,
            ..FramePassParams::default()
        };
        let mut pass = FramePass::new(&s.model, &s.vertices, &params(), pass_params, s.k, id.w_id, id.w_exp).unwrap();
        assert!(!pass.uses_features());
        for (f, pts) in frames.iter().enumerate() {
            let out = pass
                .step(
                    FrameStep {
                        landmark_points: pts.as_deref(),
                        landmarks: None,
                        have_image: false,
                    },
                    &mut StillPoints,
                )
                .unwrap();
            match pts {
                None => assert!(out.state.is_none() && out.rms_landmarks.is_nan()),
                Some(_) => {
                    assert!(out.rms_landmarks < 0.05, "frame {f}: {out:?}");
                    let st = out.state.unwrap();
                    let truth = s.model.generate_points(&w_id, &exps[f % 3]).unwrap();
                    let fit = s.model.generate_points(&st.w_id, &st.w_exp).unwrap();
                    let err = truth
                        .iter()
                        .zip(&fit)
                        .map(|(a, b)| (a - b).norm() as f64)
                        .fold(0.0, f64::max);
                    assert!(err < 0.05, "frame {f}: shape error {err}");
                }
            }
        }
        assert_eq!(pass.report(), FramePassReport::default());
    }

    /// A tracker that moves one point far away and loses another on each call.
    struct Sabotage {
        calls: usize,
    }

    impl FeatureTracker for Sabotage {
        fn track(&mut self, points: &mut [Point2<f64>], alive: &mut [bool]) -> Result<()> {
            self.calls += 1;
            points[0].x += 100.0;
            alive[1] = false;
            Ok(())
        }
    }

    /// A tracker that loses every point.
    struct LoseAll;

    impl FeatureTracker for LoseAll {
        fn track(&mut self, _points: &mut [Point2<f64>], alive: &mut [bool]) -> Result<()> {
            alive.iter_mut().for_each(|a| *a = false);
            Ok(())
        }
    }

    fn feature_pass(s: &Scene) -> (FramePass<'_>, Vec<Point2<f64>>, Landmarks68) {
        let w_id = vec![0.2; 5];
        let w_exp = vec![0.25; 4];
        let p = pose(0);
        let pts = project(s, &w_id, &w_exp, &p, &s.vertices);
        let all: Vec<u32> = (0..400).collect();
        let lm = outline_landmarks(&project(s, &w_id, &w_exp, &p, &all));
        let pass_params = FramePassParams {
            feature_step: 6.0,
            feature_max_px: 4.0,
            feature_margin: 0.0,
            ..FramePassParams::default()
        };
        let pass = FramePass::new(&s.model, &s.vertices, &params(), pass_params, s.k, w_id, w_exp).unwrap();
        (pass, pts, lm)
    }

    #[test]
    fn feature_points_are_seeded_tracked_dropped_and_reseeded() {
        let s = scene();
        let (mut pass, pts, lm) = feature_pass(&s);
        let step = FrameStep {
            landmark_points: Some(&pts),
            landmarks: Some(&lm),
            have_image: true,
        };
        // Frame 0: fitted on the landmarks, then points are seeded.
        let first = pass.step(step, &mut StillPoints).unwrap();
        assert_eq!(first.live_features, 0);
        let seeded = pass.report().seeded_features;
        assert!(seeded > 10, "seeded {seeded}");
        assert_eq!(pass.report().seedings, 1);
        // A still face with still points: every point stays live and fits.
        let still = pass.step(step, &mut StillPoints).unwrap();
        assert_eq!(still.live_features, seeded);
        assert!(still.rms_features < 0.05, "{still:?}");
        // One point moved 100 px is dropped by the reprojection test, one lost by the
        // tracker: two fewer live points.
        let mut sabotage = Sabotage { calls: 0 };
        let hurt = pass.step(step, &mut sabotage).unwrap();
        assert_eq!(sabotage.calls, 1);
        assert_eq!(hurt.live_features, seeded - 2);
        assert!(hurt.rms_landmarks < 0.05, "{hurt:?}");
        // Losing every point makes the pass seed anew on that frame.
        let lost = pass.step(step, &mut LoseAll).unwrap();
        assert_eq!(lost.live_features, 0);
        assert_eq!(pass.report().seedings, 2);
        assert!(pass.feature_points().count() > 10);
    }

    #[test]
    fn frames_without_an_image_end_the_feature_points_and_bad_input_is_rejected() {
        let s = scene();
        let (mut pass, pts, lm) = feature_pass(&s);
        let with_image = FrameStep {
            landmark_points: Some(&pts),
            landmarks: Some(&lm),
            have_image: true,
        };
        pass.step(with_image, &mut StillPoints).unwrap();
        assert!(pass.feature_points().count() > 0);
        let no_image = FrameStep {
            have_image: false,
            ..with_image
        };
        let out = pass.step(no_image, &mut StillPoints).unwrap();
        assert_eq!(out.live_features, 0);
        assert_eq!(pass.report().seedings, 1, "no seeding without an image");
        let short = &pts[..10];
        let bad = FrameStep {
            landmark_points: Some(short),
            ..with_image
        };
        assert!(pass.step(bad, &mut StillPoints).is_err());
        let bad_params = FramePassParams {
            feature_drop_px: f64::NAN,
            ..FramePassParams::default()
        };
        assert!(bad_params.validate().is_err());
        assert!(FramePassParams {
            frame_sweeps: 0,
            ..FramePassParams::default()
        }
        .validate()
        .is_err());
        assert!(fit_identity(&s.model, &s.vertices, &params(), s.k, &[None, None], 3).is_err());
    }
}
