//! Rigid pose from 3D model points and their 2D images (PnP), allocation-free.
//!
//! A temporary solver of this crate until `facecap_geom::pnp` lands: a scaled
//! orthographic (weak-perspective) initialisation by linear least squares, as in
//! POSIT's first step (DeMenthon & Davis 1995), then Levenberg-Marquardt on the full
//! perspective reprojection error in pixels with the rotation updated
//! multiplicatively (`R <- exp([w]x) R`).
//!
//! Conventions: [`ModelToCamera`] maps model to camera space (`X_c = R X_m + t`),
//! camera +Z forward, pixels 0-based (see `facecap_core::camera`). Points with weight
//! 0 are ignored (lost tracks).

use facecap_core::camera::{Intrinsics, ModelToCamera};
use nalgebra::{
    Isometry3, Matrix2x3, Matrix3, Matrix6, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

use facecap_core::error::{Error, Result};

/// Initial Levenberg-Marquardt damping (relative to the Gauss-Newton diagonal).
const LM_LAMBDA0: f64 = 1e-3;
/// Relative cost decrease below which the refinement has converged (actual or
/// predicted by the Gauss-Newton model).
const LM_REL_TOL: f64 = 1e-12;
/// Smallest depth accepted for a point in front of the camera (model units).
const MIN_DEPTH: f64 = 1e-9;

/// Scaled-orthographic pose from weighted correspondences.
///
/// # Errors
/// [`Error::Numerical`] when fewer than 4 weighted points are given or the points are
/// degenerate (collinear); [`Error::DimensionMismatch`] for unequal slice lengths.
pub fn init_scaled_orthographic(
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    weights: &[f64],
    k: &Intrinsics,
) -> Result<ModelToCamera> {
    check(model, image, weights)?;
    let mut sw = 0.0;
    let mut pm = Vector3::zeros();
    let mut um = nalgebra::Vector2::zeros();
    let mut used = 0;
    for ((p, x), &w) in model.iter().zip(image).zip(weights) {
        if w > 0.0 {
            sw += w;
            pm += w * p.coords;
            um += w * nalgebra::Vector2::new((x.x - k.cx) / k.fx, (x.y - k.cy) / k.fy);
            used += 1;
        }
    }
    if used < 4 || sw <= 0.0 {
        return Err(Error::Numerical {
            operation: "pose init",
            reason: format!("{used} weighted points, need >= 4"),
        });
    }
    pm /= sw;
    um /= sw;
    let mut c = Matrix3::zeros();
    let mut b = Matrix2x3::zeros();
    for ((p, x), &w) in model.iter().zip(image).zip(weights) {
        if w > 0.0 {
            let dp = p.coords - pm;
            let du = nalgebra::Vector2::new((x.x - k.cx) / k.fx, (x.y - k.cy) / k.fy) - um;
            c += w * dp * dp.transpose();
            b += w * du * dp.transpose();
        }
    }
    // Tiny ridge for nearly planar point sets.
    let ridge = 1e-12 * c.trace().max(1e-300);
    let cinv = (c + Matrix3::identity() * ridge)
        .try_inverse()
        .ok_or_else(|| Error::Numerical {
            operation: "pose init",
            reason: "model points are degenerate".into(),
        })?;
    let m = b * cinv;
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(Error::Numerical {
            operation: "pose init",
            reason: "SVD failed".into(),
        });
    };
    let s = 0.5 * (svd.singular_values[0] + svd.singular_values[1]);
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::Numerical {
            operation: "pose init",
            reason: "points are degenerate (zero scale)".into(),
        });
    }
    let r2 = u * vt; // 2x3 with orthonormal rows
    let r1v = Vector3::new(r2[(0, 0)], r2[(0, 1)], r2[(0, 2)]);
    let r2v = Vector3::new(r2[(1, 0)], r2[(1, 1)], r2[(1, 2)]);
    let r3v = r1v.cross(&r2v);
    let rot = Matrix3::from_rows(&[r1v.transpose(), r2v.transpose(), r3v.transpose()]);
    let rot = Rotation3::from_matrix(&rot);
    let rp = rot * pm;
    let tz = 1.0 / s;
    let t = Vector3::new(um.x * tz - rp.x, um.y * tz - rp.y, tz - rp.z);
    Ok(ModelToCamera(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&rot),
    )))
}

