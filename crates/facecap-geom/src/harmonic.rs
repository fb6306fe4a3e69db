//! Harmonic interpolation over a triangle mesh: values given at some vertices, spread to
//! the others as the minimiser of the membrane energy `sum_edges w_ij |d_i - d_j|^2`
//! (`w_ij = 1 / |p_i - p_j|`, the edges of the given triangles), i.e. each free vertex
//! ends up at the weighted mean of its neighbours. No overshoot: every free value lies
//! inside the range of the given ones (maximum principle), and the values only travel
//! along the mesh, so two sides of an opening that shares no triangle (lips, lids) move
//! independently.
//!
//! The system over the free vertices is factorised once ([`Harmonic::new`]); each
//! [`Harmonic::interpolate`] is then two triangular solves. A free vertex with no path
//! to a fixed one gets 0 (a tiny pull to zero keeps the system definite).

use crate::{cholesky, Error, Result};

/// Most free vertices accepted (the dense factorisation is `n^2` memory).
const MAX_FREE: usize = 8192;

/// A factorised harmonic interpolation (module docs).
#[derive(Debug, Clone)]
pub struct Harmonic {
    n: usize,
    /// Position of each vertex among the free ones, `None` for a fixed vertex.
    free_index: Vec<Option<usize>>,
    /// Position of each vertex among the fixed ones.
    fixed_index: Vec<Option<usize>>,
    /// Per free vertex: `(fixed position, weight)` of its edges to fixed vertices.
    coupling: Vec<Vec<(usize, f64)>>,
    /// Cholesky factor of the free vertices' system ([`cholesky::factor`], row-major,
    /// lower triangle).
    factor: Vec<f64>,
}

fn invalid(reason: impl Into<String>) -> Error {
    Error::Numerical {
        operation: "harmonic interpolation",
        reason: reason.into(),
    }
}

