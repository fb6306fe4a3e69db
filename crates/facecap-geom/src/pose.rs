//! Weighted scaled-orthographic pose start and weighted reprojection error,
//! allocation-free (the tensor fit's pose step; the refinement is
//! [`crate::pnp::refine_pose`]).
//!
//! [`init_scaled_orthographic`] is POSIT's first step (DeMenthon & Davis 1995) with
//! weights, solved by linear least squares and an SVD re-orthonormalisation; the
//! perspective refinement that follows is the workspace's one Levenberg-Marquardt pose
//! refinement, [`crate::pnp::refine_pose`].
//!
//! Conventions: [`ModelToCamera`] maps model to camera space (`X_c = R X_m + t`),
//! camera +Z forward, pixels 0-based (see `facecap_core::camera`). Points with weight
//! 0 are ignored (lost tracks).

use facecap_core::camera::{Intrinsics, ModelToCamera};
use nalgebra::{Isometry3, Matrix2x3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use facecap_core::error::{Error, Result};

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
    use crate::pnp::{refine_pose, PnpParams};
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
        let params = PnpParams::default();
        refine_pose(&mut pose, &k, &model, &image, Some(&w), &params).unwrap_or_else(|_| unreachable!());
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
        let its = refine_pose(&mut opt, &k, &model, &noisy, Some(&w), &params)
            .unwrap_or_else(|_| unreachable!())
            .iterations;
        assert!(its > 1, "{its}");
        let mut again = opt;
        let its = refine_pose(&mut again, &k, &model, &noisy, Some(&w), &params)
            .unwrap_or_else(|_| unreachable!())
            .iterations;
        assert_eq!(its, 1);
        assert_eq!(again, opt);
        assert!(reprojection_rms(&model, &noisy, &w, &k, &opt) < 2.0);
    }
}
