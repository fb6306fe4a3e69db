//! Per-subject neutral calibration for `facecap capture --neutral`.
//!
//! A generic rig's neutral face is not the subject's: a person whose resting mouth
//! is wider than the mean face's "smiles" in every frame, and the solver reports that
//! identity difference as expression. Calibration makes the rig's neutral landmarks
//! the subject's own, from one frame where the subject's face is at rest (as Live
//! Link Face's neutral-pose calibration does):
//!
//! 1. choose the neutral frame: `--neutral N` names it; `--neutral auto` takes the
//!    frame whose face shape is closest to the clip's median face shape (every
//!    frame's landmarks similarity-aligned to the first frame's on the stable points,
//!    then the per-coordinate median over the clip): expressions come and go, the
//!    resting face is what most frames share;
//! 2. solve that frame (pose or 2D similarity) and place the rig's neutral landmarks
//!    with zero weights;
//! 3. move each neutral landmark so it lands on the tracked one: with a 3D pose, the
//!    tracked pixel is back-projected at the model point's depth and the offset is
//!    rotated into the model frame (`δ = Rᵀ(X' − X)`); with a 2D similarity the
//!    offset is mapped back through it into the rig's frontal plane (`δZ = 0`);
//! 4. solve all frames with the calibrated rig.
//!
//! Expression deltas are kept; meshes written afterwards are the generic rig
//! animated by the calibrated weights.

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_solve::{AnySolver, BlendshapeRig, ExpressionSolver, Solution, SolveState};
use nalgebra::Point3;
use serde_json::json;

/// How the subject's neutral is found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NeutralChoice {
    /// No calibration.
    None,
    /// The default: the subject's neutral fitted in 3D over many frames
    /// ([`facecap_solve::calibrate`]) with the 3D solver; with a 2D solver, the frame closest
    /// to the clip's median face shape.
    Auto,
    /// This frame index.
    Frame(u64),
}

impl std::str::FromStr for NeutralChoice {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> anyhow::Result<Self> {
        match s {
            "none" => Ok(NeutralChoice::None),
            "auto" => Ok(NeutralChoice::Auto),
            n => n
                .parse::<u64>()
                .map(NeutralChoice::Frame)
                .map_err(|_| anyhow::anyhow!("--neutral must be none, auto or a frame index, got {n:?}")),
        }
    }
}

/// The calibrated rig and what was done (for `summary.json`).
pub struct Calibrated {
    /// The rig with the subject's neutral landmarks.
    pub rig: BlendshapeRig,
    /// JSON report: mode, frame, offsets.
    pub report: serde_json::Value,
}

