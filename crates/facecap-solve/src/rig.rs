//! Blendshape rigs reduced to the 68 iBUG landmarks.
//!
//! A rig is a neutral shape plus `n` named expression deltas (`B = B0 + sum_i e_i B_i`,
//! `e_i in [0, 1]`). For solving only the 68 landmark vertices matter; the full mesh is kept
//! (optionally) for output.
//!
//! | field | shape | units |
//! |---|---|---|
//! | `neutral` | `68 x 3` | model units (ICT: cm, SFM: mm), +Y up, +Z out of the face |
//! | `deltas` | `n x 68 x 3` | same units |
//! | `mapped` | `68` | landmarks with a vertex; unmapped rows are zero and excluded from every objective |
//!
//! Sources: a [`MorphMesh`] (e.g. read from a glTF with morph targets) plus a [`LandmarkMap`];
//! a neutral OBJ plus one OBJ per expression (the seed's layout); the raw ICT FaceKit files; or a
//! synthetic rig made in code for tests ([`BlendshapeRig::synthetic`]).

use std::path::Path;

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::NUM_LANDMARKS;
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use nalgebra::{Point3, Vector3};
use ndarray::{Array2, Array3};
use rand::{Rng, SeedableRng};

use crate::contour::{ContourCandidates, ContourParams};
use crate::error::{Error, Result};

/// A blendshape rig at the 68 landmarks (see module docs).
#[derive(Debug, Clone)]
pub struct BlendshapeRig {
    /// Blendshape names in order (unique, non-empty).
    pub names: Vec<String>,
    /// Neutral landmark positions, `68 x 3` (zero rows where unmapped).
    pub neutral: Array2<f64>,
    /// Expression deltas at the landmarks, `n x 68 x 3`.
    pub deltas: Array3<f64>,
    /// Which landmarks have a vertex.
    pub mapped: [bool; NUM_LANDMARKS],
    /// The full morph mesh, when the rig came from one (for posed-mesh output).
    pub mesh: Option<MorphMesh>,
    /// Candidate vertices of the jaw contour landmarks on `mesh` (derived from the mesh
    /// and the landmark map by [`BlendshapeRig::from_morph_mesh`]; `None` or empty: the
    /// contour keeps its fixed vertices), see [`crate::contour`].
    pub contour: Option<ContourCandidates>,
}

fn check_names(source: &str, names: &[String]) -> Result<()> {
    if names.is_empty() {
        return Err(Error::rig(source, "the rig has no blendshapes"));
    }
    let mut seen = std::collections::HashSet::new();
    for (i, n) in names.iter().enumerate() {
        if n.trim().is_empty() {
            return Err(Error::rig(source, format!("blendshape {i} has an empty name")));
        }
        if !seen.insert(n.as_str()) {
            return Err(Error::rig(source, format!("blendshape name {n:?} appears twice")));
        }
    }
    Ok(())
}

impl BlendshapeRig {
    /// Number of blendshapes.
    pub fn num_shapes(&self) -> usize {
        self.names.len()
    }

    /// Number of mapped landmarks.
    pub fn num_mapped(&self) -> usize {
        self.mapped.iter().filter(|m| **m).count()
    }

    /// Builds a rig from landmark-level arrays, checking shapes, finiteness and names.
    pub fn from_arrays(
        names: Vec<String>,
        neutral: Array2<f64>,
        deltas: Array3<f64>,
        mapped: [bool; NUM_LANDMARKS],
    ) -> Result<Self> {
        let src = "in-memory rig";
        check_names(src, &names)?;
        if neutral.dim() != (NUM_LANDMARKS, 3) {
            return Err(Error::DimensionMismatch {
                what: "rig neutral rows (68 x 3)".into(),
                expected: NUM_LANDMARKS * 3,
                got: neutral.len(),
            });
        }
        if deltas.dim() != (names.len(), NUM_LANDMARKS, 3) {
            return Err(Error::DimensionMismatch {
                what: "rig deltas (n x 68 x 3)".into(),
                expected: names.len() * NUM_LANDMARKS * 3,
                got: deltas.len(),
            });
        }
        if neutral.iter().chain(deltas.iter()).any(|v| !v.is_finite()) {
            return Err(Error::rig(src, "non-finite coordinate"));
        }
        let rig = BlendshapeRig {
            names,
            neutral,
            deltas,
            mapped,
            mesh: None,
            contour: None,
        };
        rig.check_mapped(src)?;
        Ok(rig)
    }

