//! Dense correspondences: where the points of a dense landmark layout (MediaPipe's
//! 478-point face mesh) lie on a rig, so that the 3D solve can use all of them rather than
//! the 68 iBUG points only (docs/expressions.md, "Dense solve").
//!
//! # Method
//! 1. A 3D model of the layout (MediaPipe's canonical face) is aligned to the rig's
//!    neutral by a similarity ([`facecap_geom::align::umeyama3`]) on the iBUG points both
//!    know (the layout's iBUG vertex of each landmark, the rig's [`LandmarkMap`]).
//! 2. A 3D thin-plate spline ([`facecap_geom::tps::Tps3`]) on the same pairs warps it onto
//!    the rig's proportions.
//! 3. Each warped point is projected to the closest point of the rig's surface (a triangle
//!    and barycentric weights). Points further than `max_residual_iod` inter-ocular
//!    distances from the surface (off the rig: eyeballs, mouth interior, the back of the
//!    head) are dropped.
//!
//! The rig's neutral and deltas at a mapped point are the barycentric mix of its triangle's
//! vertices ([`DenseMap::points`]), so the point moves with the rig's expressions.

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::NUM_LANDMARKS;
use facecap_core::mesh::{Mesh, MorphMesh};
use facecap_geom::align::umeyama3;
use facecap_geom::tps::Tps3;
use nalgebra::{Point3, Vector3};

use crate::error::{Error, Result};
use crate::exact3d::DensePoints;
use crate::rig::BlendshapeRig;

/// Parameters of [`map_onto_rig`].
#[derive(Debug, Clone, PartialEq)]
pub struct DenseMapParams {
    /// Largest distance (in rig inter-ocular distances) from a warped point to the rig's
    /// surface; further points are dropped.
    pub max_residual_iod: f64,
    /// Layout points never mapped (e.g. the points already used as the 68 iBUG points).
    pub skip: Vec<usize>,
}

impl Default for DenseMapParams {
    fn default() -> Self {
        DenseMapParams {
            max_residual_iod: 0.05,
            skip: Vec::new(),
        }
    }
}

/// One layout point on the rig's surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseTarget {
    /// Index of the point in the layout (e.g. the mesh landmark).
    pub source: usize,
    /// The rig triangle it lies on.
    pub triangle: [u32; 3],
    /// Barycentric weights on `triangle` (sum 1, each `>= 0`).
    pub bary: [f64; 3],
    /// Distance from the warped point to the surface, in rig inter-ocular distances.
    pub residual_iod: f64,
}

/// The layout points that landed on the rig (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseMap {
    /// Mapped points, in layout order.
    pub targets: Vec<DenseTarget>,
    /// Layout points dropped for lying off the rig.
    pub dropped: Vec<usize>,
    /// The rig's inter-ocular distance (outer eye corners 36-45), rig units.
    pub iod: f64,
    /// RMS distance, after the similarity, of the layout's iBUG points to the rig's (IOD).
    pub similarity_rms_iod: f64,
}

fn p3(p: &Point3<f32>) -> Vector3<f64> {
    Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z))
}

/// Closest point of triangle `abc` to `p` as barycentric weights (Ericson, "Real-Time
/// Collision Detection", 5.1.5).
fn closest_on_triangle(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> [f64; 3] {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = va + vb + vc;
    if denom.abs() < 1e-300 || !denom.is_finite() {
        return [1.0, 0.0, 0.0];
    }
    let v = vb / denom;
    let w = vc / denom;
    [1.0 - v - w, v, w]
}

/// The closest surface point of `mesh` to `p`: (triangle, barycentric weights, distance).
fn closest_on_mesh(mesh: &Mesh, p: &Vector3<f64>) -> Option<([u32; 3], [f64; 3], f64)> {
    let mut best: Option<([u32; 3], [f64; 3], f64)> = None;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|v| p3(&mesh.positions[v as usize]));
        // cheap reject: the triangle's bounding sphere is further than the best so far
        if let Some((_, _, d)) = best {
            let centre = (a + b + c) / 3.0;
            let r = (a - centre).norm().max((b - centre).norm()).max((c - centre).norm());
            if (p - centre).norm() - r > d {
                continue;
            }
        }
        let w = closest_on_triangle(p, &a, &b, &c);
        let q = a * w[0] + b * w[1] + c * w[2];
        let d = (p - q).norm();
        if d.is_finite() && best.map_or(true, |(_, _, bd)| d < bd) {
            best = Some((*t, w, d));
        }
    }
    best
}

