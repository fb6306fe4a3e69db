//! EPnP: a closed-form, O(n) perspective-n-point initialiser.
//!
//! Lepetit, Moreno-Noguer & Fua, "EPnP: An Accurate O(n) Solution to the PnP Problem",
//! IJCV 81(2), 2009. Every model point is written as a barycentric combination of four
//! control points, `X_i = sum_j a_ij C_j` (`sum_j a_ij = 1`), which also holds in camera
//! space. Each pixel `u_i` gives two linear equations in the 12 unknown camera-space
//! control-point coordinates:
//!
//! ```text
//! sum_j a_ij (fx Cx_j + (cx - u_i) Cz_j) = 0
//! sum_j a_ij (fy Cy_j + (cy - v_i) Cz_j) = 0
//! ```
//!
//! i.e. `M x = 0` with `M` of size `2n x 12`. The solution lies in the span of the
//! right-singular vectors of `M` with the smallest singular values, `x = sum_k b_k v_k`
//! (`k < N`, `N = 1..4`); the `b_k` are fixed by requiring that the six distances between
//! control points equal their model-space values (the 6 x 10 system `L b = rho` in the
//! products `b_k b_l`), approximated linearly for N = 2, 3 and 4 and then refined by four
//! Gauss-Newton steps. The camera-space points give the pose by rigid (no-scale) Umeyama
//! alignment; of the three candidates, the one with the smallest reprojection error wins.
//!
//! Control points: the centroid of the model points and the centroid plus the principal
//! axes scaled by the RMS spread along them (the paper's choice); planar models (a zero
//! spread) are rejected as degenerate, since [`crate::pnp::solve_pnp`] targets faces.
//!
//! Cost: one 12 x 12 symmetric eigen-decomposition plus O(n) work; no iteration over
//! the points beyond building `M^T M` (accumulated directly, `M` is never stored).

use nalgebra::{Matrix3, Point2, Point3, SMatrix, SVector, Vector3};

use crate::align::umeyama3;
use crate::pnp::reprojection_sse;
use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::error::{Error, Result};

type Matrix12 = SMatrix<f64, 12, 12>;
type Vector12 = SVector<f64, 12>;
type Matrix6x10 = SMatrix<f64, 6, 10>;
type Vector6 = SVector<f64, 6>;