    fn check_mapped(&self, src: &str) -> Result<()> {
        const MIN_MAPPED: usize = 6;
        if self.num_mapped() < MIN_MAPPED {
            return Err(Error::rig(
                src,
                format!(
                    "only {} landmarks are mapped; at least {MIN_MAPPED} are needed",
                    self.num_mapped()
                ),
            ));
        }
        Ok(())
    }

    /// Builds a rig from a morph mesh and a landmark map. Every target must have one delta per
    /// vertex, names must be unique, and every mapped vertex id must exist.
    pub fn from_morph_mesh(mesh: MorphMesh, map: &LandmarkMap, source_name: &str) -> Result<Self> {
        mesh.validate().map_err(|e| Error::rig(source_name, e.to_string()))?;
        let names: Vec<String> = mesh.targets.iter().map(|t| t.name.clone()).collect();
        check_names(source_name, &names)?;
        let nv = mesh.base.num_vertices();
        map.validate(nv).map_err(|e| Error::rig(source_name, e.to_string()))?;
        let n = names.len();
        let mut neutral = Array2::zeros((NUM_LANDMARKS, 3));
        let mut deltas = Array3::zeros((n, NUM_LANDMARKS, 3));
        let mut mapped = [false; NUM_LANDMARKS];
        for (l, v) in map.mapped() {
            let v = v as usize;
            mapped[l] = true;
            let p = mesh.base.positions[v];
            for c in 0..3 {
                neutral[[l, c]] = p[c] as f64;
            }
            for (k, t) in mesh.targets.iter().enumerate() {
                for c in 0..3 {
                    deltas[[k, l, c]] = t.deltas[v][c] as f64;
                }
            }
        }
        let contour = ContourCandidates::from_mesh(&mesh.base, map, &ContourParams::default());
        let rig = BlendshapeRig {
            names,
            neutral,
            deltas,
            mapped,
            mesh: Some(mesh),
            contour: (!contour.is_empty()).then_some(contour),
        };
        rig.check_mapped(source_name)?;
        Ok(rig)
    }

    /// Reads a glTF/GLB with morph targets (via `facecap_io::gltf_io`) and a landmark map
    /// JSON file (`vertex_by_ibug_0based`, `vertex_by_ibug_1based` or a plain list of 68 ids).
    pub fn from_gltf(rig: &Path, landmark_map: &Path) -> Result<Self> {
        let mesh = facecap_io::gltf_io::read_morph_mesh(rig)?;
        let map = LandmarkMap::from_json_file(landmark_map)?;
        Self::from_morph_mesh(mesh, &map, &rig.display().to_string())
    }

    /// The seed's layout: a neutral OBJ plus one OBJ per expression (same vertex count and order;
    /// the blendshape is named after the file stem unless a name is given).
    pub fn from_obj_files(
        neutral: &Path,
        expressions: &[(String, std::path::PathBuf)],
        map: &LandmarkMap,
    ) -> Result<Self> {
        let base = read_obj(neutral, None)?;
        let mut targets = Vec::with_capacity(expressions.len());
        for (name, path) in expressions {
            let m = read_obj(path, None)?;
            if m.positions.len() != base.positions.len() {
                return Err(Error::rig(
                    path.display().to_string(),
                    format!(
                        "has {} vertices but the neutral {} has {}",
                        m.positions.len(),
                        neutral.display(),
                        base.positions.len()
                    ),
                ));
            }
            let deltas = m.positions.iter().zip(&base.positions).map(|(a, b)| a - b).collect();
            targets.push(MorphTarget {
                name: name.clone(),
                deltas,
            });
        }
        Self::from_morph_mesh(MorphMesh { base, targets }, map, &neutral.display().to_string())
    }