/// Maps the layout `source` (3D points; `source_ibug[l]` is the layout point of iBUG
/// landmark `l`) onto the surface of `mesh` (the rig's neutral; `map` its iBUG vertices).
///
/// # Errors
/// Fewer than 6 usable iBUG pairs, a mesh without triangles, an out-of-range index, or a
/// degenerate alignment.
pub fn map_onto_rig(
    source: &[[f64; 3]],
    source_ibug: &[usize; NUM_LANDMARKS],
    mesh: &Mesh,
    map: &LandmarkMap,
    params: &DenseMapParams,
) -> Result<DenseMap> {
    let src_name = "dense map";
    if mesh.triangles.is_empty() {
        return Err(Error::rig(src_name, "the rig mesh has no triangles"));
    }
    let nv = mesh.positions.len();
    if mesh.triangles.iter().any(|t| t.iter().any(|&v| v as usize >= nv)) {
        return Err(Error::rig(src_name, "a triangle names a vertex the mesh does not have"));
    }
    if !(params.max_residual_iod.is_finite() && params.max_residual_iod > 0.0) {
        return Err(Error::invalid(
            "max_residual_iod",
            params.max_residual_iod,
            "a finite number > 0",
        ));
    }
    let mut src = Vec::new();
    let mut dst = Vec::new();
    for (l, v) in map.mapped() {
        let s = source_ibug[l];
        if s >= source.len() || v as usize >= nv {
            return Err(Error::rig(src_name, format!("iBUG point {l}: index out of range")));
        }
        let q = mesh.positions[v as usize];
        src.push(Point3::new(source[s][0], source[s][1], source[s][2]));
        dst.push(Point3::new(f64::from(q.x), f64::from(q.y), f64::from(q.z)));
    }
    if src.len() < 6 {
        return Err(Error::rig(
            src_name,
            format!("{} iBUG pairs; at least 6 needed", src.len()),
        ));
    }
    let sim = umeyama3(&src, &dst, None, true).map_err(|e| Error::rig(src_name, e.to_string()))?;
    let iod = match (map.vertices[36], map.vertices[45]) {
        (Some(a), Some(b)) => (p3(&mesh.positions[a as usize]) - p3(&mesh.positions[b as usize])).norm(),
        _ => {
            // the spread of the mapped points stands in for the eye distance
            let c = dst.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) / dst.len() as f64;
            let rms = (dst.iter().map(|p| (p.coords - c).norm_squared()).sum::<f64>() / dst.len() as f64).sqrt();
            rms * 0.8
        }
    };
    if !(iod.is_finite() && iod > 0.0) {
        return Err(Error::rig(src_name, "degenerate rig landmarks (zero eye distance)"));
    }
    let aligned: Vec<[f64; 3]> = src.iter().map(|p| sim.apply(p).coords.into()).collect();
    let targets_ibug: Vec<[f64; 3]> = dst.iter().map(|p| p.coords.into()).collect();
    let similarity_rms_iod = (aligned
        .iter()
        .zip(&targets_ibug)
        .map(|(a, b)| (Vector3::from(*a) - Vector3::from(*b)).norm_squared())
        .sum::<f64>()
        / aligned.len() as f64)
        .sqrt()
        / iod;
    let tps = Tps3::fit(&aligned, &targets_ibug)
        .ok_or_else(|| Error::rig(src_name, "the thin-plate warp onto the rig is singular"))?;
    let mut targets = Vec::new();
    let mut dropped = Vec::new();
    let skip: std::collections::HashSet<usize> = params.skip.iter().copied().collect();
    for (i, s) in source.iter().enumerate() {
        if skip.contains(&i) {
            continue;
        }
        let a = sim.apply(&Point3::new(s[0], s[1], s[2]));
        let w = Vector3::from(tps.apply(&a.coords.into()));
        match closest_on_mesh(mesh, &w) {
            Some((triangle, bary, d)) if d <= params.max_residual_iod * iod => targets.push(DenseTarget {
                source: i,
                triangle,
                bary,
                residual_iod: d / iod,
            }),
            _ => dropped.push(i),
        }
    }
    Ok(DenseMap {
        targets,
        dropped,
        iod,
        similarity_rms_iod,
    })
}

