//! Thin-plate spline interpolation `R^2 -> R` (Duchon 1976, Bookstein 1989): the
//! smoothest surface through given values at given 2D centres, plus an affine part.
//!
//! ```
//! use facecap_geom::tps::Tps;
//! let centres = vec![(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)];
//! let tps = Tps::new(centres).ok_or("singular")?;
//! let coef = tps.fit(&[0.0, 1.0, 2.0, 4.0]).ok_or("singular")?;
//! assert!((tps.eval(&coef, 1.0, 1.0) - 4.0).abs() < 1e-9);
//! # Ok::<(), &str>(())
//! ```

use nalgebra::{DMatrix, DVector};

/// Thin-plate spline `R^2 -> R` through a set of 2D centres.
#[derive(Debug)]
pub struct Tps {
    centres: Vec<(f64, f64)>,
    lu: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

/// The thin-plate kernel `U(r) = r^2 log r`, written in `r^2`: `r2 ln(r2) / 2`.
pub fn tps_kernel(r2: f64) -> f64 {
    if r2 <= 0.0 {
        0.0
    } else {
        0.5 * r2 * r2.ln()
    }
}

impl Tps {
    /// The spline's system for `centres`; `None` when it is singular (e.g. fewer than
    /// three non-collinear centres).
    pub fn new(centres: Vec<(f64, f64)>) -> Option<Self> {
        let n = centres.len();
        let mut a = DMatrix::zeros(n + 3, n + 3);
        for i in 0..n {
            for j in 0..n {
                let (dx, dy) = (centres[i].0 - centres[j].0, centres[i].1 - centres[j].1);
                a[(i, j)] = tps_kernel(dx * dx + dy * dy);
            }
            a[(i, n)] = 1.0;
            a[(i, n + 1)] = centres[i].0;
            a[(i, n + 2)] = centres[i].1;
            a[(n, i)] = 1.0;
            a[(n + 1, i)] = centres[i].0;
            a[(n + 2, i)] = centres[i].1;
        }
        let lu = a.lu();
        lu.is_invertible().then_some(Tps { centres, lu })
    }

    /// Coefficients for values at the centres.
    pub fn fit(&self, values: &[f64]) -> Option<DVector<f64>> {
        let n = self.centres.len();
        let mut b = DVector::zeros(n + 3);
        for (i, v) in values.iter().enumerate() {
            b[i] = *v;
        }
        self.lu.solve(&b)
    }

    /// The spline with coefficients `coef` (from [`Tps::fit`]) at `(x, y)`.
    pub fn eval(&self, coef: &DVector<f64>, x: f64, y: f64) -> f64 {
        let n = self.centres.len();
        let mut v = coef[n] + coef[n + 1] * x + coef[n + 2] * y;
        for (i, c) in self.centres.iter().enumerate() {
            let (dx, dy) = (x - c.0, y - c.1);
            v += coef[i] * tps_kernel(dx * dx + dy * dy);
        }
        v
    }
}

/// Thin-plate (biharmonic) spline `R^3 -> R^3`: `f(x) = A x + b + sum_i c_i |x - x_i|`,
/// the smoothest 3D warp taking each centre `x_i` exactly to its target `y_i` (the 3D
/// kernel is `U(r) = r`).
#[derive(Debug, Clone)]
pub struct Tps3 {
    centres: Vec<[f64; 3]>,
    /// `(n + 4) x 3` coefficients: one per centre, then the affine part (constant, x, y, z).
    coef: DMatrix<f64>,
}

impl Tps3 {
    /// The warp taking `centres[i]` to `targets[i]`; `None` when the system is singular
    /// (fewer than four non-coplanar centres, repeated centres) or the sizes differ.
    pub fn fit(centres: &[[f64; 3]], targets: &[[f64; 3]]) -> Option<Self> {
        let n = centres.len();
        if n != targets.len() || n < 4 {
            return None;
        }
        let mut a = DMatrix::zeros(n + 4, n + 4);
        let mut b = DMatrix::zeros(n + 4, 3);
        for i in 0..n {
            for j in 0..n {
                a[(i, j)] = dist3(&centres[i], &centres[j]);
            }
            a[(i, n)] = 1.0;
            a[(n, i)] = 1.0;
            for c in 0..3 {
                a[(i, n + 1 + c)] = centres[i][c];
                a[(n + 1 + c, i)] = centres[i][c];
                b[(i, c)] = targets[i][c];
            }
        }
        let coef = a.lu().solve(&b)?;
        coef.iter().all(|v| v.is_finite()).then(|| Tps3 {
            centres: centres.to_vec(),
            coef,
        })
    }

    /// The warped point.
    pub fn apply(&self, p: &[f64; 3]) -> [f64; 3] {
        let n = self.centres.len();
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            *o = self.coef[(n, c)] + (0..3).map(|k| self.coef[(n + 1 + k, c)] * p[k]).sum::<f64>();
        }
        for (i, x) in self.centres.iter().enumerate() {
            let u = dist3(p, x);
            for (c, o) in out.iter_mut().enumerate() {
                *o += self.coef[(i, c)] * u;
            }
        }
        out
    }
}

fn dist3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests3 {
    use super::*;

    #[test]
    fn tps3_interpolates_and_reproduces_affine() {
        let centres: Vec<[f64; 3]> = (0..10)
            .map(|i| {
                let t = i as f64;
                [t.sin() * 3.0, (1.7 * t).cos() * 2.0, (0.3 * t * t).sin()]
            })
            .collect();
        let affine = |p: &[f64; 3]| [2.0 * p[0] - p[1] + 1.0, p[1] + 0.5 * p[2], -p[0] + 3.0 * p[2] - 2.0];
        let targets: Vec<[f64; 3]> = centres.iter().map(affine).collect();
        let tps = Tps3::fit(&centres, &targets).unwrap();
        let q = [0.3, -0.7, 0.2];
        let (got, want) = (tps.apply(&q), affine(&q));
        for c in 0..3 {
            assert!((got[c] - want[c]).abs() < 1e-8, "{got:?} vs {want:?}");
        }
        let mut bent = targets.clone();
        bent[3][2] += 0.5;
        let tps = Tps3::fit(&centres, &bent).unwrap();
        let y = tps.apply(&centres[3]);
        assert!((y[2] - bent[3][2]).abs() < 1e-8);
        assert!(Tps3::fit(&centres[..3], &bent[..3]).is_none());
    }
}
