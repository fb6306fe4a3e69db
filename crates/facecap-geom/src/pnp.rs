//! Perspective-n-point: the pose of a rigid model from its projections.
//!
//! Given model points `X_i` (model units) and their pixels `u_i` under pinhole
//! intrinsics `K`, finds the [`ModelToCamera`] pose `(R, t)` minimising the
//! reprojection error `sum_i || u_i - pi(K (R X_i + t)) ||^2`.
//!
//! 1. **Initialisation** (when no previous pose is given), chosen by [`PnpInit`]:
//!    EPnP (Lepetit et al. 2009, [`crate::epnp`], the default) with POSIT as the
//!    fallback should it fail, or POSIT alone: "Model-based object pose in 25 lines of
//!    code" (DeMenthon & Davis 1995), in its least-squares form: fit a
//!    scaled-orthographic camera to normalised image points corrected by the current
//!    perspective factors `1 + eps_i = z_i / t_z`, re-orthonormalise, repeat.
//!    Both need non-coplanar points (a face's 68 landmarks are).
//! 2. **Refinement**: Levenberg-Marquardt on the 6 pose parameters (rotation
//!    increment as a left-multiplied rotation vector, translation), analytic
//!    Jacobian, fixed-size 6x6 normal equations: no heap allocation.

use nalgebra::{Matrix3, Matrix6, Point2, Point3, Rotation3, UnitQuaternion, Vector3, Vector6};

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::error::{Error, Result};

/// Parameters of [`solve_pnp`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `max_iterations` | 30 | LM iteration cap | >= 1 |
/// | `posit_iterations` | 20 | POSIT iteration cap for the initial guess | >= 1 |
/// | `tolerance_px` | 1e-6 | stop when the RMS error improves by less (px) | >= 0 |
/// | `init` | `Epnp` | initialiser when no previous pose is given | [`PnpInit`] |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpParams {
    /// Levenberg-Marquardt iteration cap.
    pub max_iterations: usize,
    /// POSIT iteration cap.
    pub posit_iterations: usize,
    /// Convergence tolerance on the RMS reprojection error, in pixels.
    pub tolerance_px: f64,
    /// Initialiser used by [`solve_pnp`] without a previous pose.
    pub init: PnpInit,
}

/// Closed-form initialiser of [`solve_pnp`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PnpInit {
    /// EPnP ([`crate::epnp::epnp`]); POSIT if EPnP fails.
    #[default]
    Epnp,
    /// POSIT ([`posit`]).
    Posit,
}

impl Default for PnpParams {
    fn default() -> Self {
        PnpParams {
            max_iterations: 30,
            posit_iterations: 20,
            tolerance_px: 1e-6,
            init: PnpInit::Epnp,
        }
    }
}

/// Why the refinement stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PnpStop {
    /// The RMS error changed by less than the tolerance.
    Converged,
    /// The iteration cap was reached.
    MaxIterations,
}

/// Outcome of [`solve_pnp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpReport {
    /// LM iterations taken.
    pub iterations: usize,
    /// Final RMS reprojection error in pixels.
    pub rms_px: f64,
    /// Why it stopped.
    pub stop: PnpStop,
}

fn validate(model: &[Point3<f64>], image: &[Point2<f64>], params: &PnpParams) -> Result<()> {
    if model.len() != image.len() {
        return Err(Error::DimensionMismatch {
            what: "PnP point count".into(),
            expected: model.len(),
            got: image.len(),
        });
    }
    if model.len() < 4 {
        return Err(Error::invalid("PnP point count", model.len(), ">= 4"));
    }
    if params.max_iterations == 0 {
        return Err(Error::invalid("max_iterations", 0, ">= 1"));
    }
    if params.posit_iterations == 0 {
        return Err(Error::invalid("posit_iterations", 0, ">= 1"));
    }
    if !(params.tolerance_px >= 0.0 && params.tolerance_px.is_finite()) {
        return Err(Error::invalid("tolerance_px", params.tolerance_px, "finite and >= 0"));
    }
    for (i, (m, u)) in model.iter().zip(image).enumerate() {
        if !(m.coords.iter().all(|v| v.is_finite()) && u.coords.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid("PnP point", format!("point {i}"), "finite coordinates"));
        }
    }
    Ok(())
}

