#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

//! Pose-dependent contour correspondences against fixed ones, on a synthetic head seen at
//! 30 degrees of yaw: the tracked contour points are made from the true silhouette of the
//! posed surface, so fixed vertices bias the pose and the weights.

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_solve::{
    BlendshapeRig, ContourCandidates, ContourParams, Exact3dParams, Exact3dSolver, ExpressionSolver, ObjectiveParams,
    Solution, SolveState,
};
use nalgebra::{Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

const A: f64 = 7.0; // half-width and half-height (x, y)
const C: f64 = 9.0; // depth (z, towards the viewer)
const RING_DEG: f64 = 2.5;
const RINGS: usize = 53; // alpha 0..130 degrees
const SPOKES: usize = 144; // beta in 2.5 degree steps

/// The head's surface: angle `alpha` from the +z axis (the face's front), `beta` around it.
fn surface(alpha: f64, beta: f64) -> Vector3<f64> {
    Vector3::new(
        A * alpha.sin() * beta.cos(),
        A * alpha.sin() * beta.sin(),
        C * alpha.cos(),
    )
}

/// Smooth expression fields: a jaw drop, a sideways mouth, a brow raise.
fn delta(k: usize, p: &Vector3<f64>) -> Vector3<f64> {
    let low = (-p.y / A).max(0.0);
    let front = (p.z / C).max(0.0);
    match k {
        0 => Vector3::new(0.0, -1.5 * low * low, 0.4 * low * low),
        1 => Vector3::new(1.2 * low * front, 0.0, 0.0),
        _ => Vector3::new(0.0, 0.8 * (p.y / A).max(0.0) * front, 0.0),
    }
}

fn posed(p: &Vector3<f64>, e: &[f64]) -> Vector3<f64> {
    let mut q = *p;
    for (k, &w) in e.iter().enumerate() {
        q += delta(k, p) * w;
    }
    q
}

fn vertex(ring: usize, spoke: usize) -> usize {
    if ring == 0 {
        0
    } else {
        1 + (ring - 1) * SPOKES + spoke % SPOKES
    }
}

fn angles(v: usize) -> (f64, f64) {
    if v == 0 {
        return (0.0, 0.0);
    }
    let ring = 1 + (v - 1) / SPOKES;
    let spoke = (v - 1) % SPOKES;
    (
        (ring as f64 * RING_DEG).to_radians(),
        (spoke as f64 * RING_DEG).to_radians(),
    )
}

/// The mapped vertex of each landmark: the contour on the frontal silhouette (alpha 90)
/// from the right temple (beta 190) round the chin (270) to the left temple (350), the
/// other points spread over the front.
fn landmark_vertex(l: usize) -> usize {
    if l < 17 {
        let beta = 190.0 + 10.0 * l as f64;
        return vertex((90.0 / RING_DEG) as usize, (beta / RING_DEG) as usize);
    }
    match l {
        36 => vertex(14, 72), // alpha 35, beta 180
        45 => vertex(14, 0),
        _ => {
            let ring = 4 + (l * 7) % 20;
            let spoke = (l * 37) % SPOKES;
            vertex(ring, spoke)
        }
    }
}

fn rig() -> BlendshapeRig {
    let nv = 1 + (RINGS - 1) * SPOKES;
    let positions: Vec<Point3<f32>> = (0..nv)
        .map(|v| {
            let (a, b) = angles(v);
            let p = surface(a, b);
            Point3::new(p.x as f32, p.y as f32, p.z as f32)
        })
        .collect();
    let mut triangles = Vec::new();
    for s in 0..SPOKES {
        triangles.push([0, vertex(1, s) as u32, vertex(1, s + 1) as u32]);
    }
    for r in 1..RINGS - 1 {
        for s in 0..SPOKES {
            let (a, b, c, d) = (vertex(r, s), vertex(r, s + 1), vertex(r + 1, s), vertex(r + 1, s + 1));
            triangles.push([a as u32, c as u32, d as u32]);
            triangles.push([a as u32, d as u32, b as u32]);
        }
    }
    let targets = (0..3)
        .map(|k| MorphTarget {
            name: format!("shape{k}"),
            deltas: positions
                .iter()
                .map(|p| {
                    let d = delta(k, &Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)));
                    Vector3::new(d.x as f32, d.y as f32, d.z as f32)
                })
                .collect(),
        })
        .collect();
    let base = Mesh {
        positions,
        triangles,
        normals: Vec::new(),
        uvs: Vec::new(),
    };
    BlendshapeRig::from_morph_mesh(MorphMesh { base, targets }, &map(), "synthetic head").unwrap()
}

