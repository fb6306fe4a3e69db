//! Similarity and rigid alignment of point sets (Umeyama 1991).
//!
//! Given corresponding points `x_i` (source) and `y_i` (target), finds scale `s`,
//! rotation `R` (det = +1) and translation `t` minimising
//! `sum_i w_i || y_i - (s R x_i + t) ||^2`.
//!
//! With centred sets `X`, `Y` (columns `x_i - mu_x`, `y_i - mu_y`), covariance
//! `Sigma = Y W X^T / sum(w)`, SVD `Sigma = U D V^T` and `S = diag(1, .., det(U V^T))`:
//! `R = U S V^T`, `s = tr(D S) / sigma_x^2`, `t = mu_y - s R mu_x`.
//! Reference: S. Umeyama, "Least-squares estimation of transformation parameters
//! between two point patterns", IEEE PAMI 13(4), 1991.

use nalgebra::{Matrix2, Matrix3, Point, Point2, Point3, SMatrix, SVector, Vector2, Vector3};

use facecap_core::error::{Error, Result};

/// A 2D similarity `y = s R x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity2 {
    /// Uniform scale (> 0).
    pub scale: f64,
    /// Rotation matrix (det +1).
    pub rotation: Matrix2<f64>,
    /// Translation.
    pub translation: Vector2<f64>,
}

impl Similarity2 {
    /// The identity transform.
    pub fn identity() -> Self {
        Similarity2 {
            scale: 1.0,
            rotation: Matrix2::identity(),
            translation: Vector2::zeros(),
        }
    }

    /// Applies the transform to a point.
    pub fn apply(&self, p: &Point2<f64>) -> Point2<f64> {
        Point2::from(self.scale * (self.rotation * p.coords) + self.translation)
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        let s = 1.0 / self.scale;
        Similarity2 {
            scale: s,
            rotation: rt,
            translation: -(s * (rt * self.translation)),
        }
    }

    /// Rotation angle in radians (counter-clockwise in a y-up frame).
    pub fn angle(&self) -> f64 {
        self.rotation[(1, 0)].atan2(self.rotation[(0, 0)])
    }
}

/// A 3D similarity `y = s R x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity3 {
    /// Uniform scale (> 0; 1 for rigid alignment).
    pub scale: f64,
    /// Rotation matrix (det +1).
    pub rotation: Matrix3<f64>,
    /// Translation.
    pub translation: Vector3<f64>,
}

impl Similarity3 {
    /// Applies the transform to a point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }
}

fn check_inputs(n_src: usize, n_dst: usize, weights: Option<&[f64]>, min: usize) -> Result<()> {
    if n_src != n_dst {
        return Err(Error::DimensionMismatch {
            what: "alignment point count".into(),
            expected: n_src,
            got: n_dst,
        });
    }
    if let Some(w) = weights {
        if w.len() != n_src {
            return Err(Error::DimensionMismatch {
                what: "alignment weight count".into(),
                expected: n_src,
                got: w.len(),
            });
        }
    }
    if n_src < min {
        return Err(Error::invalid("alignment point count", n_src, format!(">= {min}")));
    }
    Ok(())
}

/// Weighted means, cross-covariance `Sigma = sum w (y - mu_y)(x - mu_x)^T / sum w` and
/// source variance of two corresponding point sets (the shared part of Umeyama).
struct Moments<const D: usize> {
    mx: SVector<f64, D>,
    my: SVector<f64, D>,
    cov: SMatrix<f64, D, D>,
    var_x: f64,
}

/// The moments over the points of non-zero weight (a point of weight 0 is not read, so
/// it may be non-finite). No allocation.
fn weighted_moments<const D: usize>(
    src: &[Point<f64, D>],
    dst: &[Point<f64, D>],
    weight: impl Fn(usize) -> f64,
    operation: &'static str,
) -> Result<Moments<D>> {
    let mut wsum = 0.0;
    let (mut mx, mut my) = (SVector::<f64, D>::zeros(), SVector::<f64, D>::zeros());
    for i in 0..src.len().min(dst.len()) {
        let w = weight(i);
        if !(w.is_finite() && w >= 0.0) {
            return Err(Error::invalid(
                "alignment weight",
                format!("w[{i}] = {w}"),
                "finite and >= 0",
            ));
        }
        if w == 0.0 {
            continue;
        }
        if !(src[i].coords.iter().chain(dst[i].coords.iter()).all(|v| v.is_finite())) {
            return Err(Error::invalid(
                "alignment point",
                format!("point {i}"),
                "finite coordinates",
            ));
        }
        wsum += w;
        mx += w * src[i].coords;
        my += w * dst[i].coords;
    }
    if wsum <= 0.0 {
        return Err(Error::Numerical {
            operation,
            reason: "weights sum to zero".into(),
        });
    }
    mx /= wsum;
    my /= wsum;
    let mut cov = SMatrix::<f64, D, D>::zeros();
    let mut var_x = 0.0;
    for i in 0..src.len().min(dst.len()) {
        let w = weight(i);
        if w == 0.0 {
            continue;
        }
        let xs = src[i].coords - mx;
        let ys = dst[i].coords - my;
        cov += w * ys * xs.transpose();
        var_x += w * xs.norm_squared();
    }
    cov /= wsum;
    var_x /= wsum;
    if var_x <= f64::EPSILON * (1.0 + mx.norm_squared()) {
        return Err(Error::Numerical {
            operation,
            reason: "source points are all coincident".into(),
        });
    }
    Ok(Moments { mx, my, cov, var_x })
}

