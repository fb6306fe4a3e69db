//! HOSVD linear algebra at the thesis size (56 identities x 7 expressions x 5090
//! vertices, 3V = 15270): Gram products D(2)D(2)^T and D(3)D(3)^T, eigen-decomposition
//! of the 56x56 and 7x7 Gram matrices, and the two core mode products, with
//! (a) ndarray `general_mat_mul` (matrixmultiply) + nalgebra `SymmetricEigen` (what
//! facecap-tensor uses) and (b) faer (one thread). Also a thin SVD of the 56 x 106890
//! unfolding with faer (the direct route the Gram trick avoids). Median of 7 runs.

use std::time::Instant;

use ndarray::linalg::general_mat_mul;
use ndarray::Array2;
use rand::{Rng, SeedableRng};

const P3: usize = 15270;
const NI: usize = 56;
const NE: usize = 7;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn time<F: FnMut() -> f64>(mut f: F) -> (f64, f64) {
    let mut t = Vec::new();
    let mut chk = 0.0;
    for _ in 0..7 {
        let t0 = Instant::now();
        chk = f();
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    (median(t), chk)
}

fn main() {
    faer::set_global_parallelism(faer::Par::Seq);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // Unfoldings, row-major: D2 (I, 3V*E), D3 (E, 3V*I).
    let d2 = Array2::from_shape_fn((NI, P3 * NE), |_| rng.random_range(-1.0..1.0));
    let d3 = Array2::from_shape_fn((NE, P3 * NI), |(e, c)| d2[[c % NI, (c / NI) * NE + e]]);
    let u_exp = Array2::from_shape_fn((NE, NE), |(i, j)| if i == j { 1.0 } else { 0.01 });
    let u_id = Array2::from_shape_fn((NI, NI), |(i, j)| if i == j { 1.0 } else { 0.01 });
    let f2 = faer::Mat::<f64>::from_fn(NI, P3 * NE, |i, j| d2[[i, j]]);
    let f3 = faer::Mat::<f64>::from_fn(NE, P3 * NI, |i, j| d3[[i, j]]);
    let fu_exp = faer::Mat::<f64>::from_fn(NE, NE, |i, j| u_exp[[i, j]]);
    let fu_id = faer::Mat::<f64>::from_fn(NI, NI, |i, j| u_id[[i, j]]);

    let (t, c) = time(|| {
        let mut g = Array2::<f64>::zeros((NI, NI));
        general_mat_mul(1.0, &d2, &d2.t(), 0.0, &mut g);
        let mut h = Array2::<f64>::zeros((NE, NE));
        general_mat_mul(1.0, &d3, &d3.t(), 0.0, &mut h);
        g[[3, 4]] + h[[1, 2]]
    });
    println!("gram products      ndarray/matrixmultiply {t:8.2} ms  (check {c:.6})");
    let (t, c) = time(|| {
        let g = &f2 * f2.transpose();
        let h = &f3 * f3.transpose();
        g[(3, 4)] + h[(1, 2)]
    });
    println!("gram products      faer                   {t:8.2} ms  (check {c:.6})");

    let mut g = Array2::<f64>::zeros((NI, NI));
    general_mat_mul(1.0, &d2, &d2.t(), 0.0, &mut g);
    let (t, c) = time(|| {
        let m = nalgebra::DMatrix::from_fn(NI, NI, |r, c| g[[r, c]]);
        let e = nalgebra::SymmetricEigen::new(m);
        e.eigenvalues.max()
    });
    println!("eigh 56x56         nalgebra               {t:8.3} ms  (max eig {c:.3})");
    let fg = faer::Mat::<f64>::from_fn(NI, NI, |i, j| g[[i, j]]);
    let (t, c) = time(|| {
        let e = fg.self_adjoint_eigen(faer::Side::Lower).expect("evd");
        let s = e.S();
        s.column_vector()[NI - 1]
    });
    println!("eigh 56x56         faer                   {t:8.3} ms  (max eig {c:.3})");

    let (t, c) = time(|| {
        let mut y = Array2::<f64>::zeros((NE, P3 * NI));
        general_mat_mul(1.0, &u_exp.t(), &d3, 0.0, &mut y);
        let y = y.into_shape_with_order((NE * P3, NI)).expect("shape");
        let mut z = Array2::<f64>::zeros((NE * P3, NI));
        general_mat_mul(1.0, &y, &u_id, 0.0, &mut z);
        z[[5, 6]]
    });
    println!("core mode products ndarray/matrixmultiply {t:8.2} ms  (check {c:.6})");
    let (t, c) = time(|| {
        let y = fu_exp.transpose() * &f3;
        // (E, 3V*I) row-major -> (E*3V, I): faer is column-major, so rebuild the view.
        let yr = faer::Mat::<f64>::from_fn(NE * P3, NI, |r, i| y[(r / P3, (r % P3) * NI + i)]);
        let z = &yr * &fu_id;
        z[(5, 6)]
    });
    println!("core mode products faer (+ relayout)      {t:8.2} ms  (check {c:.6})");
    let (t, c) = time(|| {
        let s = f2.thin_svd().expect("svd");
        s.S().column_vector()[0]
    });
    println!("thin SVD 56x106890 faer (direct route)    {t:8.2} ms  (max sv {c:.3})");
}
