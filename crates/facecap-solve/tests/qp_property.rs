#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The exact box-QP solver against the slow enumerating reference, on seeded random problems.

use facecap_geom::qp::{
    active_set, projected_newton, qp_cost, reference_box_qp, solve_box_qp, solve_box_qp_reuse, QpOptions, QpWorkspace,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_problem(rng: &mut ChaCha8Rng, n: usize, rows: usize) -> (Vec<f64>, Vec<f64>) {
    // H = 2 A^T A (PSD, usually PD), g random
    let a: Vec<f64> = (0..rows * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut h = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            h[i * n + j] = 2.0 * (0..rows).map(|r| a[r * n + i] * a[r * n + j]).sum::<f64>();
        }
        h[i * n + i] += 1e-9;
    }
    let g: Vec<f64> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
    (h, g)
}

#[test]
fn matches_reference_on_random_problems() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut ws = QpWorkspace::new(8);
    for trial in 0..300 {
        let n = rng.random_range(1..=6);
        let rows = rng.random_range(n..n + 6);
        let (h, g) = random_problem(&mut rng, n, rows);
        let lo = vec![0.0; n];
        let hi = vec![1.0; n];
        let reference = reference_box_qp(&h, &g, &lo, &hi).expect("reference finds a KKT point");
        let mut x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
        let o = solve_box_qp(&h, &g, &lo, &hi, &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged, "trial {trial}: not converged {o:?}");
        let (c, cr) = (qp_cost(&h, &g, &x), qp_cost(&h, &g, &reference));
        assert!(
            c <= cr + 1e-9 * (1.0 + cr.abs()),
            "trial {trial}: cost {c} > reference {cr}"
        );
        for (a, b) in x.iter().zip(&reference) {
            assert!(
                (a - b).abs() < 1e-6,
                "trial {trial}: x {x:?} vs reference {reference:?}"
            );
        }
    }
}

#[test]
fn mixed_infinite_bounds_and_rank_deficiency() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut ws = QpWorkspace::new(10);
    for _ in 0..100 {
        let n = 6;
        // rank-deficient: only 3 rows
        let (mut h, g) = random_problem(&mut rng, n, 3);
        for i in 0..n {
            h[i * n + i] += 1e-6;
        }
        let lo = [f64::NEG_INFINITY, f64::NEG_INFINITY, 0.0, 0.0, 0.0, 0.0];
        let hi = [f64::INFINITY, f64::INFINITY, 1.0, 1.0, 1.0, 1.0];
        let mut x = vec![0.0; n];
        let o = solve_box_qp(&h, &g, &lo, &hi, &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged, "{o:?}");
        let reference = reference_box_qp(&h, &g, &lo, &hi).unwrap();
        let (c, cr) = (qp_cost(&h, &g, &x), qp_cost(&h, &g, &reference));
        assert!(c <= cr + 1e-7 * (1.0 + cr.abs()), "cost {c} vs reference {cr}");
    }
}

#[test]
fn warm_start_from_optimum_takes_no_iteration() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (h, g) = random_problem(&mut rng, 8, 20);
    let (lo, hi) = (vec![0.0; 8], vec![1.0; 8]);
    let mut ws = QpWorkspace::new(8);
    let mut x = vec![0.5; 8];
    solve_box_qp(&h, &g, &lo, &hi, &mut x, &QpOptions::default(), &mut ws);
    let o = solve_box_qp(&h, &g, &lo, &hi, &mut x, &QpOptions::default(), &mut ws);
    assert_eq!(o.iterations, 0);
    assert!(o.converged);
}