/// Calibrates `rig` on `frames` (frame index, tracked landmarks), see the module docs.
/// `solver` is the generic rig's solver (built from `rig`); `camera` is the one it
/// was built with.
///
/// # Errors
/// When the named frame has no tracked face, no frame has one, or the solver fails on
/// the neutral frame.
pub fn calibrate(
    choice: NeutralChoice,
    solver: &AnySolver,
    rig: &BlendshapeRig,
    camera: Intrinsics,
    frames: &[(u64, Landmarks68)],
) -> anyhow::Result<Calibrated> {
    let neutral_pos = match choice {
        NeutralChoice::None => anyhow::bail!("no neutral calibration was asked for"),
        NeutralChoice::Frame(f) => frames
            .iter()
            .position(|(i, _)| *i == f)
            .ok_or_else(|| anyhow::anyhow!("--neutral {f}: no face was tracked on frame {f}"))?,
        NeutralChoice::Auto => {
            median_face_frame(frames).ok_or_else(|| anyhow::anyhow!("--neutral auto: no tracked frame"))?
        }
    };
    let (frame_index, obs) = &frames[neutral_pos];
    let n = solver.num_shapes();
    let mut ws = solver.workspace();
    let mut sol = Solution::new(n);
    solver
        .solve_into(obs, &mut ws, &mut SolveState::new(n), &mut sol)
        .map_err(|e| anyhow::anyhow!("solving the neutral frame {frame_index}: {e}"))?;
    let before: f64 = sol.weights.iter().sum();
    let mut out = rig.clone();
    let mut moved_px = Vec::new();
    for l in 0..NUM_LANDMARKS {
        if !rig.mapped[l] {
            continue;
        }
        let x = Point3::new(rig.neutral[[l, 0]], rig.neutral[[l, 1]], rig.neutral[[l, 2]]);
        let p = obs.points[l];
        let delta = if let Some(pose) = &sol.pose {
            let xc = pose.transform(&x);
            if xc.z <= 0.0 {
                continue;
            }
            if let Some(px) = camera.project(&xc) {
                moved_px.push((px - p).norm());
            }
            let xb = Point3::new(
                (p.x - camera.cx) * xc.z / camera.fx,
                (p.y - camera.cy) * xc.z / camera.fy,
                xc.z,
            );
            pose.0.rotation.inverse() * (xb - xc)
        } else if let Some(sim) = &sol.similarity {
            // the 2D basis is the frontal view (x, y) = (X, -Y)
            let (fx, fy) = sim.apply(x.x, -x.y);
            moved_px.push(((fx - p.x).powi(2) + (fy - p.y).powi(2)).sqrt());
            // offset in the basis frame, then back to the rig's axes (Y = -y)
            let (bx, by) = sim.apply_inverse(p.x, p.y);
            nalgebra::Vector3::new(bx - x.x, -(by + x.y), 0.0)
        } else {
            anyhow::bail!("the solver gave neither a pose nor a similarity for the neutral frame");
        };
        if delta.iter().all(|v| v.is_finite()) {
            for c in 0..3 {
                out.neutral[[l, c]] += delta[c];
            }
        }
    }
    let mean_px = moved_px.iter().sum::<f64>() / moved_px.len().max(1) as f64;
    Ok(Calibrated {
        rig: out,
        report: json!({
            "mode": match choice { NeutralChoice::Auto => "auto", _ => "frame" },
            "frame": frame_index,
            "generic_rig_weight_sum_on_that_frame": before,
            "mean_landmark_offset_px": mean_px,
        }),
    })
}

/// The multi-frame 3D fit of the subject's neutral ([`facecap_solve::fit_subject`]) for
/// the 3D solver: `rig` is the generic rig, `priors` and `objective` those the frames are
/// solved with.
pub fn calibrate_subject(
    rig: &BlendshapeRig,
    camera: Intrinsics,
    objective: facecap_solve::ObjectiveParams,
    priors: &facecap_solve::ShapePriors,
    frames: &[(u64, Landmarks68)],
) -> anyhow::Result<Calibrated> {
    let lms: Vec<Landmarks68> = frames.iter().map(|(_, l)| l.clone()).collect();
    let params = facecap_solve::SubjectParams::default();
    let fit = facecap_solve::fit_subject(rig, camera, objective, priors, &lms, &params)
        .map_err(|e| anyhow::anyhow!("fitting the subject's neutral: {e}"))?;
    Ok(Calibrated {
        report: json!({
            "mode": "auto",
            "method": "multi-frame 3D offset field (resting frames at zero expression)",
            "frames_used": fit.frames_used,
            "rest_frames": fit.rest_frames,
            "mouth_frames": fit.mouth_frames,
            "iterations": params.iterations,
            "mean_offset_rig_units": fit.mean_offset,
            "mean_expression_before": fit.mean_expression_before,
            "mean_expression_last_pass": fit.mean_expression_last_pass,
            "offsets": fit.offsets.iter().map(|d| [d.x, d.y, d.z]).collect::<Vec<_>>(),
        }),
        rig: fit.rig,
    })
}