/// Sum of squared reprojection errors; points behind the camera count as a large error.
pub fn reprojection_sse(pose: &ModelToCamera, k: &Intrinsics, model: &[Point3<f64>], image: &[Point2<f64>]) -> f64 {
    const BEHIND_PENALTY: f64 = 1e12;
    model
        .iter()
        .zip(image)
        .map(|(m, u)| match pose.project(k, m) {
            Some(p) => (p - u).norm_squared(),
            None => BEHIND_PENALTY,
        })
        .sum()
}

/// POSIT initial pose (see module docs).
///
/// # Errors
/// Degenerate (coplanar or coincident) model points, or no pose in front of the camera.
pub fn posit(model: &[Point3<f64>], image: &[Point2<f64>], k: &Intrinsics, iterations: usize) -> Result<ModelToCamera> {
    let n = model.len() as f64;
    let centroid = model.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    // Normal matrix of the centred model points (for the least-squares row fits).
    let mut a = Matrix3::zeros();
    for p in model {
        let d = p.coords - centroid;
        a += d * d.transpose();
    }
    let a_inv = a.try_inverse().ok_or(Error::Numerical {
        operation: "posit",
        reason: "model points are coplanar or coincident".into(),
    })?;
    let norm: Vec<(f64, f64)> = image
        .iter()
        .map(|u| ((u.x - k.cx) / k.fx, (u.y - k.cy) / k.fy))
        .collect();
    let mut eps = vec![0.0; model.len()];
    let mut rot = Matrix3::identity();
    let mut t = Vector3::new(0.0, 0.0, 1.0);
    for _ in 0..iterations {
        // x_i (1 + eps_i) - x_c = s r1 . (M_i - M_c), same for y: least squares for I = s r1, J = s r2.
        let (mut xc, mut yc) = (0.0, 0.0);
        for (i, (x, y)) in norm.iter().enumerate() {
            xc += x * (1.0 + eps[i]);
            yc += y * (1.0 + eps[i]);
        }
        xc /= n;
        yc /= n;
        let (mut bx, mut by) = (Vector3::zeros(), Vector3::zeros());
        for (i, p) in model.iter().enumerate() {
            let d = p.coords - centroid;
            bx += d * (norm[i].0 * (1.0 + eps[i]) - xc);
            by += d * (norm[i].1 * (1.0 + eps[i]) - yc);
        }
        let vi = a_inv * bx;
        let vj = a_inv * by;
        let (ni, nj) = (vi.norm(), vj.norm());
        if !(ni > 0.0 && nj > 0.0) {
            return Err(Error::Numerical {
                operation: "posit",
                reason: "image points are coincident".into(),
            });
        }
        let s = 0.5 * (ni + nj);
        // Orthonormalise the two rows (symmetric Gram-Schmidt), third row by cross product.
        let (r1, r2) = (vi / ni, vj / nj);
        let mid = (r1 + r2).normalize();
        let perp = (r1 - r2).normalize();
        let r1o = (mid + perp).normalize();
        let r2o = (mid - perp).normalize();
        let r3 = r1o.cross(&r2o);
        rot = Matrix3::from_rows(&[r1o.transpose(), r2o.transpose(), r3.transpose()]);
        let tz = 1.0 / s;
        // Centroid maps to (xc, yc) * tz.
        let tc = Vector3::new(xc * tz, yc * tz, tz);
        t = tc - rot * centroid;
        for (i, p) in model.iter().enumerate() {
            eps[i] = (r3.dot(&(p.coords - centroid))) / tz;
        }
    }
    let rotation = Rotation3::from_matrix_unchecked(rot);
    let pose = ModelToCamera(nalgebra::Isometry3::from_parts(
        t.into(),
        UnitQuaternion::from_rotation_matrix(&rotation),
    ));
    Ok(pose)
}

