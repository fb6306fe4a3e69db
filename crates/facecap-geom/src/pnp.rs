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
//! 2. **Refinement** ([`refine_pose`]): Levenberg-Marquardt on the 6 pose parameters
//!    (rotation increment as a left-multiplied rotation vector `R <- exp([w]x) R`,
//!    translation `t <- t + dt`), analytic Jacobian ([`point_jacobian`]), fixed-size 6x6
//!    normal equations: no heap allocation. Per-point weights are optional (0 ignores a
//!    point). It is the workspace's one pose refinement: [`solve_pnp`] (the pipeline's
//!    pose beside the 2D solvers, `synth`, muscle tracking), the tensor fit's pose step
//!    (weighted, started by [`crate::pose::init_scaled_orthographic`]) and the rigid step
//!    of `exact3d` (weighted by its landmark priors) all call it; `exact3d`'s joint
//!    pose-and-weights step uses the same [`point_jacobian`] and [`apply_pose_step`].

use nalgebra::{Matrix2x3, Matrix2x6, Matrix3, Matrix6, Point2, Point3, Rotation3, UnitQuaternion, Vector3, Vector6};

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::error::{Error, Result};

/// Parameters of [`solve_pnp`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `max_iterations` | 30 | LM iteration cap ([`refine_pose`] alone also takes 0: no step) | >= 1 |
/// | `posit_iterations` | 20 | POSIT iteration cap for the initial guess | >= 1 |
/// | `rel_tol` | 1e-12 | stop when the cost decreases (or is predicted to) by less, relative | [0, 1) |
/// | `initial_damping` | 1e-3 | LM damping of the first step, relative to the Gauss-Newton diagonal | > 0 |
/// | `init` | `Epnp` | initialiser when no previous pose is given | [`PnpInit`] |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpParams {
    /// Levenberg-Marquardt iteration cap.
    pub max_iterations: usize,
    /// POSIT iteration cap.
    pub posit_iterations: usize,
    /// Relative cost decrease (actual, or predicted by the Gauss-Newton model) that stops.
    pub rel_tol: f64,
    /// Damping of the first LM step, relative to the Gauss-Newton diagonal.
    pub initial_damping: f64,
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
            rel_tol: LM_REL_TOL,
            initial_damping: LM_DAMPING0,
            init: PnpInit::Epnp,
        }
    }
}

impl PnpParams {
    /// Checks every field against the ranges of the table above.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the field.
    pub fn validate(&self) -> Result<()> {
        if self.max_iterations == 0 {
            return Err(Error::invalid("max_iterations", 0, ">= 1"));
        }
        if self.posit_iterations == 0 {
            return Err(Error::invalid("posit_iterations", 0, ">= 1"));
        }
        if !(0.0..1.0).contains(&self.rel_tol) {
            return Err(Error::invalid("rel_tol", self.rel_tol, "in [0, 1)"));
        }
        if !(self.initial_damping > 0.0 && self.initial_damping.is_finite()) {
            return Err(Error::invalid(
                "initial_damping",
                self.initial_damping,
                "finite and > 0",
            ));
        }
        Ok(())
    }
}

/// Why the refinement stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PnpStop {
    /// The cost decreased, or is predicted to decrease, by less than the tolerance.
    Converged,
    /// No damping gave a decrease (at a minimum up to rounding, or a degenerate problem).
    NoDecrease,
    /// The iteration cap was reached.
    MaxIterations,
}

/// Outcome of [`solve_pnp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpReport {
    /// LM iterations taken.
    pub iterations: usize,
    /// Final (weighted) RMS reprojection error in pixels: `sqrt(sum w r^2 / sum w)`.
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
    params.validate()?;
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

/// Initial Levenberg-Marquardt damping of [`PnpParams::default`] (relative to the
/// Gauss-Newton diagonal).
pub const LM_DAMPING0: f64 = 1e-3;
/// Relative cost decrease below which [`refine_pose`] has converged, by default.
pub const LM_REL_TOL: f64 = 1e-12;
/// Smallest depth taken for a point in front of the camera (model units); a point
/// nearer or behind is projected as if at this depth.
const MIN_DEPTH: f64 = 1e-9;
/// Damping increases tried per iteration before the refinement gives up.
const LM_TRIES: usize = 8;
/// Smallest diagonal entry the damping scales (keeps a zero column damped).
const MIN_DIAGONAL: f64 = 1e-12;
/// Bounds of the damping factor after an accepted step.
const MIN_DAMPING: f64 = 1e-12;

