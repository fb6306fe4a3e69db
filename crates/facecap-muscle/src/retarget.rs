//! Retargeting a muscle set to another mesh, and baking muscles into morph targets.
//!
//! **Same topology** (thesis Algorithm 1): every control point `p` of the source set follows
//! its nearest source vertex `v = argmin_j |p - S_j|`, keeping its offset:
//! `p' = T_v + (p - S_v)`. Vertex groups keep their indices; the jaw pivot moves the same way.
//!
//! **Across topologies** (through the 68-landmark maps): a similarity `y = s R x + t` is fitted
//! (Umeyama) from the source to the target landmarks mapped on both meshes; every control
//! point is mapped by it plus an inverse-distance-weighted (4 nearest landmarks, weights
//! `1/d^2`) interpolation of the landmark residuals, so points near a landmark land on its
//! target position. Length parameters scale by `s`. Vertex groups transfer by nearest
//! neighbour: a target vertex takes the weight of the nearest warped source vertex when that
//! vertex lies within `2 * mean source edge length * s`.

use nalgebra::{Point3, Vector3};

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::{MorphMesh, MorphTarget};

use crate::error::{Error, Result};
use crate::rig::MuscleRig;
use crate::set::{MuscleSet, VertexGroup};

fn nearest(points: &[Point3<f64>], p: &Point3<f64>) -> Option<usize> {
    points
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - p).norm_squared().total_cmp(&(b.1 - p).norm_squared()))
        .map(|(i, _)| i)
}

/// Thesis Algorithm 1: retarget `set` from `source` to `target` (same topology).
///
/// # Errors
/// Different vertex counts, empty meshes, or an invalid result.
pub fn retarget_same_topology(set: &MuscleSet, source: &[Point3<f64>], target: &[Point3<f64>]) -> Result<MuscleSet> {
    if source.len() != target.len() {
        return Err(Error::DimensionMismatch {
            what: "target vertex count (same-topology retargeting)".into(),
            expected: source.len(),
            got: target.len(),
        });
    }
    let follow = |p: [f64; 3]| -> Result<[f64; 3]> {
        let q = Point3::from(p);
        let v = nearest(source, &q).ok_or_else(|| Error::invalid("source mesh", "empty", "vertices"))?;
        let r = target[v] + (q - source[v]);
        Ok([r.x, r.y, r.z])
    };
    let mut out = set.clone();
    for m in &mut out.muscles {
        let pts = m
            .shape
            .control_points()
            .into_iter()
            .map(follow)
            .collect::<Result<Vec<_>>>()?;
        m.shape.set_control_points(&pts)?;
    }
    if let Some(j) = &mut out.jaw {
        j.pivot = follow(j.pivot)?;
    }
    out.validate()?;
    Ok(out)
}

