#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Guarantees of the five solvers on seeded synthetic ground truth.

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::Landmarks68;
use facecap_solve::synth::{generate, rmse, SynthParams};
use facecap_solve::{
    Basis2d, BlendshapeRig, BobyqaParams, BobyqaSolver, Exact3dParams, Exact3dSolver, ExactParams, ExactSolver,
    ExpressionSolver, PcaParams, PcaSolver, RegionParams, RegionSolver, Solution, SolveState, StopReason,
};

/// Frontal orthographic landmarks of the rig at weights `e`: 25 px per unit, rotated by `angle`.
fn frontal_landmarks(rig: &BlendshapeRig, e: &[f64], angle: f64) -> Landmarks68 {
    let (c, s) = (angle.cos(), angle.sin());
    Landmarks68::from_fn(|l| {
        let p = rig.landmark(l, e);
        let (x, y) = (25.0 * p.x, -25.0 * p.y);
        (320.0 + c * x - s * y, 240.0 + s * x + c * y)
    })
}

fn sparse_weights(n: usize, seed: u64) -> Vec<f64> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut w = vec![0.0; n];
    for _ in 0..4 {
        w[rng.random_range(0..n)] = rng.random_range(0.2..1.0);
    }
    w
}

fn run<S: ExpressionSolver>(s: &S, lm: &Landmarks68) -> (Solution, facecap_solve::Report) {
    let mut ws = s.workspace();
    let mut st = SolveState::new(s.num_shapes());
    let mut out = Solution::new(s.num_shapes());
    let r = s.solve_into(lm, &mut ws, &mut st, &mut out).unwrap();
    (out, r)
}

#[test]
fn exact_recovers_weights_in_2d() {
    let rig = BlendshapeRig::synthetic(16, 5);
    let basis = Basis2d::frontal(&rig);
    let solver = ExactSolver::new(&basis, ExactParams::default()).unwrap();
    for seed in 0..10 {
        let w = sparse_weights(16, seed);
        let lm = frontal_landmarks(&rig, &w, 0.2);
        let (out, rep) = run(&solver, &lm);
        assert_eq!(rep.stop, StopReason::Converged);
        assert!(rmse(&out.weights, &w) < 0.01, "seed {seed}: {:?} vs {w:?}", out.weights);
        assert!(out.reprojection_error(&lm) < 0.2);
    }
}

