//! The default rig used when `facecap capture` gets no `--rig`: built here, from no
//! external file.
//!
//! * **Neutral landmarks**: a 68-point 3D mean face (iBUG order, centimetres, +Y up,
//!   +Z out of the face). The numbers are the 68 landmark vertices of the ICT-FaceKit
//!   generic neutral mesh (USC ICT, MIT licence), rounded to 0.1 mm.
//! * **Dense mesh**: the 68 points and seven forehead/temple points are
//!   Delaunay-triangulated in the frontal (x, y) plane, the triangles inside the inner
//!   lip contour are left out (the mouth opening), each triangle is split 4-to-1 twice
//!   (16 triangles each), and every new vertex gets its depth from a thin-plate spline
//!   through those points, so the surface is smooth and passes exactly through the
//!   landmarks. Vertices 0..67 are the landmarks themselves, so the landmark map is the
//!   identity.
//! * **Blendshapes**: 16 ARKit-named expression shapes (`jawOpen`, `mouthSmileLeft`, ...)
//!   defined as 3D displacements of the 68 landmarks (FACS-style: which points move,
//!   which way, by how many cm), spread piecewise-linearly over the landmark triangles
//!   (a subdivision vertex moves as the mean of its edge's ends; a spline overshoots
//!   between the nearly touching lips and folds the mesh when the mouth opens); the
//!   forehead points stay. "Left" is the subject's left
//!   (image right, +X).

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_geom::delaunay::delaunay;
use facecap_geom::tps::Tps;
use nalgebra::{Point3, Vector3};

/// 3D mean face, iBUG-68 order, cm (see module docs).
pub const MEAN_FACE_68_CM: [[f64; 3]; 68] = [
    [-7.3630, 3.6763, 3.6567],
    [-7.2762, 1.4911, 3.9250],
    [-6.9376, -0.4614, 4.5329],
    [-6.5567, -2.3563, 5.1738],
    [-5.7241, -4.4868, 6.1275],
    [-4.3023, -6.2072, 7.3472],
    [-3.0511, -6.9123, 8.7710],
    [-1.5369, -7.2580, 10.2709],
    [0.0000, -7.5671, 10.4320],
    [1.5369, -7.2580, 10.2709],
    [3.0511, -6.9123, 8.7710],
    [4.3023, -6.2072, 7.3472],
    [5.7241, -4.4868, 6.1275],
    [6.5567, -2.3563, 5.1738],
    [6.9376, -0.4614, 4.5329],
    [7.2762, 1.4911, 3.9250],
    [7.3630, 3.6763, 3.6567],
    [-5.8154, 5.1987, 7.9104],
    [-4.9326, 5.9768, 8.9889],
    [-3.7933, 6.2551, 9.8275],
    [-2.4145, 6.1917, 10.4817],
    [-1.1719, 5.9083, 10.7279],
    [1.1719, 5.9083, 10.7279],
    [2.4145, 6.1917, 10.4817],
    [3.7933, 6.2551, 9.8275],
    [4.9326, 5.9768, 8.9889],
    [5.8154, 5.1987, 7.9104],
    [0.0000, 3.7410, 10.7344],
    [0.0000, 2.6343, 11.5179],
    [0.0000, 1.6116, 12.3060],
    [0.0000, 0.4059, 13.0691],
    [-1.2531, -1.1447, 10.8712],
    [-0.6024, -1.1377, 11.4192],
    [0.0000, -1.2033, 11.5657],
    [0.6024, -1.1377, 11.4192],
    [1.2531, -1.1447, 10.8712],
    [-4.4590, 3.4321, 8.6029],
    [-3.8691, 3.8747, 9.3627],
    [-2.7813, 3.9361, 9.5314],
    [-1.8438, 3.2519, 9.1957],
    [-2.7292, 3.0847, 9.4139],
    [-3.8560, 3.0716, 9.2287],
    [1.8441, 3.2524, 9.1955],
    [2.7813, 3.9361, 9.5314],
    [3.8691, 3.8747, 9.3627],
    [4.4590, 3.4321, 8.6029],
    [3.8560, 3.0716, 9.2287],
    [2.7292, 3.0847, 9.4139],
    [-2.5349, -3.5196, 10.1875],
    [-1.7021, -2.7768, 11.2210],
    [-0.7282, -2.4223, 11.7294],
    [0.0000, -2.4825, 11.8387],
    [0.7282, -2.4223, 11.7294],
    [1.7021, -2.7768, 11.2210],
    [2.5349, -3.5196, 10.1875],
    [1.8008, -4.0565, 10.8984],
    [1.0343, -4.3023, 11.3885],
    [0.0000, -4.3769, 11.5492],
    [-1.0343, -4.3023, 11.3885],
    [-1.8008, -4.0565, 10.8984],
    [-2.2092, -3.4901, 10.1277],
    [-0.9963, -3.2969, 11.0867],
    [0.0000, -3.3235, 11.2810],
    [0.9963, -3.2969, 11.0867],
    [2.2092, -3.4901, 10.1277],
    [1.0692, -3.3797, 11.0401],
    [0.0000, -3.3998, 11.2526],
    [-1.0692, -3.3797, 11.0401],
];

