#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! HOSVD guarantees: reconstruction, orthonormal factors, sorted singular values,
//! separability, truncation bound, model file round trip and rejection.

use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use facecap_tensor::tensor::DataTensor;
use facecap_tensor::Error;
use ndarray::Array2;

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

fn unit(n: usize, k: usize) -> Vec<f64> {
    let mut v = vec![0.0; n];
    v[k] = 1.0;
    v
}

#[test]
fn reconstructs_every_database_face() {
    let d = synth::database(300, 9, 5, 1).unwrap();
    let (m, rep) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    assert_eq!((rep.rank_id, rep.rank_exp), (9, 5));
    for i in 0..9 {
        for e in 0..5 {
            let f = m.generate(&unit(9, i), &unit(5, e)).unwrap();
            let truth: Vec<f64> = d.data.slice(ndarray::s![.., i, e]).to_vec();
            let err = max_abs_diff(&f, &truth);
            assert!(err < 1e-10, "cell ({i},{e}) error {err}");
        }
    }
}

fn assert_orthonormal_columns(u: &Array2<f64>) {
    let g = u.t().dot(u);
    for r in 0..g.nrows() {
        for c in 0..g.ncols() {
            let want = if r == c { 1.0 } else { 0.0 };
            assert!((g[[r, c]] - want).abs() < 1e-10, "U^T U [{r},{c}] = {}", g[[r, c]]);
        }
    }
}