#[test]
fn exact_objective_never_above_bobyqa() {
    // same objective (alignments = 1, L1 = 1, no temporal): the exact optimum is <= BOBYQA's
    let rig = BlendshapeRig::synthetic(16, 9);
    let basis = Basis2d::frontal(&rig);
    let exact = ExactSolver::new(
        &basis,
        ExactParams {
            alignments: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let bob = BobyqaSolver::new(&basis, BobyqaParams::default()).unwrap();
    for seed in 0..15 {
        let w = sparse_weights(16, 100 + seed);
        let mut lm = frontal_landmarks(&rig, &w, -0.1);
        for (i, p) in lm.points.iter_mut().enumerate() {
            p.x += ((i * 7 + seed as usize) % 5) as f64 * 0.3 - 0.6;
        }
        let (oe, re) = run(&exact, &lm);
        let (ob, rb) = run(&bob, &lm);
        assert!(
            re.cost <= rb.cost + 1e-9 * rb.cost.abs(),
            "seed {seed}: exact {} > bobyqa {}",
            re.cost,
            rb.cost
        );
        assert!(rb.evaluations > 33, "BOBYQA evaluated {} times", rb.evaluations);
        assert!(rmse(&oe.weights, &ob.weights) < 0.2);
    }
}

#[test]
fn region_and_pca_fit_reasonably() {
    let rig = BlendshapeRig::synthetic(16, 5);
    let basis = Basis2d::frontal(&rig);
    let region = RegionSolver::new(&basis, RegionParams::default()).unwrap();
    assert!(region.group_names().len() >= 2);
    let pca = PcaSolver::new(&basis, PcaParams::default()).unwrap();
    assert!(pca.num_components() <= 16);
    for seed in 0..5 {
        let w = sparse_weights(16, 200 + seed);
        let lm = frontal_landmarks(&rig, &w, 0.05);
        let (op, _) = run(&pca, &lm);
        assert!(rmse(&op.weights, &w) < 0.02, "pca seed {seed}");
        let (or, _) = run(&region, &lm);
        assert!(or.weights.iter().all(|&x| (0.0..=1.0).contains(&x)));
        assert!(
            or.reprojection_error(&lm) < 5.0,
            "region error {}",
            or.reprojection_error(&lm)
        );
    }
}

#[test]
fn temporal_term_pulls_towards_previous_frame() {
    let rig = BlendshapeRig::synthetic(8, 2);
    let basis = Basis2d::frontal(&rig);
    let mk = |mu| {
        ExactSolver::new(
            &basis,
            ExactParams {
                objective: facecap_solve::ObjectiveParams { l1: 1.0, temporal: mu },
                ..Default::default()
            },
        )
        .unwrap()
    };
    let (s0, s1) = (mk(0.0), mk(1e6));
    let w0 = vec![0.0; 8];
    let mut w1 = vec![0.0; 8];
    w1[3] = 0.8;
    for (s, expect_move) in [(&s0, true), (&s1, false)] {
        let mut ws = s.workspace();
        let mut st = SolveState::new(8);
        let mut out = Solution::new(8);
        s.solve_into(&frontal_landmarks(&rig, &w0, 0.0), &mut ws, &mut st, &mut out)
            .unwrap();
        s.solve_into(&frontal_landmarks(&rig, &w1, 0.0), &mut ws, &mut st, &mut out)
            .unwrap();
        assert_eq!(out.weights[3] > 0.5, expect_move, "{:?}", out.weights);
    }
}

fn camera() -> Intrinsics {
    Intrinsics::default_for_frame(640, 480).unwrap()
}

#[test]
fn exact3d_recovers_pose_and_weights_and_beats_bobyqa() {
    let rig = BlendshapeRig::synthetic(16, 21);
    let cam = camera();
    let frames = generate(&rig, &cam, 640.0, &SynthParams::default(), 20, 4);
    let s3 = Exact3dSolver::new(&rig, Exact3dParams::new(cam)).unwrap();
    let bob = BobyqaSolver::new(&Basis2d::frontal(&rig), BobyqaParams::default()).unwrap();
    let mut sum = 0.0;
    for (i, f) in frames.iter().enumerate() {
        let (o3, r3) = run(&s3, &f.landmarks);
        assert_ne!(r3.stop, StopReason::MaxIterations, "frame {i}");
        let e = rmse(&o3.weights, &f.weights);
        sum += e;
        assert!(e < 0.02, "frame {i}: rmse {e}, {:?} vs {:?}", o3.weights, f.weights);
        let pose = o3.pose.unwrap();
        let ang = (pose.0.rotation.inverse() * f.pose.0.rotation).angle().to_degrees();
        assert!(ang < 0.5, "frame {i}: rotation error {ang} deg");
        // BOBYQA's weights scored under the 3D model with their best pose
        let (ob, _) = run(&bob, &f.landmarks);
        let (_, fb) = s3.fit_pose(&f.landmarks, &ob.weights).unwrap();
        assert!(
            r3.cost <= fb + 1e-9 * fb,
            "frame {i}: exact3d {} > bobyqa {fb}",
            r3.cost
        );
    }
    eprintln!("mean weight RMSE exact3d: {}", sum / frames.len() as f64);
}

#[test]
fn exact3d_tracks_with_warm_start() {
    let rig = BlendshapeRig::synthetic(12, 3);
    let cam = camera();
    let frames = generate(
        &rig,
        &cam,
        640.0,
        &SynthParams {
            noise_px: 0.5,
            ..Default::default()
        },
        10,
        8,
    );
    let s3 = Exact3dSolver::new(&rig, Exact3dParams::new(cam)).unwrap();
    let mut ws = s3.workspace();
    let mut st = SolveState::new(12);
    let mut out = Solution::new(12);
    for f in &frames {
        let r = s3.solve_into(&f.landmarks, &mut ws, &mut st, &mut out).unwrap();
        assert!(r.cost.is_finite());
        assert!(rmse(&out.weights, &f.weights) < 0.1);
        assert!(out.reprojection_error(&f.landmarks) < 2.0);
    }
}

#[test]
fn invalid_inputs_and_params_are_errors() {
    let rig = BlendshapeRig::synthetic(4, 1);
    let basis = Basis2d::frontal(&rig);
    let bad = ExactParams {
        objective: facecap_solve::ObjectiveParams {
            l1: f64::NAN,
            temporal: 0.0,
        },
        ..Default::default()
    };
    let e = ExactSolver::new(&basis, bad).unwrap_err().to_string();
    assert!(e.contains("l1"), "{e}");
    assert!(ExactSolver::new(
        &basis,
        ExactParams {
            alignments: 0,
            ..Default::default()
        }
    )
    .is_err());
    assert!(BobyqaSolver::new(
        &basis,
        BobyqaParams {
            npt: Some(2),
            ..Default::default()
        }
    )
    .is_err());
    let s = ExactSolver::new(&basis, ExactParams::default()).unwrap();
    let mut lm = frontal_landmarks(&rig, &[0.0; 4], 0.0);
    lm.points[3].x = f64::NAN;
    let mut ws = s.workspace();
    let mut st = SolveState::new(4);
    let mut out = Solution::new(4);
    assert!(s.solve_into(&lm, &mut ws, &mut st, &mut out).is_err());
    let mut st5 = SolveState::new(5);
    let lm = frontal_landmarks(&rig, &[0.0; 4], 0.0);
    assert!(s.solve_into(&lm, &mut ws, &mut st5, &mut out).is_err());
    // all landmarks at one point: degenerate alignment
    let lm = Landmarks68::from_fn(|_| (5.0, 5.0));
    assert!(s.solve_into(&lm, &mut ws, &mut st, &mut out).is_err());
    let bad_groups = RegionParams {
        groups: Some(vec![facecap_solve::RegionGroup {
            name: "x".into(),
            landmarks: vec![70],
            shapes: vec![0],
        }]),
        ..Default::default()
    };
    assert!(RegionSolver::new(&basis, bad_groups).is_err());
}

/// Dense points on a synthetic rig: `m` points between the landmarks, each with its own
/// random deltas for every shape.
fn dense_points(rig: &BlendshapeRig, m: usize, seed: u64) -> facecap_solve::DensePoints {
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = rig.num_shapes();
    let zero = vec![0.0; n];
    let mut neutral = Vec::new();
    let mut deltas = Vec::new();
    for _ in 0..m {
        let (a, b) = (rng.random_range(0..68), rng.random_range(0..68));
        let t: f64 = rng.random_range(0.2..0.8);
        let (pa, pb) = (rig.landmark(a, &zero), rig.landmark(b, &zero));
        neutral.push(pa.coords * t + pb.coords * (1.0 - t) + Vector3::new(0.0, 0.0, 0.3));
        for _ in 0..n {
            deltas.push(Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.1..0.1),
            ));
        }
    }
    facecap_solve::DensePoints::new((0..m).collect(), neutral, deltas, n, 68.0 / m as f64).unwrap()
}