/// Pairs of control points whose distances fix the scale (`rho` ordering).
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// EPnP pose of `model` seen at pixels `image` through `k` (see the module docs).
///
/// Needs at least 4 non-coplanar points (faces' 68 landmarks are). The result is a
/// closed-form estimate: refine it with [`crate::pnp::refine_pose`] when the points are
/// noisy ([`crate::pnp::solve_pnp`] does both).
///
/// # Errors
/// Mismatched lengths, fewer than 4 points, non-finite input, a planar or degenerate
/// model, or no candidate pose with the points in front of the camera.
pub fn epnp(model: &[Point3<f64>], image: &[Point2<f64>], k: &Intrinsics) -> Result<ModelToCamera> {
    if model.len() != image.len() {
        return Err(Error::DimensionMismatch {
            what: "EPnP point count".into(),
            expected: model.len(),
            got: image.len(),
        });
    }
    if model.len() < 4 {
        return Err(Error::invalid("EPnP point count", model.len(), ">= 4"));
    }
    for (i, (m, u)) in model.iter().zip(image).enumerate() {
        if !(m.coords.iter().all(|v| v.is_finite()) && u.coords.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid("EPnP point", format!("point {i}"), "finite coordinates"));
        }
    }
    let degenerate = || Error::Numerical {
        operation: "epnp",
        reason: "model points are coplanar or coincident".into(),
    };

    // Control points: centroid + principal axes scaled by the RMS spread.
    let n = model.len() as f64;
    let c0 = model.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut cov = Matrix3::zeros();
    for p in model {
        let d = p.coords - c0;
        cov += d * d.transpose();
    }
    cov /= n;
    let eig = cov.symmetric_eigen();
    let scale = eig.eigenvalues.amax();
    if scale.is_nan() || scale <= 0.0 {
        return Err(degenerate());
    }
    let mut ctrl = [c0; 4];
    let mut basis = Matrix3::zeros();
    for a in 0..3 {
        let lambda = eig.eigenvalues[a];
        if lambda.is_nan() || lambda <= 1e-12 * scale {
            return Err(degenerate());
        }
        let axis = eig.eigenvectors.column(a) * lambda.sqrt();
        ctrl[a + 1] = c0 + axis;
        basis.set_column(a, &axis);
    }
    let Some(basis_inv) = basis.try_inverse() else {
        return Err(degenerate());
    };

    // Barycentric coordinates and M^T M accumulated row pair by row pair.
    let mut alphas: Vec<[f64; 4]> = Vec::with_capacity(model.len());
    let mut mtm = Matrix12::zeros();
    for (p, u) in model.iter().zip(image) {
        let b = basis_inv * (p.coords - c0);
        let a = [1.0 - b.x - b.y - b.z, b.x, b.y, b.z];
        alphas.push(a);
        let mut r1 = Vector12::zeros();
        let mut r2 = Vector12::zeros();
        for j in 0..4 {
            r1[3 * j] = a[j] * k.fx;
            r1[3 * j + 2] = a[j] * (k.cx - u.x);
            r2[3 * j + 1] = a[j] * k.fy;
            r2[3 * j + 2] = a[j] * (k.cy - u.y);
        }
        mtm += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = mtm.symmetric_eigen();
    let mut order: [usize; 12] = std::array::from_fn(|i| i);
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // v[0] belongs to the smallest eigenvalue.
    let v: [Vector12; 4] = std::array::from_fn(|i| eig.eigenvectors.column(order[i]).into_owned());

    let l = compute_l(&v);
    let mut rho = Vector6::zeros();
    for (r, &(a, b)) in PAIRS.iter().enumerate() {
        rho[r] = (ctrl[a] - ctrl[b]).norm_squared();
    }

    let mut best: Option<(f64, ModelToCamera)> = None;
    for approx in [betas_n4(&l, &rho), betas_n2(&l, &rho), betas_n3(&l, &rho)] {
        let Some(mut betas) = approx else { continue };
        gauss_newton(&l, &rho, &mut betas);
        let Some(pose) = pose_from_betas(&v, &betas, &alphas, model) else {
            continue;
        };
        let err = reprojection_sse(&pose, k, model, image);
        if err.is_finite() && best.as_ref().map_or(true, |(e, _)| err < *e) {
            best = Some((err, pose));
        }
    }
    best.map(|(_, p)| p).ok_or_else(|| Error::Numerical {
        operation: "epnp",
        reason: "no candidate pose has the points in front of the camera".into(),
    })
}

/// The 6 x 10 matrix of distance constraints in the products
/// `[b11, b12, b22, b13, b23, b33, b14, b24, b34, b44]`.
fn compute_l(v: &[Vector12; 4]) -> Matrix6x10 {
    let mut l = Matrix6x10::zeros();
    for (r, &(a, b)) in PAIRS.iter().enumerate() {
        let d: [Vector3<f64>; 4] = std::array::from_fn(|i| {
            Vector3::new(
                v[i][3 * a] - v[i][3 * b],
                v[i][3 * a + 1] - v[i][3 * b + 1],
                v[i][3 * a + 2] - v[i][3 * b + 2],
            )
        });
        let row = [
            d[0].dot(&d[0]),
            2.0 * d[0].dot(&d[1]),
            d[1].dot(&d[1]),
            2.0 * d[0].dot(&d[2]),
            2.0 * d[1].dot(&d[2]),
            d[2].dot(&d[2]),
            2.0 * d[0].dot(&d[3]),
            2.0 * d[1].dot(&d[3]),
            2.0 * d[2].dot(&d[3]),
            d[3].dot(&d[3]),
        ];
        for (c, x) in row.into_iter().enumerate() {
            l[(r, c)] = x;
        }
    }
    l
}