/// The pixel projection `pi(K X_c)` of a camera-space point `X_c = R X + t` and the
/// Jacobian of its two rows with respect to the pose increment `(w, dt)` of
/// [`apply_pose_step`] (`R <- exp([w]x) R`, `t <- t + dt`).
///
/// `rx` is `R X` (the rotated model point), `xc = rx + t`. With
/// `a = fx / z`, `b = -fx x / z^2`, `c = fy / z`, `d = -fy y / z^2` (depth clamped to
/// a small positive value), `d pi / d X_c = [[a, 0, b], [0, c, d]]` and
/// `d X_c / d w = -[R X]x`, `d X_c / d t = I`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointJacobian {
    /// Projected pixel `(u, v)`.
    pub pixel: [f64; 2],
    /// `d pi / d X_c`, rows u and v.
    pub d_point: [[f64; 3]; 2],
    /// `d pi / d (w, dt)`, rows u and v (6 columns: rotation vector, translation).
    pub d_pose: [[f64; 6]; 2],
}

impl PointJacobian {
    /// `d pi / d X_c` as a 2x3 matrix.
    pub fn d_point_matrix(&self) -> Matrix2x3<f64> {
        Matrix2x3::from_row_slice(&[
            self.d_point[0][0],
            self.d_point[0][1],
            self.d_point[0][2],
            self.d_point[1][0],
            self.d_point[1][1],
            self.d_point[1][2],
        ])
    }

    /// `d pi / d (w, dt)` as a 2x6 matrix.
    pub fn d_pose_matrix(&self) -> Matrix2x6<f64> {
        let [u, v] = &self.d_pose;
        Matrix2x6::from_row_slice(&[u[0], u[1], u[2], u[3], u[4], u[5], v[0], v[1], v[2], v[3], v[4], v[5]])
    }
}

/// See [`PointJacobian`].
#[inline]
pub fn point_jacobian(k: &Intrinsics, rx: &Vector3<f64>, xc: &Vector3<f64>) -> PointJacobian {
    let iz = 1.0 / xc.z.max(MIN_DEPTH);
    let (a, b) = (k.fx * iz, -k.fx * xc.x * iz * iz);
    let (c, d) = (k.fy * iz, -k.fy * xc.y * iz * iz);
    PointJacobian {
        pixel: [k.fx * xc.x * iz + k.cx, k.fy * xc.y * iz + k.cy],
        d_point: [[a, 0.0, b], [0.0, c, d]],
        d_pose: [
            [b * rx.y, a * rx.z - b * rx.x, -a * rx.y, a, 0.0, b],
            [-c * rx.z + d * rx.y, -d * rx.x, c * rx.x, 0.0, c, d],
        ],
    }
}

/// The pose after the increment `(w, dt)` scaled by `alpha`: `R <- exp([alpha w]x) R`,
/// `t <- t + alpha dt` (the parameterisation of [`point_jacobian`]).
#[inline]
pub fn apply_pose_step(pose: &ModelToCamera, step: &[f64; 6], alpha: f64) -> ModelToCamera {
    let dw = Vector3::new(step[0], step[1], step[2]) * alpha;
    let dt = Vector3::new(step[3], step[4], step[5]) * alpha;
    ModelToCamera(nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::from(pose.0.translation.vector + dt),
        UnitQuaternion::from_scaled_axis(dw) * pose.0.rotation,
    ))
}

fn check_weights(n: usize, image: usize, weights: Option<&[f64]>) -> Result<()> {
    if image != n {
        return Err(Error::dim("PnP image point count", n, image));
    }
    if let Some(w) = weights {
        if w.len() != n {
            return Err(Error::dim("PnP point weight count", n, w.len()));
        }
        if let Some(i) = w.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(
                "PnP point weight",
                format!("w[{i}] = {}", w[i]),
                "finite and >= 0",
            ));
        }
    }
    Ok(())
}