impl DenseMap {
    /// The mapped points' neutral positions on `mesh`'s base.
    pub fn neutral_positions(&self, mesh: &Mesh) -> Vec<Vector3<f64>> {
        self.targets
            .iter()
            .map(|t| {
                (0..3)
                    .map(|c| p3(&mesh.positions[t.triangle[c] as usize]) * t.bary[c])
                    .sum()
            })
            .collect()
    }

    /// The mapped points as extra points of the 3D solve: neutral and per-shape deltas of
    /// `mesh` at each point, observed as layout point `source`, each squared residual
    /// weighted `weight`.
    ///
    /// # Errors
    /// A mesh that is not the one mapped (triangle out of range, targets of another size).
    pub fn points(&self, mesh: &MorphMesh, weight: f64) -> Result<DensePoints> {
        let nv = mesh.base.positions.len();
        if self
            .targets
            .iter()
            .any(|t| t.triangle.iter().any(|&v| v as usize >= nv))
            || mesh.targets.iter().any(|t| t.deltas.len() != nv)
        {
            return Err(Error::rig("dense map", "the map was made for another mesh"));
        }
        let neutral = self.neutral_positions(&mesh.base);
        let n = mesh.targets.len();
        let mut deltas = Vec::with_capacity(self.targets.len() * n);
        for t in &self.targets {
            for m in &mesh.targets {
                let d: Vector3<f64> = (0..3)
                    .map(|c| {
                        let v = m.deltas[t.triangle[c] as usize];
                        Vector3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z)) * t.bary[c]
                    })
                    .sum();
                deltas.push(d);
            }
        }
        DensePoints::new(
            self.targets.iter().map(|t| t.source).collect(),
            neutral,
            deltas,
            n,
            weight,
        )
    }
}