#[test]
fn exact3d_dense_points_recover_a_shape_the_landmarks_cannot_see() {
    let n = 12;
    let mut rig = BlendshapeRig::synthetic(n, 3);
    // shape 5 does not move any of the 68 landmarks
    rig.deltas.index_axis_mut(ndarray::Axis(0), 5).fill(0.0);
    let cam = camera();
    let frames = generate(&rig, &cam, 640.0, &SynthParams::default(), 8, 7);
    let points = dense_points(&rig, 200, 11);
    let plain = Exact3dSolver::new(&rig, Exact3dParams::new(cam)).unwrap();
    let dense = plain.clone().with_dense(points.clone()).unwrap();
    assert_eq!((dense.num_landmarks(), dense.num_dense()), (68, 200));
    for (i, f) in frames.iter().enumerate() {
        let mut w = f.weights.clone();
        w[5] = 0.6;
        // the 68 landmarks do not change with shape 5; the dense points do
        let obs: Vec<[f32; 3]> = (0..points.len())
            .map(|j| {
                let mut p = points.neutral()[j];
                for (k, wk) in w.iter().enumerate() {
                    p += dense_delta(&points, j, k, n) * *wk;
                }
                let c = f.pose.0 * nalgebra::Point3::from(p);
                [
                    (cam.fx * c.x / c.z + cam.cx) as f32,
                    (cam.fy * c.y / c.z + cam.cy) as f32,
                    0.0,
                ]
            })
            .collect();
        let mut ws = dense.workspace();
        let mut st = SolveState::new(n);
        let mut out = Solution::new(n);
        dense
            .solve_dense_into(&f.landmarks, Some(&obs), &mut ws, &mut st, &mut out)
            .unwrap();
        let e = rmse(&out.weights, &w);
        assert!(e < 0.03, "frame {i}: rmse {e}, {:?} vs {w:?}", out.weights);
        assert!(
            (out.weights[5] - 0.6).abs() < 0.05,
            "frame {i}: shape 5 at {}",
            out.weights[5]
        );
        // without the dense observations: exactly the 68-point solve
        let (o68, r68) = run(&plain, &f.landmarks);
        let (od, rd) = run(&dense, &f.landmarks);
        assert_eq!(o68.weights, od.weights, "frame {i}");
        assert_eq!(r68.cost.to_bits(), rd.cost.to_bits(), "frame {i}");
        assert!(o68.weights[5] < 1e-6, "frame {i}: the landmarks see shape 5?");
        // observations too short: the 68-point solve as well
        dense
            .solve_dense_into(
                &f.landmarks,
                Some(&obs[..10]),
                &mut ws,
                &mut SolveState::new(n),
                &mut out,
            )
            .unwrap();
        assert_eq!(out.weights, o68.weights);
    }
}

