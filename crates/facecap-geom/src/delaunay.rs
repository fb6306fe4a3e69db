//! Delaunay triangulation of 2D points by Bowyer-Watson insertion (Bowyer 1981,
//! Watson 1981), `O(n^2)`: for the few hundred points of a landmark layout.
//!
//! ```
//! let tris = facecap_geom::delaunay::delaunay(&[(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]);
//! assert_eq!(tris.len(), 2);
//! ```

/// Bowyer-Watson Delaunay triangulation of 2D points (CCW triangles).
pub fn delaunay(points: &[(f64, f64)]) -> Vec<[u32; 3]> {
    let n = points.len();
    let (mut minx, mut miny, mut maxx, mut maxy) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in points {
        minx = minx.min(p.0);
        miny = miny.min(p.1);
        maxx = maxx.max(p.0);
        maxy = maxy.max(p.1);
    }
    let size = (maxx - minx).max(maxy - miny) * 20.0;
    let (cx, cy) = ((minx + maxx) / 2.0, (miny + maxy) / 2.0);
    let mut pts = points.to_vec();
    pts.push((cx - size, cy - size));
    pts.push((cx + size, cy - size));
    pts.push((cx, cy + size));
    let mut tris: Vec<[usize; 3]> = vec![[n, n + 1, n + 2]];
    let circum = |t: &[usize; 3], pts: &[(f64, f64)]| {
        let (a, b, c) = (pts[t[0]], pts[t[1]], pts[t[2]]);
        let d = 2.0 * (a.0 * (b.1 - c.1) + b.0 * (c.1 - a.1) + c.0 * (a.1 - b.1));
        let a2 = a.0 * a.0 + a.1 * a.1;
        let b2 = b.0 * b.0 + b.1 * b.1;
        let c2 = c.0 * c.0 + c.1 * c.1;
        let ux = (a2 * (b.1 - c.1) + b2 * (c.1 - a.1) + c2 * (a.1 - b.1)) / d;
        let uy = (a2 * (c.0 - b.0) + b2 * (a.0 - c.0) + c2 * (b.0 - a.0)) / d;
        (ux, uy, (a.0 - ux).powi(2) + (a.1 - uy).powi(2))
    };
    for i in 0..n {
        let p = pts[i];
        let mut bad = Vec::new();
        let mut keep = Vec::new();
        for t in tris.drain(..) {
            let (ux, uy, r2) = circum(&t, &pts);
            if (p.0 - ux).powi(2) + (p.1 - uy).powi(2) < r2 {
                bad.push(t);
            } else {
                keep.push(t);
            }
        }
        // Boundary edges of the cavity: edges of bad triangles not shared by another bad one.
        let mut edges: Vec<(usize, usize)> = Vec::new();
        for t in &bad {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let shared = bad.iter().filter(|u| u.contains(&a) && u.contains(&b)).count() > 1;
                if !shared {
                    edges.push((a, b));
                }
            }
        }
        tris = keep;
        for (a, b) in edges {
            tris.push([a, b, i]);
        }
    }
    tris.into_iter()
        .filter(|t| t.iter().all(|&v| v < n))
        .map(|t| {
            let (a, b, c) = (pts[t[0]], pts[t[1]], pts[t[2]]);
            let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
            if cross >= 0.0 {
                [t[0] as u32, t[1] as u32, t[2] as u32]
            } else {
                [t[0] as u32, t[2] as u32, t[1] as u32]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangles_are_ccw_and_empty_circumcircle() {
        let pts: Vec<(f64, f64)> = (0..40)
            .map(|i| {
                let t = i as f64 * 2.399_963;
                let r = (i as f64).sqrt();
                (r * t.cos(), r * t.sin())
            })
            .collect();
        let tris = delaunay(&pts);
        // Euler: a triangulation of n points with h on the hull has 2n - 2 - h triangles.
        assert!(tris.len() >= pts.len(), "{}", tris.len());
        for t in &tris {
            let (a, b, c) = (pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize]);
            let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
            assert!(cross > 0.0);
            for (k, p) in pts.iter().enumerate() {
                if t.contains(&(k as u32)) {
                    continue;
                }
                // In-circle determinant (positive = strictly inside for a CCW triangle).
                let m = |q: (f64, f64)| (q.0 - p.0, q.1 - p.1, (q.0 - p.0).powi(2) + (q.1 - p.1).powi(2));
                let (x, y, z) = (m(a), m(b), m(c));
                let det = x.0 * (y.1 * z.2 - z.1 * y.2) - x.1 * (y.0 * z.2 - z.0 * y.2) + x.2 * (y.0 * z.1 - z.0 * y.1);
                assert!(det < 1e-9, "point {k} inside the circumcircle of {t:?}");
            }
        }
    }
}
