#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Mesh I/O: glTF/GLB and OBJ readers and writers, on synthetic meshes (always run),
//! the shared 3D models (skipped when absent) and the Khronos glTF validator
//! (skipped when node/npm are missing).

use std::path::{Path, PathBuf};
use std::process::Command;

use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_core::paths::shared_data_file;
use facecap_core::Error;
use facecap_io::gltf_io::{
    glb_to_vec, read_morph_file, read_morph_mesh, read_morph_mesh_from_slice, write_glb, write_gltf, write_morph_file,
    MorphAnimation,
};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A seeded `nx` x `ny` grid with normals, UVs and `k` random morph targets.
fn synthetic_rig(nx: usize, ny: usize, k: usize, seed: u64) -> MorphMesh {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut base = Mesh::default();
    for j in 0..ny {
        for i in 0..nx {
            let z: f32 = rng.random_range(-0.3..0.3);
            base.positions.push(Point3::new(i as f32, j as f32, z));
            base.uvs.push([i as f32 / (nx - 1) as f32, j as f32 / (ny - 1) as f32]);
        }
    }
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let a = (j * nx + i) as u32;
            let b = a + 1;
            let c = a + nx as u32;
            let d = c + 1;
            base.triangles.push([a, b, d]);
            base.triangles.push([a, d, c]);
        }
    }
    base.compute_normals();
    let n = base.positions.len();
    let targets = (0..k)
        .map(|t| MorphTarget {
            name: format!("shape{t}_{}", ["jawOpen", "browUp_L", "smile"][t % 3]),
            deltas: (0..n)
                .map(|_| {
                    Vector3::new(
                        rng.random_range(-0.5..0.5),
                        rng.random_range(-0.5..0.5),
                        rng.random_range(-0.5..0.5),
                    )
                })
                .collect(),
        })
        .collect();
    MorphMesh { base, targets }
}

fn synthetic_animation(frames: usize, k: usize, fps: f32, seed: u64) -> MorphAnimation {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    MorphAnimation {
        times_s: (0..frames).map(|f| f as f32 / fps).collect(),
        weights: (0..frames)
            .map(|_| (0..k).map(|_| rng.random_range(0.0..1.0)).collect())
            .collect(),
    }
}

fn assert_same_mesh(a: &MorphMesh, b: &MorphMesh) {
    assert_eq!(a.base.positions, b.base.positions);
    assert_eq!(a.base.triangles, b.base.triangles);
    assert_eq!(a.base.uvs, b.base.uvs);
    assert_eq!(a.base.normals.len(), b.base.normals.len());
    for (x, y) in a.base.normals.iter().zip(&b.base.normals) {
        assert!((x - y).norm() < 1e-6, "{x:?} vs {y:?}");
    }
    assert_eq!(a.target_names(), b.target_names());
    for (x, y) in a.targets.iter().zip(&b.targets) {
        assert_eq!(x.deltas, y.deltas);
    }
}

/// Runs `scripts/validate_gltf.sh` on `files`; `false` (with a SKIP line) when
/// node/npm or the validator package are unavailable, panics when the validator
/// reports errors.
fn khronos_validate(test: &str, files: &[&Path]) -> bool {
    let have = |tool: &str| {
        Command::new(tool)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if !have("node") || !have("npm") {
        facecap_core::paths::skip(&format!(
            "{test}: node/npm not installed, Khronos glTF validator not run"
        ));
        return false;
    }
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/validate_gltf.sh");
    let out = Command::new("bash").arg(&script).args(files).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{stdout}{stderr}");
    match out.status.code() {
        Some(0) => {
            // measured: errors=0 warnings=0 (one info) on every file facecap writes
            for line in stdout.lines().filter(|l| l.contains("errors=")) {
                assert!(line.contains("errors=0 warnings=0"), "Khronos glTF validator: {line}");
            }
            assert!(stdout.contains("errors="), "no validator summary: {stdout}");
            true
        }
        Some(2) => {
            facecap_core::paths::skip(&format!(
                "{test}: glTF validator could not be installed or run: {stderr}"
            ));
            false
        }
        _ => panic!("Khronos glTF validator reported errors:\n{stdout}\n{stderr}"),
    }
}

#[test]
fn glb_and_gltf_round_trip_and_pass_khronos_validator() {
    let dir = tempfile::tempdir().unwrap();
    let rig = synthetic_rig(7, 6, 5, 11);
    let anim = synthetic_animation(45, 5, 30.0, 12);
    let glb = dir.path().join("rig.glb");
    let gltf = dir.path().join("rig.gltf");
    let still = dir.path().join("still.glb");
    write_glb(&glb, &rig, Some(&anim)).unwrap();
    write_gltf(&gltf, &rig, Some(&anim)).unwrap();
    write_morph_file(&still, &rig, None).unwrap();

    for p in [&glb, &gltf] {
        let (back, back_anim) = read_morph_file(p).unwrap();
        assert_same_mesh(&rig, &back);
        assert_eq!(back_anim.as_ref(), Some(&anim), "{}", p.display());
    }
    let (back, none) = read_morph_file(&still).unwrap();
    assert_same_mesh(&rig, &back);
    assert!(none.is_none());
    // Only the three outputs remain in the folder (no temporary files).
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);

    khronos_validate(
        "glb_and_gltf_round_trip_and_pass_khronos_validator",
        &[&glb, &gltf, &still],
    );
}