/// Forehead and temple points (cm) above the brows, so the rig reads as a face and not
/// as a mask cut off at the brows; not landmarks (vertices 68..), still in every shape.
const FOREHEAD_CM: [[f64; 3]; 7] = [
    [-6.9, 7.6, 5.4],
    [-5.0, 9.9, 7.6],
    [-2.5, 10.6, 9.9],
    [0.0, 10.8, 10.6],
    [2.5, 10.6, 9.9],
    [5.0, 9.9, 7.6],
    [6.9, 7.6, 5.4],
];

/// iBUG indices of the inner lip contour, in order around the mouth.
const INNER_LIP: [usize; 8] = [60, 61, 62, 63, 64, 65, 66, 67];

/// Whether `p` is inside the polygon (even-odd rule).
fn point_in_polygon(poly: &[(f64, f64)], p: (f64, f64)) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a.1 > p.1) != (b.1 > p.1) && p.0 < (b.0 - a.0) * (p.1 - a.1) / (b.1 - a.1) + a.0 {
            c = !c;
        }
    }
    c
}

/// Number of 4-to-1 subdivision passes of the landmark triangulation.
const SUBDIVISIONS: usize = 2;

/// Names of the default rig's blendshapes (a subset of ARKit's 52).
pub const DEFAULT_SHAPES: [&str; 16] = [
    "jawOpen",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthPucker",
    "mouthStretchLeft",
    "mouthStretchRight",
    "browInnerUp",
    "browDownLeft",
    "browDownRight",
    "browOuterUpLeft",
    "browOuterUpRight",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "mouthRollLower",
];

