//! 2D reanimation (Papanek 2010, sec. 5.2): the source performer's mouth region is
//! warped onto where the transferred face's mouth lies in the target frame and
//! blended in by Poisson seamless cloning ([`crate::poisson`]).
//!
//! The warp is the least-squares similarity transform (Umeyama 1991, 2D) taking the
//! destination mouth points (the transferred mesh's mouth vertices projected with the
//! target pose, which sizes the region by the transferred shape) to the source mouth
//! points; each destination pixel samples the source bilinearly. The clone region is
//! the destination mouth polygon pushed out by `margin_px` from its centroid.
//! Images are interleaved 8-bit RGB, row-major, 0-based pixel centres.

use facecap_geom::align::umeyama2;
use nalgebra::{Point2, Vector2};

use crate::error::{Error, Result};
use crate::features::inside;
use crate::poisson::{clone_plane, PoissonParams, PoissonReport};

/// Clones the source mouth region into `target` (in place). `src_pts` are the mouth
/// points in the source frame, `dst_pts` the corresponding points in the target frame.
///
/// # Errors
/// [`Error::DimensionMismatch`] for buffer sizes, as [`similarity`] and [`clone_plane`].
#[allow(clippy::too_many_arguments)]
pub fn clone_mouth(
    target: &mut [u8],
    tw: usize,
    th: usize,
    source: &[u8],
    sw: usize,
    sh: usize,
    src_pts: &[Point2<f64>],
    dst_pts: &[Point2<f64>],
    margin_px: f64,
    params: &PoissonParams,
) -> Result<PoissonReport> {
    if target.len() != tw * th * 3 {
        return Err(Error::dim("target RGB buffer", tw * th * 3, target.len()));
    }
    if source.len() != sw * sh * 3 {
        return Err(Error::dim("source RGB buffer", sw * sh * 3, source.len()));
    }
    let warp = umeyama2(dst_pts, src_pts, None, true)?;
    let c = dst_pts.iter().fold(Vector2::zeros(), |a, p| a + p.coords) / dst_pts.len() as f64;
    let poly: Vec<Point2<f64>> = dst_pts
        .iter()
        .map(|p| {
            let d = p.coords - c;
            let n = d.norm().max(1e-9);
            Point2::from(c + d * ((n + margin_px) / n))
        })
        .collect();
    let sample = |q: Point2<f64>| -> Option<[f64; 3]> {
        let s = warp.apply(&q);
        if s.x < 0.0 || s.y < 0.0 || s.x > (sw - 1) as f64 || s.y > (sh - 1) as f64 {
            return None;
        }
        let (x0, y0) = (s.x.floor() as usize, s.y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(sw - 1), (y0 + 1).min(sh - 1));
        let (fx, fy) = (s.x - x0 as f64, s.y - y0 as f64);
        let px = |xx: usize, yy: usize, ch: usize| source[(yy * sw + xx) * 3 + ch] as f64;
        let mut out = [0.0; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            *o = (1.0 - fy) * ((1.0 - fx) * px(x0, y0, ch) + fx * px(x1, y0, ch))
                + fy * ((1.0 - fx) * px(x0, y1, ch) + fx * px(x1, y1, ch));
        }
        Some(out)
    };
    // Mask: inside the polygon, not on the image border, with the pixel and its
    // 4-neighbours inside the warped source (so every guidance difference is a source one).
    let mut mask = vec![false; tw * th];
    let mut warped: Vec<Option<[f64; 3]>> = vec![None; tw * th];
    for y in 0..th {
        for x in 0..tw {
            let q = Point2::new(x as f64, y as f64);
            let near = poly.iter().any(|_| true) && {
                // within 2 px of the polygon's bounding region is enough to need samples
                let (mut x0, mut y0, mut x1, mut y1) =
                    (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
                for p in &poly {
                    x0 = x0.min(p.x);
                    y0 = y0.min(p.y);
                    x1 = x1.max(p.x);
                    y1 = y1.max(p.y);
                }
                q.x >= x0 - 2.0 && q.x <= x1 + 2.0 && q.y >= y0 - 2.0 && q.y <= y1 + 2.0
            };
            if near {
                warped[y * tw + x] = sample(q);
            }
        }
    }
    for y in 1..th.saturating_sub(1) {
        for x in 1..tw.saturating_sub(1) {
            let p = y * tw + x;
            if inside(&poly, &Point2::new(x as f64, y as f64))
                && [p, p - 1, p + 1, p - tw, p + tw].iter().all(|&q| warped[q].is_some())
            {
                mask[p] = true;
            }
        }
    }
    // The guidance uses source gradients only inside the mask; outside, the target.
    let mut report = PoissonReport {
        unknowns: 0,
        iterations: 0,
        relative_residual: 0.0,
        converged: true,
    };
    let mut out = vec![0.0; tw * th];
    for ch in 0..3 {
        let t: Vec<f64> = (0..tw * th).map(|p| target[p * 3 + ch] as f64).collect();
        let s: Vec<f64> = (0..tw * th).map(|p| warped[p].map_or(t[p], |w| w[ch])).collect();
        let r = clone_plane(&t, &s, &mask, tw, th, params, &mut out)?;
        for p in 0..tw * th {
            target[p * 3 + ch] = out[p].round().clamp(0.0, 255.0) as u8;
        }
        report.unknowns = r.unknowns;
        report.iterations = report.iterations.max(r.iterations);
        report.relative_residual = report.relative_residual.max(r.relative_residual);
        report.converged &= r.converged;
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cloning_a_shifted_copy_of_the_same_image_changes_nothing() {
        // Source = target shifted by (3, 2) plus a constant: warping it back and
        // cloning must reproduce the target (up to rounding of the bilinear samples).
        let (w, h) = (60, 50);
        let val = |x: f64, y: f64| 120.0 + 50.0 * (x / 9.0).sin() + 30.0 * (y / 7.0).cos();
        let mut target = vec![0u8; w * h * 3];
        let mut source = vec![0u8; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                for ch in 0..3 {
                    target[(y * w + x) * 3 + ch] = val(x as f64, y as f64).round() as u8;
                    source[(y * w + x) * 3 + ch] = (val(x as f64 - 3.0, y as f64 - 2.0) + 20.0).round() as u8;
                }
            }
        }
        let orig = target.clone();
        let dst = [
            Point2::new(20.0, 20.0),
            Point2::new(40.0, 20.0),
            Point2::new(30.0, 32.0),
        ];
        let src: Vec<_> = dst.iter().map(|p| Point2::new(p.x + 3.0, p.y + 2.0)).collect();
        let rep = clone_mouth(
            &mut target,
            w,
            h,
            &source,
            w,
            h,
            &src,
            &dst,
            4.0,
            &PoissonParams::default(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(rep.converged && rep.unknowns > 100);
        let err = target
            .iter()
            .zip(&orig)
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max()
            .unwrap_or(0);
        assert!(err <= 2, "max difference {err}");
    }
}
