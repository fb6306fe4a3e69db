//! The multilinear (Tucker) face model: HOSVD of the data tensor, the generative
//! function, and the model file.
//!
//! # Maths (Vlasic et al. 2005; Papanek 2010, ch. 3; De Lathauwer et al. 2000)
//!
//! With `D` the `(3V, I, E)` data tensor ([`crate::tensor`]), **centring** subtracts the
//! mean face `m = 1/(I E) sum_{i,e} D[:, i, e]`: `Dc = D - m`. The HOSVD keeps the
//! point mode and decomposes the identity and expression modes through their Gram
//! matrices, as in the thesis:
//!
//! * `G_id = Dc(2) Dc(2)^T` (`I x I`), `G_id = U_id diag(s_id^2) U_id^T`,
//! * `G_exp = Dc(3) Dc(3)^T` (`E x E`), `G_exp = U_exp diag(s_exp^2) U_exp^T`,
//! * core `M(1) = Dc(1) (U_id kron U_exp)`, i.e. `M = Dc x2 U_id^T x3 U_exp^T`
//!   (computed as two mode products, which costs `3V I E (I + E)` instead of the
//!   `3V (I E)^2` of the explicit Kronecker product; same numbers).
//!
//! The singular values `s` are sorted in decreasing order; each singular vector's sign is
//! fixed so that its largest-magnitude entry is positive. **Truncation** keeps the
//! leading `r` modes whose squared singular values reach a fraction `energy` of the total.
//!
//! **Generative function** (thesis convention): with *database* weights
//! `w_id in R^I` and `w_exp in R^E`,
//!
//! `f(w_id, w_exp) = m + M(1) (U_id^T w_id kron U_exp^T w_exp)`,
//!
//! so the unit vectors `w_id = e_i`, `w_exp = e_e` give back database face `(i, e)`
//! exactly when nothing is truncated. `alpha = U_id^T w_id` (`r_id`) and
//! `beta = U_exp^T w_exp` (`r_exp`) are the *mode* coordinates.
//!
//! Memory layout: `core` is `(3V, r_id, r_exp)` row-major, `u_id` is `(I, r_id)`,
//! `u_exp` is `(E, r_exp)`. Units are those of the database meshes.
//!
//! # Model file (version 1, little-endian)
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `FCTENSOR` |
//! | 4 | `u32` version = 1 |
//! | 4 | `u32` scalar size: 4 (`f32`) or 8 (`f64`) |
//! | 24 | `u32` V, I, E, r_id, r_exp, number of triangles |
//! | ... | I + E names: `u32` byte length + UTF-8 (identities, then expressions) |
//! | ... | scalars: s_id (I), s_exp (E), m (3V), U_id (I r_id), U_exp (E r_exp), core (3V r_id r_exp) |
//! | ... | triangles: 3 `u32` each |
//!
//! Nothing may follow. Every read is bounds-checked; truncated, oversized, non-finite
//! or out-of-range content is rejected with the byte offset.

use std::path::Path;

use nalgebra::{DMatrix, SymmetricEigen};
use ndarray::linalg::general_mat_mul;
use ndarray::{Array1, Array2, Array3, ArrayView2, Axis};

use crate::error::{Error, Result};
use crate::tensor::DataTensor;

/// Magic bytes at the start of a model file.
pub const MAGIC: &[u8; 8] = b"FCTENSOR";
/// The model file version this crate writes and reads.
pub const FILE_VERSION: u32 = 1;
const WHAT: &str = "tensor model";

/// Parameters of [`TensorModel::build`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `energy_id` | 1.0 | fraction of identity-mode energy kept (1 = no truncation) | (0, 1] |
/// | `energy_exp` | 1.0 | fraction of expression-mode energy kept | (0, 1] |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HosvdParams {
    /// Fraction of `sum s_id^2` kept.
    pub energy_id: f64,
    /// Fraction of `sum s_exp^2` kept.
    pub energy_exp: f64,
}

impl Default for HosvdParams {
    fn default() -> Self {
        HosvdParams {
            energy_id: 1.0,
            energy_exp: 1.0,
        }
    }
}

