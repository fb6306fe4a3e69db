//! Sparse pyramidal Lucas-Kanade optical flow (Bouguet 2001), numerically
//! following OpenCV's `calcOpticalFlowPyrLK` (`modules/video/src/lkpyramid.cpp`).
//!
//! # Maths
//!
//! For a point `u` of the previous frame `I`, LK looks for the displacement `d`
//! minimising the window sum of squared differences
//! `e(d) = Σ_{x ∈ W(u)} (J(x + d) - I(x))²` with the next frame `J`. Linearising
//! `J` around the current estimate gives the Gauss-Newton step
//!
//! ```text
//! G = Σ [Ix²  IxIy; IxIy  Iy²]      (spatial gradient matrix of I, fixed per level)
//! b = Σ (J(x + d) - I(x)) [Ix; Iy]  (image mismatch vector)
//! d ← d - G⁻¹ b
//! ```
//!
//! iterated until `|Δd| <= epsilon` or `max_iterations` steps (Bouguet 2001, §2.4,
//! "iterative Lucas-Kanade"). The search runs coarse-to-fine over a Gaussian
//! pyramid: the result of level `L+1`, doubled, is the initial guess at level `L`.
//!
//! # Numerics (what makes it match OpenCV)
//!
//! * Pyramid: OpenCV `pyrDown` — separable 5x5 kernel `[1 4 6 4 1]/16` in both
//!   directions, integer arithmetic with round-half-up (`(s + 128) >> 8`),
//!   `BORDER_REFLECT_101`, level size `((w+1)/2, (h+1)/2)`. Levels stop early
//!   when the next level would be no larger than the window (as OpenCV's
//!   `buildOpticalFlowPyramid`). Each level is stored with a border (the window
//!   side rounded up to 8, plus 32) whose inner `window + 2` columns / rows hold
//!   reflect-101 values, so windows near the edge read valid data.
//! * Gradients: Scharr `[3 10 3]ᵀ ⊗ [-1 0 1]` (and transposed) in 16-bit integers,
//!   i.e. 32x the central-difference gradient; zero outside the image. OpenCV
//!   differentiates every level of the previous frame; we compute them only for the
//!   `(window + 1)²` pixels each point needs at each level (identical values), which
//!   for sparse points is far cheaper and lets the pyramid skip the gradient pass.
//! * Sub-pixel sampling: bilinear with 14-bit fixed-point weights
//!   `iw00 = round((1-a)(1-b)·2¹⁴)` (round half to even, as `cvRound`),
//!   `iw11 = 2¹⁴ - iw00 - iw01 - iw10`; intensities keep 5 fractional bits,
//!   gradients none (`CV_DESCALE`).
//! * `G` and `b` are scaled by `2⁻²⁰`; the minimum-eigenvalue gate compares
//!   `λ_min(G) / window²` with `min_eig_threshold` (OpenCV default `1e-4`).
//! * Oscillation check: when two consecutive steps nearly cancel
//!   (`|Δ_k + Δ_{k-1}| < 0.01` per axis) the point is moved back by half the last
//!   step and iteration stops.
//! * Error value: mean absolute difference between the interpolated windows of
//!   `I` and `J` at the final position, in grey levels (OpenCV's `err`).
//! * Point coordinates are processed in `f32` like OpenCV (the API takes and
//!   returns `f64`; inputs are rounded to `f32` first).
//!
//! # Implementation (speed)
//!
//! The window loops use 128-bit SIMD through the safe `wide` crate (SSE2 on
//! x86-64, NEON on aarch64, scalar elsewhere), as OpenCV's SSE2 path does: window
//! rows are processed 8 columns at a time (the window side is padded to a multiple
//! of 8, padding lanes masked to zero); for 8 columns the two 8-byte loads at `x`
//! and `x + 1` of an image row, zero-extended to `i16`, are exactly the pixel pairs
//! `(p[x+2k], p[x+2k+1])` (even columns) and `(p[x+2k+1], p[x+2k+2])` (odd columns),
//! so every bilinear sum is one `pmaddwd` lane with the weight pairs; the stored
//! window therefore holds each chunk's even columns before its odd ones, which no
//! window sum can see. Per frame only the pyramid is built (vertical-first
//! `pyrDown`, borders filled only as far as windows reach); no allocation once
//! frame sizes are stable.
//!
//! Coordinates are 0-based pixel centres (top-left pixel centre is `(0, 0)`).
//!
//! # Departures from OpenCV
//!
//! * Status is a [`TrackStatus`] value saying *why* a point was lost, not a `u8`.
//! * Parameters are validated, never clamped (OpenCV clamps the iteration count to
//!   `0..=100` and epsilon to `0..=10`).
//! * Optional forward-backward check (Kalal et al. 2010) in the same call.
//! * Optional `require_convergence` marks points that hit the iteration cap at
//!   level 0 as [`TrackStatus::LostNoConvergence`] (OpenCV keeps them tracked; off
//!   by default for parity).
//! * `G` is accumulated in exact 64-bit integers (OpenCV's SIMD path sums `f32`
//!   products), so results can differ from OpenCV in the last float bits.
//!
//! # Parameters
//!
//! | name | default | meaning | range |
//! |---|---|---|---|
//! | `window` | 21 | square window side (px) | odd, 3..=63 |
//! | `max_level` | 3 | highest pyramid level (0 = no pyramid; OpenCV `maxLevel`) | 0..=8 |
//! | `max_iterations` | 30 | Gauss-Newton steps per level | >= 1 |
//! | `epsilon` | 0.01 | stop when the step length is <= epsilon (px) | > 0, finite |
//! | `min_eig_threshold` | 1e-4 | minimum-eigenvalue gate (OpenCV units, see above) | >= 0, finite |
//! | `forward_backward` | `None` | if `Some(t)`, lose points whose backward track lands more than `t` px from the start | `t` > 0, finite |
//! | `require_convergence` | false | lose points that hit the iteration cap at level 0 | - |
//! | `use_initial_flow` | false | start from the contents of `next_pts` (OpenCV `OPTFLOW_USE_INITIAL_FLOW`) | - |
//! | `par` | `Par::Seq` | sequential or rayon over points (identical results) | - |
//!
//! # Example
//!
//! ```
//! use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
//! use image::GrayImage;
//! use nalgebra::Point2;
//!
//! let texture = |x: f64, y: f64| 128.0 + 60.0 * (x / 7.0).sin() * (y / 9.0).cos() + 30.0 * ((x + y) / 5.0).sin();
//! let a = GrayImage::from_fn(160, 120, |x, y| image::Luma([texture(x as f64, y as f64) as u8]));
//! let b = GrayImage::from_fn(160, 120, |x, y| image::Luma([texture(x as f64 - 1.5, y as f64 - 0.5) as u8]));
//! let lk = PyramidLk::new(LkParams::default()).unwrap();
//! let mut ws = LkWorkspace::new(&lk);
//! ws.push_frame(&a).unwrap();
//! ws.push_frame(&b).unwrap();
//! let prev = [Point2::new(80.0, 60.0)];
//! let mut next = [Point2::origin()];
//! let mut status = [TrackStatus::Tracked];
//! let mut err = [0.0];
//! let report = lk.track_into(&ws, &prev, &mut next, &mut status, &mut err).unwrap();
//! assert_eq!(report.tracked, 1);
//! assert!((next[0].x - 81.5).abs() < 0.1 && (next[0].y - 60.5).abs() < 0.1);
//! ```