/// The true image of the head at `pose` with weights `e`: mapped vertices for the inner
/// points, and for each contour point the silhouette along its meridian (where the view ray
/// grazes the posed surface, found on the analytic surface in 0.05 degree steps).
fn observe(pose: &ModelToCamera, k: &Intrinsics, e: &[f64]) -> Landmarks68 {
    let project = |p: &Vector3<f64>| pose.project(k, &Point3::from(*p)).unwrap();
    let cam = pose.0.inverse() * Point3::origin();
    Landmarks68::from_fn(|l| {
        let (a0, b) = angles(landmark_vertex(l));
        let p = if l < 17 {
            let h = 1e-4;
            let grazing = |a: f64| {
                let x = posed(&surface(a, b), e);
                let ta = posed(&surface(a + h, b), e) - posed(&surface(a - h, b), e);
                let tb = posed(&surface(a, b + h), e) - posed(&surface(a, b - h), e);
                let mut n = ta.cross(&tb);
                if n.dot(&x) < 0.0 {
                    n = -n;
                }
                n.dot(&(cam.coords - x))
            };
            // the silhouette nearest the frontal one
            let mut best = a0;
            let mut found = f64::INFINITY;
            let mut a = 40f64.to_radians();
            while a < 128f64.to_radians() {
                let step = 0.05f64.to_radians();
                if grazing(a) * grazing(a + step) <= 0.0 && (a - a0).abs() < found {
                    found = (a - a0).abs();
                    best = a;
                }
                a += step;
            }
            posed(&surface(best, b), e)
        } else {
            posed(&surface(a0, b), e)
        };
        let q = project(&p);
        (q.x, q.y)
    })
}

/// Yaw error (degrees), translation error (model units) and the largest weight error of
/// the solve of `lm` (cold start).
fn solve_errors(
    rig: &BlendshapeRig,
    k: Intrinsics,
    lm: &Landmarks68,
    pose: &ModelToCamera,
    e: &[f64],
) -> (f64, f64, f64) {
    let params = Exact3dParams {
        objective: ObjectiveParams { l1: 0.0, temporal: 0.0 },
        ..Exact3dParams::new(k)
    };
    let solver = Exact3dSolver::new(rig, params).unwrap();
    let (mut ws, mut state, mut out) = (solver.workspace(), SolveState::new(3), Solution::new(3));
    solver.solve_into(lm, &mut ws, &mut state, &mut out).unwrap();
    let got = out.pose.unwrap();
    let dr = got.0.rotation.angle_to(&pose.0.rotation).to_degrees();
    let dt = (got.tvec() - pose.tvec()).norm();
    let de = out
        .weights
        .iter()
        .zip(e)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    (dr, dt, de)
}