impl HosvdParams {
    /// Checks both energies are finite and in `(0, 1]`.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("energy_id", self.energy_id), ("energy_exp", self.energy_exp)] {
            if !(v.is_finite() && v > 0.0 && v <= 1.0) {
                return Err(Error::invalid(name, v, "a number in (0, 1]"));
            }
        }
        Ok(())
    }
}

/// What [`TensorModel::build`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct HosvdReport {
    /// Kept identity modes.
    pub rank_id: usize,
    /// Kept expression modes.
    pub rank_exp: usize,
    /// Fraction of identity energy kept.
    pub energy_id: f64,
    /// Fraction of expression energy kept.
    pub energy_exp: f64,
}

/// A built tensor model (see module docs for the maths and layout).
#[derive(Debug, Clone, PartialEq)]
pub struct TensorModel {
    /// Identity names (database order).
    pub identities: Vec<String>,
    /// Expression names (database order).
    pub expressions: Vec<String>,
    /// Mean face `m`, length `3V`.
    pub mean: Array1<f64>,
    /// Identity mode matrix `(I, r_id)`, orthonormal columns.
    pub u_id: Array2<f64>,
    /// Expression mode matrix `(E, r_exp)`, orthonormal columns.
    pub u_exp: Array2<f64>,
    /// All `I` identity singular values, decreasing.
    pub sigma_id: Vec<f64>,
    /// All `E` expression singular values, decreasing.
    pub sigma_exp: Vec<f64>,
    /// Core tensor `(3V, r_id, r_exp)`.
    pub core: Array3<f64>,
    /// Triangles of the topology (may be empty).
    pub triangles: Vec<[u32; 3]>,
}

/// Eigen-decomposition of a symmetric Gram matrix: (singular values decreasing,
/// singular vectors as columns with the sign convention of the module docs).
pub fn gram_eigh(g: ArrayView2<f64>) -> Result<(Vec<f64>, Array2<f64>)> {
    let n = g.nrows();
    let m = DMatrix::from_fn(n, n, |r, c| 0.5 * (g[[r, c]] + g[[c, r]]));
    if m.iter().any(|x| !x.is_finite()) {
        return Err(Error::Numerical {
            operation: "gram_eigh",
            reason: "Gram matrix has non-finite entries".into(),
        });
    }
    let eig = SymmetricEigen::new(m);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut u = Array2::<f64>::zeros((n, n));
    let mut s = Vec::with_capacity(n);
    for (k, &j) in order.iter().enumerate() {
        s.push(eig.eigenvalues[j].max(0.0).sqrt());
        let col = eig.eigenvectors.column(j);
        let mut big = 0usize;
        for r in 0..n {
            if col[r].abs() > col[big].abs() {
                big = r;
            }
        }
        let sign = if col[big] < 0.0 { -1.0 } else { 1.0 };
        for r in 0..n {
            u[[r, k]] = sign * col[r];
        }
    }
    Ok((s, u))
}

/// Smallest rank whose leading squared singular values reach `energy` of the total.
pub fn rank_for_energy(sigma: &[f64], energy: f64) -> (usize, f64) {
    let total: f64 = sigma.iter().map(|s| s * s).sum();
    if total <= 0.0 || energy >= 1.0 {
        return (sigma.len(), 1.0);
    }
    let mut acc = 0.0;
    for (k, s) in sigma.iter().enumerate() {
        acc += s * s;
        if acc >= energy * total {
            return (k + 1, acc / total);
        }
    }
    (sigma.len(), 1.0)
}

