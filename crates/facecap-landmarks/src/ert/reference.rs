//! Slow, obvious reference implementation of dlib's `shape_predictor::operator()`,
//! line by line as in `dlib/image_processing/shape_predictor.h`, on the nested
//! [`ErtModel`] layout. The similarity uses Umeyama's SVD formula as dlib does. It
//! exists to check the optimised [`super::ShapePredictor`] (property tests) and is
//! not meant for production use (it allocates).

use facecap_core::landmarks::Rect;
use image::GrayImage;
use nalgebra::{Matrix2, Point2, Vector2};

use super::ErtModel;

/// Umeyama (1991) similarity from `from` to `to` (both `2P` interleaved), the 2x2
/// part only, as dlib's `find_similarity_transform` (f64).
///
/// Deliberately not `facecap_geom::align::umeyama2`: this reference follows dlib's code
/// line by line (SVD, reflection handling, the same sums) so that the optimised
/// predictor can be checked against dlib itself, bit for bit where dlib's rounding
/// allows; a shared fit with another summation order would test against something else.
pub fn find_similarity_2x2(from: &[f32], to: &[f32]) -> Matrix2<f64> {
    let n = from.len() / 2;
    if n == 1 {
        return Matrix2::identity();
    }
    let pts = |s: &[f32]| -> Vec<Vector2<f64>> {
        s.chunks_exact(2)
            .map(|p| Vector2::new(f64::from(p[0]), f64::from(p[1])))
            .collect()
    };
    let (f, t) = (pts(from), pts(to));
    let mf = f.iter().sum::<Vector2<f64>>() / n as f64;
    let mt = t.iter().sum::<Vector2<f64>>() / n as f64;
    let mut sigma_from = 0.0;
    let mut cov = Matrix2::zeros();
    for (a, b) in f.iter().zip(&t) {
        sigma_from += (a - mf).norm_squared();
        cov += (b - mt) * (a - mf).transpose();
    }
    sigma_from /= n as f64;
    cov /= n as f64;
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Matrix2::identity();
    };
    let d = svd.singular_values;
    let mut s = Matrix2::identity();
    if cov.determinant() < 0.0 || (cov.determinant() == 0.0 && u.determinant() * vt.determinant() < 0.0) {
        if d[1] < d[0] {
            s[(1, 1)] = -1.0;
        } else {
            s[(0, 0)] = -1.0;
        }
    }
    let r = u * s * vt;
    let c = if sigma_from != 0.0 {
        1.0 / sigma_from * (d[0] * s[(0, 0)] + d[1] * s[(1, 1)])
    } else {
        1.0
    };
    r * c
}

/// dlib's prediction for the face in `rect` (sub-pixel result, before dlib's final
/// rounding). `start` replaces the mean shape when given (normalised coordinates).
pub fn predict(model: &ErtModel, image: &GrayImage, rect: &Rect, start: Option<&[f32]>) -> Vec<Point2<f64>> {
    let (l, t) = (rect.left, rect.top);
    let (sx, sy) = (rect.width - 1.0, rect.height - 1.0);
    let to_img = |x: f32, y: f32| (sx * f64::from(x) + l, sy * f64::from(y) + t);
    let mut current: Vec<f32> = start.map_or_else(|| model.initial_shape.clone(), <[f32]>::to_vec);
    for c in 0..model.forests.len() {
        let m = find_similarity_2x2(&model.initial_shape, &current);
        let m = [m[(0, 0)] as f32, m[(0, 1)] as f32, m[(1, 0)] as f32, m[(1, 1)] as f32];
        let mut fpv = vec![0f32; model.deltas[c].len()];
        for (i, v) in fpv.iter_mut().enumerate() {
            let a = model.anchor_idx[c][i] as usize;
            let d = model.deltas[c][i];
            let qx = m[0] * d[0] + m[1] * d[1] + current[2 * a];
            let qy = m[2] * d[0] + m[3] * d[1] + current[2 * a + 1];
            let (x, y) = to_img(qx, qy);
            let (px, py) = ((x + 0.5).floor() as i64, (y + 0.5).floor() as i64);
            if px >= 0 && py >= 0 && px < i64::from(image.width()) && py < i64::from(image.height()) {
                *v = f32::from(image.get_pixel(px as u32, py as u32).0[0]);
            }
        }
        for tree in &model.forests[c] {
            let mut i = 0;
            while i < tree.splits.len() {
                let s = tree.splits[i];
                i = if fpv[s.idx1 as usize] - fpv[s.idx2 as usize] > s.thresh {
                    2 * i + 1
                } else {
                    2 * i + 2
                };
            }
            let leaf = &tree.leaf_values[i - tree.splits.len()];
            for (cv, lv) in current.iter_mut().zip(leaf) {
                *cv += *lv;
            }
        }
    }
    current
        .chunks_exact(2)
        .map(|p| {
            let (x, y) = to_img(p[0], p[1]);
            Point2::new(x, y)
        })
        .collect()
}