#[test]
fn contour_candidates_follow_the_silhouette_at_30_degrees_of_yaw() {
    // default parameters: the side points only (the chin's, facing down, stay fixed)
    let sides = rig();
    let cand = sides.contour.as_ref().expect("the head's mesh extends behind the jaw");
    let kept: Vec<usize> = cand.lines.iter().map(|l| l.landmark).collect();
    assert_eq!(kept, vec![0, 1, 15, 16], "lines where |n_y| < 0.5");
    // every contour point
    let mut with = sides.clone();
    let all = ContourParams {
        max_vertical_normal: 1.1,
        ..ContourParams::default()
    };
    with.contour = Some(ContourCandidates::from_mesh(
        &with.mesh.as_ref().unwrap().base,
        &map(),
        &all,
    ));
    assert_eq!(
        with.contour.as_ref().unwrap().lines.len(),
        17,
        "every contour landmark has a line"
    );
    let mut without = with.clone();
    without.contour = None;
    let k = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
    let e = [0.4, 0.3, 0.2];
    // model +Y up / +Z to the viewer, camera +Y down / +Z forward: frontal is a half turn
    // about x, then 30 degrees of yaw and a little pitch
    let frontal = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let turn = Rotation3::from_euler_angles(5f64.to_radians(), 30f64.to_radians(), 0.0);
    let pose = ModelToCamera(nalgebra::Isometry3::from_parts(
        Translation3::new(1.0, -0.5, 60.0),
        UnitQuaternion::from_rotation_matrix(&(turn * frontal)),
    ));
    let lm = observe(&pose, &k, &e);
    let (r_fixed, t_fixed, e_fixed) = solve_errors(&without, k, &lm, &pose, &e);
    let (r_pose, t_pose, e_pose) = solve_errors(&with, k, &lm, &pose, &e);
    let (r_side, t_side, e_side) = solve_errors(&sides, k, &lm, &pose, &e);
    eprintln!("fixed: rotation {r_fixed:.3} deg, translation {t_fixed:.3}, weights {e_fixed:.3}");
    eprintln!("pose:  rotation {r_pose:.3} deg, translation {t_pose:.3}, weights {e_pose:.3}");
    eprintln!("sides: rotation {r_side:.3} deg, translation {t_side:.3}, weights {e_side:.3}");
    assert!(
        r_side < r_fixed,
        "sides only: rotation error {r_side} against {r_fixed}"
    );
    assert!(r_pose < 0.5 * r_fixed, "rotation error {r_pose} against {r_fixed}");
    assert!(e_pose < 0.5 * e_fixed, "weight error {e_pose} against {e_fixed}");
    assert!(t_pose < t_fixed, "translation error {t_pose} against {t_fixed}");
    // frontal: the contour points slide only by the perspective (the camera sees past
    // the orthographic silhouette), and the solve stays as exact
    let front = ModelToCamera(nalgebra::Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 60.0),
        UnitQuaternion::from_rotation_matrix(&frontal),
    ));
    let lm0 = observe(&front, &k, &e);
    let (r0, t0, e0) = solve_errors(&with, k, &lm0, &front, &e);
    eprintln!("frontal: rotation {r0:.3} deg, translation {t0:.3}, weights {e0:.3}");
    assert!(r0 < 0.5 && t0 < 0.3 && e0 < 0.05, "frontal: {r0} {t0} {e0}");
}

#[test]
fn a_mesh_that_ends_at_the_contour_keeps_fixed_vertices() {
    // the built-in style: the 68 points and nothing behind the jaw
    let rig = BlendshapeRig::synthetic(4, 3);
    assert!(rig.contour.is_none());
    let head = rig_without_back();
    assert!(head.contour.is_none(), "no line without candidates behind the jaw");
}

/// The head's mesh cut at the frontal silhouette (alpha <= 90).
fn rig_without_back() -> BlendshapeRig {
    let full = rig();
    let mut mesh = full.mesh.clone().unwrap();
    let keep = 1 + ((90.0 / RING_DEG) as usize - 1 + 1) * SPOKES;
    mesh.base.triangles.retain(|t| t.iter().all(|&v| (v as usize) < keep));
    BlendshapeRig::from_morph_mesh(mesh, &map(), "cut head").unwrap()
}

fn map() -> LandmarkMap {
    let v: Vec<Option<u32>> = (0..NUM_LANDMARKS).map(|l| Some(landmark_vertex(l) as u32)).collect();
    LandmarkMap::from_slice(&v).unwrap()
}
