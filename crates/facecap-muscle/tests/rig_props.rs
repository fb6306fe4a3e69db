#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
//! Guarantees of the deformers and the rig: identity at rest, linearity in the
//! contractions, fast path == slow reference, analytic == finite-difference derivatives,
//! mirror symmetry, parameter validation.

use std::f64::consts::PI;

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_muscle::defaults::{default_muscle_set, landmark_positions, NUM_DEFAULT_MUSCLES};
use facecap_muscle::deform::*;
use facecap_muscle::rig::{pose_reference, vertex_normals, MuscleRig};
use facecap_muscle::set::{Muscle, MuscleSet};
use facecap_muscle::synthetic::{mirror_landmark, SyntheticFace};
use facecap_muscle::track::TrackModel;
use nalgebra::{Point3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn face() -> (SyntheticFace, MuscleSet, Vec<Vector3<f64>>) {
    let f = SyntheticFace::new(41, 45);
    let lm = landmark_positions(&f.map, &f.positions);
    let set = default_muscle_set(&lm, &f.positions).unwrap();
    let n = vertex_normals(&f.positions, &f.triangles);
    (f, set, n)
}

/// Default set plus a wrinkled linear muscle, so wrinkles are covered too.
fn set_with_wrinkle(set: &MuscleSet) -> MuscleSet {
    let mut s = set.clone();
    s.muscles.push(Muscle {
        name: "wrinkler".into(),
        vertex_group: None,
        shape: MuscleShape::Linear(LinearMuscle {
            origin: [0.0, 6.0, 3.0],
            insertion: [0.0, 2.0, 5.0],
            rs: 4.0,
            rf: 6.0,
            k: 0.5,
            zone: PI / 2.0,
            wrinkle: Some(Wrinkle { height: 0.2, count: 3 }),
        }),
    });
    s
}

#[test]
fn default_set_has_the_thesis_muscles() {
    let (_, set, _) = face();
    assert_eq!(set.muscles.len(), NUM_DEFAULT_MUSCLES);
    let names = set.names();
    for n in [
        "cheek_L",
        "cheek_R",
        "lips1_L",
        "lips1_R",
        "lips3_L",
        "lips3_R",
        "nose_forehead_L",
        "nose_forehead_R",
        "eyebrow_forehead_L",
        "eyebrow_forehead_R",
        "lips",
    ] {
        assert!(names.contains(&n), "{n}");
    }
    let types: Vec<_> = set.muscles.iter().map(|m| m.shape.type_name()).collect();
    assert_eq!(types.iter().filter(|t| **t == "linear").count(), 8);
    assert_eq!(types.iter().filter(|t| **t == "parallel").count(), 2);
    assert_eq!(types.iter().filter(|t| **t == "sphincter").count(), 1);
}

#[test]
fn zero_contraction_and_jaw_is_identity() {
    let (f, set, n) = face();
    let rig = MuscleRig::new(&set_with_wrinkle(&set), &f.positions, &n).unwrap();
    let mut out = vec![Point3::origin(); f.positions.len()];
    rig.pose_into(&vec![0.0; rig.num_muscles()], 0.0, &mut out).unwrap();
    assert_eq!(out, f.positions);
    // Every muscle moves something at full contraction.
    for (i, fld) in rig.fields().iter().enumerate() {
        assert!(!fld.indices.is_empty(), "muscle {i} moves nothing");
    }
}

#[test]
fn displacement_is_linear_in_contraction_and_matches_reference() {
    let (f, set, n) = face();
    let set = set_with_wrinkle(&set);
    let rig = MuscleRig::new(&set, &f.positions, &n).unwrap();
    let m = rig.num_muscles();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut a = vec![Point3::origin(); f.positions.len()];
    let mut b = a.clone();
    for _ in 0..5 {
        let c: Vec<f64> = (0..m).map(|_| rng.random::<f64>()).collect();
        let alpha = rng.random::<f64>();
        let ca: Vec<f64> = c.iter().map(|v| v * alpha).collect();
        rig.pose_into(&c, 0.0, &mut a).unwrap();
        rig.pose_into(&ca, 0.0, &mut b).unwrap();
        for ((p, q), r) in a.iter().zip(&b).zip(&f.positions) {
            assert!(((q - r) - (p - r) * alpha).norm() < 1e-10);
        }
        let jaw = rng.random::<f64>() * rig.max_jaw();
        rig.pose_into(&c, jaw, &mut a).unwrap();
        let r = pose_reference(&set, &f.positions, &n, &c, jaw).unwrap();
        for (p, q) in a.iter().zip(&r) {
            assert!((p - q).norm() < 1e-10, "{p} vs {q}");
        }
    }
}

#[test]
fn analytic_derivatives_match_finite_differences() {
    let (f, set, n) = face();
    let rig = MuscleRig::new(&set, &f.positions, &n).unwrap();
    let model = TrackModel::from_landmarks(&rig, &f.map, &[], 1).unwrap();
    let intr = Intrinsics::new(800.0, 780.0, 320.0, 240.0).unwrap();
    let pose = ModelToCamera::from_rvec_tvec(Vector3::new(PI - 0.2, 0.3, 0.1), Vector3::new(1.0, -2.0, 45.0));
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let m = model.num_muscles();
    let c: Vec<f64> = (0..m).map(|_| 0.1 + 0.8 * rng.random::<f64>()).collect();
    let jaw = 0.2;
    let mut dc = vec![Vector2::zeros(); m];
    let h = 1e-6;
    let mut checked = 0;
    for k in 0..model.num_points() {
        let (p, dj) = model.project_with_jacobian(k, &pose, &intr, &c, jaw, &mut dc).unwrap();
        let proj = |c: &[f64], j: f64| pose.project(&intr, &model.point(k, c, j)).unwrap();
        assert!((proj(&c, jaw) - p).norm() < 1e-9);
        for i in 0..m {
            let mut cp = c.clone();
            cp[i] += h;
            let mut cm = c.clone();
            cm[i] -= h;
            let fd = (proj(&cp, jaw) - proj(&cm, jaw)) / (2.0 * h);
            assert!(
                (fd - dc[i]).norm() < 1e-5 * (1.0 + fd.norm()),
                "point {k} muscle {i}: {fd} vs {}",
                dc[i]
            );
            checked += usize::from(dc[i].norm() > 1e-3);
        }
        let fd = (proj(&c, jaw + h) - proj(&c, jaw - h)) / (2.0 * h);
        assert!(
            (fd - dj).norm() < 1e-5 * (1.0 + fd.norm()),
            "point {k} jaw: {fd} vs {dj}"
        );
    }
    assert!(checked > 20, "only {checked} non-trivial derivatives");
}

#[test]
fn mirrored_muscles_on_a_mirrored_mesh_give_mirrored_deformations() {
    let (f, set, n) = face();
    let set = set_with_wrinkle(&set);
    let nv = f.positions.len();
    // The mirrored mesh: x -> -x with reversed winding; mirrored muscles; same result mirrored.
    let mirrored_pos: Vec<Point3<f64>> = (0..nv)
        .map(|v| {
            let p = f.positions[f.mirror_vertex(v)];
            Point3::new(-p.x, p.y, p.z)
        })
        .collect();
    // On this symmetric grid the mirrored mesh coincides with the original up to the permutation.
    for (a, b) in mirrored_pos.iter().zip(&f.positions) {
        assert!((a - b).norm() < 1e-9);
    }
    let mut mset = set.clone();
    for m in &mut mset.muscles {
        m.shape = m.shape.mirrored_x();
    }
    if let Some(j) = &mut mset.jaw {
        j.pivot[0] = -j.pivot[0];
    }
    for g in mset.vertex_groups.values_mut() {
        for i in &mut g.indices {
            *i = f.mirror_vertex(*i as usize) as u32;
        }
    }
    let rig = MuscleRig::new(&set, &f.positions, &n).unwrap();
    let mrig = MuscleRig::new(&mset, &f.positions, &n).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let c: Vec<f64> = (0..rig.num_muscles()).map(|_| rng.random::<f64>()).collect();
    let (mut a, mut b) = (f.positions.clone(), f.positions.clone());
    rig.pose_into(&c, 0.2, &mut a).unwrap();
    mrig.pose_into(&c, 0.2, &mut b).unwrap();
    for v in 0..nv {
        let p = a[v];
        let q = b[f.mirror_vertex(v)];
        assert!((Point3::new(-p.x, p.y, p.z) - q).norm() < 1e-9, "vertex {v}");
    }
    // The default set is itself symmetric: X_L is the mirror of X_R.
    let names = rig.names().to_vec();
    for (i, name) in names.iter().enumerate() {
        let Some(base) = name.strip_suffix("_L") else { continue };
        let j = names.iter().position(|x| *x == format!("{base}_R")).unwrap();
        let (fl, fr) = (rig.dense_field(i), rig.dense_field(j));
        for v in 0..nv {
            let d = fr[f.mirror_vertex(v)];
            assert!(
                (fl[v] - Vector3::new(-d.x, d.y, d.z)).norm() < 1e-9,
                "{name} vertex {v}"
            );
        }
    }
    assert_eq!(mirror_landmark(36), 45);
}

#[test]
fn parameters_are_validated() {
    let (f, set, n) = face();
    let rig = MuscleRig::new(&set, &f.positions, &n).unwrap();
    let m = rig.num_muscles();
    let mut out = f.positions.clone();
    let mut c = vec![0.0; m];
    c[3] = 1.5;
    let e = rig.pose_into(&c, 0.0, &mut out).unwrap_err().to_string();
    assert!(e.contains(&rig.names()[3]), "{e}");
    c[3] = f64::NAN;
    assert!(rig.pose_into(&c, 0.0, &mut out).is_err());
    c[3] = 0.0;
    assert!(rig
        .pose_into(&c, -0.1, &mut out)
        .unwrap_err()
        .to_string()
        .contains("jaw"));
    assert!(rig.pose_into(&c, 1.0, &mut out).is_err());
    assert!(rig.pose_into(&c[1..], 0.0, &mut out).is_err());
    assert!(rig.pose_into(&c, 0.0, &mut out[1..]).is_err());
    // Group indices beyond the mesh.
    assert!(MuscleRig::new(&set, &f.positions[..10], &n[..10]).is_err());
}
