//! Pose-dependent correspondences of the jaw contour (iBUG points 0-16).
//!
//! The tracked contour points lie on the *silhouette* of the jaw and cheek: when the head
//! turns (or pitches), they slide over the face, so one fixed rig vertex per point biases
//! the pose, the jaw and the mouth. As in eos (Huber et al. 2016,
//! `fitting/contour_correspondence.hpp`), each contour landmark gets a list of candidate
//! rig points and, per frame, the candidate on the silhouette under the current pose is
//! used. Ours differs in how both are found:
//!
//! * **Candidates** ([`ContourCandidates::from_mesh`]): for contour landmark `l` with
//!   mapped vertex `a`, the rig's mesh vertices near the plane through `a` perpendicular to
//!   the contour's tangent there (`P[l+1] - P[l-1]`), reachable from `a` over mesh edges
//!   inside that slab, ordered along the surface from the front of the face (towards the
//!   nose or lips) to the back (towards the ear or under the chin), one vertex per edge
//!   length. Lines whose mesh ends at the contour (nothing behind the mapped vertex, e.g.
//!   the built-in 68-point rig) are dropped: those landmarks keep their fixed vertex.
//! * **Selection** (in [`crate::Exact3dSolver`]): each candidate's facing
//!   `f = n . v` (the cosine between its outward normal, rotated by the current head pose,
//!   and the direction from it to the camera, perspective) is compared with the mapped
//!   vertex's facing in the orthographic frontal view, `tau = n_a . z`: the rig's map
//!   places the vertex on the silhouette of a frontal face (a level above 0 where the map's
//!   vertex sits in front of the mesh's geometric silhouette), so the silhouette at another
//!   pose is where `f` crosses `tau` along the line (linear interpolation between the two
//!   candidates either side, so the point moves continuously). In the orthographic frontal
//!   view that is the mapped vertex itself; a near camera sees a little past it, and the
//!   points slide forwards by that much.
//!
//! | param | default | meaning |
//! |---|---|---|
//! | `slab` | 1.0 | half-width of the cross-section slab, in mean edge lengths at the vertex |
//! | `reach_iod` | 0.7 | largest distance of a candidate from the mapped vertex, inter-ocular distances |
//! | `min_back_iod` | 0.1 | a line needs candidates at least this deep (along -z) behind the mapped vertex |
//! | `max_vertical_normal` | 0.5 | lines whose mapped vertex's normal has `|n_y|` at least this (under the chin) are dropped |
//!
//! The last row keeps the chin's points (those facing downwards) fixed: there the silhouette
//! follows the head's pitch, which the 68 points determine poorly, and measured on real
//! video (docs/expressions.md, "Contour correspondences") letting them slide lowers `jawOpen`.

use std::collections::VecDeque;

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::Mesh;
use nalgebra::Vector3;

/// The contour landmarks: iBUG 0-16.
pub const CONTOUR_LANDMARKS: usize = 17;

/// Parameters of [`ContourCandidates::from_mesh`] (table in the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContourParams {
    /// Slab half-width, mean edge lengths.
    pub slab: f64,
    /// Reach, inter-ocular distances.
    pub reach_iod: f64,
    /// Shortest backward extent, inter-ocular distances.
    pub min_back_iod: f64,
    /// Largest `|n_y|` of the mapped vertex's normal.
    pub max_vertical_normal: f64,
}

impl Default for ContourParams {
    fn default() -> Self {
        ContourParams {
            slab: 1.0,
            reach_iod: 0.7,
            min_back_iod: 0.1,
            max_vertical_normal: 0.5,
        }
    }
}

/// The candidates of one contour landmark, front to back.
#[derive(Debug, Clone, PartialEq)]
pub struct ContourLine {
    /// The iBUG landmark (0-16).
    pub landmark: usize,
    /// Mesh vertices, front (towards the face's centre) to back.
    pub vertices: Vec<u32>,
    /// Index of the landmark's mapped vertex in `vertices`.
    pub anchor: usize,
    /// Each candidate's position minus the mapped vertex's, on the mesh's neutral.
    pub offsets: Vec<Vector3<f64>>,
    /// Unit outward normals of the candidates (smoothed along the line).
    pub normals: Vec<Vector3<f64>>,
}

impl ContourLine {
    /// The mapped vertex's facing in the frontal view (`n_a . z`), the silhouette's level.
    pub fn frontal_facing(&self) -> f64 {
        self.normals[self.anchor].z
    }
}

/// Candidate lines of the contour landmarks of a rig (see module docs); empty when the rig's
/// mesh gives none.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ContourCandidates {
    /// One line per contour landmark that has one.
    pub lines: Vec<ContourLine>,
}