#[test]
fn mesh_without_normals_uvs_or_targets_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let mut rig = synthetic_rig(3, 3, 0, 5);
    rig.base.normals.clear();
    rig.base.uvs.clear();
    let p = dir.path().join("plain.glb");
    write_glb(&p, &rig, None).unwrap();
    let back = read_morph_mesh(&p).unwrap();
    assert_same_mesh(&rig, &back);
    // An animation needs morph targets.
    let anim = synthetic_animation(3, 0, 30.0, 1);
    assert!(write_glb(dir.path().join("x.glb"), &rig, Some(&anim)).is_err());
    assert!(!dir.path().join("x.glb").exists());
}

#[test]
fn invalid_animations_and_meshes_are_rejected_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let rig = synthetic_rig(3, 3, 2, 3);
    let p = dir.path().join("bad.glb");
    let good = synthetic_animation(4, 2, 25.0, 3);
    let mut cases: Vec<MorphAnimation> = Vec::new();
    let mut a = good.clone();
    a.times_s[2] = a.times_s[1];
    cases.push(a);
    let mut a = good.clone();
    a.times_s[3] = f32::NAN;
    cases.push(a);
    let mut a = good.clone();
    a.times_s[0] = -1.0;
    cases.push(a);
    let mut a = good.clone();
    a.weights[1][0] = f32::INFINITY;
    cases.push(a);
    let mut a = good.clone();
    a.weights[1].push(0.0);
    cases.push(a);
    let mut a = good.clone();
    a.weights.pop();
    cases.push(a);
    cases.push(MorphAnimation::default());
    for (i, c) in cases.iter().enumerate() {
        let r = write_glb(&p, &rig, Some(c));
        assert!(
            matches!(r, Err(Error::InvalidParameter { .. } | Error::DimensionMismatch { .. })),
            "case {i}: {r:?}"
        );
        assert!(!p.exists());
    }
    let mut bad = rig.clone();
    bad.base.triangles.push([0, 1, 99]);
    assert!(write_glb(&p, &bad, None).is_err());
    let mut bad = rig.clone();
    bad.targets[0].deltas.pop();
    assert!(write_glb(&p, &bad, None).is_err());
    let mut bad = rig.clone();
    bad.base.normals[0].x = f32::NAN;
    assert!(write_glb(&p, &bad, None).is_err());
    assert!(write_morph_file(dir.path().join("x.obj"), &rig, None).is_err());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn truncated_and_corrupted_glb_never_panics() {
    let rig = synthetic_rig(3, 2, 2, 9);
    let anim = synthetic_animation(3, 2, 30.0, 9);
    let bytes = glb_to_vec(&rig, Some(&anim)).unwrap();
    assert!(read_morph_mesh_from_slice(&bytes, None).is_ok());
    for len in 0..bytes.len() {
        let r = read_morph_mesh_from_slice(&bytes[..len], None);
        assert!(r.is_err(), "truncation to {len} of {} bytes accepted", bytes.len());
    }
    // Seeded random byte corruption: Ok or Err, never a panic.
    // Half of the edits hit the JSON chunk (bytes 20..20+json_len), with printable bytes.
    let json_len = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]) as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    for _ in 0..3000 {
        let mut b = bytes.clone();
        for _ in 0..rng.random_range(1..4) {
            if rng.random_bool(0.5) {
                let i = rng.random_range(20..20 + json_len);
                const PRINTABLE: &[u8] = b"0123456789,:[]{}-eE.9 ";
                b[i] = PRINTABLE[rng.random_range(0..PRINTABLE.len())];
            } else {
                let i = rng.random_range(0..b.len());
                b[i] = rng.random();
            }
        }
        let _ = read_morph_file_from_slice_ok(&b);
    }
}