/// Refines `pose` in place by Levenberg-Marquardt (no allocation).
pub fn refine_pose(
    pose: &mut ModelToCamera,
    k: &Intrinsics,
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    params: &PnpParams,
) -> PnpReport {
    let n = model.len().max(1) as f64;
    let mut sse = reprojection_sse(pose, k, model, image);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut stop = PnpStop::MaxIterations;
    while iterations < params.max_iterations {
        iterations += 1;
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        for (m, u) in model.iter().zip(image) {
            let pc = pose.transform(m);
            if pc.z <= 1e-9 {
                continue;
            }
            let (x, y, z) = (pc.x, pc.y, pc.z);
            let iz = 1.0 / z;
            let rx = k.fx * x * iz + k.cx - u.x;
            let ry = k.fy * y * iz + k.cy - u.y;
            // d(proj)/d(pc)
            let dpx = Vector3::new(k.fx * iz, 0.0, -k.fx * x * iz * iz);
            let dpy = Vector3::new(0.0, k.fy * iz, -k.fy * y * iz * iz);
            // pc' = exp(w) pc + dt -> d pc / d w = -[pc]x, d pc / d t = I.
            let pv = pc.coords;
            let jx = Vector6::new(
                dpx.y * (-pv.z) + dpx.z * pv.y,
                dpx.x * pv.z + dpx.z * (-pv.x),
                dpx.x * (-pv.y) + dpx.y * pv.x,
                dpx.x,
                dpx.y,
                dpx.z,
            );
            let jy = Vector6::new(
                dpy.y * (-pv.z) + dpy.z * pv.y,
                dpy.x * pv.z + dpy.z * (-pv.x),
                dpy.x * (-pv.y) + dpy.y * pv.x,
                dpy.x,
                dpy.y,
                dpy.z,
            );
            jtj += jx * jx.transpose() + jy * jy.transpose();
            jtr += jx * rx + jy * ry;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut h = jtj;
            for d in 0..6 {
                h[(d, d)] += lambda * (1.0 + jtj[(d, d)]);
            }
            let Some(delta) = h.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let w = Vector3::new(delta[0], delta[1], delta[2]);
            let dt = Vector3::new(delta[3], delta[4], delta[5]);
            let dr = UnitQuaternion::from_scaled_axis(w);
            let mut cand = *pose;
            cand.0.rotation = dr * pose.0.rotation;
            cand.0.translation.vector = dr * pose.0.translation.vector + dt;
            let cand_sse = reprojection_sse(&cand, k, model, image);
            if cand_sse < sse {
                let old_rms = (sse / n).sqrt();
                *pose = cand;
                sse = cand_sse;
                lambda = (lambda * 0.3).max(1e-12);
                improved = true;
                if old_rms - (sse / n).sqrt() < params.tolerance_px {
                    stop = PnpStop::Converged;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            stop = PnpStop::Converged;
            break;
        }
        if stop == PnpStop::Converged {
            break;
        }
    }
    PnpReport {
        iterations,
        rms_px: (sse / n).sqrt(),
        stop,
    }
}

/// Solves PnP: EPnP or POSIT initialisation ([`PnpParams::init`]; or `init` when
/// given), then LM refinement.
///
/// # Errors
/// Mismatched lengths, fewer than 4 points, non-finite input, invalid parameters,
/// or degenerate geometry.
pub fn solve_pnp(
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    k: &Intrinsics,
    init: Option<ModelToCamera>,
    params: &PnpParams,
) -> Result<(ModelToCamera, PnpReport)> {
    validate(model, image, params)?;
    let mut pose = match init {
        Some(p) => p,
        None => match params.init {
            PnpInit::Epnp => match crate::epnp::epnp(model, image, k) {
                Ok(p) => p,
                Err(_) => posit(model, image, k, params.posit_iterations)?,
            },
            PnpInit::Posit => posit(model, image, k, params.posit_iterations)?,
        },
    };
    let report = refine_pose(&mut pose, k, model, image, params);
    if !report.rms_px.is_finite() {
        return Err(Error::Numerical {
            operation: "solve_pnp",
            reason: "reprojection error is not finite".into(),
        });
    }
    Ok((pose, report))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn face_like_points(rng: &mut ChaCha8Rng) -> Vec<Point3<f64>> {
        face_like_points_n(rng, 68)
    }

    /// `n` random points on a face-like surface (shared with the EPnP tests).
    pub(crate) fn face_like_points_n(rng: &mut ChaCha8Rng, n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| {
                let x: f64 = rng.random_range(-7.0..7.0);
                let y: f64 = rng.random_range(-9.0..6.0);
                Point3::new(x, y, 4.0 - 0.06 * x * x - 0.03 * y * y + rng.random_range(-0.5..0.5))
            })
            .collect()
    }

    #[test]
    fn recovers_pose_without_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let k = Intrinsics::new(640.0, 640.0, 320.0, 240.0).unwrap();
        for _ in 0..30 {
            let model = face_like_points(&mut rng);
            let rvec = Vector3::new(
                rng.random_range(-0.35..0.35),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.3..0.3),
            );
            let tvec = Vector3::new(
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
                rng.random_range(40.0..80.0),
            );
            let truth = ModelToCamera::from_rvec_tvec(rvec, tvec);
            let image: Vec<_> = model.iter().map(|m| truth.project(&k, m).unwrap()).collect();
            let (pose, report) = solve_pnp(&model, &image, &k, None, &PnpParams::default()).unwrap();
            assert!(report.rms_px < 1e-6, "rms {}", report.rms_px);
            assert!((pose.rvec() - rvec).norm() < 1e-6);
            assert!((pose.tvec() - tvec).norm() < 1e-4);
        }
    }

    #[test]
    fn noisy_points_give_small_error() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let k = Intrinsics::new(640.0, 640.0, 320.0, 240.0).unwrap();
        let model = face_like_points(&mut rng);
        let truth = ModelToCamera::from_rvec_tvec(Vector3::new(0.1, 0.4, -0.05), Vector3::new(1.0, -2.0, 60.0));
        let image: Vec<_> = model
            .iter()
            .map(|m| {
                let p = truth.project(&k, m).unwrap();
                Point2::new(p.x + rng.random_range(-1.0..1.0), p.y + rng.random_range(-1.0..1.0))
            })
            .collect();
        let (pose, report) = solve_pnp(&model, &image, &k, None, &PnpParams::default()).unwrap();
        assert!(report.rms_px < 1.0);
        let angle = (pose.0.rotation.inverse() * truth.0.rotation).angle();
        assert!(angle < 0.02, "rotation error {angle}");
    }

    #[test]
    fn rejects_bad_input() {
        let k = Intrinsics::new(640.0, 640.0, 320.0, 240.0).unwrap();
        let m = vec![Point3::new(0.0, 0.0, 0.0); 3];
        let u = vec![Point2::new(0.0, 0.0); 3];
        assert!(solve_pnp(&m, &u, &k, None, &PnpParams::default()).is_err());
        let m = vec![Point3::new(0.0, 0.0, 0.0); 5];
        let u = vec![Point2::new(0.0, 0.0); 5];
        assert!(solve_pnp(&m, &u, &k, None, &PnpParams::default()).is_err());
        let mut u2 = vec![Point2::new(1.0, 0.0); 5];
        u2[2].x = f64::NAN;
        assert!(solve_pnp(&m, &u2, &k, None, &PnpParams::default()).is_err());
    }
}