    /// Reads the raw ICT FaceKit files from `dir` (`generic_neutral_mesh.obj`, first 9409
    /// vertices; `ict_face_expression_deltas_f32le.bin`, float32 LE `[53][9409][3]`;
    /// names from `ict_face_deltas.json`; map from `ict_landmarks68.json`). MIT-licensed data.
    pub fn from_ict_dir(dir: &Path) -> Result<Self> {
        const ICT_FACE_VERTICES: usize = 9409;
        let meta_path = dir.join("ict_face_deltas.json");
        let meta_text = std::fs::read_to_string(&meta_path).map_err(|e| facecap_core::Error::io(&meta_path, e))?;
        let meta: serde_json::Value = serde_json::from_str(&meta_text).map_err(|e| Error::Parse {
            format: "ICT deltas JSON",
            path: meta_path.clone(),
            reason: e.to_string(),
        })?;
        let names: Vec<String> = meta["expression_deltas"]["names"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_str().map(str::to_string)).collect())
            .unwrap_or_default();
        let base = read_obj(&dir.join("generic_neutral_mesh.obj"), Some(ICT_FACE_VERTICES))?;
        if base.positions.len() != ICT_FACE_VERTICES {
            return Err(Error::rig(
                dir.display().to_string(),
                format!(
                    "neutral mesh has {} face vertices, expected {ICT_FACE_VERTICES}",
                    base.positions.len()
                ),
            ));
        }
        let bin_path = dir.join("ict_face_expression_deltas_f32le.bin");
        let bytes = std::fs::read(&bin_path).map_err(|e| facecap_core::Error::io(&bin_path, e))?;
        let expected = names.len() * ICT_FACE_VERTICES * 3 * 4;
        if bytes.len() != expected {
            return Err(Error::DimensionMismatch {
                what: format!("byte size of {}", bin_path.display()),
                expected,
                got: bytes.len(),
            });
        }
        let mut targets = Vec::with_capacity(names.len());
        for (k, name) in names.iter().enumerate() {
            let mut deltas = Vec::with_capacity(ICT_FACE_VERTICES);
            for v in 0..ICT_FACE_VERTICES {
                let o = ((k * ICT_FACE_VERTICES + v) * 3) * 4;
                let f =
                    |i: usize| f32::from_le_bytes([bytes[o + i], bytes[o + i + 1], bytes[o + i + 2], bytes[o + i + 3]]);
                deltas.push(Vector3::new(f(0), f(4), f(8)));
            }
            targets.push(MorphTarget {
                name: name.clone(),
                deltas,
            });
        }
        let map = LandmarkMap::from_json_file(&dir.join("ict_landmarks68.json"))?;
        Self::from_morph_mesh(MorphMesh { base, targets }, &map, &dir.display().to_string())
    }

    /// Keeps only the blendshapes whose names are listed (in the listed order).
    pub fn select(&self, names: &[&str]) -> Result<Self> {
        let mut idx = Vec::with_capacity(names.len());
        for n in names {
            let i = self
                .names
                .iter()
                .position(|x| x == n)
                .ok_or_else(|| Error::rig("rig selection", format!("unknown blendshape name {n:?}")))?;
            idx.push(i);
        }
        let mut deltas = Array3::zeros((idx.len(), NUM_LANDMARKS, 3));
        for (a, &i) in idx.iter().enumerate() {
            deltas
                .slice_mut(ndarray::s![a, .., ..])
                .assign(&self.deltas.slice(ndarray::s![i, .., ..]));
        }
        let mesh = self.mesh.as_ref().map(|m| MorphMesh {
            base: m.base.clone(),
            targets: idx.iter().map(|&i| m.targets[i].clone()).collect(),
        });
        Ok(BlendshapeRig {
            names: idx.iter().map(|&i| self.names[i].clone()).collect(),
            neutral: self.neutral.clone(),
            deltas,
            mapped: self.mapped,
            mesh,
            contour: self.contour.clone(),
        })
    }

    /// Landmark `l` of the rig posed with weights `e` (model units).
    pub fn landmark(&self, l: usize, e: &[f64]) -> Point3<f64> {
        let mut p = Point3::new(self.neutral[[l, 0]], self.neutral[[l, 1]], self.neutral[[l, 2]]);
        for (k, &w) in e.iter().enumerate() {
            if w != 0.0 {
                p.x += w * self.deltas[[k, l, 0]];
                p.y += w * self.deltas[[k, l, 1]];
                p.z += w * self.deltas[[k, l, 2]];
            }
        }
        p
    }

    /// A seeded synthetic rig for tests and examples: a plausible 68-point face (cm, +Y up,
    /// +Z towards the viewer, about 14 cm wide) and `n` localised expression deltas, each moving
    /// one region (brows, eyelids, mouth, jaw without its ends; cycling) by up to ~1.5 cm.
    pub fn synthetic(n: usize, seed: u64) -> Self {
        let neutral = synthetic_face();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // regions avoid the stable alignment points (jaw ends, nose, eye corners), as real
        // expressions barely move them
        let regions: [Vec<usize>; 4] = [
            (17..27).collect(),
            vec![37, 38, 40, 41, 43, 44, 46, 47],
            (48..68).collect(),
            (3..14).collect(),
        ];
        let mut deltas = Array3::zeros((n, NUM_LANDMARKS, 3));
        let mut names = Vec::with_capacity(n);
        for k in 0..n {
            let r = &regions[k % regions.len()];
            names.push(format!("{}_{k}", ["brow", "eye", "mouth", "jaw"][k % 4]));
            // a smooth displacement: random direction field varying linearly across the region
            let base = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.5..0.5),
            );
            let grad = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.3..0.3),
            );
            let amp: f64 = rng.random_range(0.5..1.5);
            let len = r.len() as f64;
            for (j, &l) in r.iter().enumerate() {
                let s = j as f64 / (len - 1.0).max(1.0) - 0.5;
                let d = (base + grad * (2.0 * s)) * amp;
                for c in 0..3 {
                    deltas[[k, l, c]] = d[c];
                }
            }
        }
        BlendshapeRig {
            names,
            neutral,
            deltas,
            mapped: [true; NUM_LANDMARKS],
            mesh: None,
            contour: None,
        }
    }
}

