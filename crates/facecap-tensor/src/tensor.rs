//! The data tensor `D` of a corresponded face database.
//!
//! `D` has three modes: **points** (`3V` rows: vertex `v` coordinate `c` at row
//! `3v + c`), **identities** (`I`) and **expressions** (`E`). It is stored as an
//! `ndarray::Array3<f64>` of shape `(3V, I, E)` in standard (row-major) layout, so
//! the mode-1 unfolding `D(1)` (`3V x I*E`, column `i*E + e`) is a free reshape.
//!
//! Sources:
//! * [`DataTensor::from_mesh_folder`]: a folder of OBJ meshes named
//!   `<identity>_<expression>.obj`. The identity is the text **before the first
//!   underscore**, the expression everything after it (so expression names may contain
//!   underscores, identity names may not): `anna_jawOpen.obj`, `anna_mouthSmile_L.obj`.
//!   Every identity must have every expression (a full grid) and every mesh the same
//!   vertex count; the triangles of the first mesh are kept for output.
//! * [`DataTensor::from_rigs`]: an identity rig (morph targets = identity modes, e.g.
//!   `ict_face_identity100.glb`, `sfm_shape63.glb`) and an expression rig on the same
//!   topology (`ict_face_arkit53.glb`, `sfm_expressions6.glb`). Identity `i` is
//!   `base + sum_k w_ik * id_delta_k` with `w_ik ~ N(0, sigma^2)` drawn from a seeded
//!   ChaCha8 generator (the ICT identity deltas are pre-scaled so that `N(0, 1)` is
//!   their prior); expression `e` adds `exp_delta_e` ("neutral" adds nothing).
//!   Because every identity receives the same expression deltas, such a tensor is
//!   separable (see `docs/tensor.md`): a plumbing and scale test, not a real
//!   multilinear database.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use facecap_core::mesh::MorphMesh;
use nalgebra::Point3;
use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{Error, Result};

/// Name given to the unmodified expression (no expression delta) in rig sampling.
pub const NEUTRAL: &str = "neutral";

/// A corresponded database as a 3-mode tensor (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DataTensor {
    /// Identity names (mode 2), in tensor order.
    pub identities: Vec<String>,
    /// Expression names (mode 3), in tensor order.
    pub expressions: Vec<String>,
    /// Shape `(3V, I, E)`, model units (those of the source meshes).
    pub data: Array3<f64>,
    /// Triangles of the shared topology (for writing meshes), may be empty.
    pub triangles: Vec<[u32; 3]>,
}

/// How identities are sampled from an identity rig in [`DataTensor::from_rigs`].
#[derive(Debug, Clone, PartialEq)]
pub struct RigSampling {
    /// Number of identities to draw (>= 2).
    pub identities: usize,
    /// Seed of the ChaCha8 generator.
    pub seed: u64,
    /// Standard deviation of the identity-mode weights (> 0; 1 = the ICT prior).
    pub sigma: f64,
    /// Expression targets to use, by name; `None` = all targets of the expression rig.
    pub expressions: Option<Vec<String>>,
    /// Whether to add the unmodified face as expression [`NEUTRAL`] (first).
    pub include_neutral: bool,
}

impl Default for RigSampling {
    fn default() -> Self {
        RigSampling {
            identities: 56,
            seed: 0,
            sigma: 1.0,
            expressions: None,
            include_neutral: true,
        }
    }
}

/// One standard normal draw (Box-Muller; `rand` 0.9 has no normal distribution).
pub(crate) fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