/// Weighted 2D Umeyama alignment mapping `src` onto `dst`. With `with_scale = false`
/// the scale is fixed to 1 (rigid). `weights` default to 1; a point of weight 0 is
/// ignored. Allocation-free ([`similarity2_weighted`] with the weights as a function).
///
/// # Errors
/// Mismatched lengths, fewer than 2 points, negative/non-finite weights or points,
/// or a degenerate (all coincident) source set.
pub fn umeyama2(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    weights: Option<&[f64]>,
    with_scale: bool,
) -> Result<Similarity2> {
    check_inputs(src.len(), dst.len(), weights, 2)?;
    similarity2_weighted(src, dst, |i| weights.map_or(1.0, |w| w[i]), with_scale)
}

/// The 2D Umeyama alignment of [`umeyama2`] with the weight of point `i` given by
/// `weight(i)` (e.g. 1 for a tracked point and 0 for a lost one: a masked fit), without
/// allocating. Points of weight 0 are not read. Pairs beyond the shorter slice are
/// ignored.
///
/// # Errors
/// A negative or non-finite weight, a non-finite point of non-zero weight, weights
/// summing to zero, or a degenerate (all coincident) source set.
pub fn similarity2_weighted(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    weight: impl Fn(usize) -> f64,
    with_scale: bool,
) -> Result<Similarity2> {
    let Moments { mx, my, cov, var_x } = weighted_moments(src, dst, weight, "umeyama2")?;
    // Closed form in 2D: R is the rotation by atan2(c10 - c01, c00 + c11).
    let a = cov[(0, 0)] + cov[(1, 1)];
    let b = cov[(1, 0)] - cov[(0, 1)];
    let norm = (a * a + b * b).sqrt();
    let (c, s) = if norm > 0.0 { (a / norm, b / norm) } else { (1.0, 0.0) };
    let rotation = Matrix2::new(c, -s, s, c);
    // tr(D S) = tr(R^T Sigma) for the optimal R.
    let scale = if with_scale { norm / var_x } else { 1.0 };
    let translation = my - scale * (rotation * mx);
    Ok(Similarity2 {
        scale,
        rotation,
        translation,
    })
}

