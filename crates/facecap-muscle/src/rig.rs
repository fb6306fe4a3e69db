//! A muscle rig: a mesh with each muscle's displacement field precomputed at full
//! contraction, plus the jaw.
//!
//! Posing (Mramornov 2015, combination of contractions, then the jaw):
//!
//! ```text
//! P_m     = P + sum_i c_i * w_i(P) * (P'_i - P)                 c_i in [0, 1]
//! P_final = P_m + w_j(P) * (R_axis(theta) (P_m - pivot) + pivot - P_m),   theta in [0, max_angle]
//! ```
//!
//! `w_i` are the muscle's vertex-group weights (1 without a group), `w_j` the jaw group's.
//! Because `P_m` is linear in `c`, each field is stored once as a sparse list of
//! `(vertex, delta)` pairs and posing is one `axpy` per muscle plus one rotation pass over
//! the jaw group: no allocation per frame.
//!
//! Shapes: `base` has `N` points; field `i` has `nnz_i` entries; the jaw group `N_j` entries.

use nalgebra::{Point3, Rotation3, Unit, Vector3};

use crate::deform::{Deformer, MuscleShape};
use crate::error::{Error, Result};
use crate::set::MuscleSet;

/// One muscle's displacement field at `c = 1`, sparse.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseField {
    /// Vertex indices with a non-zero displacement, ascending.
    pub indices: Vec<u32>,
    /// Displacements `w_i(P) (P'_i - P)`, one per index.
    pub deltas: Vec<Vector3<f64>>,
}

/// The jaw: pivot, axis, range and weighted vertex group.
#[derive(Debug, Clone, PartialEq)]
pub struct JawRig {
    /// Rotation centre.
    pub pivot: Point3<f64>,
    /// Unit rotation axis (model X by default).
    pub axis: Unit<Vector3<f64>>,
    /// Largest angle (rad).
    pub max_angle: f64,
    /// Jaw vertices.
    pub indices: Vec<u32>,
    /// Their weights in `[0, 1]`.
    pub weights: Vec<f64>,
}

/// A mesh with precomputed muscle fields (see module docs).
#[derive(Debug, Clone)]
pub struct MuscleRig {
    names: Vec<String>,
    base: Vec<Point3<f64>>,
    fields: Vec<SparseField>,
    jaw: Option<JawRig>,
}

/// Area-weighted unit vertex normals of a triangle mesh (zero for isolated vertices).
pub fn vertex_normals(positions: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    let mut n = vec![Vector3::zeros(); positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= positions.len() || b >= positions.len() || c >= positions.len() {
            continue;
        }
        let f = (positions[b] - positions[a]).cross(&(positions[c] - positions[a]));
        n[a] += f;
        n[b] += f;
        n[c] += f;
    }
    for v in &mut n {
        let l = v.norm();
        if l > 0.0 {
            *v /= l;
        }
    }
    n
}

/// The outward direction for a sphincter: mean normal of the vertices within the
/// corner distance of its centre (None when there are no normals nearby).
fn outward_hint(shape: &MuscleShape, positions: &[Point3<f64>], normals: &[Vector3<f64>]) -> Option<Vector3<f64>> {
    let MuscleShape::Sphincter(s) = shape else {
        return None;
    };
    let c = Point3::from(s.centre);
    let r = (Point3::from(s.corner) - c).norm();
    let mut acc = Vector3::zeros();
    for (p, n) in positions.iter().zip(normals) {
        if (p - c).norm() <= r {
            acc += n;
        }
    }
    (acc.norm() > 0.0).then_some(acc)
}

/// Per-vertex weight lookup of a muscle's group (`None` = every vertex, weight 1).
fn group_weights(set: &MuscleSet, group: Option<&String>, n: usize) -> Option<Vec<f64>> {
    let g = set.vertex_groups.get(group?)?;
    let mut w = vec![0.0; n];
    for (k, &i) in g.indices.iter().enumerate() {
        w[i as usize] = g.weight(k);
    }
    Some(w)
}

fn check_inputs(set: &MuscleSet, positions: &[Point3<f64>], normals: &[Vector3<f64>]) -> Result<()> {
    set.validate()?;
    set.validate_for_mesh(positions.len())?;
    if normals.len() != positions.len() {
        return Err(Error::DimensionMismatch {
            what: "normal count".into(),
            expected: positions.len(),
            got: normals.len(),
        });
    }
    if let Some(i) = positions.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid(
            "vertex position",
            format!("vertex {i}"),
            "finite coordinates",
        ));
    }
    Ok(())
}