mod kernel;
mod pyramid;
pub mod reference;

use nalgebra::Point2;

use crate::error::{Error, Result};

pub use pyramid::{LkWorkspace, Pyramid, PyramidLevel};

/// Largest accepted window side. Keeps the per-row integer sums of the
/// mismatch vector inside `i32` (63 · 8160 · 4080 < 2³¹).
pub const MAX_WINDOW: usize = 63;
/// Largest accepted `max_level`.
pub const MAX_LEVEL: usize = 8;

/// How points are distributed over threads. Results are identical.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Par {
    /// One thread (the caller's).
    #[default]
    Seq,
    /// Rayon's global pool, points split between its threads.
    Rayon,
}

/// Parameters of [`PyramidLk`]; see the module docs for the table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LkParams {
    /// Window side in pixels (odd, 3..=63).
    pub window: usize,
    /// Highest pyramid level (OpenCV `maxLevel`), 0..=8.
    pub max_level: usize,
    /// Iteration cap per level (>= 1).
    pub max_iterations: usize,
    /// Step-length stopping threshold in pixels (> 0).
    pub epsilon: f64,
    /// Minimum-eigenvalue gate (>= 0), OpenCV units.
    pub min_eig_threshold: f64,
    /// Forward-backward threshold in pixels, `None` = no check.
    pub forward_backward: Option<f64>,
    /// Lose points that hit the iteration cap at level 0.
    pub require_convergence: bool,
    /// Use the incoming `next_pts` as initial guesses.
    pub use_initial_flow: bool,
    /// Thread use.
    pub par: Par,
}