/// Weighted 3D Umeyama alignment mapping `src` onto `dst` (scale fixed to 1 when
/// `with_scale` is false).
///
/// # Errors
/// As [`umeyama2`], with at least 3 points.
pub fn umeyama3(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    weights: Option<&[f64]>,
    with_scale: bool,
) -> Result<Similarity3> {
    check_inputs(src.len(), dst.len(), weights, 3)?;
    let Moments { mx, my, cov, var_x } = weighted_moments(src, dst, |i| weights.map_or(1.0, |w| w[i]), "umeyama3")?;
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(Error::Numerical {
            operation: "umeyama3",
            reason: "SVD did not converge".into(),
        });
    };
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if (u * vt).determinant() < 0.0 {
        s[2] = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&s) * vt;
    let scale = if with_scale {
        svd.singular_values.dot(&s) / var_x
    } else {
        1.0
    };
    let translation = my - scale * (rotation * mx);
    Ok(Similarity3 {
        scale,
        rotation,
        translation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::Rotation3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_known_2d_similarity() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..50 {
            let angle: f64 = rng.random_range(-3.0..3.0);
            let scale: f64 = rng.random_range(0.2..5.0);
            let t = Vector2::new(rng.random_range(-100.0..100.0), rng.random_range(-100.0..100.0));
            let truth = Similarity2 {
                scale,
                rotation: *nalgebra::Rotation2::new(angle).matrix(),
                translation: t,
            };
            let src: Vec<_> = (0..10)
                .map(|_| Point2::new(rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0)))
                .collect();
            let dst: Vec<_> = src.iter().map(|p| truth.apply(p)).collect();
            let est = umeyama2(&src, &dst, None, true).unwrap();
            assert_relative_eq!(est.scale, scale, epsilon = 1e-9);
            assert_relative_eq!(est.rotation, truth.rotation, epsilon = 1e-9);
            assert_relative_eq!(est.translation, t, epsilon = 1e-7);
            let inv = est.inverse();
            assert_relative_eq!(inv.apply(&dst[3]).coords, src[3].coords, epsilon = 1e-7);
        }
    }

    #[test]
    fn recovers_known_3d_similarity_and_never_reflects() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..50 {
            let axis = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let rot = Rotation3::new(axis * 2.0);
            let scale: f64 = rng.random_range(0.5..2.0);
            let t = Vector3::new(rng.random_range(-10.0..10.0), 3.0, -4.0);
            let truth = Similarity3 {
                scale,
                rotation: *rot.matrix(),
                translation: t,
            };
            let src: Vec<_> = (0..12)
                .map(|_| {
                    Point3::new(
                        rng.random_range(-5.0..5.0),
                        rng.random_range(-5.0..5.0),
                        rng.random_range(-5.0..5.0),
                    )
                })
                .collect();
            let dst: Vec<_> = src.iter().map(|p| truth.apply(p)).collect();
            let est = umeyama3(&src, &dst, None, true).unwrap();
            assert_relative_eq!(est.scale, scale, epsilon = 1e-9);
            assert_relative_eq!(est.rotation, truth.rotation, epsilon = 1e-9);
            assert_relative_eq!(est.rotation.determinant(), 1.0, epsilon = 1e-12);
        }
        // A mirrored target must still give a proper rotation.
        let src = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
        ];
        let dst: Vec<_> = src.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let est = umeyama3(&src, &dst, None, false).unwrap();
        assert_relative_eq!(est.rotation.determinant(), 1.0, epsilon = 1e-12);
    }

    #[test]
    fn masked_fit_ignores_unread_points_and_equals_the_fit_of_the_rest() {
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let truth = Similarity2 {
            scale: 1.3,
            rotation: *nalgebra::Rotation2::new(0.4).matrix(),
            translation: Vector2::new(5.0, -2.0),
        };
        let src: Vec<_> = (0..21)
            .map(|_| Point2::new(rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0)))
            .collect();
        let mut dst: Vec<_> = src
            .iter()
            .map(|p| truth.apply(p) + Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)))
            .collect();
        dst[4] = Point2::new(f64::NAN, 1e9);
        dst[9].x += 300.0;
        let mask = |i: usize| if i == 4 || i == 9 { 0.0 } else { 1.0 };
        let masked = similarity2_weighted(&src, &dst, mask, true).unwrap();
        let keep: Vec<usize> = (0..21).filter(|&i| mask(i) > 0.0).collect();
        let (s2, d2): (Vec<_>, Vec<_>) = keep.iter().map(|&i| (src[i], dst[i])).unzip();
        let rest = umeyama2(&s2, &d2, None, true).unwrap();
        assert_relative_eq!(masked.scale, rest.scale, epsilon = 1e-12);
        assert_relative_eq!(masked.rotation, rest.rotation, epsilon = 1e-12);
        assert_relative_eq!(masked.translation, rest.translation, epsilon = 1e-9);
        let weights: Vec<f64> = (0..21).map(mask).collect();
        assert_eq!(umeyama2(&src, &dst, Some(&weights), true).unwrap(), masked);
        // One point left is degenerate; a negative weight is an error.
        assert!(similarity2_weighted(&src, &dst, |i| if i == 0 { 1.0 } else { 0.0 }, true).is_err());
        assert!(similarity2_weighted(&src, &dst, |i| if i == 0 { -1.0 } else { 1.0 }, true).is_err());
    }

    #[test]
    fn rejects_bad_input() {
        let p = [Point2::new(1.0, 1.0), Point2::new(1.0, 1.0)];
        assert!(umeyama2(&p, &p, None, true).is_err());
        assert!(umeyama2(&p, &p[..1], None, true).is_err());
        let q = [Point2::new(0.0, 0.0), Point2::new(f64::NAN, 1.0)];
        assert!(umeyama2(&q, &q, None, true).is_err());
        let r = [Point2::new(0.0, 0.0), Point2::new(1.0, 1.0)];
        assert!(umeyama2(&r, &r, Some(&[1.0, -1.0]), true).is_err());
    }
}
