//! Triangle meshes with optional normals, UVs and morph targets (blendshapes).
//!
//! Positions are in the source file's units (ICT: cm, SFM: mm). Triangles are
//! counter-clockwise seen from outside. Morph targets store **position deltas**
//! (`posed = positions + sum_k w_k * targets[k].deltas`), as glTF does.

use nalgebra::{Point3, Vector3};

use crate::error::{Error, Result};

/// A triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Point3<f32>>,
    /// Triangles as vertex indices (CCW).
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex normals (empty or same length as `positions`).
    pub normals: Vec<Vector3<f32>>,
    /// Per-vertex texture coordinates (empty or same length as `positions`).
    pub uvs: Vec<[f32; 2]>,
}

/// One named morph target: a per-vertex position delta.
#[derive(Debug, Clone, PartialEq)]
pub struct MorphTarget {
    /// Target name (e.g. an ARKit blendshape name).
    pub name: String,
    /// Position deltas, same length as the base mesh's positions.
    pub deltas: Vec<Vector3<f32>>,
}

/// A mesh with named morph targets: a blendshape rig's geometry.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MorphMesh {
    /// The neutral (base) mesh.
    pub base: Mesh,
    /// Morph targets in file order.
    pub targets: Vec<MorphTarget>,
}

impl Mesh {
    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Checks that indices are in range, attribute lengths match and all values are finite.
    pub fn validate(&self) -> Result<()> {
        let n = self.positions.len();
        if !self.normals.is_empty() && self.normals.len() != n {
            return Err(Error::DimensionMismatch {
                what: "normal count".into(),
                expected: n,
                got: self.normals.len(),
            });
        }
        if !self.uvs.is_empty() && self.uvs.len() != n {
            return Err(Error::DimensionMismatch {
                what: "uv count".into(),
                expected: n,
                got: self.uvs.len(),
            });
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            for &i in tri {
                if i as usize >= n {
                    return Err(Error::invalid(
                        "triangle index",
                        format!("triangle {t} vertex {i}"),
                        format!("< {n}"),
                    ));
                }
            }
        }
        if let Some(i) = self
            .positions
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
        {
            return Err(Error::invalid(
                "vertex position",
                format!("vertex {i}"),
                "finite coordinates",
            ));
        }
        Ok(())
    }

    /// Recomputes area-weighted vertex normals from the triangles.
    pub fn compute_normals(&mut self) {
        let mut normals = vec![Vector3::<f32>::zeros(); self.positions.len()];
        for tri in &self.triangles {
            let [a, b, c] = tri.map(|i| self.positions[i as usize]);
            let n = (b - a).cross(&(c - a));
            for &i in tri {
                normals[i as usize] += n;
            }
        }
        for n in &mut normals {
            let len = n.norm();
            if len > 0.0 {
                *n /= len;
            }
        }
        self.normals = normals;
    }
}

impl MorphMesh {
    /// Target names in order.
    pub fn target_names(&self) -> Vec<&str> {
        self.targets.iter().map(|t| t.name.as_str()).collect()
    }

    /// Checks the base mesh and that every target has one delta per vertex.
    pub fn validate(&self) -> Result<()> {
        self.base.validate()?;
        let n = self.base.num_vertices();
        for t in &self.targets {
            if t.deltas.len() != n {
                return Err(Error::DimensionMismatch {
                    what: format!("delta count of morph target {:?}", t.name),
                    expected: n,
                    got: t.deltas.len(),
                });
            }
        }
        Ok(())
    }

    /// Writes `base + sum_k weights[k] * targets[k]` into `out` (resized as needed).
    pub fn pose_into(&self, weights: &[f64], out: &mut Vec<Point3<f32>>) -> Result<()> {
        if weights.len() != self.targets.len() {
            return Err(Error::DimensionMismatch {
                what: "morph weight count".into(),
                expected: self.targets.len(),
                got: weights.len(),
            });
        }
        out.clear();
        out.extend_from_slice(&self.base.positions);
        for (t, &w) in self.targets.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            let w = w as f32;
            for (p, d) in out.iter_mut().zip(&t.deltas) {
                *p += d * w;
            }
        }
        Ok(())
    }
}