/// Weighted RMS reprojection error (pixels) of `pose`.
pub fn reprojection_rms(
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    weights: &[f64],
    k: &Intrinsics,
    pose: &ModelToCamera,
) -> f64 {
    let (mut e, mut sw) = (0.0, 0.0);
    for ((p, x), &w) in model.iter().zip(image).zip(weights) {
        if w > 0.0 {
            let xc = pose.transform(p);
            let z = xc.z.max(MIN_DEPTH);
            let r = nalgebra::Vector2::new(k.fx * xc.x / z + k.cx - x.x, k.fy * xc.y / z + k.cy - x.y);
            e += w * r.norm_squared();
            sw += w;
        }
    }
    if sw > 0.0 {
        (e / sw).sqrt()
    } else {
        0.0
    }
}

/// Levenberg-Marquardt refinement of `pose` on the perspective reprojection error.
/// Returns the number of iterations done (normal-equation passes over the points).
///
/// Stops after `max_iter` iterations, when an accepted step decreased the cost by less
/// than `1e-12` relative (or moved less than `1e-12`), when the quadratic model predicts a
/// relative decrease below `1e-12` for the next step (a warm start at the optimum costs
/// one pass), or when no damping in eight tries gave a decrease.
///
/// # Errors
/// [`Error::DimensionMismatch`] for unequal slice lengths.
pub fn refine_perspective(
    model: &[Point3<f64>],
    image: &[Point2<f64>],
    weights: &[f64],
    k: &Intrinsics,
    pose: &mut ModelToCamera,
    max_iter: usize,
) -> Result<usize> {
    check(model, image, weights)?;
    // The rotation as a matrix once per pose (9 multiplications per point instead of
    // the quaternion's ~30).
    // The same arithmetic as the residuals of the normal-equations pass below, so that
    // the cost of the current pose can be taken from that pass.
    let cost = |pose: &ModelToCamera| {
        let rm = *pose.0.rotation.to_rotation_matrix().matrix();
        let t = pose.0.translation.vector;
        let mut e = 0.0;
        for ((p, x), &w) in model.iter().zip(image).zip(weights) {
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
    let mut lambda = LM_LAMBDA0;
    // Cost of `pose`: from the first normal-equations pass, then from the accepted candidates.
    let mut cur = f64::NAN;
    let mut it = 0;
    while it < max_iter {
        it += 1;
        // Upper triangle of J^T W J (6 x 6, 21 entries) and J^T W r, with the two
        // Jacobian rows written out: J = [dpi * (-[R p]x) | dpi], dpi = d pixel / d X_c.
        let rm = *pose.0.rotation.to_rotation_matrix().matrix();
        let tv = pose.0.translation.vector;
        let mut hu = [0.0f64; 21];
        let mut gv = [0.0f64; 6];
        let mut e = 0.0;
        for ((p, x), &w) in model.iter().zip(image).zip(weights) {
            if w <= 0.0 {
                continue;
            }
            let rp = rm * p.coords;
            let xc = rp + tv;
            let z = xc.z.max(MIN_DEPTH);
            let iz = 1.0 / z;
            let r0 = k.fx * xc.x * iz + k.cx - x.x;
            let r1 = k.fy * xc.y * iz + k.cy - x.y;
            e += w * (r0 * r0 + r1 * r1);
            let (a, b) = (k.fx * iz, -k.fx * xc.x * iz * iz);
            let (c, d) = (k.fy * iz, -k.fy * xc.y * iz * iz);
            let j0 = [b * rp.y, a * rp.z - b * rp.x, -a * rp.y, a, 0.0, b];
            let j1 = [-c * rp.z + d * rp.y, -d * rp.x, c * rp.x, 0.0, c, d];
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
        for _ in 0..8 {
            let mut hd = h;
            for d in 0..6 {
                hd[(d, d)] += lambda * h[(d, d)].max(1e-12);
            }
            let Some(step) = hd.cholesky().map(|c| c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            // Converged when even the quadratic model predicts a negligible decrease
            // (the candidate's cost would only show rounding noise).
            let predicted = -g.dot(&step) - 0.5 * step.dot(&(h * step));
            if predicted <= LM_REL_TOL * cur {
                return Ok(it);
            }
            let dw = Vector3::new(step[0], step[1], step[2]);
            let dt = Vector3::new(step[3], step[4], step[5]);
            let cand = ModelToCamera(Isometry3::from_parts(
                Translation3::from(pose.0.translation.vector + dt),
                UnitQuaternion::from_scaled_axis(dw) * pose.0.rotation,
            ));
            let c = cost(&cand);
            if c <= cur {
                let rel = (cur - c) / cur.max(1e-300);
                *pose = cand;
                cur = c;
                lambda = (lambda * 0.1).max(1e-12);
                improved = true;
                if rel < LM_REL_TOL || step.norm() < 1e-12 {
                    return Ok(it);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    Ok(it)
}

fn check(model: &[Point3<f64>], image: &[Point2<f64>], weights: &[f64]) -> Result<()> {
    if image.len() != model.len() {
        return Err(Error::dim("image point count", model.len(), image.len()));
    }
    if weights.len() != model.len() {
        return Err(Error::dim("point weight count", model.len(), weights.len()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn recovers_a_random_pose() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let k = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap_or_else(|_| unreachable!());
        let model: Vec<Point3<f64>> = (0..68)
            .map(|_| {
                Point3::new(
                    rng.random_range(-7.0..7.0),
                    rng.random_range(-9.0..9.0),
                    rng.random_range(-3.0..3.0),
                )
            })
            .collect();
        let truth = ModelToCamera::from_rvec_tvec(Vector3::new(0.2, -0.3, 0.1), Vector3::new(1.0, -2.0, 60.0));
        let image: Vec<Point2<f64>> = model
            .iter()
            .map(|p| truth.project(&k, p).unwrap_or(Point2::origin()))
            .collect();
        let w = vec![1.0; 68];
        let mut pose = init_scaled_orthographic(&model, &image, &w, &k).unwrap_or_else(|_| unreachable!());
        refine_perspective(&model, &image, &w, &k, &mut pose, 30).unwrap_or_else(|_| unreachable!());
        assert!(reprojection_rms(&model, &image, &w, &k, &pose) < 1e-6);
        assert!((pose.tvec() - truth.tvec()).norm() < 1e-6);

        // Noisy points (a non-zero optimum): started at its own optimum the refinement
        // stops after one normal-equations pass without moving (the predicted decrease
        // is rounding noise), and it does not stop there when started elsewhere.
        let noisy: Vec<Point2<f64>> = image
            .iter()
            .map(|x| Point2::new(x.x + rng.random_range(-2.0..2.0), x.y + rng.random_range(-2.0..2.0)))
            .collect();
        let mut opt = pose;
        let its = refine_perspective(&model, &noisy, &w, &k, &mut opt, 30).unwrap_or_else(|_| unreachable!());
        assert!(its > 1, "{its}");
        let mut again = opt;
        let its = refine_perspective(&model, &noisy, &w, &k, &mut again, 30).unwrap_or_else(|_| unreachable!());
        assert_eq!(its, 1);
        assert_eq!(again, opt);
        assert!(reprojection_rms(&model, &noisy, &w, &k, &opt) < 2.0);
    }
}
