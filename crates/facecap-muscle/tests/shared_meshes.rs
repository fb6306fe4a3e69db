#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
//! The default set on the shared meshes (ICT, SFM, the James scan), baking, and retargeting.
//! Skips (with a SKIP line) when the shared data is absent.

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::{Mesh, MorphMesh};
use facecap_core::paths::shared_data_file;
use facecap_muscle::defaults::{default_muscle_set, landmark_positions, FaceFrame, NUM_DEFAULT_MUSCLES};
use facecap_muscle::retarget::{bake, retarget_same_topology, retarget_via_landmarks, JAW_TARGET};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::synthetic::SyntheticFace;
use nalgebra::{Point3, Vector3};

fn pos(mesh: &Mesh) -> Vec<Point3<f64>> {
    mesh.positions.iter().map(|p| p.cast()).collect()
}

/// Builds the default set and rig, checks every muscle moves the face by a sensible amount
/// and that the left/right pairs are about as strong, bakes, and returns the peak
/// displacement per muscle in units of the eye distance.
fn check_mesh(label: &str, mesh: &Mesh, map: &LandmarkMap) -> Vec<f64> {
    let p = pos(mesh);
    let lm = landmark_positions(map, &p);
    let frame = FaceFrame::from_landmarks(&lm).unwrap();
    let set = default_muscle_set(&lm, &p).unwrap();
    let rig = MuscleRig::from_mesh(&set, mesh).unwrap();
    let mut peaks = Vec::new();
    for (i, name) in rig.names().iter().enumerate() {
        let f = &rig.fields()[i];
        let peak = f.deltas.iter().map(|d| d.norm()).fold(0.0, f64::max) / frame.s;
        println!(
            "{label}: {name}: {} vertices moved, peak {:.3} eye distances",
            f.indices.len(),
            peak
        );
        assert!(f.indices.len() >= 3, "{label} {name} moves too few vertices");
        assert!(peak > 0.02 && peak < 0.5, "{label} {name} peak {peak}");
        peaks.push(peak);
    }
    for (i, name) in rig.names().iter().enumerate() {
        if let Some(b) = name.strip_suffix("_L") {
            let j = rig.names().iter().position(|n| *n == format!("{b}_R")).unwrap();
            let r = peaks[i] / peaks[j];
            assert!((0.5..2.0).contains(&r), "{label} {b}: L/R peak ratio {r}");
        }
    }
    let jaw = rig.jaw().unwrap();
    println!("{label}: jaw group {} vertices", jaw.indices.len());
    assert!(jaw.indices.len() > 10);
    // The chin (or lower lip) opens downwards (-y in the face frame).
    let chin = map.vertices[8].or(map.vertices[57]).unwrap() as usize;
    let d = rig.dense_jaw(rig.max_jaw())[chin];
    assert!(d.dot(&frame.y) < -0.05 * frame.s, "{label}: chin moves {d}");
    let baked = bake(
        &rig,
        &MorphMesh {
            base: mesh.clone(),
            targets: vec![],
        },
    )
    .unwrap();
    assert_eq!(baked.targets.len(), NUM_DEFAULT_MUSCLES + 1);
    assert_eq!(baked.targets.last().unwrap().name, JAW_TARGET);
    baked.validate().unwrap();
    peaks
}

#[test]
fn default_set_on_ict() {
    let (Some(glb), Some(mp)) = (
        shared_data_file("default_set_on_ict", "models3d/ict_facekit/ict_face_arkit53.glb"),
        shared_data_file("default_set_on_ict", "models3d/ict_facekit/ict_landmarks68.json"),
    ) else {
        return;
    };
    let mm = facecap_io::gltf_io::read_morph_mesh(&glb).unwrap();
    let map = LandmarkMap::from_json_file(&mp).unwrap();
    check_mesh("ICT", &mm.base, &map);
}