/// Retargets across topologies through the landmark maps (see module docs).
///
/// # Errors
/// Fewer than 4 landmarks mapped on both meshes, map indices out of range, degenerate
/// alignment.
pub fn retarget_via_landmarks(
    set: &MuscleSet,
    source: &[Point3<f64>],
    source_map: &LandmarkMap,
    target: &[Point3<f64>],
    target_map: &LandmarkMap,
    source_triangles: &[[u32; 3]],
) -> Result<MuscleSet> {
    source_map.validate(source.len())?;
    target_map.validate(target.len())?;
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for i in 0..68 {
        if let (Some(a), Some(b)) = (source_map.vertices[i], target_map.vertices[i]) {
            src.push(source[a as usize]);
            dst.push(target[b as usize]);
        }
    }
    if src.len() < 4 {
        return Err(Error::invalid("landmarks mapped on both meshes", src.len(), ">= 4"));
    }
    let sim = facecap_geom::align::umeyama3(&src, &dst, None, true)?;
    let resid: Vec<Vector3<f64>> = src.iter().zip(&dst).map(|(a, b)| b - sim.apply(a)).collect();
    let warped_lm: Vec<Point3<f64>> = src.iter().map(|a| sim.apply(a)).collect();
    let warp = |p: &Point3<f64>| -> Point3<f64> {
        let q = sim.apply(p);
        let mut d: Vec<(f64, usize)> = warped_lm
            .iter()
            .enumerate()
            .map(|(i, l)| ((l - q).norm_squared(), i))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut acc, mut wsum) = (Vector3::zeros(), 0.0);
        for &(d2, i) in d.iter().take(4) {
            if d2 < 1e-24 {
                return q + resid[i];
            }
            acc += resid[i] / d2;
            wsum += 1.0 / d2;
        }
        q + acc / wsum
    };
    let mut out = set.clone();
    for m in &mut out.muscles {
        let pts: Vec<[f64; 3]> = m
            .shape
            .control_points()
            .into_iter()
            .map(|p| {
                let w = warp(&Point3::from(p));
                [w.x, w.y, w.z]
            })
            .collect();
        m.shape.set_control_points(&pts)?;
        m.shape.scale_lengths(sim.scale);
    }
    if let Some(j) = &mut out.jaw {
        let w = warp(&Point3::from(j.pivot));
        j.pivot = [w.x, w.y, w.z];
    }
    // Vertex groups by nearest warped source vertex (uniform grid search).
    if !out.vertex_groups.is_empty() {
        let mut edge = 0.0;
        let mut ne = 0usize;
        for t in source_triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                if let (Some(p), Some(q)) = (source.get(a as usize), source.get(b as usize)) {
                    edge += (p - q).norm();
                    ne += 1;
                }
            }
        }
        let radius = if ne > 0 {
            2.0 * edge / ne as f64 * sim.scale
        } else {
            f64::INFINITY
        };
        let warped: Vec<Point3<f64>> = source.iter().map(&warp).collect();
        let grid = Grid::new(&warped, if radius.is_finite() { radius } else { 1.0 });
        let nearest_src: Vec<Option<usize>> = target.iter().map(|p| grid.nearest_within(&warped, p, radius)).collect();
        for g in out.vertex_groups.values_mut() {
            let mut w_of = vec![0.0; source.len()];
            for (k, &i) in g.indices.iter().enumerate() {
                if let Some(x) = w_of.get_mut(i as usize) {
                    *x = g.weight(k);
                }
            }
            let (mut idx, mut ws) = (Vec::new(), Vec::new());
            for (t, ns) in nearest_src.iter().enumerate() {
                if let Some(s) = ns {
                    if w_of[*s] > 0.0 {
                        idx.push(t as u32);
                        ws.push(w_of[*s]);
                    }
                }
            }
            *g = VertexGroup {
                indices: idx,
                weights: Some(ws),
            };
        }
    }
    out.validate()?;
    Ok(out)
}

/// A uniform hash grid for nearest-neighbour queries within a radius.
struct Grid {
    cell: f64,
    map: std::collections::HashMap<(i64, i64, i64), Vec<usize>>,
}

impl Grid {
    fn key(&self, p: &Point3<f64>) -> (i64, i64, i64) {
        (
            (p.x / self.cell).floor() as i64,
            (p.y / self.cell).floor() as i64,
            (p.z / self.cell).floor() as i64,
        )
    }
    fn new(points: &[Point3<f64>], cell: f64) -> Self {
        let mut g = Grid {
            cell: cell.max(1e-12),
            map: Default::default(),
        };
        for (i, p) in points.iter().enumerate() {
            let k = g.key(p);
            g.map.entry(k).or_default().push(i);
        }
        g
    }
    fn nearest_within(&self, points: &[Point3<f64>], p: &Point3<f64>, radius: f64) -> Option<usize> {
        let (x, y, z) = self.key(p);
        let mut best: Option<(f64, usize)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(v) = self.map.get(&(x + dx, y + dy, z + dz)) {
                        for &i in v {
                            let d = (points[i] - p).norm();
                            if d <= radius && best.map_or(true, |b| d < b.0) {
                                best = Some((d, i));
                            }
                        }
                    }
                }
            }
        }
        best.map(|b| b.1)
    }
}

/// Name of the baked jaw morph target.
pub const JAW_TARGET: &str = "jaw_open";

/// Bakes every muscle at full contraction (and the jaw at `max_angle`, as [`JAW_TARGET`])
/// into named morph targets on `base` (whose positions the rig was built from).
/// Existing targets of `base` are kept and the new ones appended.
///
/// # Errors
/// Vertex count mismatch between `base` and the rig.
pub fn bake(rig: &MuscleRig, base: &MorphMesh) -> Result<MorphMesh> {
    let n = base.base.num_vertices();
    if n != rig.base().len() {
        return Err(Error::DimensionMismatch {
            what: "mesh vertex count (bake)".into(),
            expected: rig.base().len(),
            got: n,
        });
    }
    let mut out = base.clone();
    for (i, name) in rig.names().iter().enumerate() {
        out.targets.push(MorphTarget {
            name: name.clone(),
            deltas: rig.dense_field(i).iter().map(|d| d.cast()).collect(),
        });
    }
    if rig.jaw().is_some() {
        out.targets.push(MorphTarget {
            name: JAW_TARGET.into(),
            deltas: rig.dense_jaw(rig.max_jaw()).iter().map(|d| d.cast()).collect(),
        });
    }
    Ok(out)
}