/// Levenberg-Marquardt refinement of `pose` in place on the (weighted) perspective
/// reprojection error `sum_i w_i || pi(K (R X_i + t)) - u_i ||^2` (pixels^2), with the
/// rotation updated multiplicatively ([`apply_pose_step`]) and the analytic Jacobian of
/// [`point_jacobian`]; fixed-size 6x6 normal equations, no heap allocation.
///
/// `weights`: one per point, `None` for all ones; a point with weight 0 is ignored (a lost
/// track). The damping starts at [`PnpParams::initial_damping`] times the Gauss-Newton
/// diagonal, is divided by 10 after an accepted step and multiplied by 10 after a
/// rejected one (at most eight tries per iteration).
///
/// Stops after [`PnpParams::max_iterations`] normal-equation passes, when an accepted
/// step decreased the cost by less than [`PnpParams::rel_tol`] relative (or moved less
/// than `1e-12`), when the quadratic model predicts a relative decrease below `rel_tol`
/// for the next step (a warm start at the optimum costs one pass, and does not move), or
/// when no damping gave a decrease ([`PnpStop::NoDecrease`]).
///
/// # Errors
/// [`Error::DimensionMismatch`] for unequal slice lengths; a negative or non-finite weight.
pub fn refine_pose(
    pose: &mut ModelToCamera,
    k: &Intrinsics,
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    weights: Option<&[f64]>,
    params: &PnpParams,
) -> Result<PnpReport> {
    check_weights(model.len(), image.len(), weights)?;
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    let wsum: f64 = (0..model.len()).map(&weight).filter(|w| *w > 0.0).sum();
    let rms = |sse: f64| if wsum > 0.0 { (sse / wsum).sqrt() } else { 0.0 };
    // The rotation as a matrix once per pose (9 multiplications per point instead of
    // the quaternion's ~30). The same arithmetic as the residuals of the normal-equations
    // pass below, so that the cost of the current pose can be taken from that pass.
    let cost = |pose: &ModelToCamera| {
        let rm = *pose.0.rotation.to_rotation_matrix().matrix();
        let t = pose.0.translation.vector;
        let mut e = 0.0;
        for (i, (p, x)) in model.iter().zip(image).enumerate() {
            let w = weight(i);
            if w > 0.0 {
                let xc = rm * p.coords + t;
                let iz = 1.0 / xc.z.max(MIN_DEPTH);
                let r0 = k.fx * xc.x * iz + k.cx - x.x;
                let r1 = k.fy * xc.y * iz + k.cy - x.y;
                e += w * (r0 * r0 + r1 * r1);
            }
        }
        e
    };
    let mut lambda = params.initial_damping;
    // Cost of `pose`: from the first normal-equations pass, then from the accepted candidates.
    let mut cur = if params.max_iterations == 0 {
        cost(pose)
    } else {
        f64::NAN
    };
    let mut it = 0;
    let report = |iterations: usize, sse: f64, stop: PnpStop| PnpReport {
        iterations,
        rms_px: rms(sse),
        stop,
    };
    while it < params.max_iterations {
        it += 1;
        // Upper triangle of J^T W J (6 x 6, 21 entries) and J^T W r.
        let rm = *pose.0.rotation.to_rotation_matrix().matrix();
        let tv = pose.0.translation.vector;
        let mut hu = [0.0f64; 21];
        let mut gv = [0.0f64; 6];
        let mut e = 0.0;
        for (i, (p, x)) in model.iter().zip(image).enumerate() {
            let w = weight(i);
            if w <= 0.0 {
                continue;
            }
            let rp = rm * p.coords;
            let xc = rp + tv;
            let jac = point_jacobian(k, &rp, &xc);
            let r0 = jac.pixel[0] - x.x;
            let r1 = jac.pixel[1] - x.y;
            e += w * (r0 * r0 + r1 * r1);
            let [j0, j1] = &jac.d_pose;
            let mut q = 0;
            for pi in 0..6 {
                let (u0, u1) = (w * j0[pi], w * j1[pi]);
                for pj in pi..6 {
                    hu[q] += u0 * j0[pj] + u1 * j1[pj];
                    q += 1;
                }
                gv[pi] += u0 * r0 + u1 * r1;
            }
        }
        let mut h = Matrix6::<f64>::zeros();
        let mut q = 0;
        for pi in 0..6 {
            for pj in pi..6 {
                h[(pi, pj)] = hu[q];
                h[(pj, pi)] = hu[q];
                q += 1;
            }
        }
        if it == 1 {
            cur = e;
        }
        let g = Vector6::from_column_slice(&gv);
        let mut improved = false;
        for _ in 0..LM_TRIES {
            let mut hd = h;
            for d in 0..6 {
                hd[(d, d)] += lambda * h[(d, d)].max(MIN_DIAGONAL);
            }
            let Some(step) = hd.cholesky().map(|c| c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            // Converged when even the quadratic model predicts a negligible decrease
            // (the candidate's cost would only show rounding noise).
            let predicted = -g.dot(&step) - 0.5 * step.dot(&(h * step));
            if predicted <= params.rel_tol * cur {
                return Ok(report(it, cur, PnpStop::Converged));
            }
            let cand = apply_pose_step(pose, &step.into(), 1.0);
            let c = cost(&cand);
            if c <= cur {
                let rel = (cur - c) / cur.max(1e-300);
                *pose = cand;
                cur = c;
                lambda = (lambda * 0.1).max(MIN_DAMPING);
                improved = true;
                if rel < params.rel_tol || step.norm() < 1e-12 {
                    return Ok(report(it, cur, PnpStop::Converged));
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            return Ok(report(it, cur, PnpStop::NoDecrease));
        }
    }
    Ok(report(it, cur, PnpStop::MaxIterations))
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
    let report = refine_pose(&mut pose, k, model, image, None, params)?;
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
    fn weights_of_one_are_the_unweighted_refinement_and_zero_ignores_a_point() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let k = Intrinsics::new(700.0, 700.0, 320.0, 240.0).unwrap();
        let model = face_like_points(&mut rng);
        let truth = ModelToCamera::from_rvec_tvec(Vector3::new(-0.1, 0.3, 0.05), Vector3::new(-1.0, 2.0, 55.0));
        let mut image: Vec<_> = model
            .iter()
            .map(|m| {
                let p = truth.project(&k, m).unwrap();
                Point2::new(p.x + rng.random_range(-0.5..0.5), p.y + rng.random_range(-0.5..0.5))
            })
            .collect();
        let start = ModelToCamera::from_rvec_tvec(Vector3::new(0.0, 0.2, 0.0), Vector3::new(0.0, 0.0, 50.0));
        let params = PnpParams::default();
        let (mut a, mut b) = (start, start);
        let ra = refine_pose(&mut a, &k, &model, &image, None, &params).unwrap();
        let rb = refine_pose(&mut b, &k, &model, &image, Some(&vec![1.0; model.len()]), &params).unwrap();
        assert_eq!(a, b);
        assert_eq!(ra, rb);
        assert_eq!(ra.stop, PnpStop::Converged);
        // A gross outlier with weight 0 leaves the pose of the other points.
        let mut w = vec![1.0; model.len()];
        w[10] = 0.0;
        let mut without = start;
        let mut rest_model = model.clone();
        let mut rest_image = image.clone();
        rest_model.remove(10);
        rest_image.remove(10);
        refine_pose(&mut without, &k, &rest_model, &rest_image, None, &params).unwrap();
        image[10].x += 400.0;
        let mut masked = start;
        refine_pose(&mut masked, &k, &model, &image, Some(&w), &params).unwrap();
        assert!((masked.tvec() - without.tvec()).norm() < 1e-9);
        assert!((masked.rvec() - without.rvec()).norm() < 1e-10);
        // Bad weights are errors, not panics.
        assert!(refine_pose(&mut masked, &k, &model, &image, Some(&w[1..]), &params).is_err());
        w[3] = f64::NAN;
        assert!(refine_pose(&mut masked, &k, &model, &image, Some(&w), &params).is_err());
    }

    #[test]
    fn point_jacobian_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let k = Intrinsics::new(640.0, 600.0, 320.0, 240.0).unwrap();
        let pose = ModelToCamera::from_rvec_tvec(Vector3::new(0.2, -0.4, 0.1), Vector3::new(2.0, -1.0, 40.0));
        for m in face_like_points_n(&mut rng, 10) {
            let rx = pose.0.rotation * m.coords;
            let xc = rx + pose.0.translation.vector;
            let jac = point_jacobian(&k, &rx, &xc);
            let p = pose.project(&k, &m).unwrap();
            assert!((jac.pixel[0] - p.x).abs() < 1e-9 && (jac.pixel[1] - p.y).abs() < 1e-9);
            for c in 0..6 {
                let h = 1e-6;
                let mut step = [0.0; 6];
                step[c] = h;
                let plus = apply_pose_step(&pose, &step, 1.0).project(&k, &m).unwrap();
                let minus = apply_pose_step(&pose, &step, -1.0).project(&k, &m).unwrap();
                let fd = (plus - minus) / (2.0 * h);
                let scale = 1.0 + fd.norm();
                assert!((fd.x - jac.d_pose[0][c]).abs() < 1e-5 * scale, "u col {c}");
                assert!((fd.y - jac.d_pose[1][c]).abs() < 1e-5 * scale, "v col {c}");
            }
        }
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