fn read_morph_file_from_slice_ok(b: &[u8]) -> bool {
    facecap_io::gltf_io::read_morph_file_from_slice(b, None).is_ok()
}

#[test]
fn malformed_gltf_json_is_a_parse_error() {
    let cases = [
        r#"{"asset":{"version":"2.0"}}"#.to_string(),
        r#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{}}]}]}"#.to_string(),
        r#"not json"#.to_string(),
        // accessor beyond its buffer view
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA"}],
           "bufferViews":[{"buffer":0,"byteLength":12}],
           "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}],
           "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]}"#
            .to_string(),
        // POSITION of the wrong type
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA"}],
           "bufferViews":[{"buffer":0,"byteLength":12}],
           "accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC2"}],
           "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]}"#
            .to_string(),
        // wrong number of target names
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":36,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}],
           "bufferViews":[{"buffer":0,"byteLength":36}],
           "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],
           "meshes":[{"extras":{"targetNames":["a","b"]},"primitives":[{"attributes":{"POSITION":0},"targets":[{"POSITION":0}]}]}]}"#
            .to_string(),
    ];
    for (i, c) in cases.iter().enumerate() {
        let r = read_morph_mesh_from_slice(c.as_bytes(), None);
        assert!(matches!(r, Err(Error::Parse { .. })), "case {i}: {r:?}");
    }
    // The same file with one name is fine and unnamed targets get target_<k>.
    let ok = cases[5].replace(r#"["a","b"]"#, r#"["a"]"#);
    let m = read_morph_mesh_from_slice(ok.as_bytes(), None).unwrap();
    assert_eq!(m.target_names(), vec!["a"]);
    assert_eq!(m.base.triangles, vec![[0, 1, 2]]);
    let unnamed = cases[5].replace(r#""extras":{"targetNames":["a","b"]},"#, "");
    let m = read_morph_mesh_from_slice(unnamed.as_bytes(), None).unwrap();
    assert_eq!(m.target_names(), vec!["target_0"]);

    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.glb");
    assert!(matches!(read_morph_mesh(&missing), Err(Error::Io { .. })));
}

#[test]
fn shared_glb_models_read() {
    let cases: [(&str, usize); 4] = [
        ("models3d/ict_facekit/ict_face_arkit53.glb", 53),
        ("models3d/ict_facekit/ict_face_identity100.glb", 100),
        ("models3d/eos_sfm/sfm_shape63.glb", 63),
        ("models3d/eos_sfm/sfm_expressions6.glb", 6),
    ];
    for (rel, k) in cases {
        let Some(p) = shared_data_file("shared_glb_models_read", rel) else {
            continue;
        };
        let m = read_morph_mesh(&p).unwrap();
        assert_eq!(m.targets.len(), k, "{rel}");
        assert!(m.base.num_vertices() > 1000, "{rel}");
        assert!(!m.base.triangles.is_empty());
        m.validate().unwrap();
        for (i, t) in m.targets.iter().enumerate() {
            assert!(
                !t.name.is_empty() && t.name != format!("target_{i}"),
                "{rel}: unnamed target {i}"
            );
        }
        eprintln!(
            "{rel}: {} vertices, {} triangles, {} targets, first {:?}",
            m.base.num_vertices(),
            m.base.triangles.len(),
            k,
            m.targets[0].name
        );
    }
    if let Some(p) = shared_data_file("shared_glb_models_read", "models3d/ict_facekit/ict_face_arkit53.glb") {
        let m = read_morph_mesh(&p).unwrap();
        let names = m.target_names();
        assert!(names.contains(&"jawOpen"), "{names:?}");
    }
}

#[test]
fn ict_rig_with_300_keyframes_is_valid_gltf() {
    let test = "ict_rig_with_300_keyframes_is_valid_gltf";
    let Some(p) = shared_data_file(test, "models3d/ict_facekit/ict_face_arkit53.glb") else {
        return;
    };
    let rig = read_morph_mesh(&p).unwrap();
    let anim = synthetic_animation(300, rig.targets.len(), 30.0, 53);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ict_anim.glb");
    write_glb(&out, &rig, Some(&anim)).unwrap();
    let (back, back_anim) = read_morph_file(&out).unwrap();
    assert_same_mesh(&rig, &back);
    assert_eq!(back_anim.unwrap(), anim);
    khronos_validate(test, &[&out]);
}

// ------------------------------------------------------------------ OBJ

use facecap_io::obj::{obj_to_string, parse_obj, read_obj, read_obj_with_sources, write_obj};

/// `v` lines of an OBJ parsed independently (first three numbers).
fn independent_v_lines(text: &str) -> Vec<[f32; 3]> {
    text.lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            (f.next() == Some("v")).then(|| {
                let v: Vec<f32> = f.take(3).map(|x| x.parse().unwrap()).collect();
                [v[0], v[1], v[2]]
            })
        })
        .collect()
}