/// A 68-point iBUG-like face in cm (+Y up, +Z to the viewer), origin near the nose base.
fn synthetic_face() -> Array2<f64> {
    let mut p = Array2::zeros((NUM_LANDMARKS, 3));
    let mut set = |i: usize, x: f64, y: f64, z: f64| {
        p[[i, 0]] = x;
        p[[i, 1]] = y;
        p[[i, 2]] = z;
    };
    // jaw 0-16: a U from the right temple (image left, x < 0) round the chin
    for i in 0..17 {
        let a = std::f64::consts::PI * (i as f64 / 16.0);
        set(i, -7.0 * a.cos(), 1.0 - 8.0 * a.sin(), -4.0 + 3.5 * a.sin());
    }
    // brows 17-21 (right), 22-26 (left)
    for j in 0..5 {
        let t = j as f64 / 4.0;
        set(
            17 + j,
            -5.5 + 4.5 * t,
            4.0 + 0.8 * (std::f64::consts::PI * t).sin(),
            1.0 + 1.0 * t,
        );
        set(
            22 + j,
            1.0 + 4.5 * t,
            4.0 + 0.8 * (std::f64::consts::PI * t).sin(),
            2.0 - 1.0 * t,
        );
    }
    // nose bridge 27-30, base 31-35
    for j in 0..4 {
        set(27 + j, 0.0, 2.8 - 1.1 * j as f64, 2.0 + 0.8 * j as f64);
    }
    for j in 0..5 {
        let x = -1.6 + 0.8 * j as f64;
        set(31 + j, x, -1.0 - 0.2 * (1.0 - (x / 1.6).powi(2)), 3.5 - 0.3 * x.abs());
    }
    // eyes 36-41 (right), 42-47 (left): hexagons
    let eye = |cx: f64| -> [(f64, f64); 6] {
        [
            (cx - 1.5, 2.0),
            (cx - 0.7, 2.5),
            (cx + 0.5, 2.5),
            (cx + 1.3, 2.0),
            (cx + 0.5, 1.7),
            (cx - 0.7, 1.7),
        ]
    };
    for (j, (x, y)) in eye(-3.2).into_iter().enumerate() {
        set(36 + j, x, y, 1.5);
    }
    for (j, (x, y)) in eye(3.2).into_iter().enumerate() {
        let (x, y) = (x, y);
        set(42 + j, x, y, 1.5);
    }
    // mouth outer 48-59, inner 60-67
    for j in 0..12 {
        let a = 2.0 * std::f64::consts::PI * j as f64 / 12.0;
        set(48 + j, -2.6 * a.cos(), -3.5 + 1.0 * a.sin(), 2.8 - 0.4 * a.cos().abs());
    }
    for j in 0..8 {
        let a = 2.0 * std::f64::consts::PI * j as f64 / 8.0;
        set(60 + j, -1.8 * a.cos(), -3.5 + 0.3 * a.sin(), 2.7);
    }
    p
}

/// An OBJ's positions in file order (optionally only the first `max_vertices`) and its faces
/// (faces touching a dropped vertex are skipped), through [`facecap_io::obj::read_obj_positions`].
fn read_obj(path: &Path, max_vertices: Option<usize>) -> Result<Mesh> {
    let mesh = facecap_io::obj::read_obj_positions(path, max_vertices)?;
    if mesh.positions.is_empty() {
        return Err(Error::Parse {
            format: "Wavefront OBJ",
            path: path.to_path_buf(),
            reason: "line 0: no vertices".into(),
        });
    }
    Ok(mesh)
}