impl MuscleRig {
    /// Builds the rig: validates the set against the mesh and evaluates every deformer on
    /// every vertex once (O(N * muscles)).
    ///
    /// # Errors
    /// Invalid set, group indices out of range, normals count mismatch, non-finite positions.
    pub fn new(set: &MuscleSet, positions: &[Point3<f64>], normals: &[Vector3<f64>]) -> Result<Self> {
        check_inputs(set, positions, normals)?;
        let n = positions.len();
        let mut fields = Vec::with_capacity(set.muscles.len());
        for m in &set.muscles {
            let def = Deformer::new(&m.shape, &m.name, outward_hint(&m.shape, positions, normals))?;
            let gw = group_weights(set, m.vertex_group.as_ref(), n);
            let mut f = SparseField {
                indices: Vec::new(),
                deltas: Vec::new(),
            };
            for (i, (p, nm)) in positions.iter().zip(normals).enumerate() {
                let w = gw.as_ref().map_or(1.0, |g| g[i]);
                if w == 0.0 {
                    continue;
                }
                let d = def.displacement(p, nm) * w;
                if d != Vector3::zeros() {
                    f.indices.push(i as u32);
                    f.deltas.push(d);
                }
            }
            fields.push(f);
        }
        let jaw = match &set.jaw {
            None => None,
            Some(j) => {
                let g = &set.vertex_groups[&j.vertex_group];
                let (mut indices, mut weights) = (Vec::new(), Vec::new());
                for (k, &i) in g.indices.iter().enumerate() {
                    if g.weight(k) > 0.0 {
                        indices.push(i);
                        weights.push(g.weight(k));
                    }
                }
                Some(JawRig {
                    pivot: Point3::from(j.pivot),
                    axis: Unit::new_normalize(Vector3::from(j.axis)),
                    max_angle: j.max_angle,
                    indices,
                    weights,
                })
            }
        };
        Ok(MuscleRig {
            names: set.muscles.iter().map(|m| m.name.clone()).collect(),
            base: positions.to_vec(),
            fields,
            jaw,
        })
    }

    /// Builds from a core mesh (f32), computing normals from its triangles.
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn from_mesh(set: &MuscleSet, mesh: &facecap_core::mesh::Mesh) -> Result<Self> {
        let pos: Vec<Point3<f64>> = mesh.positions.iter().map(|p| p.cast()).collect();
        let normals = vertex_normals(&pos, &mesh.triangles);
        Self::new(set, &pos, &normals)
    }

    /// Muscle names (CSV columns / morph target names).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Number of muscles.
    pub fn num_muscles(&self) -> usize {
        self.fields.len()
    }

    /// Rest positions.
    pub fn base(&self) -> &[Point3<f64>] {
        &self.base
    }

    /// Per-muscle sparse fields.
    pub fn fields(&self) -> &[SparseField] {
        &self.fields
    }

    /// The jaw, if the set has one.
    pub fn jaw(&self) -> Option<&JawRig> {
        self.jaw.as_ref()
    }

    /// Largest jaw angle (0 without a jaw).
    pub fn max_jaw(&self) -> f64 {
        self.jaw.as_ref().map_or(0.0, |j| j.max_angle)
    }

