#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Rig loading errors, the Shapes2d file format, and the ICT rig when the shared data is present.

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_solve::{Basis2d, BlendshapeRig, Shapes2d};
use nalgebra::{Point3, Vector3};

fn tiny_mesh(nv: usize, names: &[&str]) -> MorphMesh {
    MorphMesh {
        base: Mesh {
            positions: (0..nv)
                .map(|i| Point3::new(i as f32, (i * i % 7) as f32, (i % 3) as f32))
                .collect(),
            triangles: vec![[0, 1, 2]],
            normals: vec![],
            uvs: vec![],
        },
        targets: names
            .iter()
            .enumerate()
            .map(|(k, n)| MorphTarget {
                name: n.to_string(),
                deltas: (0..nv)
                    .map(|i| Vector3::new(((i + k) % 5) as f32 * 0.1, 0.0, 0.0))
                    .collect(),
            })
            .collect(),
    }
}

fn identity_map() -> LandmarkMap {
    let v: Vec<Option<u32>> = (0..68).map(Some).collect();
    LandmarkMap::from_slice(&v).unwrap()
}

#[test]
fn morph_mesh_rig_and_errors() {
    let rig = BlendshapeRig::from_morph_mesh(tiny_mesh(80, &["a", "b"]), &identity_map(), "tiny").unwrap();
    assert_eq!(rig.num_shapes(), 2);
    assert_eq!(rig.num_mapped(), 68);
    assert!((rig.deltas[[1, 4, 0]] - 0.0).abs() < 1e-6); // (4+1)%5 = 0
                                                         // map beyond the vertex count
    let e = BlendshapeRig::from_morph_mesh(tiny_mesh(50, &["a"]), &identity_map(), "small").unwrap_err();
    assert!(e.to_string().contains("small"), "{e}");
    // mismatched delta count
    let mut m = tiny_mesh(80, &["a", "b"]);
    m.targets[1].deltas.pop();
    let e = BlendshapeRig::from_morph_mesh(m, &identity_map(), "bad").unwrap_err();
    assert!(e.to_string().contains("\"b\""), "{e}");
    // duplicate names
    assert!(BlendshapeRig::from_morph_mesh(tiny_mesh(80, &["a", "a"]), &identity_map(), "dup").is_err());
    // unknown name in a selection
    let e = rig.select(&["a", "zzz"]).unwrap_err();
    assert!(e.to_string().contains("zzz"));
    let s = rig.select(&["b"]).unwrap();
    assert_eq!(s.names, vec!["b".to_string()]);
    // too few mapped landmarks
    let mut v: Vec<Option<u32>> = vec![None; 68];
    v[0] = Some(1);
    let sparse = LandmarkMap::from_slice(&v).unwrap();
    assert!(BlendshapeRig::from_morph_mesh(tiny_mesh(80, &["a"]), &sparse, "sparse").is_err());
}

