#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The face mesh's points mapped onto three real faces of different topologies (the dense
//! solve's correspondences, the "478-point map for any rig"): the ICT-FaceKit rig, the
//! Surrey Face Model (3448 vertices) and the James scan (menpo3d). Most points land, and the
//! lids and lips land where they belong. Writes the mapped points as OBJs
//! (`dense_map_<face>.obj` in the test's temporary folder) to look at beside the meshes.
//! The three faces are research-only shared test data (`SKIP:` when absent).

use std::io::Write;

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::Mesh;
use facecap_mesh::canonical::{read_canonical_face, GEOMETRY_METADATA};
use facecap_mesh::ibug68::IBUG68_FROM_MESH;
use facecap_solve::dense::{map_onto_rig, DenseMapParams};
use nalgebra::Vector3;

#[test]
fn mesh_points_land_on_the_right_parts_of_the_ict_face() {
    let test = "mesh_points_land_on_the_right_parts_of_the_ict_face";
    let Some(glb) = facecap_core::paths::shared_data_file(test, "models3d/ict_facekit/ict_face_arkit53.glb") else {
        return;
    };
    let Some(map_file) = facecap_core::paths::shared_data_file(test, "models3d/ict_facekit/ict_landmarks68.json")
    else {
        return;
    };
    let mesh = facecap_io::gltf_io::read_morph_mesh(&glb).unwrap();
    let map = LandmarkMap::from_json_file(&map_file).unwrap();
    check_dense_map(test, "ict", &mesh.base, &map);
}

#[test]
fn mesh_points_land_on_the_right_parts_of_the_sfm_face() {
    let test = "mesh_points_land_on_the_right_parts_of_the_sfm_face";
    let Some(glb) = facecap_core::paths::shared_data_file(test, "models3d/eos_sfm/sfm_shape63.glb") else {
        return;
    };
    let Some(map_file) = facecap_core::paths::shared_data_file(test, "models3d/eos_sfm/sfm_landmarks68.json") else {
        return;
    };
    let mesh = facecap_io::gltf_io::read_morph_mesh(&glb).unwrap();
    let map = LandmarkMap::from_json_file(&map_file).unwrap();
    check_dense_map(test, "sfm", &mesh.base, &map);
}

#[test]
fn mesh_points_land_on_the_right_parts_of_the_james_scan() {
    let test = "mesh_points_land_on_the_right_parts_of_the_james_scan";
    let Some(obj) = facecap_core::paths::shared_data_file(test, "models3d/menpo3d_james/james.obj") else {
        return;
    };
    let Some(lj) = facecap_core::paths::shared_data_file(test, "models3d/menpo3d_james/james.ljson") else {
        return;
    };
    let mesh = facecap_io::obj::read_obj(&obj).unwrap();
    // the scan's 68 landmarks are 3D points: each takes its nearest vertex
    let lj = facecap_io::formats::ljson::read_ljson(&lj).unwrap();
    let points = lj.groups[0].mesh_landmarks68().unwrap();
    let map = LandmarkMap::nearest_vertices(&mesh.positions, &points).unwrap();
    check_dense_map(test, "james", &mesh, &map);
}

/// Maps the canonical face onto `mesh` (68-point `map`) and checks where the lids and lips land.
fn check_dense_map(test: &str, face: &str, mesh: &Mesh, map: &LandmarkMap) {
    let Some(geometry) = facecap_core::paths::model_file_or_skip(test, GEOMETRY_METADATA) else {
        return;
    };
    let canonical = read_canonical_face(&geometry).unwrap();
    let params = DenseMapParams {
        skip: IBUG68_FROM_MESH.to_vec(),
        ..DenseMapParams::default()
    };
    let t = std::time::Instant::now();
    let m = map_onto_rig(&canonical, &IBUG68_FROM_MESH, mesh, map, &params).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let pos = m.neutral_positions(mesh);
    eprintln!(
        "{face}: mapped {} of {} points ({} dropped: {:?}), similarity RMS {:.3} IOD, max residual {:.3} IOD, {secs:.2} s",
        m.targets.len(),
        canonical.len() - IBUG68_FROM_MESH.len(),
        m.dropped.len(),
        m.dropped,
        m.similarity_rms_iod,
        m.targets.iter().map(|t| t.residual_iod).fold(0.0, f64::max),
    );
    assert!(m.targets.len() >= 300, "only {} points mapped", m.targets.len());
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let mut obj = Vec::new();
    writeln!(
        obj,
        "# face-mesh points on the {face} neutral: v x y z, then a comment with the mesh index"
    )
    .unwrap();
    for (t, p) in m.targets.iter().zip(&pos) {
        writeln!(obj, "v {:.5} {:.5} {:.5} # {}", p.x, p.y, p.z, t.source).unwrap();
    }
    std::fs::write(dir.join(format!("dense_map_{face}.obj")), obj).unwrap();

    let rig_lm = |l: usize| {
        let v = map.vertices[l].unwrap() as usize;
        let q = mesh.positions[v];
        Vector3::new(f64::from(q.x), f64::from(q.y), f64::from(q.z))
    };
    let at = |src: usize| -> Vector3<f64> {
        let k = m
            .targets
            .iter()
            .position(|t| t.source == src)
            .unwrap_or_else(|| panic!("mesh point {src} not mapped"));
        pos[k]
    };
    let iod = m.iod;
    // upper lids (mesh 159 between iBUG 37/38, 386 between 43/44), lower lids (145
    // between 41/40, 374 between 47/46)
    for (src, a, b) in [(159, 37, 38), (386, 43, 44), (145, 41, 40), (374, 47, 46)] {
        let d = (at(src) - (rig_lm(a) + rig_lm(b)) / 2.0).norm() / iod;
        eprintln!("{face}: mesh {src}: {d:.3} IOD from the middle of iBUG {a}-{b}");
        assert!(d < 0.08, "mesh {src}: {d:.3} IOD from iBUG {a}-{b}");
    }
    // lips: mesh 11 / 12 between the outer (51) and inner (62) upper lip, 16 / 15 between
    // the inner (66) and outer (57) lower lip, in height
    for (src, outer, inner) in [(11, 51, 62), (12, 51, 62), (16, 57, 66), (15, 57, 66)] {
        let (y, yo, yi) = (at(src).y, rig_lm(outer).y, rig_lm(inner).y);
        let (lo, hi) = (yo.min(yi) - 0.02 * iod, yo.max(yi) + 0.02 * iod);
        eprintln!("{face}: mesh {src}: y {y:.3}, iBUG {outer} {yo:.3}, iBUG {inner} {yi:.3}");
        assert!(
            y >= lo && y <= hi,
            "mesh {src} at y {y} not between iBUG {outer} and {inner}"
        );
        let x = (at(src).x - rig_lm(outer).x).abs() / iod;
        assert!(x < 0.05, "mesh {src}: {x:.3} IOD off the lips' middle");
    }
}