impl Harmonic {
    /// Prepares the interpolation on the mesh `(positions, triangles)` with values given
    /// at the vertices `fixed` (in that order for [`Harmonic::interpolate`]).
    ///
    /// # Errors
    /// A triangle naming a vertex past `positions`, a repeated or out-of-range fixed
    /// vertex, non-finite positions, or more than 8192 free vertices.
    pub fn new(positions: &[[f64; 3]], triangles: &[[u32; 3]], fixed: &[usize]) -> Result<Self> {
        let n = positions.len();
        if positions.iter().flatten().any(|c| !c.is_finite()) {
            return Err(invalid("non-finite vertex position"));
        }
        let mut fixed_index = vec![None; n];
        for (k, &v) in fixed.iter().enumerate() {
            if v >= n {
                return Err(invalid(format!("fixed vertex {v} past the {n} vertices")));
            }
            if fixed_index[v].replace(k).is_some() {
                return Err(invalid(format!("fixed vertex {v} given twice")));
            }
        }
        let mut free_index = vec![None; n];
        let mut m = 0;
        for (v, f) in free_index.iter_mut().enumerate() {
            if fixed_index[v].is_none() {
                *f = Some(m);
                m += 1;
            }
        }
        if m > MAX_FREE {
            return Err(invalid(format!("{m} free vertices, at most {MAX_FREE}")));
        }
        let mut edges = std::collections::BTreeSet::new();
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
                if a >= n || b >= n {
                    return Err(invalid(format!("triangle {t:?} names a vertex past the {n} vertices")));
                }
                if a != b {
                    edges.insert((a.min(b), a.max(b)));
                }
            }
        }
        let mut a = vec![0.0f64; m * m];
        let mut coupling = vec![Vec::new(); m];
        let mut wsum = 0.0;
        for &(i, j) in &edges {
            let d = (0..3)
                .map(|c| (positions[i][c] - positions[j][c]).powi(2))
                .sum::<f64>()
                .sqrt();
            let w = 1.0 / d.max(1e-9);
            wsum += w;
            match (free_index[i], free_index[j]) {
                (Some(fi), Some(fj)) => {
                    a[fi * m + fi] += w;
                    a[fj * m + fj] += w;
                    a[fi * m + fj] -= w;
                    a[fj * m + fi] -= w;
                }
                (Some(fi), None) => {
                    a[fi * m + fi] += w;
                    coupling[fi].push((fixed_index[j].unwrap_or(0), w));
                }
                (None, Some(fj)) => {
                    a[fj * m + fj] += w;
                    coupling[fj].push((fixed_index[i].unwrap_or(0), w));
                }
                (None, None) => {}
            }
        }
        let eps = 1e-9 * wsum / edges.len().max(1) as f64 + 1e-12;
        for i in 0..m {
            a[i * m + i] += eps;
        }
        cholesky::factor(&mut a, m)
            .map_err(|pivot| invalid(format!("system not positive definite (pivot {pivot})")))?;
        Ok(Harmonic {
            n,
            free_index,
            fixed_index,
            coupling,
            factor: a,
        })
    }

    /// Number of mesh vertices.
    pub fn num_vertices(&self) -> usize {
        self.n
    }

    /// The values at every vertex given `values[k]` at `fixed[k]`: fixed vertices keep
    /// theirs exactly, free ones get the harmonic interpolation.
    ///
    /// # Errors
    /// `values` of another length than `fixed`, or non-finite values.
    pub fn interpolate(&self, values: &[[f64; 3]]) -> Result<Vec<[f64; 3]>> {
        let n_fixed = self.fixed_index.iter().filter(|f| f.is_some()).count();
        if values.len() != n_fixed {
            return Err(Error::DimensionMismatch {
                what: "harmonic interpolation values".into(),
                expected: n_fixed,
                got: values.len(),
            });
        }
        if values.iter().flatten().any(|c| !c.is_finite()) {
            return Err(invalid("non-finite value"));
        }
        let m = self.coupling.len();
        let mut out = vec![[0.0; 3]; self.n];
        let mut x = vec![0.0f64; m];
        for c in 0..3 {
            for (xi, cs) in x.iter_mut().zip(&self.coupling) {
                *xi = cs.iter().map(|&(k, w)| w * values[k][c]).sum();
            }
            cholesky::solve_factored(&self.factor, m, &mut x);
            for (v, o) in out.iter_mut().enumerate() {
                o[c] = match (self.free_index[v], self.fixed_index[v]) {
                    (Some(fi), _) => x[fi],
                    (None, Some(k)) => values[k][c],
                    (None, None) => 0.0,
                };
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip of `k` squares along x, two triangles each.
    fn strip(k: usize) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        for i in 0..=k {
            p.push([i as f64, 0.0, 0.0]);
            p.push([i as f64, 1.0, 0.0]);
        }
        let mut t = Vec::new();
        for i in 0..k as u32 {
            let (a, b, c, d) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
            t.push([a, c, b]);
            t.push([b, c, d]);
        }
        (p, t)
    }

    #[test]
    fn each_free_vertex_is_the_weighted_mean_of_its_neighbours() {
        let (p, t) = strip(4);
        // both ends fixed: x = 0 -> 0, x = 4 -> (4, -2, 1)
        let fixed = [0, 1, 8, 9];
        let h = Harmonic::new(&p, &t, &fixed).unwrap();
        let end = [4.0, -2.0, 1.0];
        let v = h.interpolate(&[[0.0; 3], [0.0; 3], end, end]).unwrap();
        assert_eq!(v[0], [0.0; 3]);
        assert_eq!(v[9], end);
        let mut nb: Vec<Vec<usize>> = vec![Vec::new(); p.len()];
        for tri in &t {
            for k in 0..3 {
                let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                nb[a].push(b);
                nb[b].push(a);
            }
        }
        for i in 2..8 {
            let (mut s, mut ws) = ([0.0; 3], 0.0);
            for &j in &nb[i] {
                let d = ((p[i][0] - p[j][0]).powi(2) + (p[i][1] - p[j][1]).powi(2)).sqrt();
                // each edge is listed once per triangle: the weight counts once per edge
                let w = 1.0 / d / nb[i].iter().filter(|&&k| k == j).count() as f64;
                ws += w;
                for c in 0..3 {
                    s[c] += w * v[j][c];
                }
            }
            for c in 0..3 {
                assert!((v[i][c] - s[c] / ws).abs() < 1e-6, "vertex {i}: {:?}", v[i]);
            }
        }
        // monotone from one end to the other
        for i in 0..4 {
            assert!(v[2 * i + 2][0] > v[2 * i][0]);
        }
    }

    #[test]
    fn values_stay_inside_the_given_range_and_unreachable_vertices_get_zero() {
        let (mut p, mut t) = strip(3);
        // an island triangle with no path to a fixed vertex
        let base = p.len() as u32;
        p.extend_from_slice(&[[10.0, 0.0, 0.0], [11.0, 0.0, 0.0], [10.0, 1.0, 0.0]]);
        t.push([base, base + 1, base + 2]);
        let h = Harmonic::new(&p, &t, &[0, 7]).unwrap();
        let v = h.interpolate(&[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]).unwrap();
        for q in &v[..8] {
            assert!(q[0] >= -1.0 - 1e-9 && q[0] <= 1.0 + 1e-9);
        }
        for q in &v[8..] {
            assert!(q[0].abs() < 1e-6);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (p, t) = strip(2);
        assert!(Harmonic::new(&p, &t, &[0, 0]).is_err());
        assert!(Harmonic::new(&p, &t, &[99]).is_err());
        assert!(Harmonic::new(&p, &[[0, 1, 99]], &[0]).is_err());
        let h = Harmonic::new(&p, &t, &[0]).unwrap();
        assert!(h.interpolate(&[]).is_err());
        assert!(h.interpolate(&[[f64::NAN, 0.0, 0.0]]).is_err());
    }
}