type Corner = ([u32; 3], [u32; 2]);

fn key(p: &[f32], uv: Option<&[f32]>) -> Corner {
    let uv = uv.map(|t| [t[0].to_bits(), t[1].to_bits()]).unwrap_or([0, 0]);
    ([p[0].to_bits(), p[1].to_bits(), p[2].to_bits()], uv)
}

/// Triangles as sorted (position, uv) corner triples, from our reader.
fn our_corners(m: &Mesh) -> Vec<[Corner; 3]> {
    let mut v: Vec<[Corner; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            t.map(|i| {
                let p = m.positions[i as usize];
                key(&[p.x, p.y, p.z], m.uvs.get(i as usize).map(|u| &u[..]))
            })
        })
        .collect();
    v.sort();
    v
}

/// The same from tobj (the reference reader; single-index mode aligns attributes).
fn tobj_corners(path: &Path) -> Option<Vec<[Corner; 3]>> {
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _materials) = tobj::load_obj(path, &opts).ok()?;
    let mut v = Vec::new();
    for m in &models {
        let mm = &m.mesh;
        for t in mm.indices.chunks_exact(3) {
            v.push([t[0], t[1], t[2]].map(|i| {
                let i = i as usize;
                let uv = (!mm.texcoords.is_empty()).then(|| &mm.texcoords[2 * i..2 * i + 2]);
                key(&mm.positions[3 * i..3 * i + 3], uv)
            }));
        }
    }
    v.sort();
    Some(v)
}

#[test]
fn shared_obj_files_match_tobj_and_keep_vertex_order() {
    let test = "shared_obj_files_match_tobj_and_keep_vertex_order";
    // (file, v lines, triangles or None)
    let cases: [(&str, usize, Option<usize>); 7] = [
        ("models3d/mediapipe/canonical_face_model.obj", 468, Some(898)),
        ("models3d/mediapipe/face_model_with_iris.obj", 478, Some(906)),
        ("models3d/menpo3d_james/james.obj", 6393, Some(12228)),
        ("models3d/eos_sfm/sfm_reference.obj", 845, Some(1610)),
        ("models3d/eos_sfm/sfm_reference_annotated.obj", 845, Some(1610)),
        (
            "models3d/ict_facekit/generic_neutral_mesh.obj",
            26719,
            Some(548 + 2 * 25836),
        ),
        ("models3d/ict_facekit/jawOpen.obj", 26719, Some(548 + 2 * 25836)),
    ];
    for (rel, nv, nt) in cases {
        let Some(p) = shared_data_file(test, rel) else { continue };
        let text = std::fs::read_to_string(&p).unwrap();
        let (m, sources) = read_obj_with_sources(&p).unwrap();
        m.validate().unwrap();
        let v = independent_v_lines(&text);
        assert_eq!(v.len(), nv, "{rel}");
        for (i, q) in v.iter().enumerate() {
            let p = m.positions[i];
            assert_eq!([p.x, p.y, p.z], *q, "{rel}: vertex {i} moved");
        }
        for (i, &s) in sources.iter().enumerate() {
            assert_eq!(m.positions[i], m.positions[s as usize]);
        }
        if let Some(nt) = nt {
            assert_eq!(m.triangles.len(), nt, "{rel}");
        }
        match tobj_corners(&p) {
            Some(reference) => assert_eq!(our_corners(&m), reference, "{rel}: triangles differ from tobj"),
            // tobj 4.0.5 fails on `v x y z r g b # comment` (sfm_reference_annotated.obj);
            // that file is sfm_reference.obj plus colours and comments.
            None => {
                let plain = shared_data_file(test, "models3d/eos_sfm/sfm_reference.obj").unwrap();
                assert!(
                    rel.ends_with("sfm_reference_annotated.obj"),
                    "{rel}: tobj cannot read it"
                );
                assert_eq!(m, read_obj(plain).unwrap(), "{rel}");
            }
        }
        eprintln!(
            "{rel}: {} v lines, {} vertices after seam split, {} triangles, uvs: {}",
            nv,
            m.num_vertices(),
            m.triangles.len(),
            !m.uvs.is_empty()
        );
        // Round trip: write and read back bit-identically.
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("rt.obj");
        write_obj(&out, &m).unwrap();
        let back = read_obj(&out).unwrap();
        assert_eq!(back, m, "{rel}: round trip");
    }
}