impl ContourCandidates {
    /// Whether no landmark has candidates.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// Derives the candidate lines from a mesh and its landmark map (module docs). Never
    /// fails: landmarks whose vertices, neighbours or mesh give no usable line are left out.
    pub fn from_mesh(mesh: &Mesh, map: &LandmarkMap, params: &ContourParams) -> Self {
        let nv = mesh.positions.len();
        let pos: Vec<Vector3<f64>> = mesh
            .positions
            .iter()
            .map(|p| Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
            .collect();
        let vertex = |l: usize| map.vertices[l].map(|v| v as usize).filter(|&v| v < nv);
        let iod = match (vertex(36), vertex(45)) {
            (Some(a), Some(b)) => (pos[a] - pos[b]).norm(),
            _ => return ContourCandidates::default(),
        };
        if !(iod.is_finite() && iod > 0.0) || mesh.triangles.is_empty() {
            return ContourCandidates::default();
        }
        let normals = vertex_normals(&pos, &mesh.triangles, map);
        let neighbours = vertex_neighbours(nv, &mesh.triangles);
        let mut lines = Vec::new();
        for l in 0..CONTOUR_LANDMARKS {
            let Some(a) = vertex(l) else { continue };
            let prev = if l > 0 { vertex(l - 1) } else { None }.unwrap_or(a);
            let next = if l + 1 < CONTOUR_LANDMARKS { vertex(l + 1) } else { None }.unwrap_or(a);
            if let Some(line) = line_for(l, a, prev, next, &pos, &normals, &neighbours, iod, params) {
                lines.push(line);
            }
        }
        ContourCandidates { lines }
    }
}

/// Area-weighted vertex normals, oriented so the face (the mapped non-contour landmarks)
/// looks towards +z on average.
fn vertex_normals(pos: &[Vector3<f64>], tris: &[[u32; 3]], map: &LandmarkMap) -> Vec<Vector3<f64>> {
    let nv = pos.len();
    let mut n = vec![Vector3::zeros(); nv];
    for t in tris {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= nv || b >= nv || c >= nv {
            continue;
        }
        let f = (pos[b] - pos[a]).cross(&(pos[c] - pos[a]));
        if f.iter().all(|x| x.is_finite()) {
            n[a] += f;
            n[b] += f;
            n[c] += f;
        }
    }
    let mut facing = 0.0;
    for l in CONTOUR_LANDMARKS..map.vertices.len() {
        if let Some(v) = map.vertices[l].map(|v| v as usize).filter(|&v| v < nv) {
            facing += n[v].try_normalize(0.0).map_or(0.0, |u| u.z);
        }
    }
    let sign = if facing < 0.0 { -1.0 } else { 1.0 };
    n.iter()
        .map(|v| v.try_normalize(1e-300).map_or(Vector3::zeros(), |u| u * sign))
        .collect()
}

fn vertex_neighbours(nv: usize, tris: &[[u32; 3]]) -> Vec<Vec<u32>> {
    let mut nb: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for t in tris {
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            let (a, b) = (t[i], t[j]);
            if (a as usize) < nv && (b as usize) < nv && a != b {
                nb[a as usize].push(b);
                nb[b as usize].push(a);
            }
        }
    }
    for v in &mut nb {
        v.sort_unstable();
        v.dedup();
    }
    nb
}