/// Displacement (cm) of each of the 68 landmarks for the named shape.
fn landmark_displacements(name: &str) -> [Vector3<f64>; 68] {
    let mut d = [Vector3::zeros(); 68];
    let p = |i: usize| Vector3::new(MEAN_FACE_68_CM[i][0], MEAN_FACE_68_CM[i][1], MEAN_FACE_68_CM[i][2]);
    let mut set = |ids: &[usize], v: Vector3<f64>| {
        for &i in ids {
            d[i] += v;
        }
    };
    match name {
        "jawOpen" => {
            // Jaw rotates down: chin moves most, jaw angle points little.
            for i in 2..=14usize {
                let w = (1.0 - (i as f64 - 8.0).abs() / 6.5).max(0.0);
                set(&[i], Vector3::new(0.0, -1.6 * w, -0.4 * w));
            }
            set(&[56, 57, 58, 65, 66, 67], Vector3::new(0.0, -1.5, -0.3));
            set(&[55, 59], Vector3::new(0.0, -1.0, -0.2));
            set(&[48, 54, 60, 64], Vector3::new(0.0, -0.5, -0.1));
        }
        "mouthSmileLeft" | "mouthSmileRight" => {
            let (s, corner, inner, near) = if name.ends_with("Left") {
                (1.0, 54, 64, [53, 55])
            } else {
                (-1.0, 48, 60, [49, 59])
            };
            set(&[corner, inner], Vector3::new(0.5 * s, 0.55, -0.15));
            set(&near, Vector3::new(0.25 * s, 0.3, -0.05));
            let cheek = if s > 0.0 { [12, 13] } else { [4, 3] };
            set(&cheek, Vector3::new(0.1 * s, 0.15, 0.05));
        }
        "mouthFrownLeft" | "mouthFrownRight" => {
            let (corner, inner, near) = if name.ends_with("Left") {
                (54, 64, [53, 55])
            } else {
                (48, 60, [49, 59])
            };
            set(&[corner, inner], Vector3::new(0.0, -0.5, 0.0));
            set(&near, Vector3::new(0.0, -0.25, 0.0));
        }
        "mouthPucker" => {
            set(&[48, 60], Vector3::new(0.7, 0.0, 0.3));
            set(&[54, 64], Vector3::new(-0.7, 0.0, 0.3));
            set(&[49, 59, 61, 67], Vector3::new(0.35, 0.0, 0.45));
            set(&[53, 55, 63, 65], Vector3::new(-0.35, 0.0, 0.45));
            set(&[50, 51, 52, 56, 57, 58, 62, 66], Vector3::new(0.0, 0.0, 0.5));
        }
        "mouthStretchLeft" | "mouthStretchRight" => {
            let (s, corner, inner, near) = if name.ends_with("Left") {
                (1.0, 54, 64, [53, 55])
            } else {
                (-1.0, 48, 60, [49, 59])
            };
            set(&[corner, inner], Vector3::new(0.6 * s, -0.2, -0.1));
            set(&near, Vector3::new(0.3 * s, -0.1, 0.0));
        }
        "browInnerUp" => {
            set(&[21, 22], Vector3::new(0.0, 0.7, 0.0));
            set(&[20, 23], Vector3::new(0.0, 0.4, 0.0));
            set(&[19, 24], Vector3::new(0.0, 0.15, 0.0));
        }
        "browDownLeft" | "browDownRight" => {
            let (ids, s) = if name.ends_with("Left") {
                ([22, 23, 24, 25, 26], 1.0)
            } else {
                ([21, 20, 19, 18, 17], -1.0)
            };
            for (k, &i) in ids.iter().enumerate() {
                let w = 1.0 - 0.15 * k as f64;
                set(&[i], Vector3::new(-0.15 * s * w, -0.45 * w, 0.0));
            }
        }
        "browOuterUpLeft" | "browOuterUpRight" => {
            let ids = if name.ends_with("Left") {
                [26, 25, 24]
            } else {
                [17, 18, 19]
            };
            for (k, &i) in ids.iter().enumerate() {
                set(&[i], Vector3::new(0.0, 0.6 - 0.2 * k as f64, 0.0));
            }
        }
        "eyeBlinkLeft" | "eyeBlinkRight" => {
            // Upper lid meets the lower lid.
            let pairs: [(usize, usize); 2] = if name.ends_with("Left") {
                [(43, 47), (44, 46)]
            } else {
                [(37, 41), (38, 40)]
            };
            for (up, low) in pairs {
                let dy = p(low).y - p(up).y;
                set(&[up], Vector3::new(0.0, 0.85 * dy, 0.0));
                set(&[low], Vector3::new(0.0, -0.15 * dy, 0.0));
            }
        }
        "mouthRollLower" => {
            set(&[56, 57, 58], Vector3::new(0.0, 0.35, -0.3));
            set(&[65, 66, 67], Vector3::new(0.0, 0.2, -0.3));
        }
        _ => {}
    }
    d
}