/// Position in `frames` of the frame closest to the median aligned face shape.
fn median_face_frame(frames: &[(u64, Landmarks68)]) -> Option<usize> {
    use facecap_solve::basis::{Similarity2d, DEFAULT_STABLE};
    let flat = |l: &Landmarks68| -> Vec<f64> { l.points.iter().flat_map(|p| [p.x, p.y]).collect() };
    let reference = flat(&frames.first()?.1);
    let mut mask = [false; NUM_LANDMARKS];
    for &i in &DEFAULT_STABLE {
        mask[i] = true;
    }
    let aligned: Vec<Vec<f64>> = frames
        .iter()
        .filter_map(|(_, l)| {
            let f = flat(l);
            let sim = Similarity2d::fit(&f, &reference, &mask)?;
            Some(
                f.chunks_exact(2)
                    .flat_map(|p| {
                        let (x, y) = sim.apply(p[0], p[1]);
                        [x, y]
                    })
                    .collect(),
            )
        })
        .collect();
    if aligned.len() != frames.len() {
        return None;
    }
    let mut median = vec![0.0; 2 * NUM_LANDMARKS];
    let mut column = Vec::with_capacity(aligned.len());
    for (c, m) in median.iter_mut().enumerate() {
        column.clear();
        column.extend(aligned.iter().map(|a| a[c]));
        column.sort_by(f64::total_cmp);
        *m = column[column.len() / 2];
    }
    aligned
        .iter()
        .map(|a| a.iter().zip(&median).map(|(x, m)| (x - m).powi(2)).sum::<f64>())
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| k)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;
    use facecap_core::camera::ModelToCamera;
    use facecap_solve::{Method, ObjectiveParams};
    use nalgebra::{Point2, Vector3};

    /// A subject whose neutral differs from the rig's: after calibration on a neutral
    /// frame, the other frames' weights are recovered (they are not without it).
    #[test]
    fn calibration_removes_an_identity_offset() {
        let rig = BlendshapeRig::synthetic(8, 3);
        let camera = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
        // the subject: the rig with a fixed landmark offset (its identity)
        let mut subject = rig.clone();
        for l in 0..NUM_LANDMARKS {
            let s = (l as f64 * 0.7).sin();
            subject.neutral[[l, 0]] += 0.4 * s;
            subject.neutral[[l, 1]] += 0.3 * (l as f64 * 1.3).cos();
        }
        // facing the camera (model +Z towards it), 50 cm away, turned a little
        let facing = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        let turn = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(0.05, 0.2, 0.0));
        let pose = ModelToCamera::from_rvec_tvec((turn * facing).scaled_axis(), Vector3::new(0.0, 0.0, 50.0));
        let weights: Vec<Vec<f64>> = (0..12)
            .map(|f| {
                let mut w = vec![0.0; 8];
                if f > 0 {
                    w[f % 8] = 0.6;
                    w[(f + 3) % 8] = 0.3;
                }
                w
            })
            .collect();
        let frames: Vec<(u64, Landmarks68)> = weights
            .iter()
            .enumerate()
            .map(|(f, w)| {
                let pts: Vec<(f64, f64)> = (0..NUM_LANDMARKS)
                    .map(|l| {
                        let p: Point2<f64> = pose.project(&camera, &subject.landmark(l, w)).unwrap();
                        (p.x, p.y)
                    })
                    .collect();
                (f as u64, Landmarks68::from_slice(&pts).unwrap())
            })
            .collect();
        let objective = ObjectiveParams::default();
        let rmse = |r: &BlendshapeRig| {
            let solver = AnySolver::new(Method::Exact3d, r, camera, objective).unwrap();
            let mut ws = solver.workspace();
            let mut st = SolveState::new(8);
            let mut sol = Solution::new(8);
            let mut se = 0.0;
            for ((_, l), w) in frames.iter().zip(&weights) {
                solver.solve_into(l, &mut ws, &mut st, &mut sol).unwrap();
                se += sol.weights.iter().zip(w).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
            }
            (se / (8 * frames.len()) as f64).sqrt()
        };
        let generic = rmse(&rig);
        let solver_3d = AnySolver::new(Method::Exact3d, &rig, camera, objective).unwrap();
        let cal = calibrate(NeutralChoice::Auto, &solver_3d, &rig, camera, &frames).unwrap();
        assert_eq!(cal.report["frame"], 0);
        let calibrated = rmse(&cal.rig);
        assert!(
            calibrated < 0.02,
            "calibrated weight RMSE {calibrated} (generic {generic})"
        );
        assert!(
            calibrated < generic / 3.0,
            "calibrated {calibrated} vs generic {generic}"
        );
        // explicit frame; a frame without a face is an error
        assert!(calibrate(NeutralChoice::Frame(0), &solver_3d, &rig, camera, &frames).is_ok());
        assert!(calibrate(NeutralChoice::Frame(99), &solver_3d, &rig, camera, &frames).is_err());
        // the 2D exact solver calibrates through its similarity
        let solver_2d = AnySolver::new(Method::Exact, &rig, camera, objective).unwrap();
        let cal2 = calibrate(NeutralChoice::Frame(0), &solver_2d, &rig, camera, &frames).unwrap();
        assert!(cal2.report["mean_landmark_offset_px"].as_f64().unwrap() > 0.0);
    }
}