/// `points` moved by the neutral calibration that took `generic` to `calibrated` (the
/// same rig with the subject's neutral at the 68 points): the offsets at the mapped iBUG
/// points, interpolated to the dense points by a 3D thin-plate spline over the generic
/// neutral. Unchanged when the rigs' neutrals are equal or too few points are mapped.
pub fn calibrate_points(points: &DensePoints, generic: &BlendshapeRig, calibrated: &BlendshapeRig) -> DensePoints {
    let mut centres = Vec::new();
    let mut offsets = Vec::new();
    let mut any = false;
    for l in 0..NUM_LANDMARKS {
        if !(generic.mapped[l] && calibrated.mapped[l]) {
            continue;
        }
        let g = [
            generic.neutral[[l, 0]],
            generic.neutral[[l, 1]],
            generic.neutral[[l, 2]],
        ];
        let c = [
            calibrated.neutral[[l, 0]],
            calibrated.neutral[[l, 1]],
            calibrated.neutral[[l, 2]],
        ];
        let o = [c[0] - g[0], c[1] - g[1], c[2] - g[2]];
        any |= o.iter().any(|v| *v != 0.0);
        centres.push(g);
        offsets.push(o);
    }
    if !any {
        return points.clone();
    }
    let Some(tps) = Tps3::fit(&centres, &offsets) else {
        return points.clone();
    };
    let mut out = points.clone();
    out.shift_neutral(|p| {
        let o = tps.apply(&[p.x, p.y, p.z]);
        Vector3::new(o[0], o[1], o[2])
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bumpy grid surface with 68 "iBUG" vertices spread over it.
    fn grid_mesh() -> (Mesh, LandmarkMap, Vec<[f64; 3]>, [usize; NUM_LANDMARKS]) {
        let (nx, ny) = (20usize, 20usize);
        let mut positions = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let (x, y) = (i as f64 * 0.5 - 5.0, j as f64 * 0.5 - 5.0);
                let z = 2.0 * (-(x * x + y * y) / 20.0).exp() + 0.1 * (x * 0.7).sin();
                positions.push(Point3::new(x as f32, y as f32, z as f32));
            }
        }
        let mut triangles = Vec::new();
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let v = (j * nx + i) as u32;
                let w = nx as u32;
                triangles.push([v, v + 1, v + w + 1]);
                triangles.push([v, v + w + 1, v + w]);
            }
        }
        let mesh = Mesh {
            positions,
            triangles,
            normals: Vec::new(),
            uvs: Vec::new(),
        };
        let mut vertices = [None; NUM_LANDMARKS];
        let mut ibug = [0usize; NUM_LANDMARKS];
        for l in 0..NUM_LANDMARKS {
            let v = (l * 37 + 11) % (nx * ny);
            vertices[l] = Some(v as u32);
            ibug[l] = v;
        }
        // eye corners far enough apart
        vertices[36] = Some((10 * nx + 4) as u32);
        vertices[45] = Some((10 * nx + 15) as u32);
        ibug[36] = 10 * nx + 4;
        ibug[45] = 10 * nx + 15;
        let source: Vec<[f64; 3]> = mesh
            .positions
            .iter()
            .map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)])
            .collect();
        (mesh, LandmarkMap { vertices }, source, ibug)
    }

    #[test]
    fn a_rig_that_is_the_layout_maps_every_point_to_itself() {
        let (mesh, map, source, ibug) = grid_mesh();
        // the layout in another frame: rotated, scaled and moved
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let moved: Vec<[f64; 3]> = source
            .iter()
            .map(|p| (r * Vector3::from(*p) * 3.0 + Vector3::new(1.0, -2.0, 5.0)).into())
            .collect();
        let m = map_onto_rig(&moved, &ibug, &mesh, &map, &DenseMapParams::default()).unwrap();
        assert!(m.dropped.is_empty(), "dropped {:?}", m.dropped);
        assert_eq!(m.targets.len(), source.len());
        assert!(m.similarity_rms_iod < 1e-6);
        let pos = m.neutral_positions(&mesh);
        for (t, p) in m.targets.iter().zip(&pos) {
            let want = Vector3::from(source[t.source]);
            assert!(
                (p - want).norm() < 1e-4 * m.iod,
                "point {} off by {}",
                t.source,
                (p - want).norm()
            );
        }
    }

    #[test]
    fn far_points_are_dropped_and_skipped_ones_left_out() {
        let (mesh, map, mut source, ibug) = grid_mesh();
        source.push([0.0, 0.0, 30.0]);
        let far = source.len() - 1;
        let params = DenseMapParams {
            skip: vec![0, 1],
            ..DenseMapParams::default()
        };
        let m = map_onto_rig(&source, &ibug, &mesh, &map, &params).unwrap();
        assert_eq!(m.dropped, vec![far]);
        assert!(m.targets.iter().all(|t| t.source >= 2 && t.source != far));
    }

    #[test]
    fn closest_point_on_a_triangle() {
        let (a, b, c) = (Vector3::zeros(), Vector3::x(), Vector3::y());
        let w = closest_on_triangle(&Vector3::new(0.25, 0.25, 1.0), &a, &b, &c);
        assert!((w[0] - 0.5).abs() < 1e-12 && (w[1] - 0.25).abs() < 1e-12);
        assert_eq!(
            closest_on_triangle(&Vector3::new(-1.0, -1.0, 0.0), &a, &b, &c),
            [1.0, 0.0, 0.0]
        );
        let w = closest_on_triangle(&Vector3::new(1.0, 1.0, 0.0), &a, &b, &c);
        assert!((w[1] - 0.5).abs() < 1e-12 && (w[2] - 0.5).abs() < 1e-12);
    }
}