/// Least-squares solution of the 6 x C system made of the given columns of `l`.
fn lsq_columns<const C: usize>(l: &Matrix6x10, cols: [usize; C], rho: &Vector6) -> Option<[f64; C]> {
    let a = nalgebra::DMatrix::from_fn(6, C, |r, j| l[(r, cols[j])]);
    let b = nalgebra::DVector::from_column_slice(rho.as_slice());
    let x = a.svd(true, true).solve(&b, 1e-12).ok()?;
    let out: [f64; C] = std::array::from_fn(|i| x[i]);
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// N = 4: `[b11, b12, b13, b14]` linearly.
fn betas_n4(l: &Matrix6x10, rho: &Vector6) -> Option<[f64; 4]> {
    let b = lsq_columns(l, [0, 1, 3, 6], rho)?;
    let b0 = b[0].abs().sqrt();
    if b0 == 0.0 {
        return None;
    }
    let s = if b[0] < 0.0 { -1.0 } else { 1.0 };
    Some([b0, s * b[1] / b0, s * b[2] / b0, s * b[3] / b0])
}

/// `(b1, b2)` from the linear estimates of `b11`, `b12`, `b22` (N = 2 and N = 3 cases).
fn leading_betas(b11: f64, b12: f64, b22: f64) -> (f64, f64) {
    let (b0, b1) = if b11 < 0.0 {
        ((-b11).sqrt(), if b22 < 0.0 { (-b22).sqrt() } else { 0.0 })
    } else {
        (b11.sqrt(), if b22 > 0.0 { b22.sqrt() } else { 0.0 })
    };
    (if b12 < 0.0 { -b0 } else { b0 }, b1)
}

/// N = 2: `[b11, b12, b22]` linearly.
fn betas_n2(l: &Matrix6x10, rho: &Vector6) -> Option<[f64; 4]> {
    let b = lsq_columns(l, [0, 1, 2], rho)?;
    let (b0, b1) = leading_betas(b[0], b[1], b[2]);
    Some([b0, b1, 0.0, 0.0])
}

/// N = 3: `[b11, b12, b22, b13, b23]` linearly.
fn betas_n3(l: &Matrix6x10, rho: &Vector6) -> Option<[f64; 4]> {
    let b = lsq_columns(l, [0, 1, 2, 3, 4], rho)?;
    let (b0, b1) = leading_betas(b[0], b[1], b[2]);
    if b0 == 0.0 {
        return None;
    }
    Some([b0, b1, b[3] / b0, 0.0])
}

/// Gauss-Newton on the four betas for the distance constraints `L b = rho`.
fn gauss_newton(l: &Matrix6x10, rho: &Vector6, betas: &mut [f64; 4]) {
    for _ in 0..4 {
        let b = *betas;
        let mut a = SMatrix::<f64, 6, 4>::zeros();
        let mut r = Vector6::zeros();
        for i in 0..6 {
            let q = |c: usize| l[(i, c)];
            a[(i, 0)] = 2.0 * q(0) * b[0] + q(1) * b[1] + q(3) * b[2] + q(6) * b[3];
            a[(i, 1)] = q(1) * b[0] + 2.0 * q(2) * b[1] + q(4) * b[2] + q(7) * b[3];
            a[(i, 2)] = q(3) * b[0] + q(4) * b[1] + 2.0 * q(5) * b[2] + q(8) * b[3];
            a[(i, 3)] = q(6) * b[0] + q(7) * b[1] + q(8) * b[2] + 2.0 * q(9) * b[3];
            let model = q(0) * b[0] * b[0]
                + q(1) * b[0] * b[1]
                + q(2) * b[1] * b[1]
                + q(3) * b[0] * b[2]
                + q(4) * b[1] * b[2]
                + q(5) * b[2] * b[2]
                + q(6) * b[0] * b[3]
                + q(7) * b[1] * b[3]
                + q(8) * b[2] * b[3]
                + q(9) * b[3] * b[3];
            r[i] = rho[i] - model;
        }
        let Ok(dx) = a.svd(true, true).solve(&r, 1e-12) else {
            return;
        };
        if !dx.iter().all(|v| v.is_finite()) {
            return;
        }
        for (bk, d) in betas.iter_mut().zip(dx.iter()) {
            *bk += d;
        }
    }
}

/// Camera-space points from the betas, sign fixed so the points are in front, then the
/// rigid alignment model -> camera.
fn pose_from_betas(
    v: &[Vector12; 4],
    betas: &[f64; 4],
    alphas: &[[f64; 4]],
    model: &[Point3<f64>],
) -> Option<ModelToCamera> {
    let mut x = Vector12::zeros();
    for (vk, b) in v.iter().zip(betas) {
        x += vk * *b;
    }
    let ctrl: [Vector3<f64>; 4] = std::array::from_fn(|j| Vector3::new(x[3 * j], x[3 * j + 1], x[3 * j + 2]));
    let mut cam: Vec<Point3<f64>> = alphas
        .iter()
        .map(|a| Point3::from(ctrl[0] * a[0] + ctrl[1] * a[1] + ctrl[2] * a[2] + ctrl[3] * a[3]))
        .collect();
    let mean_z = cam.iter().map(|p| p.z).sum::<f64>() / cam.len() as f64;
    if mean_z < 0.0 {
        for p in &mut cam {
            p.coords = -p.coords;
        }
    }
    let sim = umeyama3(model, &cam, None, false).ok()?;
    let rot = nalgebra::Rotation3::from_matrix_unchecked(sim.rotation);
    let iso = nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::from(sim.translation),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    );
    iso.translation
        .vector
        .iter()
        .all(|t| t.is_finite())
        .then_some(ModelToCamera(iso))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn face_like_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Point3<f64>> {
        crate::pnp::tests::face_like_points_n(rng, n)
    }

    #[test]
    fn exact_on_noise_free_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let k = Intrinsics::new(640.0, 630.0, 320.0, 240.0).unwrap();
        for n in [6, 12, 68] {
            for _ in 0..25 {
                let model = face_like_points(&mut rng, n);
                let rvec = Vector3::new(
                    rng.random_range(-0.35..0.35),
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.3..0.3),
                );
                let tvec = Vector3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(30.0..90.0),
                );
                let truth = ModelToCamera::from_rvec_tvec(rvec, tvec);
                let image: Vec<Point2<f64>> = model.iter().map(|m| truth.project(&k, m).unwrap()).collect();
                let pose = epnp(&model, &image, &k).unwrap();
                let dr = (pose.0.rotation.inverse() * truth.0.rotation).angle();
                let dt = (pose.tvec() - tvec).norm();
                assert!(dr < 1e-6, "n={n} rotation error {dr}");
                assert!(dt < 1e-5 * tvec.norm(), "n={n} translation error {dt}");
            }
        }
    }

    #[test]
    fn close_under_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let k = Intrinsics::new(640.0, 640.0, 320.0, 240.0).unwrap();
        for _ in 0..25 {
            let model = face_like_points(&mut rng, 68);
            let truth = ModelToCamera::from_rvec_tvec(Vector3::new(0.1, -0.3, 0.05), Vector3::new(1.0, -0.5, 50.0));
            let image: Vec<Point2<f64>> = model
                .iter()
                .map(|m| {
                    let p = truth.project(&k, m).unwrap();
                    Point2::new(p.x + rng.random_range(-1.0..1.0), p.y + rng.random_range(-1.0..1.0))
                })
                .collect();
            let pose = epnp(&model, &image, &k).unwrap();
            let dr = (pose.0.rotation.inverse() * truth.0.rotation).angle();
            assert!(dr < 0.05, "rotation error {dr} rad");
            let rms = (reprojection_sse(&pose, &k, &model, &image) / 68.0).sqrt();
            assert!(rms < 3.0, "rms {rms}");
        }
    }

    #[test]
    fn rejects_bad_input() {
        let k = Intrinsics::new(500.0, 500.0, 0.0, 0.0).unwrap();
        let m = vec![Point3::new(0.0, 0.0, 0.0); 3];
        let u = vec![Point2::new(0.0, 0.0); 3];
        assert!(epnp(&m, &u, &k).is_err());
        let m = vec![Point3::new(0.0, 0.0, 0.0); 5];
        assert!(epnp(&m, &u, &k).is_err());
        let u5 = vec![Point2::new(0.0, 0.0); 5];
        assert!(epnp(&m, &u5, &k).is_err(), "coincident points");
        let planar: Vec<Point3<f64>> = (0..8).map(|i| Point3::new(i as f64, (i * i) as f64, 0.0)).collect();
        let u8 = vec![Point2::new(1.0, 2.0); 8];
        assert!(epnp(&planar, &u8, &k).is_err(), "planar model");
        let mut bad = face_like_points(&mut ChaCha8Rng::seed_from_u64(1), 8);
        bad[3].x = f64::NAN;
        assert!(epnp(&bad, &u8, &k).is_err());
    }
}