#[test]
fn active_set_alone_converges_and_matches_reference() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let mut ws = QpWorkspace::new(8);
    for trial in 0..300 {
        let n = rng.random_range(1..=7);
        let rows = rng.random_range(n..n + 6);
        let (h, g) = random_problem(&mut rng, n, rows);
        let (lo, hi) = (vec![0.0; n], vec![1.0; n]);
        let reference = reference_box_qp(&h, &g, &lo, &hi).expect("reference finds a KKT point");
        let mut x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
        if trial % 3 == 0 {
            x.fill(0.0); // cold start at a vertex
        }
        let o = active_set(&h, &g, &lo, &hi, &mut x, &QpOptions::default(), &mut ws);
        assert!(o.converged, "trial {trial}: active set did not converge {o:?}");
        assert!((o.cost - qp_cost(&h, &g, &x)).abs() < 1e-9 * (1.0 + o.cost.abs()));
        for (a, b) in x.iter().zip(&reference) {
            assert!(
                (a - b).abs() < 1e-6,
                "trial {trial}: x {x:?} vs reference {reference:?}"
            );
        }
    }
}

#[test]
fn active_set_agrees_with_projected_newton_on_blendshape_sizes() {
    // n = 16 and 53 as the solvers use, ill-conditioned Gram-like H, cold and warm starts
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for &n in &[16usize, 53] {
        let mut ws = QpWorkspace::new(n);
        for trial in 0..20 {
            let (mut h, g0) = random_problem(&mut rng, n, 136);
            for v in h.iter_mut() {
                *v *= 50.0;
            }
            let g: Vec<f64> = g0.iter().map(|v| 40.0 * v).collect();
            let (lo, hi) = (vec![0.0; n], vec![1.0; n]);
            let mut xa: Vec<f64> = if trial % 2 == 0 {
                vec![0.0; n]
            } else {
                (0..n).map(|_| rng.random_range(0.0..1.0)).collect()
            };
            let mut xp = xa.clone();
            let oa = active_set(&h, &g, &lo, &hi, &mut xa, &QpOptions::default(), &mut ws);
            let op = projected_newton(&h, &g, &lo, &hi, &mut xp, &QpOptions::default(), &mut ws);
            assert!(oa.converged && op.converged, "n {n} trial {trial}: {oa:?} {op:?}");
            let (ca, cp) = (qp_cost(&h, &g, &xa), qp_cost(&h, &g, &xp));
            assert!(ca <= cp + 1e-9 * (1.0 + cp.abs()), "n {n} trial {trial}: {ca} > {cp}");
            for (a, b) in xa.iter().zip(&xp) {
                assert!((a - b).abs() < 1e-6, "n {n} trial {trial}");
            }
        }
    }
}

#[test]
fn factor_reuse_over_a_sequence_gives_the_same_solutions() {
    // a tracking-like sequence: H = c_t * H0 (changing scale), g drifting; solved with the
    // factor kept between calls and from scratch
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let n = 30;
    let (h0, mut g) = random_problem(&mut rng, n, 136);
    let (lo, hi) = (vec![0.0; n], vec![1.0; n]);
    let (mut ws_a, mut ws_b) = (QpWorkspace::new(n), QpWorkspace::new(n));
    let (mut xa, mut xb) = (vec![0.0; n], vec![0.0; n]);
    let mut prev_c = 1.0;
    for t in 0..200 {
        let c = 1.0 + 0.5 * (0.1 * t as f64).sin();
        let h: Vec<f64> = h0.iter().map(|v| c * v).collect();
        for v in g.iter_mut() {
            *v += rng.random_range(-0.3..0.3);
        }
        let reuse = if t == 0 { None } else { Some(c / prev_c) };
        prev_c = c;
        let oa = solve_box_qp_reuse(&h, &g, &lo, &hi, &mut xa, &QpOptions::default(), &mut ws_a, reuse);
        let ob = solve_box_qp(&h, &g, &lo, &hi, &mut xb, &QpOptions::default(), &mut ws_b);
        assert!(oa.converged && ob.converged, "t {t}: {oa:?} {ob:?}");
        for (a, b) in xa.iter().zip(&xb) {
            assert!((a - b).abs() < 1e-8, "t {t}: {a} vs {b}");
        }
    }
}