#[test]
fn ict_obj_and_glb_share_vertex_positions() {
    let test = "ict_obj_and_glb_share_vertex_positions";
    let (Some(obj), Some(glb)) = (
        shared_data_file(test, "models3d/ict_facekit/generic_neutral_mesh.obj"),
        shared_data_file(test, "models3d/ict_facekit/ict_face_arkit53.glb"),
    ) else {
        return;
    };
    let m = read_obj(obj).unwrap();
    let g = read_morph_mesh(glb).unwrap();
    // The glb holds the face area: its vertices are the first ones of the OBJ.
    let n = g.base.num_vertices().min(m.num_vertices());
    let max_err = (0..n)
        .map(|i| (m.positions[i] - g.base.positions[i]).norm())
        .fold(0.0f32, f32::max);
    eprintln!(
        "ICT: obj {} vertices, glb {} vertices, max |diff| over first {n} = {max_err}",
        m.num_vertices(),
        g.base.num_vertices()
    );
    assert!(max_err < 1e-4, "{max_err}");
}

#[test]
fn obj_round_trip_synthetic_and_seams() {
    let rig = synthetic_rig(5, 4, 0, 21);
    for (uv, nn) in [(true, true), (true, false), (false, true), (false, false)] {
        let mut m = rig.base.clone();
        if !uv {
            m.uvs.clear();
        }
        if !nn {
            m.normals.clear();
        }
        let text = obj_to_string(&m).unwrap();
        let (back, src) = parse_obj(&text).unwrap();
        assert_eq!(back, m, "uv {uv} normals {nn}");
        assert_eq!(src, (0..m.num_vertices() as u32).collect::<Vec<_>>());
    }
    // A quad with a seam: vertex 1 used with two UVs; negative indices; groups; comments.
    let text = "# test\no a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 9 9 9\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n\
                g g1\nf 1/1 2/2 3/3 4/4\ng g2\nf -4/-1 -3/3 1/1 # trailing comment\n";
    let (m, src) = parse_obj(text).unwrap();
    assert_eq!(m.num_vertices(), 6);
    assert_eq!(src, vec![0, 1, 2, 3, 4, 1]);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [5, 2, 0]]);
    assert_eq!(m.uvs[1], [1.0, 0.0]);
    assert_eq!(m.uvs[5], [0.5, 0.5]);
    assert_eq!(m.uvs[4], [0.0, 0.0]); // unused vertex kept
    assert_eq!(m.positions[5], m.positions[1]);
}

