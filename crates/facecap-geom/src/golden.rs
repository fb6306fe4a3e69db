//! Golden-section search: the minimiser of a unimodal function on an interval, from
//! function values only (Kiefer 1953).
//!
//! ```
//! let x = facecap_geom::golden::golden_section(|x| (x - 0.3) * (x - 0.3), 0.0, 1.0, 1e-9);
//! assert!((x - 0.3).abs() < 1e-6);
//! ```

/// Golden-section minimisation of `f` on `[a, b]` to bracket width `tol`.
pub fn golden_section(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> f64 {
    const INV_PHI: f64 = 0.618_033_988_749_894_8;
    let mut x1 = b - INV_PHI * (b - a);
    let mut x2 = a + INV_PHI * (b - a);
    let (mut f1, mut f2) = (f(x1), f(x2));
    while (b - a).abs() > tol {
        if f1 <= f2 {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - INV_PHI * (b - a);
            f1 = f(x1);
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + INV_PHI * (b - a);
            f2 = f(x2);
        }
    }
    // The bounds themselves are candidates (the minimum is often at theta = 0).
    let mid = 0.5 * (a + b);
    let mut best = (mid, f(mid));
    for x in [a, b] {
        let v = f(x);
        if v < best.1 {
            best = (x, v);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_interior_and_boundary_minima() {
        let x = golden_section(|x| (x - 0.7).powi(2), 0.0, 2.0, 1e-10);
        assert!((x - 0.7).abs() < 1e-6, "{x}");
        // Increasing on the interval: the minimum is the lower bound.
        let x = golden_section(|x| x, 0.0, 1.0, 1e-10);
        assert!(x < 1e-6, "{x}");
    }
}
