//! Extra feature points for fitting (Papanek 2010, sec. 4.2): image samples around
//! the mouth and brows are attached to the model vertex they show, found by
//! reprojecting the fitted model into the first frame. The caller (the CLI) tracks
//! the samples through the video with LK and drops lost ones (weight 0).

use facecap_core::camera::{Intrinsics, ModelToCamera};
use nalgebra::{Point2, Point3};

use crate::error::{Error, Result};

/// For each image sample, the model vertex whose projection is within `max_px` pixels
/// and nearest the camera (a z-buffer test among the nearby projections), or `None`.
///
/// `vertices` are the model-space positions of all mesh vertices.
///
/// # Errors
/// [`Error::InvalidParameter`] for a non-finite or negative `max_px`.
pub fn closest_visible_vertices(
    vertices: &[Point3<f64>],
    pose: &ModelToCamera,
    k: &Intrinsics,
    samples: &[Point2<f64>],
    max_px: f64,
) -> Result<Vec<Option<u32>>> {
    if !(max_px.is_finite() && max_px >= 0.0) {
        return Err(Error::invalid("max_px", max_px, "a finite number >= 0"));
    }
    let proj: Vec<Option<(Point2<f64>, f64)>> = vertices
        .iter()
        .map(|p| {
            let c = pose.transform(p);
            k.project(&c).map(|x| (x, c.z))
        })
        .collect();
    // Depth tolerance: among projections within the radius, keep those within this
    // depth of the nearest one and take the closest in the image.
    let r2 = max_px * max_px;
    Ok(samples
        .iter()
        .map(|s| {
            let near: Vec<(usize, f64, f64)> = proj
                .iter()
                .enumerate()
                .filter_map(|(v, p)| {
                    let (x, z) = (*p)?;
                    let d2 = (x - s).norm_squared();
                    (d2 <= r2).then_some((v, d2, z))
                })
                .collect();
            let zmin = near.iter().map(|n| n.2).fold(f64::INFINITY, f64::min);
            let zmax_front = near.iter().map(|n| n.2).fold(f64::NEG_INFINITY, f64::max);
            let tol = 0.25 * (zmax_front - zmin).max(0.0);
            near.iter()
                .filter(|n| n.2 <= zmin + tol)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|n| n.0 as u32)
        })
        .collect())
}

/// Regular grid samples (spacing `step` pixels) inside the polygon `outline`
/// (e.g. the mouth or brow landmarks expanded by `margin` pixels from their centroid).
pub fn grid_samples_in_polygon(outline: &[Point2<f64>], margin: f64, step: f64) -> Vec<Point2<f64>> {
    if outline.len() < 3 || step.is_nan() || step <= 0.0 {
        return Vec::new();
    }
    let c = outline.iter().fold(nalgebra::Vector2::zeros(), |a, p| a + p.coords) / outline.len() as f64;
    let poly: Vec<Point2<f64>> = outline
        .iter()
        .map(|p| {
            let d = p.coords - c;
            let n = d.norm().max(1e-9);
            Point2::from(c + d * ((n + margin) / n))
        })
        .collect();
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in &poly {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    let mut out = Vec::new();
    let mut y = y0;
    while y <= y1 {
        let mut x = x0;
        while x <= x1 {
            let q = Point2::new(x, y);
            if inside(&poly, &q) {
                out.push(q);
            }
            x += step;
        }
        y += step;
    }
    out
}

/// Even-odd point-in-polygon test.
pub fn inside(poly: &[Point2<f64>], q: &Point2<f64>) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a.y > q.y) != (b.y > q.y) && q.x < (b.x - a.x) * (q.y - a.y) / (b.y - a.y) + a.x {
            c = !c;
        }
    }
    c
}