#[test]
fn mode_matrices_orthonormal_and_singular_values_sorted_and_match_svd() {
    let d = synth::database(200, 8, 6, 2).unwrap();
    let (m, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    assert_orthonormal_columns(&m.u_id);
    assert_orthonormal_columns(&m.u_exp);
    let uu = m.u_id.dot(&m.u_id.t());
    for r in 0..8 {
        assert!((uu[[r, r]] - 1.0).abs() < 1e-10);
    }
    for s in [&m.sigma_id, &m.sigma_exp] {
        assert!(s.windows(2).all(|w| w[0] >= w[1]), "not sorted: {s:?}");
    }
    // Slow reference: the SVD of the centred mode-2 unfolding.
    let (p3, ni, ne) = d.data.dim();
    let mean: Vec<f64> = (0..p3)
        .map(|p| d.data.slice(ndarray::s![p, .., ..]).sum() / (ni * ne) as f64)
        .collect();
    let d2 = nalgebra::DMatrix::from_fn(ni, p3 * ne, |i, c| d.data[[c / ne, i, c % ne]] - mean[c / ne]);
    let mut sv: Vec<f64> = d2.svd(false, false).singular_values.iter().copied().collect();
    sv.sort_by(|a, b| b.total_cmp(a));
    for (a, b) in sv.iter().zip(&m.sigma_id) {
        assert!((a - b).abs() < 1e-8 * sv[0], "{a} vs {b}");
    }
}

#[test]
fn separable_tensor_keeps_expression_pattern_across_identities() {
    let d = synth::separable_database(150, 6, 4, 3).unwrap();
    let (m, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let disp = |w_id: &[f64], e: usize| -> Vec<f64> {
        let a = m.generate(w_id, &unit(4, e)).unwrap();
        let b = m.generate(w_id, &unit(4, 0)).unwrap();
        a.iter().zip(&b).map(|(x, y)| x - y).collect()
    };
    let mixed = [0.5, 0.1, 0.0, 0.2, 0.15, 0.05];
    for e in 1..4 {
        let ref_disp = disp(&unit(6, 0), e);
        for w in [unit(6, 3), unit(6, 5), mixed.to_vec()] {
            let err = max_abs_diff(&disp(&w, e), &ref_disp);
            assert!(err < 1e-9, "expression {e}: displacement changed by {err}");
        }
    }
    // The interaction term makes the non-separable database differ.
    let d = synth::database(150, 6, 4, 3).unwrap();
    let (m2, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let a: Vec<f64> = {
        let x = m2.generate(&unit(6, 0), &unit(4, 2)).unwrap();
        let y = m2.generate(&unit(6, 0), &unit(4, 0)).unwrap();
        x.iter().zip(&y).map(|(p, q)| p - q).collect()
    };
    let b: Vec<f64> = {
        let x = m2.generate(&unit(6, 3), &unit(4, 2)).unwrap();
        let y = m2.generate(&unit(6, 3), &unit(4, 0)).unwrap();
        x.iter().zip(&y).map(|(p, q)| p - q).collect()
    };
    assert!(max_abs_diff(&a, &b) > 1e-3);
}

#[test]
fn truncation_error_within_discarded_energy() {
    let d = synth::database(200, 10, 6, 4).unwrap();
    let params = HosvdParams {
        energy_id: 0.9,
        energy_exp: 0.95,
    };
    let (m, rep) = TensorModel::build(&d, &params).unwrap();
    assert!(rep.rank_id < 10 && rep.rank_exp <= 6);
    assert!(rep.energy_id >= 0.9 && rep.energy_exp >= 0.95);
    let mut err2 = 0.0;
    for i in 0..10 {
        for e in 0..6 {
            let f = m.generate(&unit(10, i), &unit(6, e)).unwrap();
            let t = d.data.slice(ndarray::s![.., i, e]);
            err2 += f.iter().zip(t.iter()).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
        }
    }
    let bound: f64 = m.sigma_id[rep.rank_id..].iter().map(|s| s * s).sum::<f64>()
        + m.sigma_exp[rep.rank_exp..].iter().map(|s| s * s).sum::<f64>();
    assert!(err2 <= bound * (1.0 + 1e-9) + 1e-12, "error^2 {err2} > bound {bound}");
    assert!(TensorModel::build(
        &d,
        &HosvdParams {
            energy_id: 0.0,
            energy_exp: 1.0
        }
    )
    .is_err());
    assert!(TensorModel::build(
        &d,
        &HosvdParams {
            energy_id: f64::NAN,
            energy_exp: 1.0
        }
    )
    .is_err());
}

#[test]
fn model_file_round_trip_and_rejections() {
    let d = synth::database(40, 3, 2, 5).unwrap();
    let (m, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let bytes = m.to_bytes(false);
    assert_eq!(TensorModel::from_bytes(&bytes).unwrap(), m);
    let m32 = TensorModel::from_bytes(&m.to_bytes(true)).unwrap();
    let a = m.generate(&unit(3, 1), &unit(2, 1)).unwrap();
    let b = m32.generate(&unit(3, 1), &unit(2, 1)).unwrap();
    assert!(max_abs_diff(&a, &b) < 1e-4);
    // Every truncation is rejected with a format error.
    for len in 0..bytes.len() {
        match TensorModel::from_bytes(&bytes[..len]) {
            Err(Error::Format { .. }) => {}
            other => panic!("prefix {len} accepted or wrong error: {other:?}"),
        }
    }
    let mut extra = bytes.clone();
    extra.push(0);
    assert!(TensorModel::from_bytes(&extra).is_err());
    let mut bad = bytes.clone();
    bad[0] = b'X';
    assert!(TensorModel::from_bytes(&bad).unwrap_err().to_string().contains("magic"));
    let mut bad = bytes.clone();
    bad[8] = 2;
    assert!(TensorModel::from_bytes(&bad)
        .unwrap_err()
        .to_string()
        .contains("version"));
    let mut bad = bytes.clone();
    let off = bytes.len() - 8; // last core value
    bad[off..].copy_from_slice(&f64::NAN.to_le_bytes());
    assert!(TensorModel::from_bytes(&bad).is_err());
    // Counts read from the header are checked against the bytes present before anything
    // is reserved: I = 0xFFFFFFFF (header offset 20) or E = 0xFFFFFFFF (offset 24) once
    // reserved 100 GB and aborted the process; now they are format errors.
    for off in [20, 24] {
        let mut huge = bytes.clone();
        huge[off..off + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        match TensorModel::from_bytes(&huge) {
            Err(Error::Format { reason, .. }) => assert!(reason.contains("cannot fit"), "{reason}"),
            other => panic!("count 0xFFFFFFFF at offset {off}: {other:?}"),
        }
    }
    // Through a file.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.fctensor");
    m.save(&p, false).unwrap();
    assert_eq!(TensorModel::load(&p).unwrap(), m);
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = TensorModel::load(&p).unwrap_err().to_string();
    assert!(e.contains("m.fctensor"), "{e}");
}

fn write_obj(path: &std::path::Path, pts: &[nalgebra::Point3<f64>]) {
    let mut s = String::new();
    for p in pts {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    s += "f 1 2 3\n";
    std::fs::write(path, s).unwrap();
}

#[test]
fn mesh_folder_database_and_errors() {
    let d = synth::database(30, 3, 2, 6).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let exps = ["neutral", "mouth_Open"];
    for i in 0..3 {
        for (e, en) in exps.iter().enumerate() {
            write_obj(&dir.path().join(format!("p{i}_{en}.obj")), &d.cell(i, e).unwrap());
        }
    }
    let t = DataTensor::from_mesh_folder(dir.path()).unwrap();
    assert_eq!(t.identities, vec!["p0", "p1", "p2"]);
    assert_eq!(t.expressions, vec!["mouth_Open", "neutral"]);
    assert_eq!(t.triangles, vec![[0, 1, 2]]);
    let c = t.cell(1, 1).unwrap();
    assert!((c[4] - d.cell(1, 0).unwrap()[4]).norm() < 1e-5);
    // Missing cell.
    std::fs::remove_file(dir.path().join("p2_neutral.obj")).unwrap();
    match DataTensor::from_mesh_folder(dir.path()) {
        Err(Error::MissingCell { identity, expression }) => {
            assert_eq!((identity.as_str(), expression.as_str()), ("p2", "neutral"));
        }
        other => panic!("{other:?}"),
    }
    // Inconsistent vertex count.
    write_obj(&dir.path().join("p2_neutral.obj"), &d.cell(2, 0).unwrap()[..20]);
    let e = DataTensor::from_mesh_folder(dir.path()).unwrap_err();
    assert!(
        matches!(
            e,
            Error::DimensionMismatch {
                expected: 30,
                got: 20,
                ..
            }
        ),
        "{e}"
    );
    // Bad name.
    write_obj(&dir.path().join("nounderscore.obj"), &d.cell(2, 0).unwrap());
    assert!(matches!(
        DataTensor::from_mesh_folder(dir.path()),
        Err(Error::Format { .. })
    ));
}

#[test]
fn rigs_give_sampled_identities_times_expressions() {
    use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
    use nalgebra::{Point3, Vector3};
    let base = Mesh {
        positions: (0..10).map(|k| Point3::new(k as f32, 0.0, 0.0)).collect(),
        ..Default::default()
    };
    let target = |name: &str, s: f32| MorphTarget {
        name: name.into(),
        deltas: (0..10).map(|k| Vector3::new(0.0, s * k as f32, 0.0)).collect(),
    };
    let id_rig = MorphMesh {
        base: base.clone(),
        targets: vec![target("m0", 1.0), target("m1", -0.5)],
    };
    let exp_rig = MorphMesh {
        base: base.clone(),
        targets: vec![target("smile", 0.0), target("jawOpen", 2.0)],
    };
    let s = facecap_tensor::tensor::RigSampling {
        identities: 4,
        seed: 9,
        ..Default::default()
    };
    let t = DataTensor::from_rigs(&id_rig, &exp_rig, &s).unwrap();
    assert_eq!(t.expressions, vec!["neutral", "smile", "jawOpen"]);
    assert_eq!(t.num_identities(), 4);
    let again = DataTensor::from_rigs(&id_rig, &exp_rig, &s).unwrap();
    assert_eq!(t, again, "seeded");
    let n = t.cell(2, 0).unwrap();
    let j = t.cell(2, 2).unwrap();
    assert!(((j[3].y - n[3].y) - 6.0).abs() < 1e-6);
    let s2 = facecap_tensor::tensor::RigSampling {
        expressions: Some(vec!["jawOpen".into(), "nope".into()]),
        ..s.clone()
    };
    assert!(DataTensor::from_rigs(&id_rig, &exp_rig, &s2).is_err());
    let mut short = exp_rig.clone();
    short.base.positions.pop();
    for t in &mut short.targets {
        t.deltas.pop();
    }
    assert!(matches!(
        DataTensor::from_rigs(&id_rig, &short, &s),
        Err(Error::DimensionMismatch { .. })
    ));
}

#[test]
fn expression_rig_reproduces_the_generative_function() {
    let d = synth::database(80, 4, 3, 8).unwrap();
    let (m, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let w_id = [0.1, 0.5, 0.3, 0.1];
    let w_exp = [0.2, 0.7, 0.4];
    let rig = m.expression_rig(&w_id).unwrap();
    assert_eq!(rig.targets.len(), 3);
    let mut posed = Vec::new();
    rig.pose_into(&w_exp, &mut posed).unwrap();
    let f = m.generate(&w_id, &w_exp).unwrap();
    for (p, c) in posed.iter().zip(f.chunks_exact(3)) {
        for k in 0..3 {
            assert!((p[k] as f64 - c[k]).abs() < 1e-4);
        }
    }
}

#[test]
fn closest_visible_vertex_prefers_the_front() {
    use facecap_core::camera::{Intrinsics, ModelToCamera};
    use facecap_tensor::features::{closest_visible_vertices, grid_samples_in_polygon};
    use nalgebra::{Point2, Point3, Vector3};
    // Two vertices on the same ray: the nearer one (z = 50) must win.
    let verts = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.0, 0.0, 10.0),
        Point3::new(5.0, 0.0, 0.0),
    ];
    let pose = ModelToCamera::from_rvec_tvec(Vector3::zeros(), Vector3::new(0.0, 0.0, 60.0));
    // Camera looks along +Z; model +Z points away here, so vertex 0 (z_cam = 60) is nearer than vertex 1 (70).
    let k = Intrinsics::new(500.0, 500.0, 100.0, 100.0).unwrap();
    let got = closest_visible_vertices(
        &verts,
        &pose,
        &k,
        &[Point2::new(100.2, 100.0), Point2::new(500.0, 0.0)],
        3.0,
    )
    .unwrap();
    assert_eq!(got, vec![Some(0), None]);
    let square = [
        Point2::new(0.0, 0.0),
        Point2::new(10.0, 0.0),
        Point2::new(10.0, 10.0),
        Point2::new(0.0, 10.0),
    ];
    let s = grid_samples_in_polygon(&square, 0.0, 2.5);
    assert!(s.len() >= 9 && s.iter().all(|p| p.x >= 0.0 && p.x <= 10.0));
}