impl TensorModel {
    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.mean.len() / 3
    }
    /// Number of database identities `I` (length of `w_id`).
    pub fn num_identities(&self) -> usize {
        self.u_id.nrows()
    }
    /// Number of database expressions `E` (length of `w_exp`).
    pub fn num_expressions(&self) -> usize {
        self.u_exp.nrows()
    }
    /// Kept identity modes `r_id`.
    pub fn rank_id(&self) -> usize {
        self.u_id.ncols()
    }
    /// Kept expression modes `r_exp`.
    pub fn rank_exp(&self) -> usize {
        self.u_exp.ncols()
    }

    /// Centres the tensor and runs the Gram-matrix HOSVD (module docs).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for bad `params`; [`Error::Numerical`] if the data is not finite.
    pub fn build(data: &DataTensor, params: &HosvdParams) -> Result<(TensorModel, HosvdReport)> {
        params.validate()?;
        let (p3, ni, ne) = data.data.dim();
        // Centring.
        let mean = data
            .data
            .view()
            .into_shape_with_order((p3, ni * ne))
            .map_err(|e| Error::Numerical {
                operation: "hosvd",
                reason: e.to_string(),
            })?
            .mean_axis(Axis(1))
            .ok_or_else(|| Error::Numerical {
                operation: "hosvd",
                reason: "empty tensor".into(),
            })?;
        // Unfoldings as row-major copies: D2 = (I, 3V*E) [i][p][e], D3 = (E, 3V*I) [e][p][i].
        let mut d2 = Array3::<f64>::zeros((ni, p3, ne));
        let mut d3 = Array3::<f64>::zeros((ne, p3, ni));
        for p in 0..p3 {
            let mp = mean[p];
            for i in 0..ni {
                for e in 0..ne {
                    let x = data.data[[p, i, e]] - mp;
                    d2[[i, p, e]] = x;
                    d3[[e, p, i]] = x;
                }
            }
        }
        let d2 = d2.into_shape_with_order((ni, p3 * ne)).map_err(num_err)?;
        let d3 = d3.into_shape_with_order((ne, p3 * ni)).map_err(num_err)?;
        let mut g_id = Array2::<f64>::zeros((ni, ni));
        general_mat_mul(1.0, &d2, &d2.t(), 0.0, &mut g_id);
        drop(d2);
        let mut g_exp = Array2::<f64>::zeros((ne, ne));
        general_mat_mul(1.0, &d3, &d3.t(), 0.0, &mut g_exp);
        let (sigma_id, u_id_full) = gram_eigh(g_id.view())?;
        let (sigma_exp, u_exp_full) = gram_eigh(g_exp.view())?;
        let (r_id, en_id) = rank_for_energy(&sigma_id, params.energy_id);
        let (r_exp, en_exp) = rank_for_energy(&sigma_exp, params.energy_exp);
        let u_id = u_id_full.slice(ndarray::s![.., ..r_id]).to_owned();
        let u_exp = u_exp_full.slice(ndarray::s![.., ..r_exp]).to_owned();
        // Core: Y = U_exp^T D3 (r_exp, 3V*I) -> (r_exp*3V, I); Z = Y U_id (r_exp*3V, r_id).
        let mut y = Array2::<f64>::zeros((r_exp, p3 * ni));
        general_mat_mul(1.0, &u_exp.t(), &d3, 0.0, &mut y);
        drop(d3);
        let y = y.into_shape_with_order((r_exp * p3, ni)).map_err(num_err)?;
        let mut z = Array2::<f64>::zeros((r_exp * p3, r_id));
        general_mat_mul(1.0, &y, &u_id, 0.0, &mut z);
        let z = z.into_shape_with_order((r_exp, p3, r_id)).map_err(num_err)?;
        let core = z.permuted_axes([1, 2, 0]).as_standard_layout().into_owned();
        let model = TensorModel {
            identities: data.identities.clone(),
            expressions: data.expressions.clone(),
            mean,
            u_id,
            u_exp,
            sigma_id,
            sigma_exp,
            core,
            triangles: data.triangles.clone(),
        };
        Ok((
            model,
            HosvdReport {
                rank_id: r_id,
                rank_exp: r_exp,
                energy_id: en_id,
                energy_exp: en_exp,
            },
        ))
    }

    /// Mode coordinates `alpha = U_id^T w_id` written into `alpha` (length `r_id`).
    pub fn id_modes_into(&self, w_id: &[f64], alpha: &mut [f64]) {
        project_weights(&self.u_id, w_id, alpha);
    }

    /// Mode coordinates `beta = U_exp^T w_exp` written into `beta` (length `r_exp`).
    pub fn exp_modes_into(&self, w_exp: &[f64], beta: &mut [f64]) {
        project_weights(&self.u_exp, w_exp, beta);
    }

    /// Evaluates `m + M x2 alpha x3 beta` for mode coordinates into `out` (`3V`).
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when a length is wrong.
    pub fn generate_modes_into(&self, alpha: &[f64], beta: &[f64], out: &mut [f64]) -> Result<()> {
        let (p3, r_id, r_exp) = self.core.dim();
        check_len("alpha", r_id, alpha.len())?;
        check_len("beta", r_exp, beta.len())?;
        check_len("output", p3, out.len())?;
        let core = self.core.as_slice().ok_or_else(|| Error::Numerical {
            operation: "generate",
            reason: "core not contiguous".into(),
        })?;
        for (p, o) in out.iter_mut().enumerate() {
            let block = &core[p * r_id * r_exp..(p + 1) * r_id * r_exp];
            let mut acc = 0.0;
            for (a, row) in block.chunks_exact(r_exp).enumerate() {
                let mut t = 0.0;
                for (c, b) in row.iter().zip(beta) {
                    t += c * b;
                }
                acc += alpha[a] * t;
            }
            *o = self.mean[p] + acc;
        }
        Ok(())
    }

    /// The generative function `f(w_id, w_exp)` (database weights, module docs) as `3V` values.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] for wrong weight lengths; [`Error::InvalidParameter`] for non-finite weights.
    pub fn generate(&self, w_id: &[f64], w_exp: &[f64]) -> Result<Vec<f64>> {
        check_len("identity weights", self.num_identities(), w_id.len())?;
        check_len("expression weights", self.num_expressions(), w_exp.len())?;
        if let Some(x) = w_id.iter().chain(w_exp).find(|x| !x.is_finite()) {
            return Err(Error::invalid("weight", x, "finite"));
        }
        let mut alpha = vec![0.0; self.rank_id()];
        let mut beta = vec![0.0; self.rank_exp()];
        self.id_modes_into(w_id, &mut alpha);
        self.exp_modes_into(w_exp, &mut beta);
        let mut out = vec![0.0; self.mean.len()];
        self.generate_modes_into(&alpha, &beta, &mut out)?;
        Ok(out)
    }

    /// [`Self::generate`] as points (f32, for mesh output).
    ///
    /// # Errors
    /// As [`Self::generate`].
    pub fn generate_points(&self, w_id: &[f64], w_exp: &[f64]) -> Result<Vec<nalgebra::Point3<f32>>> {
        let f = self.generate(w_id, w_exp)?;
        Ok(f.chunks_exact(3)
            .map(|c| nalgebra::Point3::new(c[0] as f32, c[1] as f32, c[2] as f32))
            .collect())
    }

    /// The model as a blendshape rig for a fixed identity: `f(w_id, w_exp)` is linear
    /// in `w_exp`, `f = m + sum_e w_exp[e] B_e(w_id)` with
    /// `B_e = M x2 (U_id^T w_id) x3 (U_exp^T unit_e)`, so the rig's base mesh is the mean
    /// face `m` and target `e` (named after database expression `e`) has deltas `B_e`.
    /// Posing it with weights `w_exp` reproduces `f(w_id, w_exp)` exactly.
    ///
    /// # Errors
    /// As [`Self::generate`].
    pub fn expression_rig(&self, w_id: &[f64]) -> Result<facecap_core::mesh::MorphMesh> {
        use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
        check_len("identity weights", self.num_identities(), w_id.len())?;
        let mut alpha = vec![0.0; self.rank_id()];
        self.id_modes_into(w_id, &mut alpha);
        let zero = vec![0.0; self.num_expressions()];
        let base = self.generate(w_id, &zero)?;
        let to_pts = |f: &[f64]| -> Vec<nalgebra::Point3<f32>> {
            f.chunks_exact(3)
                .map(|c| nalgebra::Point3::new(c[0] as f32, c[1] as f32, c[2] as f32))
                .collect()
        };
        let mut targets = Vec::with_capacity(self.num_expressions());
        let mut beta = vec![0.0; self.rank_exp()];
        let mut out = vec![0.0; self.mean.len()];
        for (e, name) in self.expressions.iter().enumerate() {
            let mut unit = zero.clone();
            unit[e] = 1.0;
            self.exp_modes_into(&unit, &mut beta);
            self.generate_modes_into(&alpha, &beta, &mut out)?;
            let deltas = out
                .chunks_exact(3)
                .zip(base.chunks_exact(3))
                .map(|(a, b)| nalgebra::Vector3::new((a[0] - b[0]) as f32, (a[1] - b[1]) as f32, (a[2] - b[2]) as f32))
                .collect();
            targets.push(MorphTarget {
                name: name.clone(),
                deltas,
            });
        }
        Ok(MorphMesh {
            base: Mesh {
                positions: to_pts(&base),
                triangles: self.triangles.clone(),
                ..Default::default()
            },
            targets,
        })
    }

    /// Serialises to the version-1 model format (module docs) with `f64` or `f32` scalars.
    pub fn to_bytes(&self, f32_scalars: bool) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(MAGIC);
        let put_u32 = |b: &mut Vec<u8>, v: u32| b.extend_from_slice(&v.to_le_bytes());
        put_u32(&mut b, FILE_VERSION);
        put_u32(&mut b, if f32_scalars { 4 } else { 8 });
        for v in [
            self.num_vertices(),
            self.num_identities(),
            self.num_expressions(),
            self.rank_id(),
            self.rank_exp(),
            self.triangles.len(),
        ] {
            put_u32(&mut b, v as u32);
        }
        for n in self.identities.iter().chain(&self.expressions) {
            put_u32(&mut b, n.len() as u32);
            b.extend_from_slice(n.as_bytes());
        }
        let mut put = |x: f64| {
            if f32_scalars {
                b.extend_from_slice(&(x as f32).to_le_bytes());
            } else {
                b.extend_from_slice(&x.to_le_bytes());
            }
        };
        self.sigma_id.iter().for_each(|&x| put(x));
        self.sigma_exp.iter().for_each(|&x| put(x));
        self.mean.iter().for_each(|&x| put(x));
        self.u_id.iter().for_each(|&x| put(x));
        self.u_exp.iter().for_each(|&x| put(x));
        self.core.iter().for_each(|&x| put(x));
        for t in &self.triangles {
            for &v in t {
                put_u32(&mut b, v);
            }
        }
        b
    }

    /// Writes the model file (atomically).
    ///
    /// # Errors
    /// [`Error::Io`] on write failure.
    pub fn save(&self, path: &Path, f32_scalars: bool) -> Result<()> {
        let bytes = self.to_bytes(f32_scalars);
        Ok(facecap_core::atomic::write_atomic(path, |w| {
            std::io::Write::write_all(w, &bytes)
        })?)
    }

    /// Reads a model file.
    ///
    /// # Errors
    /// [`Error::Io`] if unreadable, [`Error::Format`] (with byte offset) if malformed.
    pub fn load(path: &Path) -> Result<TensorModel> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes).map_err(|e| match e {
            Error::Format { what, reason, .. } => Error::Format {
                what,
                path: path.to_path_buf(),
                reason,
            },
            other => other,
        })
    }

    /// Parses the version-1 model format.
    ///
    /// # Errors
    /// [`Error::Format`] naming what is wrong and where.
    pub fn from_bytes(bytes: &[u8]) -> Result<TensorModel> {
        let mut r = Reader { b: bytes, pos: 0 };
        let magic = r.take(8, "magic")?;
        if magic != MAGIC {
            return Err(fmt_err(0, "not a facecap tensor model (bad magic)"));
        }
        let version = r.u32("version")?;
        if version != FILE_VERSION {
            return Err(fmt_err(
                8,
                format!("unsupported version {version} (this build reads {FILE_VERSION})"),
            ));
        }
        let scalar = r.u32("scalar size")? as usize;
        if scalar != 4 && scalar != 8 {
            return Err(fmt_err(12, format!("scalar size {scalar}, expected 4 or 8")));
        }
        let nv = r.u32("V")? as usize;
        let ni = r.u32("I")? as usize;
        let ne = r.u32("E")? as usize;
        let r_id = r.u32("r_id")? as usize;
        let r_exp = r.u32("r_exp")? as usize;
        let ntri = r.u32("triangle count")? as usize;
        if nv == 0 || ni == 0 || ne == 0 || r_id == 0 || r_exp == 0 || r_id > ni || r_exp > ne {
            return Err(fmt_err(
                16,
                format!("bad dimensions V={nv} I={ni} E={ne} r_id={r_id} r_exp={r_exp}"),
            ));
        }
        // Every name takes at least its 4-byte length: check the counts against the bytes
        // present before reserving anything (a count of 0xFFFFFFFF must not reserve 100 GB).
        let remaining = r.b.len() - r.pos;
        if (ni + ne).checked_mul(4).map_or(true, |b| b > remaining) {
            return Err(fmt_err(
                r.pos,
                format!(
                    "{} names (I={ni} + E={ne}) cannot fit in the {remaining} bytes left",
                    ni + ne
                ),
            ));
        }
        let mut names = Vec::with_capacity(ni + ne);
        for k in 0..ni + ne {
            let len = r.u32("name length")? as usize;
            let at = r.pos;
            let s = r.take(len, "name")?;
            let s = std::str::from_utf8(s).map_err(|_| fmt_err(at, format!("name {k} is not UTF-8")))?;
            names.push(s.to_string());
        }
        let expressions = names.split_off(ni);
        let identities = names;
        // Size check before allocating anything large.
        let count = [ni, ne, 3 * nv, ni * r_id, ne * r_exp]
            .iter()
            .try_fold(0usize, |a, &x| a.checked_add(x))
            .and_then(|a| (3 * nv).checked_mul(r_id)?.checked_mul(r_exp)?.checked_add(a));
        let need = count
            .and_then(|c| c.checked_mul(scalar))
            .and_then(|c| ntri.checked_mul(12)?.checked_add(c));
        match need {
            Some(n) if n == r.b.len() - r.pos => {}
            Some(n) => {
                return Err(fmt_err(
                    r.pos,
                    format!(
                        "expected {n} bytes of data after the header, found {}",
                        r.b.len() - r.pos
                    ),
                ))
            }
            None => return Err(fmt_err(r.pos, "dimensions overflow")),
        }
        let mut read_vec = |n: usize, what: &'static str| -> Result<Vec<f64>> {
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                let at = r.pos;
                let x = if scalar == 4 {
                    f32::from_le_bytes(r.arr::<4>(what)?) as f64
                } else {
                    f64::from_le_bytes(r.arr::<8>(what)?)
                };
                if !x.is_finite() {
                    return Err(fmt_err(at, format!("non-finite value in {what}")));
                }
                v.push(x);
            }
            Ok(v)
        };
        let sigma_id = read_vec(ni, "s_id")?;
        let sigma_exp = read_vec(ne, "s_exp")?;
        let mean = Array1::from(read_vec(3 * nv, "mean")?);
        let u_id = Array2::from_shape_vec((ni, r_id), read_vec(ni * r_id, "U_id")?).map_err(num_err)?;
        let u_exp = Array2::from_shape_vec((ne, r_exp), read_vec(ne * r_exp, "U_exp")?).map_err(num_err)?;
        let core =
            Array3::from_shape_vec((3 * nv, r_id, r_exp), read_vec(3 * nv * r_id * r_exp, "core")?).map_err(num_err)?;
        let mut triangles = Vec::with_capacity(ntri);
        for _ in 0..ntri {
            let at = r.pos;
            let t = [r.u32("triangle")?, r.u32("triangle")?, r.u32("triangle")?];
            if t.iter().any(|&v| v as usize >= nv) {
                return Err(fmt_err(at, format!("triangle {t:?} out of range for {nv} vertices")));
            }
            triangles.push(t);
        }
        Ok(TensorModel {
            identities,
            expressions,
            mean,
            u_id,
            u_exp,
            sigma_id,
            sigma_exp,
            core,
            triangles,
        })
    }
}

fn project_weights(u: &Array2<f64>, w: &[f64], out: &mut [f64]) {
    for (k, o) in out.iter_mut().enumerate() {
        let mut acc = 0.0;
        for (r, wr) in w.iter().enumerate() {
            acc += u[[r, k]] * wr;
        }
        *o = acc;
    }
}

fn check_len(what: &str, expected: usize, got: usize) -> Result<()> {
    if expected != got {
        return Err(Error::dim(what, expected, got));
    }
    Ok(())
}

fn num_err(e: ndarray::ShapeError) -> Error {
    Error::Numerical {
        operation: "tensor reshape",
        reason: e.to_string(),
    }
}

fn fmt_err(offset: usize, reason: impl Into<String>) -> Error {
    Error::Format {
        what: WHAT,
        path: Default::default(),
        reason: format!("at byte {offset}: {}", reason.into()),
    }
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.b.len()).ok_or_else(|| {
            fmt_err(
                self.pos,
                format!(
                    "truncated while reading {what} ({n} bytes needed, {} left)",
                    self.b.len() - self.pos
                ),
            )
        })?;
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.arr::<4>(what)?))
    }
}
