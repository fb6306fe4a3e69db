//! Piecewise-affine image warp driven by landmarks (used by `facecap synth`).
//!
//! Source and destination share one triangulation (Delaunay of the source points).
//! Each destination pixel inside destination triangle `T` gets barycentric
//! coordinates `(b0, b1, b2)` in `T`; its colour is sampled bilinearly at
//! `b0 s0 + b1 s1 + b2 s2` in the source image (inverse mapping, no holes).

use image::{Rgb, RgbImage};

/// Bilinear sample of an RGB image at a 0-based pixel position (clamped at borders).
pub fn sample_bilinear(img: &RgbImage, x: f64, y: f64) -> [u8; 3] {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as i64, y.floor() as i64);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let px = |xx: i64, yy: i64| img.get_pixel(xx as u32, yy as u32).0;
    let (a, b, c, d) = (px(x0, y0), px(x1, y0), px(x0, y1), px(x1, y1));
    let mut out = [0u8; 3];
    for k in 0..3 {
        let top = a[k] as f64 * (1.0 - fx) + b[k] as f64 * fx;
        let bot = c[k] as f64 * (1.0 - fx) + d[k] as f64 * fx;
        out[k] = (top * (1.0 - fy) + bot * fy).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// Warps `src` so that `src_pts[i]` moves to `dst_pts[i]`, over `triangles`.
/// Pixels covered by no triangle copy the source pixel.
pub fn warp_piecewise_affine(
    src: &RgbImage,
    src_pts: &[(f64, f64)],
    dst_pts: &[(f64, f64)],
    triangles: &[[u32; 3]],
    out: &mut RgbImage,
) {
    out.clone_from(src);
    let (w, h) = (src.width() as i64, src.height() as i64);
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let (d0, d1, d2) = (dst_pts[a], dst_pts[b], dst_pts[c]);
        let area = (d1.0 - d0.0) * (d2.1 - d0.1) - (d1.1 - d0.1) * (d2.0 - d0.0);
        if area.abs() < 1e-9 {
            continue;
        }
        let minx = d0.0.min(d1.0).min(d2.0).floor().max(0.0) as i64;
        let maxx = (d0.0.max(d1.0).max(d2.0).ceil() as i64).min(w - 1);
        let miny = d0.1.min(d1.1).min(d2.1).floor().max(0.0) as i64;
        let maxy = (d0.1.max(d1.1).max(d2.1).ceil() as i64).min(h - 1);
        for y in miny..=maxy {
            for x in minx..=maxx {
                let (px, py) = (x as f64, y as f64);
                let b0 = ((d1.0 - px) * (d2.1 - py) - (d1.1 - py) * (d2.0 - px)) / area;
                let b1 = ((d2.0 - px) * (d0.1 - py) - (d2.1 - py) * (d0.0 - px)) / area;
                let b2 = 1.0 - b0 - b1;
                const EDGE_TOLERANCE: f64 = -1e-9;
                if b0 < EDGE_TOLERANCE || b1 < EDGE_TOLERANCE || b2 < EDGE_TOLERANCE {
                    continue;
                }
                let sx = b0 * src_pts[a].0 + b1 * src_pts[b].0 + b2 * src_pts[c].0;
                let sy = b0 * src_pts[a].1 + b1 * src_pts[b].1 + b2 * src_pts[c].1;
                out.put_pixel(x as u32, y as u32, Rgb(sample_bilinear(src, sx, sy)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_and_translation() {
        let src = RgbImage::from_fn(40, 30, |x, y| Rgb([(x * 5) as u8, (y * 7) as u8, 9]));
        let pts = vec![(0.0, 0.0), (39.0, 0.0), (0.0, 29.0), (39.0, 29.0), (20.0, 15.0)];
        let tris = facecap_geom::delaunay::delaunay(&pts);
        let mut out = RgbImage::new(1, 1);
        warp_piecewise_affine(&src, &pts, &pts, &tris, &mut out);
        assert_eq!(out, src);
        // Moving the centre point by (+2, 0): the pixel at (22, 15) now shows source (20, 15).
        let mut dst = pts.clone();
        dst[4].0 += 2.0;
        warp_piecewise_affine(&src, &pts, &dst, &tris, &mut out);
        assert_eq!(out.get_pixel(22, 15), src.get_pixel(20, 15));
    }
}
