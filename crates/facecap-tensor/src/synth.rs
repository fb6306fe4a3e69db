//! Seeded synthetic databases for tests, benchmarks, examples and the evidence in
//! `docs/tensor.md` (no data files needed).
//!
//! A face-like point cloud (the front of an ellipsoid, about 16 x 22 x 10 model units,
//! like a head in cm) gets smooth random identity and expression displacement fields.
//! [`database`] adds an identity x expression interaction term (so the tensor is a
//! genuine multilinear one), [`separable_database`] does not (`D = base + id_i + exp_e`).

use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::tensor::{standard_normal, DataTensor};

/// Number of smooth basis functions per random displacement field.
const FIELD_TERMS: usize = 6;

/// The neutral face-like point cloud of `nv` vertices.
pub fn base_face(nv: usize) -> Vec<Point3<f64>> {
    // Golden-angle spiral over the front half of an ellipsoid.
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..nv)
        .map(|k| {
            let zz = 1.0 - (k as f64 + 0.5) / nv as f64; // 1 .. 0: front hemisphere
            let r = (1.0 - zz * zz).sqrt();
            let th = golden * k as f64;
            Point3::new(8.0 * r * th.cos(), 11.0 * r * th.sin(), 5.0 * zz)
        })
        .collect()
}

/// A smooth random displacement field over `pts` with amplitude `amp`.
fn field(rng: &mut ChaCha8Rng, pts: &[Point3<f64>], amp: f64) -> Vec<nalgebra::Vector3<f64>> {
    let terms: Vec<([f64; 3], [f64; 3], [f64; 3])> = (0..FIELD_TERMS)
        .map(|_| {
            let f = [
                rng.random_range(0.05..0.4),
                rng.random_range(0.05..0.4),
                rng.random_range(0.05..0.4),
            ];
            let ph = [
                rng.random_range(0.0..6.3),
                rng.random_range(0.0..6.3),
                rng.random_range(0.0..6.3),
            ];
            let a = [standard_normal(rng), standard_normal(rng), standard_normal(rng)];
            (f, ph, a)
        })
        .collect();
    let norm = amp / (FIELD_TERMS as f64).sqrt();
    pts.iter()
        .map(|p| {
            let mut d = nalgebra::Vector3::zeros();
            for (f, ph, a) in &terms {
                let s = (f[0] * p.x + ph[0]).sin() * (f[1] * p.y + ph[1]).cos() * (f[2] * p.z + ph[2]).cos();
                d += nalgebra::Vector3::new(a[0], a[1], a[2]) * (s * norm);
            }
            d
        })
        .collect()
}

/// A non-separable database: `base + id_i + exp_e + coupling * (id_i . exp_e pattern)`.
///
/// # Errors
/// As [`DataTensor::from_cells`] (fewer than 2 identities or expressions).
pub fn database(nv: usize, ni: usize, ne: usize, seed: u64) -> Result<DataTensor> {
    build(nv, ni, ne, seed, 0.6)
}

/// A separable database `base + id_i + exp_e`.
///
/// # Errors
/// As [`DataTensor::from_cells`].
pub fn separable_database(nv: usize, ni: usize, ne: usize, seed: u64) -> Result<DataTensor> {
    build(nv, ni, ne, seed, 0.0)
}

fn build(nv: usize, ni: usize, ne: usize, seed: u64, coupling: f64) -> Result<DataTensor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let base = base_face(nv);
    let ids: Vec<_> = (0..ni).map(|_| field(&mut rng, &base, 1.0)).collect();
    let exps: Vec<_> = (0..ne)
        .map(|e| field(&mut rng, &base, if e == 0 { 0.0 } else { 0.8 }))
        .collect();
    // Interaction: each identity scales each expression's displacement differently, per axis.
    let gains: Vec<[f64; 3]> = (0..ni * ne)
        .map(|_| {
            [
                standard_normal(&mut rng),
                standard_normal(&mut rng),
                standard_normal(&mut rng),
            ]
        })
        .collect();
    let names = |p: &str, n: usize| (0..n).map(|k| format!("{p}{k:03}")).collect::<Vec<_>>();
    let mut exp_names = names("exp", ne);
    exp_names[0] = crate::tensor::NEUTRAL.to_string();
    DataTensor::from_cells(names("id", ni), exp_names, nv, Vec::new(), |i, e| {
        Ok(base
            .iter()
            .enumerate()
            .map(|(v, b)| {
                let d = exps[e][v];
                let g = gains[i * ne + e];
                let inter = nalgebra::Vector3::new(d.x * g[0], d.y * g[1], d.z * g[2]) * coupling;
                b + ids[i][v] + d + inter
            })
            .collect())
    })
}
