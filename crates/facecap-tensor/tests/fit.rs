#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Fitting guarantees: recovery from synthetic projections, monotone cost, NNLS
//! against a reference, sequences with one identity, lost points.

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_geom::nnls;
use facecap_tensor::fit::{FitInput, FitParams, Fitter, Method, Projection, Stop};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use nalgebra::{Point2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Scene {
    model: TensorModel,
    vertices: Vec<u32>,
    k: Intrinsics,
}

fn scene(nv: usize, ni: usize, ne: usize, npts: usize, seed: u64) -> Scene {
    let d = synth::database(nv, ni, ne, seed).unwrap();
    let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let step = nv / npts;
    let vertices = (0..npts).map(|k| (k * step) as u32).collect();
    Scene {
        model,
        vertices,
        k: Intrinsics::new(900.0, 900.0, 319.5, 239.5).unwrap(),
    }
}

/// Random non-negative weights summing to 1 (a convex combination of database cells).
fn simplex(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    let v: Vec<f64> = (0..n).map(|_| -rng.random::<f64>().max(1e-12).ln()).collect();
    let s: f64 = v.iter().sum();
    v.iter().map(|x| x / s).collect()
}

fn project(s: &Scene, w_id: &[f64], w_exp: &[f64], pose: &ModelToCamera) -> (Vec<f64>, Vec<Point2<f64>>) {
    let f = s.model.generate(w_id, w_exp).unwrap();
    let img = s
        .vertices
        .iter()
        .map(|&v| {
            let p = nalgebra::Point3::new(f[3 * v as usize], f[3 * v as usize + 1], f[3 * v as usize + 2]);
            pose.project(&s.k, &p).unwrap()
        })
        .collect();
    (f, img)
}

fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / (a.len() / 3) as f64).sqrt()
}

#[test]
fn recovers_shape_and_pose_from_exact_points() {
    let s = scene(600, 8, 5, 200, 11);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let w_id = simplex(&mut rng, 8);
    let w_exp = simplex(&mut rng, 5);
    let pose = ModelToCamera::from_rvec_tvec(Vector3::new(0.1, -0.25, 0.05), Vector3::new(1.5, -0.5, 70.0));
    let (truth, image) = project(&s, &w_id, &w_exp, &pose);
    let params = FitParams {
        lambda_id: 1e-9,
        lambda_exp: 1e-9,
        projection: Projection::PerPointDepth,
        max_sweeps: 300,
        tol: 1e-14,
        ..Default::default()
    };
    let fitter = Fitter::new(&s.model, &s.vertices, params).unwrap();
    let mut ws = fitter.workspace();
    let mut st = fitter.initial_state();
    let weights = vec![1.0; s.vertices.len()];
    let input = FitInput {
        image: &image,
        weights: &weights,
        intrinsics: s.k,
    };
    let rep = fitter.solve_into(&input, &mut ws, &mut st).unwrap();
    let fitted = s.model.generate(&st.w_id, &st.w_exp).unwrap();
    let err = rms(&fitted, &truth);
    assert!(rep.rms_px < 1e-2, "{rep:?}");
    assert!(err < 1e-2, "shape RMS error {err} ({rep:?})");
    assert!((st.pose.unwrap().tvec() - pose.tvec()).norm() < 0.05);
}

#[test]
fn cost_never_increases_between_sweeps() {
    for (seed, method, projection) in [
        (1, Method::Regularised, Projection::WeakPerspective),
        (2, Method::Regularised, Projection::PerPointDepth),
        (3, Method::NonNegative, Projection::WeakPerspective),
        (4, Method::NonNegative, Projection::PerPointDepth),
    ] {
        let s = scene(400, 7, 4, 68, seed);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let pose = ModelToCamera::from_rvec_tvec(
            Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.2..0.2),
            ),
            Vector3::new(0.0, 0.0, rng.random_range(40.0..90.0)),
        );
        let (_, mut image) = project(&s, &simplex(&mut rng, 7), &simplex(&mut rng, 4), &pose);
        for p in &mut image {
            p.x += rng.random_range(-1.0..1.0);
            p.y += rng.random_range(-1.0..1.0);
        }
        let params = FitParams {
            method,
            projection,
            max_sweeps: 40,
            tol: 0.0,
            ..Default::default()
        };
        let fitter = Fitter::new(&s.model, &s.vertices, params).unwrap();
        let mut ws = fitter.workspace();
        let mut st = fitter.initial_state();
        let weights = vec![1.0; 68];
        let input = FitInput {
            image: &image,
            weights: &weights,
            intrinsics: s.k,
        };
        let rep = fitter.solve_into(&input, &mut ws, &mut st).unwrap();
        assert!(
            rep.max_increase <= 1e-12 * rep.initial_cost,
            "{method:?} {projection:?}: {rep:?}"
        );
        assert!(rep.final_cost <= rep.initial_cost);
        if method == Method::NonNegative {
            assert!(st.w_id.iter().chain(&st.w_exp).all(|&w| w >= 0.0));
        }
        // Sweep-by-sweep: re-run one sweep at a time from the state and check the cost sequence.
        let one = FitParams {
            method,
            projection,
            max_sweeps: 1,
            tol: 0.0,
            ..Default::default()
        };
        let f1 = Fitter::new(&s.model, &s.vertices, one).unwrap();
        let mut st1 = f1.initial_state();
        let mut prev = f64::INFINITY;
        for _ in 0..15 {
            f1.solve_into(&input, &mut ws, &mut st1).unwrap();
            let c = f1.cost(&input, &st1, &mut ws).unwrap();
            assert!(c <= prev * (1.0 + 1e-12), "cost went up: {prev} -> {c}");
            prev = c;
        }
    }
}