impl DataTensor {
    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.data.shape()[0] / 3
    }

    /// Number of identities `I`.
    pub fn num_identities(&self) -> usize {
        self.data.shape()[1]
    }

    /// Number of expressions `E`.
    pub fn num_expressions(&self) -> usize {
        self.data.shape()[2]
    }

    /// Builds the tensor cell by cell: `cell(i, e)` returns the mesh of identity `i`
    /// with expression `e` (exactly `num_vertices` points).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for fewer than 2 identities or expressions, or a
    /// non-finite coordinate; [`Error::DimensionMismatch`] naming the cell whose vertex
    /// count differs; whatever `cell` returns.
    pub fn from_cells(
        identities: Vec<String>,
        expressions: Vec<String>,
        num_vertices: usize,
        triangles: Vec<[u32; 3]>,
        mut cell: impl FnMut(usize, usize) -> Result<Vec<Point3<f64>>>,
    ) -> Result<Self> {
        if identities.len() < 2 {
            return Err(Error::invalid("number of identities", identities.len(), ">= 2"));
        }
        if expressions.len() < 2 {
            return Err(Error::invalid("number of expressions", expressions.len(), ">= 2"));
        }
        if num_vertices == 0 {
            return Err(Error::invalid("number of vertices", 0, ">= 1"));
        }
        let (ni, ne) = (identities.len(), expressions.len());
        let mut data = Array3::<f64>::zeros((3 * num_vertices, ni, ne));
        for i in 0..ni {
            for e in 0..ne {
                let pts = cell(i, e)?;
                if pts.len() != num_vertices {
                    return Err(Error::dim(
                        format!(
                            "vertex count of identity {:?} expression {:?}",
                            identities[i], expressions[e]
                        ),
                        num_vertices,
                        pts.len(),
                    ));
                }
                for (v, p) in pts.iter().enumerate() {
                    for c in 0..3 {
                        if !p[c].is_finite() {
                            return Err(Error::invalid(
                                "vertex coordinate",
                                format!(
                                    "identity {:?} expression {:?} vertex {v}",
                                    identities[i], expressions[e]
                                ),
                                "finite",
                            ));
                        }
                        data[[3 * v + c, i, e]] = p[c];
                    }
                }
            }
        }
        Ok(DataTensor {
            identities,
            expressions,
            data,
            triangles,
        })
    }

    /// The mesh of identity `i` with expression `e`, or `None` when out of range.
    pub fn cell(&self, i: usize, e: usize) -> Option<Vec<Point3<f64>>> {
        if i >= self.num_identities() || e >= self.num_expressions() {
            return None;
        }
        let col = self.data.slice(ndarray::s![.., i, e]);
        Some(
            (0..self.num_vertices())
                .map(|v| Point3::new(col[3 * v], col[3 * v + 1], col[3 * v + 2]))
                .collect(),
        )
    }

    /// Reads a folder of `<identity>_<expression>.obj` meshes (see module docs).
    /// Identities and expressions are sorted by name.
    ///
    /// # Errors
    /// [`Error::Io`] if the folder cannot be listed, [`Error::Format`] for a file name
    /// without `_` or a malformed OBJ, [`Error::MissingCell`] for a hole in the grid,
    /// [`Error::DimensionMismatch`] naming the first mesh whose vertex count differs.
    pub fn from_mesh_folder(dir: &Path) -> Result<Self> {
        let rd = std::fs::read_dir(dir).map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let mut files: BTreeMap<(String, String), std::path::PathBuf> = BTreeMap::new();
        for entry in rd {
            let entry = entry.map_err(|source| Error::Io {
                path: dir.to_path_buf(),
                source,
            })?;
            let path = entry.path();
            if path
                .extension()
                .and_then(|x| x.to_str())
                .map(|x| x.eq_ignore_ascii_case("obj"))
                != Some(true)
            {
                continue;
            }
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("").to_string();
            let Some((id, ex)) = stem.split_once('_').filter(|(a, b)| !a.is_empty() && !b.is_empty()) else {
                return Err(Error::Format {
                    what: "mesh database",
                    path,
                    reason: "file name must be <identity>_<expression>.obj".into(),
                });
            };
            files.insert((id.to_string(), ex.to_string()), path);
        }
        if files.is_empty() {
            return Err(Error::Format {
                what: "mesh database",
                path: dir.to_path_buf(),
                reason: "no <identity>_<expression>.obj files".into(),
            });
        }
        let ids: Vec<String> = files
            .keys()
            .map(|k| k.0.clone())
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        let exps: Vec<String> = files
            .keys()
            .map(|k| k.1.clone())
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        for i in &ids {
            for e in &exps {
                if !files.contains_key(&(i.clone(), e.clone())) {
                    return Err(Error::MissingCell {
                        identity: i.clone(),
                        expression: e.clone(),
                    });
                }
            }
        }
        let first_key = (ids[0].clone(), exps[0].clone());
        let first = facecap_io::obj::read_obj_positions(&files[&first_key], None)?;
        let nv = first.positions.len();
        let triangles = first.triangles.clone();
        let (ids2, exps2) = (ids.clone(), exps.clone());
        Self::from_cells(ids, exps, nv, triangles, |i, e| {
            let path = &files[&(ids2[i].clone(), exps2[e].clone())];
            let g = facecap_io::obj::read_obj_positions(path, None)?;
            if g.positions.len() != nv {
                return Err(Error::dim(
                    format!("vertex count of {}", path.display()),
                    nv,
                    g.positions.len(),
                ));
            }
            Ok(g.positions.iter().map(|p| p.cast::<f64>()).collect())
        })
    }

    /// Samples identities from an identity rig and applies every expression of an
    /// expression rig (see module docs and [`RigSampling`]).
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when the rigs' vertex counts differ,
    /// [`Error::InvalidParameter`] for a bad sampling parameter or an unknown expression name.
    pub fn from_rigs(identity_rig: &MorphMesh, expression_rig: &MorphMesh, sampling: &RigSampling) -> Result<Self> {
        identity_rig.validate()?;
        expression_rig.validate()?;
        let nv = identity_rig.base.num_vertices();
        if expression_rig.base.num_vertices() != nv {
            return Err(Error::dim(
                "vertex count of the expression rig (must equal the identity rig's)",
                nv,
                expression_rig.base.num_vertices(),
            ));
        }
        if identity_rig.targets.is_empty() {
            return Err(Error::invalid("identity rig morph targets", 0, ">= 1"));
        }
        if sampling.identities < 2 {
            return Err(Error::invalid("identities", sampling.identities, ">= 2"));
        }
        if !(sampling.sigma.is_finite() && sampling.sigma > 0.0) {
            return Err(Error::invalid("sigma", sampling.sigma, "a finite number > 0"));
        }
        let mut exp_idx: Vec<Option<usize>> = Vec::new();
        if sampling.include_neutral {
            exp_idx.push(None);
        }
        match &sampling.expressions {
            None => exp_idx.extend((0..expression_rig.targets.len()).map(Some)),
            Some(names) => {
                for n in names {
                    let k = expression_rig
                        .targets
                        .iter()
                        .position(|t| &t.name == n)
                        .ok_or_else(|| {
                            Error::invalid(
                                "expression name",
                                n,
                                format!(
                                    "one of the expression rig's targets: {}",
                                    expression_rig.target_names().join(",")
                                ),
                            )
                        })?;
                    exp_idx.push(Some(k));
                }
            }
        }
        let exp_names: Vec<String> = exp_idx
            .iter()
            .map(|k| match k {
                None => NEUTRAL.to_string(),
                Some(k) => expression_rig.targets[*k].name.clone(),
            })
            .collect();
        let id_names: Vec<String> = (0..sampling.identities).map(|i| format!("id{i:03}")).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(sampling.seed);
        let mut neutrals: Vec<Vec<Point3<f64>>> = Vec::with_capacity(sampling.identities);
        for _ in 0..sampling.identities {
            let mut p: Vec<Point3<f64>> = identity_rig.base.positions.iter().map(|q| q.cast::<f64>()).collect();
            for t in &identity_rig.targets {
                let w = sampling.sigma * standard_normal(&mut rng);
                for (pv, d) in p.iter_mut().zip(&t.deltas) {
                    *pv += d.cast::<f64>() * w;
                }
            }
            neutrals.push(p);
        }
        Self::from_cells(id_names, exp_names, nv, identity_rig.base.triangles.clone(), |i, e| {
            let mut p = neutrals[i].clone();
            if let Some(k) = exp_idx[e] {
                for (pv, d) in p.iter_mut().zip(&expression_rig.targets[k].deltas) {
                    *pv += d.cast::<f64>();
                }
            }
            Ok(p)
        })
    }
}