impl Default for LkParams {
    fn default() -> Self {
        LkParams {
            window: 21,
            max_level: 3,
            max_iterations: 30,
            epsilon: 0.01,
            min_eig_threshold: 1e-4,
            forward_backward: None,
            require_convergence: false,
            use_initial_flow: false,
            par: Par::Seq,
        }
    }
}

impl LkParams {
    /// Checks every parameter, naming the offending one.
    pub fn validate(&self) -> Result<()> {
        if self.window < 3 || self.window > MAX_WINDOW || self.window % 2 == 0 {
            return Err(Error::InvalidParameter {
                name: "lk.window",
                value: self.window.to_string(),
                expected: format!("an odd number in 3..={MAX_WINDOW}"),
            });
        }
        if self.max_level > MAX_LEVEL {
            return Err(Error::InvalidParameter {
                name: "lk.max_level",
                value: self.max_level.to_string(),
                expected: format!("0..={MAX_LEVEL}"),
            });
        }
        if self.max_iterations < 1 {
            return Err(Error::InvalidParameter {
                name: "lk.max_iterations",
                value: self.max_iterations.to_string(),
                expected: ">= 1".into(),
            });
        }
        if !(self.epsilon.is_finite() && self.epsilon > 0.0) {
            return Err(Error::InvalidParameter {
                name: "lk.epsilon",
                value: self.epsilon.to_string(),
                expected: "a finite number > 0".into(),
            });
        }
        if !(self.min_eig_threshold.is_finite() && self.min_eig_threshold >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "lk.min_eig_threshold",
                value: self.min_eig_threshold.to_string(),
                expected: "a finite number >= 0".into(),
            });
        }
        if let Some(t) = self.forward_backward {
            if !(t.is_finite() && t > 0.0) {
                return Err(Error::InvalidParameter {
                    name: "lk.forward_backward",
                    value: t.to_string(),
                    expected: "a finite number > 0 (or None)".into(),
                });
            }
        }
        Ok(())
    }
}

/// Outcome for one point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum TrackStatus {
    /// Tracked to the next frame.
    #[default]
    Tracked,
    /// The window left the image (plus border) at level 0.
    LostOutOfImage,
    /// The gradient matrix is near-singular (minimum eigenvalue below the gate) at level 0.
    LostLowTexture,
    /// Hit the iteration cap at level 0 (only with `require_convergence`).
    LostNoConvergence,
    /// The backward track did not return within the threshold (only with `forward_backward`).
    LostForwardBackward,
}

impl TrackStatus {
    /// True for [`TrackStatus::Tracked`].
    pub fn is_tracked(self) -> bool {
        self == TrackStatus::Tracked
    }
}

/// Summary of one [`PyramidLk::track_into`] call.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LkReport {
    /// Points tracked.
    pub tracked: usize,
    /// Points lost out of the image.
    pub lost_out_of_image: usize,
    /// Points lost for low texture.
    pub lost_low_texture: usize,
    /// Points lost for no convergence.
    pub lost_no_convergence: usize,
    /// Points lost by the forward-backward check.
    pub lost_forward_backward: usize,
    /// Pyramid levels used (`max_level` may shrink for small images), 1-based count.
    pub levels: usize,
    /// Mean Gauss-Newton steps per point at level 0 (forward pass).
    pub mean_iterations_level0: f64,
}

/// Pyramidal LK tracker. Immutable, `Send + Sync`; one per parameter set.
#[derive(Debug, Clone)]
pub struct PyramidLk {
    params: LkParams,
}

/// Per-point outcome inside the kernel.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PointOutcome {
    pub status: TrackStatus,
    pub iterations_level0: usize,
}

impl PyramidLk {
    /// Validates the parameters.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the first bad parameter.
    pub fn new(params: LkParams) -> Result<Self> {
        params.validate()?;
        Ok(PyramidLk { params })
    }

    /// The parameters.
    pub fn params(&self) -> &LkParams {
        &self.params
    }