    /// Checks a parameter vector: `c.len()` muscles, each finite in `[0, 1]`, jaw finite in
    /// `[0, max_angle]` (exactly 0 without a jaw).
    ///
    /// # Errors
    /// Names the offending muscle or `jaw`.
    pub fn check_params(&self, c: &[f64], jaw: f64) -> Result<()> {
        if c.len() != self.fields.len() {
            return Err(Error::DimensionMismatch {
                what: "contraction count".into(),
                expected: self.fields.len(),
                got: c.len(),
            });
        }
        for (name, &v) in self.names.iter().zip(c) {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(Error::invalid(format!("contraction of {name:?}"), v, "in [0, 1]"));
            }
        }
        let hi = self.max_jaw();
        if !(jaw.is_finite() && (0.0..=hi).contains(&jaw)) {
            return Err(Error::invalid("jaw", jaw, format!("in [0, {hi}]")));
        }
        Ok(())
    }

    /// Writes the posed mesh into `out` (length `N`): see module docs. No allocation.
    ///
    /// # Errors
    /// As [`Self::check_params`]; `out` of the wrong length.
    pub fn pose_into(&self, c: &[f64], jaw: f64, out: &mut [Point3<f64>]) -> Result<()> {
        self.check_params(c, jaw)?;
        if out.len() != self.base.len() {
            return Err(Error::DimensionMismatch {
                what: "posed output length".into(),
                expected: self.base.len(),
                got: out.len(),
            });
        }
        out.copy_from_slice(&self.base);
        for (f, &ci) in self.fields.iter().zip(c) {
            if ci == 0.0 {
                continue;
            }
            for (&i, d) in f.indices.iter().zip(&f.deltas) {
                out[i as usize] += d * ci;
            }
        }
        if let Some(j) = &self.jaw {
            if jaw != 0.0 {
                let r = Rotation3::from_axis_angle(&j.axis, jaw);
                for (&i, &w) in j.indices.iter().zip(&j.weights) {
                    let p = out[i as usize];
                    let rotated = j.pivot + r * (p - j.pivot);
                    out[i as usize] = p + (rotated - p) * w;
                }
            }
        }
        Ok(())
    }

    /// Dense displacement `P_final - P` of every vertex for one muscle at `c = 1` and a
    /// closed jaw, for baking morph targets.
    pub fn dense_field(&self, muscle: usize) -> Vec<Vector3<f64>> {
        let mut d = vec![Vector3::zeros(); self.base.len()];
        if let Some(f) = self.fields.get(muscle) {
            for (&i, v) in f.indices.iter().zip(&f.deltas) {
                d[i as usize] = *v;
            }
        }
        d
    }

    /// Dense displacement of the jaw opened to `angle` with no contraction.
    pub fn dense_jaw(&self, angle: f64) -> Vec<Vector3<f64>> {
        let mut d = vec![Vector3::zeros(); self.base.len()];
        if let Some(j) = &self.jaw {
            let r = Rotation3::from_axis_angle(&j.axis, angle);
            for (&i, &w) in j.indices.iter().zip(&j.weights) {
                let p = self.base[i as usize];
                d[i as usize] = (j.pivot + r * (p - j.pivot) - p) * w;
            }
        }
        d
    }
}

/// Slow reference: evaluates every deformer on every vertex for these contractions, with
/// no precomputation (for property tests of [`MuscleRig::pose_into`]).
///
/// # Errors
/// As [`MuscleRig::new`].
pub fn pose_reference(
    set: &MuscleSet,
    positions: &[Point3<f64>],
    normals: &[Vector3<f64>],
    c: &[f64],
    jaw: f64,
) -> Result<Vec<Point3<f64>>> {
    check_inputs(set, positions, normals)?;
    if c.len() != set.muscles.len() {
        return Err(Error::DimensionMismatch {
            what: "contraction count".into(),
            expected: set.muscles.len(),
            got: c.len(),
        });
    }
    let mut out = positions.to_vec();
    for (m, &ci) in set.muscles.iter().zip(c) {
        let def = Deformer::new(&m.shape, &m.name, outward_hint(&m.shape, positions, normals))?;
        let gw = group_weights(set, m.vertex_group.as_ref(), positions.len());
        for (i, p) in positions.iter().enumerate() {
            let w = gw.as_ref().map_or(1.0, |g| g[i]);
            // P_new = P + sum_i c_i (P'_i - P), with P'_i = P + w * displacement.
            let p_prime = p + def.displacement(p, &normals[i]) * w;
            out[i] += (p_prime - p) * ci;
        }
    }
    if let Some(j) = &set.jaw {
        let axis = Unit::new_normalize(Vector3::from(j.axis));
        let pivot = Point3::from(j.pivot);
        let g = &set.vertex_groups[&j.vertex_group];
        for (k, &i) in g.indices.iter().enumerate() {
            let w = g.weight(k);
            let p = out[i as usize];
            let rotated = pivot + Rotation3::from_axis_angle(&axis, jaw) * (p - pivot);
            out[i as usize] = p.lerp(&rotated, w);
        }
    }
    Ok(out)
}