/// The default rig: dense mesh with 16 morph targets, and its identity landmark map.
///
/// # Errors
/// Only if the built-in data were degenerate (a bug), reported as an error.
pub fn default_rig() -> anyhow::Result<(MorphMesh, LandmarkMap)> {
    let mut base_points: Vec<[f64; 3]> = MEAN_FACE_68_CM.to_vec();
    base_points.extend_from_slice(&FOREHEAD_CM);
    let centres: Vec<(f64, f64)> = base_points.iter().map(|p| (p[0], p[1])).collect();
    let inner_lip: Vec<(f64, f64)> = INNER_LIP.iter().map(|&i| centres[i]).collect();
    // The mouth opening: triangles of the inner lip contour that lie inside it are left
    // out, so an open mouth is a hole (the renderer shows a dark cavity behind it)
    // instead of skin stretched and folded between the lips.
    let mut tris: Vec<[u32; 3]> = delaunay(&centres)
        .into_iter()
        .filter(|t| {
            let all_lip = t.iter().all(|&v| INNER_LIP.contains(&(v as usize)));
            let c = t.iter().fold((0.0, 0.0), |a, &v| {
                (a.0 + centres[v as usize].0 / 3.0, a.1 + centres[v as usize].1 / 3.0)
            });
            !(all_lip && point_in_polygon(&inner_lip, c))
        })
        .collect();
    // Planar vertex positions (x, y) of the subdivided mesh, and each new vertex's
    // parents (the ends of the edge it splits).
    let mut xy = centres.clone();
    let mut parents: Vec<(u32, u32)> = Vec::new();
    for _ in 0..SUBDIVISIONS {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        let mut midpoint = |a: u32, b: u32, xy: &mut Vec<(f64, f64)>| -> u32 {
            let key = (a.min(b), a.max(b));
            *mid.entry(key).or_insert_with(|| {
                let (pa, pb) = (xy[a as usize], xy[b as usize]);
                xy.push(((pa.0 + pb.0) / 2.0, (pa.1 + pb.1) / 2.0));
                parents.push(key);
                (xy.len() - 1) as u32
            })
        };
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut xy);
            let bc = midpoint(b, c, &mut xy);
            let ca = midpoint(c, a, &mut xy);
            next.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        tris = next;
    }
    let n0 = centres.len();
    let tps = Tps::new(centres).ok_or_else(|| anyhow::anyhow!("default rig: degenerate landmark layout"))?;
    let field = |values: &[f64]| -> anyhow::Result<Vec<f64>> {
        let coef = tps
            .fit(values)
            .ok_or_else(|| anyhow::anyhow!("default rig: spline fit failed"))?;
        Ok(xy
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| if i < n0 { values[i] } else { tps.eval(&coef, x, y) })
            .collect())
    };
    let z: Vec<f64> = field(&base_points.iter().map(|p| p[2]).collect::<Vec<_>>())?;
    let positions: Vec<Point3<f32>> = xy
        .iter()
        .zip(&z)
        .map(|(&(x, y), &z)| Point3::new(x as f32, y as f32, z as f32))
        .collect();
    let uvs = {
        let (minx, maxx) = xy
            .iter()
            .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.0), a.1.max(p.0)));
        let (miny, maxy) = xy
            .iter()
            .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
        xy.iter()
            .map(|p| {
                [
                    ((p.0 - minx) / (maxx - minx)) as f32,
                    (1.0 - (p.1 - miny) / (maxy - miny)) as f32,
                ]
            })
            .collect()
    };
    let mut base = Mesh {
        positions,
        triangles: tris,
        normals: Vec::new(),
        uvs,
    };
    base.compute_normals();
    let mut targets = Vec::with_capacity(DEFAULT_SHAPES.len());
    for name in DEFAULT_SHAPES {
        // Landmarks move as defined, the forehead stays; every vertex the subdivision
        // added moves as the mean of its edge's ends (piecewise linear over the landmark
        // triangles: no overshoot, so no folds where the lips part).
        let d = landmark_displacements(name);
        let mut deltas: Vec<Vector3<f32>> = (0..n0)
            .map(|i| if i < 68 { d[i].cast::<f32>() } else { Vector3::zeros() })
            .collect();
        for &(a, b) in &parents {
            let m = (deltas[a as usize] + deltas[b as usize]) / 2.0;
            deltas.push(m);
        }
        targets.push(MorphTarget {
            name: name.to_string(),
            deltas,
        });
    }
    let rig = MorphMesh { base, targets };
    rig.validate()?;
    let ids: Vec<Option<u32>> = (0..68u32).map(Some).collect();
    let map = LandmarkMap::from_slice(&ids)?;
    Ok((rig, map))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rig_is_valid_and_exact_at_landmarks() {
        let (rig, map) = default_rig().unwrap();
        assert!(rig.base.num_vertices() > 68 * 8);
        assert_eq!(rig.targets.len(), 16);
        map.validate(rig.base.num_vertices()).unwrap();
        // the mesh ends at the jaw: the contour keeps its fixed vertices
        let solve_rig = facecap_solve::BlendshapeRig::from_morph_mesh(rig.clone(), &map, "built-in").unwrap();
        assert!(solve_rig.contour.is_none());
        for (i, p) in MEAN_FACE_68_CM.iter().enumerate() {
            let v = rig.base.positions[i];
            assert!((v.x as f64 - p[0]).abs() < 1e-5 && (v.z as f64 - p[2]).abs() < 1e-5);
        }
        // jawOpen moves the chin down by 1.6 cm and leaves the brows alone.
        let jaw = &rig.targets[0];
        assert!((jaw.deltas[8].y + 1.6).abs() < 1e-5);
        assert!(jaw.deltas[19].norm() < 1e-6);
        // Every triangle has positive area in the frontal plane (no fold-overs).
        for t in &rig.base.triangles {
            let [a, b, c] = t.map(|i| rig.base.positions[i as usize]);
            let cross = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            assert!(cross > 0.0);
        }
    }
}