    /// Tracks `prev_pts` from the workspace's previous frame to its latest frame.
    ///
    /// Writes `next_pts` (positions in the latest frame; with `use_initial_flow`
    /// their incoming contents are the initial guesses), `status` and `err`
    /// (mean absolute grey-level difference of the windows; `NaN` for lost points).
    /// Does not allocate after the first call on a thread.
    ///
    /// # Errors
    /// * [`Error::DimensionMismatch`] when the slices differ in length.
    /// * [`Error::InvalidParameter`] when fewer than two frames were pushed, the
    ///   workspace was made for another window / level count, or a point is not finite.
    pub fn track_into(
        &self,
        ws: &LkWorkspace,
        prev_pts: &[Point2<f64>],
        next_pts: &mut [Point2<f64>],
        status: &mut [TrackStatus],
        err: &mut [f64],
    ) -> Result<LkReport> {
        let n = prev_pts.len();
        for (what, got) in [
            ("next_pts", next_pts.len()),
            ("status", status.len()),
            ("err", err.len()),
        ] {
            if got != n {
                return Err(Error::DimensionMismatch {
                    what: format!("{what} length vs prev_pts"),
                    expected: n,
                    got,
                });
            }
        }
        if ws.window() != self.params.window || ws.max_level_requested() != self.params.max_level {
            return Err(Error::InvalidParameter {
                name: "lk workspace",
                value: format!("window {}, max_level {}", ws.window(), ws.max_level_requested()),
                expected: format!(
                    "a workspace made for window {}, max_level {} (LkWorkspace::new(&lk))",
                    self.params.window, self.params.max_level
                ),
            });
        }
        let (prev, next) = ws.pair().ok_or_else(|| Error::InvalidParameter {
            name: "lk workspace frames",
            value: ws.frames_pushed().to_string(),
            expected: ">= 2 frames pushed with the same size".into(),
        })?;
        if let Some((i, p)) = prev_pts
            .iter()
            .enumerate()
            .find(|(_, p)| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(Error::InvalidParameter {
                name: "prev_pts",
                value: format!("point {i} = ({}, {})", p.x, p.y),
                expected: "finite coordinates".into(),
            });
        }
        let levels = prev.levels().min(next.levels());
        let cfg = kernel::Config::new(&self.params, levels);
        let run = |p: &Point2<f64>, q: &mut Point2<f64>, s: &mut TrackStatus, e: &mut f64| -> PointOutcome {
            kernel::with_scratch(cfg.window, |scratch| {
                kernel::track_point(&cfg, prev, next, *p, q, s, e, scratch)
            })
        };
        let mut report = LkReport {
            levels,
            ..LkReport::default()
        };
        let mut iters = 0usize;
        let mut tally = |o: PointOutcome| {
            iters += o.iterations_level0;
            match o.status {
                TrackStatus::Tracked => report.tracked += 1,
                TrackStatus::LostOutOfImage => report.lost_out_of_image += 1,
                TrackStatus::LostLowTexture => report.lost_low_texture += 1,
                TrackStatus::LostNoConvergence => report.lost_no_convergence += 1,
                TrackStatus::LostForwardBackward => report.lost_forward_backward += 1,
            }
        };
        match self.params.par {
            Par::Seq => {
                for (((p, q), s), e) in prev_pts
                    .iter()
                    .zip(next_pts.iter_mut())
                    .zip(status.iter_mut())
                    .zip(err.iter_mut())
                {
                    tally(run(p, q, s, e));
                }
            }
            Par::Rayon => {
                use rayon::prelude::*;
                let counts = (prev_pts, next_pts, status, err)
                    .into_par_iter()
                    .map(|(p, q, s, e)| {
                        let o = run(p, q, s, e);
                        let mut c = [0usize; 6];
                        c[o.status as usize] = 1;
                        c[5] = o.iterations_level0;
                        c
                    })
                    .reduce(|| [0usize; 6], |a, b| std::array::from_fn(|i| a[i] + b[i]));
                report.tracked = counts[0];
                report.lost_out_of_image = counts[1];
                report.lost_low_texture = counts[2];
                report.lost_no_convergence = counts[3];
                report.lost_forward_backward = counts[4];
                iters = counts[5];
            }
        }
        report.mean_iterations_level0 = if n > 0 { iters as f64 / n as f64 } else { 0.0 };
        Ok(report)
    }
}
