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