#[test]
fn default_set_on_sfm() {
    let (Some(glb), Some(mp)) = (
        shared_data_file("default_set_on_sfm", "models3d/eos_sfm/sfm_shape63.glb"),
        shared_data_file("default_set_on_sfm", "models3d/eos_sfm/sfm_landmarks68.json"),
    ) else {
        return;
    };
    let mm = facecap_io::gltf_io::read_morph_mesh(&glb).unwrap();
    let map = LandmarkMap::from_json_file(&mp).unwrap();
    assert_eq!(mm.base.num_vertices(), 3448);
    check_mesh("SFM", &mm.base, &map);
}

#[test]
fn default_set_on_james_scan() {
    let (Some(obj), Some(lj)) = (
        shared_data_file("default_set_on_james_scan", "models3d/menpo3d_james/james.obj"),
        shared_data_file("default_set_on_james_scan", "models3d/menpo3d_james/james.ljson"),
    ) else {
        return;
    };
    let mesh = facecap_io::obj::read_obj(&obj).unwrap();
    let p = pos(&mesh);
    let lj = facecap_io::formats::ljson::read_ljson(&lj).unwrap();
    let points = lj.groups[0].mesh_landmarks68().unwrap();
    let map = LandmarkMap::nearest_vertices(&mesh.positions, &points).unwrap();
    // Sanity of the relabelling: brows above eyes, subject's right eye on the side of landmark 0.
    let lm = landmark_positions(&map, &p);
    assert!(lm[19].unwrap().y > lm[37].unwrap().y && lm[24].unwrap().y > lm[44].unwrap().y);
    assert!((lm[36].unwrap().x - lm[0].unwrap().x).abs() < (lm[45].unwrap().x - lm[0].unwrap().x).abs());
    check_mesh("James", &mesh, &map);
}

#[test]
fn retargeting_same_topology_and_across() {
    let coarse = SyntheticFace::new(31, 35);
    let fine = SyntheticFace::new(61, 67);
    let lm = landmark_positions(&coarse.map, &coarse.positions);
    let set = default_muscle_set(&lm, &coarse.positions).unwrap();
    // Algorithm 1 on a translated and slightly inflated copy: control points follow.
    let t = Vector3::new(1.0, -2.0, 0.5);
    let target: Vec<Point3<f64>> = coarse.positions.iter().map(|p| p + t).collect();
    let moved = retarget_same_topology(&set, &coarse.positions, &target).unwrap();
    for (a, b) in set.muscles.iter().zip(&moved.muscles) {
        for (p, q) in a.shape.control_points().iter().zip(b.shape.control_points()) {
            assert!((Point3::from(*p) + t - Point3::from(q)).norm() < 1e-9);
        }
    }
    assert!(retarget_same_topology(&set, &coarse.positions, &fine.positions).is_err());
    // Across topologies (coarse grid -> fine grid scaled by 10, mm-like): the retargeted set
    // is close to the one placed directly on the target, and scaled.
    let big: Vec<Point3<f64>> = fine.positions.iter().map(|p| Point3::from(p.coords * 10.0)).collect();
    let across =
        retarget_via_landmarks(&set, &coarse.positions, &coarse.map, &big, &fine.map, &coarse.triangles).unwrap();
    let direct = default_muscle_set(&landmark_positions(&fine.map, &big), &big).unwrap();
    let s = FaceFrame::from_landmarks(&landmark_positions(&fine.map, &big))
        .unwrap()
        .s;
    for (a, b) in across.muscles.iter().zip(&direct.muscles) {
        for (p, q) in a.shape.control_points().iter().zip(b.shape.control_points()) {
            let d = (Point3::from(*p) - Point3::from(q)).norm() / s;
            assert!(d < 0.1, "{}: {d} eye distances", a.name);
        }
    }
    let jg = &across.vertex_groups["jaw"];
    assert!(jg.indices.len() > 100);
    MuscleRig::new(&across, &big, &vec![Vector3::z(); big.len()]).unwrap();
}