/// The candidate line of landmark `l` at vertex `a` (module docs), `None` when there is none.
#[allow(clippy::too_many_arguments)]
fn line_for(
    l: usize,
    a: usize,
    prev: usize,
    next: usize,
    pos: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    neighbours: &[Vec<u32>],
    iod: f64,
    params: &ContourParams,
) -> Option<ContourLine> {
    let t = (pos[next] - pos[prev]).try_normalize(1e-12)?;
    let na = normals[a];
    let mut back = t.cross(&na).try_normalize(1e-12)?;
    if back.z > 0.0 {
        back = -back;
    }
    let edges = &neighbours[a];
    if edges.is_empty() {
        return None;
    }
    let edge = edges.iter().map(|&b| (pos[b as usize] - pos[a]).norm()).sum::<f64>() / edges.len() as f64;
    if !(edge.is_finite() && edge > 0.0) {
        return None;
    }
    let half = params.slab * edge;
    let reach = params.reach_iod * iod;
    let inside = |v: usize| {
        let d = pos[v] - pos[a];
        t.dot(&d).abs() <= half && d.norm() <= reach
    };
    // shortest paths from `a` over edges inside the slab; each vertex keeps the side
    // (front -1, back +1) of the first step of its path
    let nv = pos.len();
    let mut dist = vec![f64::INFINITY; nv];
    let mut side = vec![0i8; nv];
    let mut queue = VecDeque::new();
    dist[a] = 0.0;
    queue.push_back(a);
    let mut visited = 0usize;
    while let Some(v) = queue.pop_front() {
        visited += 1;
        if visited > 200_000 {
            break;
        }
        for &w in &neighbours[v] {
            let w = w as usize;
            if !inside(w) {
                continue;
            }
            let d = dist[v] + (pos[w] - pos[v]).norm();
            if d < dist[w] {
                dist[w] = d;
                side[w] = if v == a {
                    if back.dot(&(pos[w] - pos[a])) >= 0.0 {
                        1
                    } else {
                        -1
                    }
                } else {
                    side[v]
                };
                queue.push_back(w);
            }
        }
    }
    // one vertex per edge length along the path coordinate, the nearest to the plane
    let mut bins: std::collections::BTreeMap<i64, (f64, usize)> = std::collections::BTreeMap::new();
    for v in 0..nv {
        if v == a || !dist[v].is_finite() || side[v] == 0 {
            continue;
        }
        let u = f64::from(side[v]) * dist[v];
        let bin = (u / edge).round() as i64;
        if bin == 0 {
            continue;
        }
        let off = t.dot(&(pos[v] - pos[a])).abs();
        let e = bins.entry(bin).or_insert((f64::INFINITY, v));
        if off < e.0 {
            *e = (off, v);
        }
    }
    bins.insert(0, (0.0, a));
    let vertices: Vec<u32> = bins.values().map(|&(_, v)| v as u32).collect();
    let anchor = bins.keys().position(|&k| k == 0)?;
    // how far the mesh goes round behind the mapped vertex (depth, away from the viewer)
    let back_extent = vertices[anchor..]
        .iter()
        .map(|&v| pos[a].z - pos[v as usize].z)
        .fold(0.0, f64::max);
    if back_extent < params.min_back_iod * iod || vertices.len() < 2 {
        return None;
    }
    let raw: Vec<Vector3<f64>> = vertices.iter().map(|&v| normals[v as usize]).collect();
    let k = raw.len();
    let normals: Vec<Vector3<f64>> = (0..k)
        .map(|i| {
            let s = raw[i.saturating_sub(1)] + raw[i] * 2.0 + raw[(i + 1).min(k - 1)];
            s.try_normalize(1e-300).unwrap_or(raw[i])
        })
        .collect();
    if normals[anchor].y.abs() >= params.max_vertical_normal {
        return None;
    }
    Some(ContourLine {
        landmark: l,
        offsets: vertices.iter().map(|&v| pos[v as usize] - pos[a]).collect(),
        vertices,
        anchor,
        normals,
    })
}

/// Where the silhouette crosses `line` for facings `f` (one per candidate) against the
/// level `tau`: a fractional index into the line (module docs). From the anchor, backwards
/// while the anchor faces the camera more than at the frontal view, else forwards.
pub fn silhouette_index(f: &[f64], anchor: usize, tau: f64) -> f64 {
    let k = f.len();
    if k == 0 {
        return 0.0;
    }
    let g = |i: usize| f[i] - tau;
    if g(anchor) >= 0.0 {
        for c in anchor + 1..k {
            if g(c) < 0.0 {
                let (g0, g1) = (g(c - 1), g(c));
                return (c - 1) as f64 + g0 / (g0 - g1);
            }
        }
        (k - 1) as f64
    } else {
        for c in (0..anchor).rev() {
            if g(c) >= 0.0 {
                let (g0, g1) = (g(c), g(c + 1));
                return c as f64 + g0 / (g0 - g1);
            }
        }
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn silhouette_index_interpolates_the_crossing() {
        // facings decreasing front to back; level 0.5 crosses between 2 and 3
        let f = [0.9, 0.8, 0.6, 0.4, 0.1];
        assert!((silhouette_index(&f, 1, 0.5) - 2.5).abs() < 1e-12);
        // the anchor facing less than the level: forwards
        assert!((silhouette_index(&f, 4, 0.85) - 0.5).abs() < 1e-12);
        // at the level: the anchor itself
        assert!((silhouette_index(&f, 2, 0.6) - 2.0).abs() < 1e-12);
        // beyond the ends: clamped
        assert_eq!(silhouette_index(&f, 2, -1.0), 4.0);
        assert_eq!(silhouette_index(&f, 2, 2.0), 0.0);
    }
}