fn dense_delta(points: &facecap_solve::DensePoints, j: usize, k: usize, n: usize) -> nalgebra::Vector3<f64> {
    points.deltas()[j * n + k]
}

/// The landmarks of `rig` at weights `w`, seen with `pose` (as `synth::generate` projects).
fn project(
    rig: &BlendshapeRig,
    w: &[f64],
    pose: &facecap_core::camera::ModelToCamera,
    cam: &Intrinsics,
) -> Landmarks68 {
    Landmarks68::from_fn(|l| {
        let q = pose.project(cam, &rig.landmark(l, w)).unwrap();
        (q.x, q.y)
    })
}

#[test]
fn exact3d_coupled_child_acts_only_with_its_parent() {
    let rig = BlendshapeRig::synthetic(16, 21);
    let cam = camera();
    let frames = generate(&rig, &cam, 640.0, &SynthParams::default(), 3, 4);
    let (child, parent) = (5, 2);
    let priors = facecap_solve::ShapePriors {
        coupled: vec![(child, parent)],
        ..facecap_solve::ShapePriors::neutral(16)
    };
    let s3 = Exact3dSolver::new(&rig, Exact3dParams::new(cam))
        .unwrap()
        .with_priors(priors.clone())
        .unwrap();
    for (i, f) in frames.iter().enumerate() {
        // truth that keeps the coupling (child <= parent) is recovered exactly
        let mut w = vec![0.0; 16];
        w[parent] = 0.7;
        w[child] = 0.4;
        w[9] = 0.5;
        let lm = project(&rig, &w, &f.pose, &cam);
        let (o, r) = run(&s3, &lm);
        let e = rmse(&o.weights, &w);
        assert!(e < 0.01, "frame {i}: rmse {e}, {:?} vs {w:?}", o.weights);
        // the reported cost is the objective at the reported (rig) weights
        let f_at = s3.objective(&lm, &o.weights, o.pose.as_ref().unwrap(), None).unwrap();
        assert!(
            (f_at - r.cost).abs() <= 1e-6 * r.cost.abs().max(1.0),
            "frame {i}: {f_at} vs {}",
            r.cost
        );
        // truth that breaks it (the child alone) never comes out with the child above the parent
        let mut alone = vec![0.0; 16];
        alone[child] = 0.6;
        let (o, _) = run(&s3, &project(&rig, &alone, &f.pose, &cam));
        assert!(
            o.weights[child] <= o.weights[parent] + 1e-12,
            "frame {i}: child {} > parent {}",
            o.weights[child],
            o.weights[parent]
        );
        // without the coupling the same landmarks give the child alone
        let free = Exact3dSolver::new(&rig, Exact3dParams::new(cam)).unwrap();
        let (o, _) = run(&free, &project(&rig, &alone, &f.pose, &cam));
        assert!(
            (o.weights[child] - 0.6).abs() < 0.01 && o.weights[parent] < 0.01,
            "{:?}",
            o.weights
        );
    }
    // priors twice: the second replaces the first's coupling, it does not add to it
    let again = s3.with_priors(priors).unwrap();
    let mut w = vec![0.0; 16];
    w[parent] = 0.5;
    w[child] = 0.5;
    let (o, _) = run(&again, &project(&rig, &w, &frames[0].pose, &cam));
    assert!(rmse(&o.weights, &w) < 0.01, "{:?}", o.weights);
    // invalid couplings are errors
    for bad in [vec![(3, 3)], vec![(3, 16)], vec![(3, 1), (3, 2)], vec![(3, 1), (4, 3)]] {
        let p = facecap_solve::ShapePriors {
            coupled: bad.clone(),
            ..facecap_solve::ShapePriors::neutral(16)
        };
        assert!(p.validate(16).is_err(), "{bad:?}");
    }
}