#[test]
fn malformed_obj_is_an_error_with_line_number() {
    let cases = [
        ("v 1 2\n", "line 1"),
        ("v 1 2 x\n", "line 1"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3\n", "line 5"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/a 2 3\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n", "line 4"),
        ("v nan 0 0\n", "line 1"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", "line 4"),
    ];
    for (text, line) in cases {
        match parse_obj(text) {
            Err(Error::Parse { reason, .. }) => assert!(reason.contains(line), "{text:?}: {reason}"),
            other => panic!("{text:?} accepted: {other:?}"),
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.obj");
    std::fs::write(&p, "v 1 2\n").unwrap();
    match read_obj(&p) {
        Err(Error::Parse { path, .. }) => assert_eq!(path, p),
        other => panic!("{other:?}"),
    }
    assert!(matches!(read_obj(dir.path().join("none.obj")), Err(Error::Io { .. })));
}

#[test]
fn every_truncation_of_an_obj_is_handled() {
    let mut m = synthetic_rig(3, 3, 0, 4).base;
    m.triangles.truncate(4);
    let text = obj_to_string(&m).unwrap();
    let full = parse_obj(&text).unwrap().0;
    for len in 0..text.len() {
        match parse_obj(&text[..len]) {
            Ok((t, _)) => {
                // A cut at a line boundary (or inside a number) gives a smaller valid mesh.
                t.validate().unwrap();
                assert!(t.triangles.len() <= full.triangles.len());
            }
            Err(Error::Parse { .. }) => {}
            Err(e) => panic!("unexpected error kind {e:?}"),
        }
    }
    // Garbage bytes: never a panic.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..2000 {
        let mut b = text.clone().into_bytes();
        for _ in 0..3 {
            let i = rng.random_range(0..b.len());
            b[i] = b"0123456789 /-.\nfvtn#e"[rng.random_range(0..21)];
        }
        let _ = parse_obj(&String::from_utf8_lossy(&b));
    }
}

#[test]
fn obj_writer_rejects_invalid_meshes() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.obj");
    let mut m = synthetic_rig(3, 3, 0, 4).base;
    m.triangles.push([0, 1, 100]);
    assert!(write_obj(&p, &m).is_err());
    let mut m = synthetic_rig(3, 3, 0, 4).base;
    m.uvs[2][0] = f32::NAN;
    assert!(write_obj(&p, &m).is_err());
    assert!(!p.exists());
}

/// Negative control: the validator script really fails on a broken file (POSITION
/// accessor without `min`/`max`, animation times not increasing).
#[test]
fn validator_script_rejects_a_broken_file() {
    let test = "validator_script_rejects_a_broken_file";
    let have = |tool: &str| {
        Command::new(tool)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if !have("node") || !have("npm") {
        facecap_core::paths::skip(&format!("{test}: node/npm not installed"));
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("broken.gltf");
    let rig = synthetic_rig(3, 3, 2, 1);
    write_gltf(&p, &rig, Some(&synthetic_animation(3, 2, 30.0, 1))).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    let pos = v["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
        .as_u64()
        .unwrap() as usize;
    v["accessors"][pos].as_object_mut().unwrap().remove("min");
    std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/validate_gltf.sh");
    let out = Command::new("bash").arg(&script).arg(&p).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}");
    match out.status.code() {
        Some(2) => facecap_core::paths::skip(&format!("{test}: validator unavailable")),
        Some(1) => assert!(stdout.contains("errors="), "{stdout}"),
        other => panic!("validator accepted a broken file ({other:?}):\n{stdout}"),
    }
}

/// Timing of the I/O on the ICT rig (not a criterion bench: run on demand with
/// `cargo test -p facecap-core --release --test mesh_io -- --ignored --nocapture io_timings`;
/// figures go to docs/bench/core_io.md).
#[test]
#[ignore]
fn io_timings() {
    use std::time::Instant;
    let test = "io_timings";
    let (Some(glb), Some(obj)) = (
        shared_data_file(test, "models3d/ict_facekit/ict_face_arkit53.glb"),
        shared_data_file(test, "models3d/ict_facekit/generic_neutral_mesh.obj"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let reps = 5;
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let time = |f: &mut dyn FnMut()| {
        median(
            (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    f();
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect(),
        )
    };
    let mut rig = None;
    let t_read = time(&mut || rig = Some(read_morph_mesh(&glb).unwrap()));
    let rig = rig.unwrap();
    let anim = synthetic_animation(300, rig.targets.len(), 30.0, 1);
    let out = dir.path().join("ict.glb");
    let t_vec = time(&mut || {
        std::hint::black_box(glb_to_vec(&rig, Some(&anim)).unwrap());
    });
    let t_write = time(&mut || write_glb(&out, &rig, Some(&anim)).unwrap());
    let size = std::fs::metadata(&out).unwrap().len();
    let t_obj = time(&mut || {
        std::hint::black_box(read_obj(&obj).unwrap());
    });
    let outobj = dir.path().join("ict.obj");
    let m = read_obj(&obj).unwrap();
    let t_wobj = time(&mut || write_obj(&outobj, &m).unwrap());
    // Per-frame CSV row: 136 landmark + 6 pose + 53 weight columns.
    let mut cols = facecap_io::csv::landmark_columns();
    cols.extend(facecap_io::csv::POSE_COLUMNS.iter().map(|s| s.to_string()));
    cols.extend(rig.target_names().iter().map(|s| s.to_string()));
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let values: Vec<f64> = (0..cols.len()).map(|_| rng.random_range(0.0..640.0)).collect();
    let rows = 3000u64;
    let mut row_ms = Vec::new();
    let t_csv = time(&mut || {
        let mut w = facecap_io::csv::FrameCsvWriter::create(dir.path().join("t.csv"), &cols).unwrap();
        let t = Instant::now();
        for f in 0..rows {
            w.write_row(&facecap_io::csv::FrameRow {
                frame: f,
                timestamp: f as f64 / 30.0,
                success: true,
                confidence: 0.97,
                values: &values,
            })
            .unwrap();
        }
        row_ms.push(t.elapsed().as_secs_f64() * 1e3);
        w.finish().unwrap();
    });
    let csv_bytes = std::fs::metadata(dir.path().join("t.csv")).unwrap().len();
    let rows_only = median(row_ms);
    eprintln!(
        "CSV: {} columns, {rows} rows ({csv_bytes} bytes): write_row {:.1} us/row; create + rows + finish (fsync) {t_csv:.1} ms",
        cols.len() + 4,
        rows_only * 1e3 / rows as f64
    );
    eprintln!(
        "ICT arkit53 ({} vertices, {} targets): read_morph_mesh {t_read:.1} ms; \
         glb_to_vec with 300 keyframes {t_vec:.1} ms; write_glb (atomic, fsync) {t_write:.1} ms, {size} bytes; \
         read_obj ICT neutral ({} vertices) {t_obj:.1} ms; write_obj {t_wobj:.1} ms (median of {reps})",
        rig.base.num_vertices(),
        rig.targets.len(),
        m.num_vertices()
    );
}

#[test]
fn gltf_with_external_buffer_reads() {
    // Turn the embedded data URI of a written .gltf into a .bin beside it.
    let dir = tempfile::tempdir().unwrap();
    let rig = synthetic_rig(4, 3, 2, 17);
    let anim = synthetic_animation(5, 2, 30.0, 17);
    let glb = glb_to_vec(&rig, Some(&anim)).unwrap();
    let json_len = u32::from_le_bytes([glb[12], glb[13], glb[14], glb[15]]) as usize;
    let mut json: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let bin = &glb[20 + json_len + 8..];
    std::fs::write(dir.path().join("rig data.bin"), bin).unwrap();
    json["buffers"][0]["uri"] = serde_json::Value::String("rig%20data.bin".into());
    let p = dir.path().join("rig.gltf");
    std::fs::write(&p, serde_json::to_vec(&json).unwrap()).unwrap();
    let (m, a) = read_morph_file(&p).unwrap();
    assert_same_mesh(&rig, &m);
    assert_eq!(a.unwrap(), anim);
    // Missing external buffer: an error, not a panic.
    std::fs::remove_file(dir.path().join("rig data.bin")).unwrap();
    assert!(matches!(read_morph_mesh(&p), Err(Error::Parse { .. })));
    // From a slice without a base folder, external buffers are refused.
    let bytes = std::fs::read(&p).unwrap();
    assert!(read_morph_mesh_from_slice(&bytes, None).is_err());
}

/// Every `.glb` and `.obj` below `shared/data/models3d` reads (not only the ones named above).
#[test]
fn every_shared_mesh_file_reads() {
    let Some(root) = shared_data_file("every_shared_mesh_file_reads", "models3d") else {
        return;
    };
    let mut files = Vec::new();
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "glb" || e == "obj") {
                files.push(p);
            }
        }
    }
    files.sort();
    for p in &files {
        if p.extension().is_some_and(|e| e == "glb") {
            let m = read_morph_mesh(p).unwrap();
            m.validate().unwrap();
        } else {
            let m = read_obj(p).unwrap();
            m.validate().unwrap();
        }
    }
    eprintln!("read {} mesh files", files.len());
    assert!(files.len() >= 11, "{files:?}");
}