/// `H = AᵀA` and `f = -Aᵀb` (row-major `A`, `n` columns): the NNLS problem
/// `min ½xᵀHx + fᵀx, x >= 0` of the least squares `min |Ax - b|²`.
fn normal_equations(a: &[f64], b: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut h = vec![0.0; n * n];
    let mut f = vec![0.0; n];
    for (row, &br) in a.chunks_exact(n).zip(b) {
        for i in 0..n {
            f[i] -= row[i] * br;
            for j in 0..n {
                h[i * n + j] += row[i] * row[j];
            }
        }
    }
    (h, f)
}

#[test]
fn nnls_matches_exhaustive_reference() {
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    for _ in 0..30 {
        let n = rng.random_range(2..7);
        let m = n + 3;
        let a: Vec<f64> = (0..m * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let b: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (h, f) = normal_equations(&a, &b, n);
        let reference = nnls::reference_active_sets(&h, &f);
        let mut x = vec![0.0; n];
        let mut g = vec![0.0; n];
        let rep = nnls::solve_into(&h, &f, &mut x, &mut g, 10_000, 1e-12);
        assert_eq!(rep.stop, nnls::NnlsStop::Converged);
        let (o1, o2) = (nnls::objective(&h, &f, &x), nnls::objective(&h, &f, &reference));
        assert!(o1 <= o2 + 1e-9, "{o1} vs {o2}");
        for (p, q) in x.iter().zip(&reference) {
            assert!((p - q).abs() < 1e-5, "{x:?} vs {reference:?}");
        }
        // The support-polished variant (used by the fitter): same solution, far fewer
        // passes, never more than the plain coordinate passes.
        let mut xp = vec![0.0; n];
        let mut sc = vec![0.0; nnls::polish_scratch_len(n)];
        let rep_p = nnls::solve_polished_into(&h, &f, &mut xp, &mut g, &mut sc, 10_000, 1e-12);
        assert_eq!(rep_p.stop, nnls::NnlsStop::Converged);
        assert!(rep_p.iterations <= rep.iterations, "{rep_p:?} vs {rep:?}");
        let o3 = nnls::objective(&h, &f, &xp);
        assert!(o3 <= o2 + 1e-9, "{o3} vs {o2}");
        for (p, q) in xp.iter().zip(&reference) {
            assert!((p - q).abs() < 1e-5, "{xp:?} vs {reference:?}");
        }
    }
}

#[test]
fn polished_nnls_objective_never_increases_on_ill_conditioned_problems() {
    // 56 variables, condition number ~1e6 (like the identity block): every pass of the
    // polished solver must keep the objective non-increasing, and it must reach the
    // KKT point well within the pass budget the plain passes need.
    let mut rng = ChaCha8Rng::seed_from_u64(78);
    for _ in 0..5 {
        let n = 56;
        let m = 2 * n;
        let a: Vec<f64> = (0..m * n)
            .map(|q| rng.random_range(-1.0..1.0) * 10f64.powf(-3.0 * (q % n) as f64 / n as f64))
            .collect();
        let b: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (h, f) = normal_equations(&a, &b, n);
        let mut x = vec![0.0; n];
        let mut g = vec![0.0; n];
        let mut sc = vec![0.0; nnls::polish_scratch_len(n)];
        let mut prev = nnls::objective(&h, &f, &x);
        for _ in 0..200 {
            nnls::solve_polished_into(&h, &f, &mut x, &mut g, &mut sc, 1, 1e-12);
            let o = nnls::objective(&h, &f, &x);
            assert!(
                o <= prev + 1e-12 * prev.abs().max(1.0),
                "objective went up: {prev} -> {o}"
            );
            prev = o;
        }
        let mut xp = vec![0.0; n];
        let rep_p = nnls::solve_polished_into(&h, &f, &mut xp, &mut g, &mut sc, 500, 1e-10);
        let mut xs = vec![0.0; n];
        let rep_s = nnls::solve_into(&h, &f, &mut xs, &mut g, 500, 1e-10);
        assert_eq!(rep_p.stop, nnls::NnlsStop::Converged, "{rep_p:?}");
        assert!(rep_p.iterations < rep_s.iterations, "{rep_p:?} vs {rep_s:?}");
        assert!(nnls::objective(&h, &f, &xp) <= nnls::objective(&h, &f, &xs) + 1e-12);
    }
}

#[test]
fn sequence_shares_identity_and_recovers_frames() {
    let s = scene(500, 6, 5, 120, 21);
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let w_id = simplex(&mut rng, 6);
    let mut images = Vec::new();
    let mut truths = Vec::new();
    for f in 0..4 {
        let pose =
            ModelToCamera::from_rvec_tvec(Vector3::new(0.05 * f as f64, -0.1, 0.0), Vector3::new(0.0, 0.0, 60.0));
        let (t, img) = project(&s, &w_id, &simplex(&mut rng, 5), &pose);
        images.push(img);
        truths.push(t);
    }
    let params = FitParams {
        lambda_id: 1e-9,
        lambda_exp: 1e-9,
        projection: Projection::PerPointDepth,
        max_sweeps: 200,
        tol: 1e-14,
        ..Default::default()
    };
    let fitter = Fitter::new(&s.model, &s.vertices, params).unwrap();
    let mut ws = fitter.workspace();
    let weights = vec![1.0; s.vertices.len()];
    let inputs: Vec<FitInput> = images
        .iter()
        .map(|im| FitInput {
            image: im,
            weights: &weights,
            intrinsics: s.k,
        })
        .collect();
    let mut states: Vec<_> = (0..4).map(|_| fitter.initial_state()).collect();
    let rep = fitter.fit_sequence(&inputs, &mut states, &mut ws).unwrap();
    assert!(rep.max_increase <= 1e-12 * rep.initial_cost, "{rep:?}");
    for st in &states[1..] {
        assert_eq!(st.w_id, states[0].w_id);
    }
    for (st, t) in states.iter().zip(&truths) {
        let f = s.model.generate(&st.w_id, &st.w_exp).unwrap();
        assert!(rms(&f, t) < 2e-2, "frame shape error {} ({rep:?})", rms(&f, t));
    }
}

#[test]
fn lost_points_are_ignored_and_bad_input_rejected() {
    let s = scene(300, 5, 4, 60, 31);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let pose = ModelToCamera::from_rvec_tvec(Vector3::new(0.0, 0.2, 0.0), Vector3::new(0.0, 0.0, 50.0));
    let (_, mut image) = project(&s, &simplex(&mut rng, 5), &simplex(&mut rng, 4), &pose);
    let mut weights = vec![1.0; 60];
    for k in 0..10 {
        image[k] = Point2::new(f64::NAN, 1e9);
        weights[k] = 0.0;
    }
    let fitter = Fitter::new(&s.model, &s.vertices, FitParams::default()).unwrap();
    let mut ws = fitter.workspace();
    let mut st = fitter.initial_state();
    let input = FitInput {
        image: &image,
        weights: &weights,
        intrinsics: s.k,
    };
    let rep = fitter.solve_into(&input, &mut ws, &mut st).unwrap();
    assert!(matches!(rep.stop, Stop::Converged | Stop::MaxSweeps));
    // Same answer as a fitter that never saw the lost points.
    let kept: Vec<u32> = s.vertices[10..].to_vec();
    let f2 = Fitter::new(&s.model, &kept, FitParams::default()).unwrap();
    let mut ws2 = f2.workspace();
    let mut st2 = f2.initial_state();
    let input2 = FitInput {
        image: &image[10..],
        weights: &weights[10..],
        intrinsics: s.k,
    };
    let rep2 = f2.solve_into(&input2, &mut ws2, &mut st2).unwrap();
    assert_eq!(rep.sweeps, rep2.sweeps);
    for (a, b) in st.w_id.iter().chain(&st.w_exp).zip(st2.w_id.iter().chain(&st2.w_exp)) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
    assert!((rep.rms_px - rep2.rms_px).abs() < 1e-9);
    weights[10] = -1.0;
    let bad = FitInput {
        image: &image,
        weights: &weights,
        intrinsics: s.k,
    };
    assert!(fitter.solve_into(&bad, &mut ws, &mut st).is_err());
    assert!(Fitter::new(
        &s.model,
        &s.vertices,
        FitParams {
            lambda_id: f64::NAN,
            ..Default::default()
        }
    )
    .is_err());
    assert!(Fitter::new(&s.model, &[0, 1, 2], FitParams::default()).is_err());
    assert!(Fitter::new(&s.model, &[0, 1, 2, 300], FitParams::default()).is_err());
}