#[test]
fn obj_rig_from_files() {
    let dir = std::env::temp_dir().join(format!("facecap_solve_obj_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, shift: f32, nv: usize| {
        let mut s = String::new();
        for i in 0..nv {
            s += &format!("v {} {} {}\n", i as f32 + shift, (i % 9) as f32, 0.5);
        }
        s += "f 1 2 3 4\n";
        let p = dir.join(name);
        std::fs::write(&p, s).unwrap();
        p
    };
    let neutral = write("neutral.obj", 0.0, 70);
    let smile = write("smile.obj", 0.25, 70);
    let short = write("short.obj", 0.25, 69);
    let rig = BlendshapeRig::from_obj_files(&neutral, &[("smile".into(), smile)], &identity_map()).unwrap();
    assert!((rig.deltas[[0, 10, 0]] - 0.25).abs() < 1e-6);
    assert_eq!(rig.mesh.as_ref().unwrap().base.triangles.len(), 2);
    let e = BlendshapeRig::from_obj_files(&neutral, &[("short".into(), short)], &identity_map()).unwrap_err();
    assert!(e.to_string().contains("69 vertices"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

fn example_shapes() -> Shapes2d {
    let neutral = Landmarks68::from_fn(|i| (100.0 + (i as f64 * 1.7) % 40.0, 80.0 + (i as f64 * 2.3) % 50.0));
    let smile = Landmarks68::from_fn(|i| {
        let p = neutral.points[i];
        // same face, shifted/scaled, mouth corners moved
        let (dx, dy) = if i == 48 || i == 54 { (2.0, -3.0) } else { (0.0, 0.0) };
        (1.1 * p.x + 5.0 + dx, 1.1 * p.y - 2.0 + dy)
    });
    Shapes2d::from_landmarks(&neutral, &[("smile".into(), "smile.jpg".into(), smile)]).unwrap()
}

#[test]
fn shapes2d_round_trip_and_alignment() {
    let s = example_shapes();
    let dir = std::env::temp_dir().join(format!("facecap_solve_s2d_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("shapes.json");
    s.save(&p).unwrap();
    let back = Shapes2d::load(&p).unwrap();
    // serde_json parses decimals to within one ulp (no float_roundtrip feature)
    assert_eq!(back.shapes[0].name, s.shapes[0].name);
    let close = |a: &[[f64; 2]], b: &[[f64; 2]]| {
        a.iter()
            .flatten()
            .zip(b.iter().flatten())
            .all(|(x, y)| (x - y).abs() < 1e-9)
    };
    assert!(close(&back.neutral, &s.neutral) && close(&back.shapes[0].landmarks, &s.shapes[0].landmarks));
    let basis = Basis2d::from_shapes2d(&back).unwrap();
    // the similarity removes scale and shift; the stable points carry no delta
    assert!(basis.deltas[[0, 2 * 30]].abs() < 1e-9);
    assert!(basis.deltas[[0, 2 * 48]].abs() > 1.0);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn shapes2d_rejects_every_truncation_and_bad_content() {
    let text = example_shapes().to_json_string().unwrap();
    for cut in (0..text.len()).step_by(97) {
        assert!(
            Shapes2d::from_json_str(&text[..cut]).is_err(),
            "accepted truncation at {cut}"
        );
    }
    assert!(Shapes2d::from_json_str(&text.replace("facecap-shapes2d", "other")).is_err());
    let mut s = example_shapes();
    s.shapes[0].landmarks.pop();
    assert!(s.validate().is_err());
    let mut s = example_shapes();
    s.shapes.push(s.shapes[0].clone());
    assert!(s.validate().unwrap_err().to_string().contains("twice"));
    let mut s = example_shapes();
    s.neutral[3][0] = f64::INFINITY;
    assert!(s.validate().is_err());
}

#[test]
fn ict_rig_from_raw_files() {
    let Some(dir) = facecap_core::paths::shared_data_file("ict_rig_from_raw_files", "models3d/ict_facekit") else {
        return;
    };
    let rig = BlendshapeRig::from_ict_dir(&dir).unwrap();
    assert_eq!(rig.num_shapes(), 53);
    assert_eq!(rig.num_mapped(), 68);
    assert_eq!(rig.names[26], "jawOpen");
    // jawOpen moves the chin (landmark 8) down by centimetres
    assert!(rig.deltas[[26, 8, 1]] < -1.0, "{}", rig.deltas[[26, 8, 1]]);
    let mesh = rig.mesh.as_ref().unwrap();
    assert_eq!(mesh.base.positions.len(), 9409);
    assert!(!mesh.base.triangles.is_empty());
}

#[test]
fn ict_and_sfm_rigs_from_gltf() {
    for (glb, map, shapes, mapped) in [
        (
            "models3d/ict_facekit/ict_face_arkit53.glb",
            "models3d/ict_facekit/ict_landmarks68.json",
            53,
            68,
        ),
        (
            "models3d/eos_sfm/sfm_expressions6.glb",
            "models3d/eos_sfm/sfm_landmarks68.json",
            6,
            50,
        ),
    ] {
        let (Some(g), Some(m)) = (
            facecap_core::paths::shared_data_file("ict_and_sfm_rigs_from_gltf", glb),
            facecap_core::paths::shared_data_file("ict_and_sfm_rigs_from_gltf", map),
        ) else {
            continue;
        };
        let rig = BlendshapeRig::from_gltf(&g, &m).unwrap();
        assert_eq!(rig.num_shapes(), shapes, "{glb}");
        assert_eq!(rig.num_mapped(), mapped, "{glb}");
    }
}
