//! The 2D landmark basis used by the seed's methods (BOBYQA, region, PCA, exact 2D), the seed's
//! example-image shapes file ([`Shapes2d`]), and the 2D similarity (Umeyama) alignment.
//!
//! A 2D basis is `neutral` (68 points) plus `n` deltas (68 points each), in any consistent 2D
//! unit with y down (image-like). From a 3D rig it is the frontal orthographic view
//! `(x, y) = (X, -Y)` of the landmark vertices; from example images it is the example landmarks,
//! similarity-aligned to the neutral image's landmarks, minus the neutral.
//!
//! Storage: `neutral` is a flat `[x0, y0, x1, y1, ...]` of length 136; `deltas` is `n x 136`
//! (row `k` = shape `k`), rows of unmapped landmarks zero.

use std::path::Path;

use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::Point2;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::rig::BlendshapeRig;

/// Default "stable" landmarks for rigid alignment (not brows, not mouth): jaw ends 0 and 16,
/// nose 27-35, eye corners 36, 39, 42, 45 (as in the anchor `bench_bobyqa_fit.py`).
pub const DEFAULT_STABLE: [usize; 15] = [0, 16, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45];

/// A 2D landmark basis (see module docs).
#[derive(Debug, Clone)]
pub struct Basis2d {
    /// Blendshape names.
    pub names: Vec<String>,
    /// Neutral shape, flat `[x0, y0, ...]` (136).
    pub neutral: Vec<f64>,
    /// Deltas, `n x 136`.
    pub deltas: Array2<f64>,
    /// Landmarks that take part in the objective.
    pub mapped: [bool; NUM_LANDMARKS],
    /// Landmarks used for the similarity alignment (a subset of `mapped`).
    pub stable: [bool; NUM_LANDMARKS],
}

fn stable_mask(mapped: &[bool; NUM_LANDMARKS]) -> [bool; NUM_LANDMARKS] {
    let mut s = [false; NUM_LANDMARKS];
    for &i in &DEFAULT_STABLE {
        s[i] = mapped[i];
    }
    if s.iter().filter(|x| **x).count() < 3 {
        return *mapped;
    }
    s
}

impl Basis2d {
    /// Frontal orthographic projection of a 3D rig: `(x, y) = (X, -Y)` (model +Y up, image y down).
    pub fn frontal(rig: &BlendshapeRig) -> Self {
        let n = rig.num_shapes();
        let mut neutral = vec![0.0; 2 * NUM_LANDMARKS];
        let mut deltas = Array2::zeros((n, 2 * NUM_LANDMARKS));
        for l in 0..NUM_LANDMARKS {
            if !rig.mapped[l] {
                continue;
            }
            neutral[2 * l] = rig.neutral[[l, 0]];
            neutral[2 * l + 1] = -rig.neutral[[l, 1]];
            for k in 0..n {
                deltas[[k, 2 * l]] = rig.deltas[[k, l, 0]];
                deltas[[k, 2 * l + 1]] = -rig.deltas[[k, l, 1]];
            }
        }
        Basis2d {
            names: rig.names.clone(),
            neutral,
            deltas,
            mapped: rig.mapped,
            stable: stable_mask(&rig.mapped),
        }
    }

    /// The basis of a [`Shapes2d`] file: every example aligned (similarity on the stable points)
    /// to the neutral, minus the neutral.
    pub fn from_shapes2d(shapes: &Shapes2d) -> Result<Self> {
        shapes.validate()?;
        let mapped = [true; NUM_LANDMARKS];
        let stable = stable_mask(&mapped);
        let neutral: Vec<f64> = shapes.neutral.iter().flat_map(|p| [p[0], p[1]]).collect();
        let n = shapes.shapes.len();
        let mut deltas = Array2::zeros((n, 2 * NUM_LANDMARKS));
        for (k, s) in shapes.shapes.iter().enumerate() {
            let ex: Vec<f64> = s.landmarks.iter().flat_map(|p| [p[0], p[1]]).collect();
            let sim = Similarity2d::fit(&ex, &neutral, &stable).ok_or_else(|| Error::Input {
                reason: format!("example {:?} is degenerate (its stable points coincide)", s.name),
            })?;
            for l in 0..NUM_LANDMARKS {
                let (x, y) = sim.apply(ex[2 * l], ex[2 * l + 1]);
                deltas[[k, 2 * l]] = x - neutral[2 * l];
                deltas[[k, 2 * l + 1]] = y - neutral[2 * l + 1];
            }
        }
        Ok(Basis2d {
            names: shapes.shapes.iter().map(|s| s.name.clone()).collect(),
            neutral,
            deltas,
            mapped,
            stable,
        })
    }

    /// Number of shapes.
    pub fn num_shapes(&self) -> usize {
        self.names.len()
    }
}

/// A 2D similarity `p -> s R(theta) p + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity2d {
    /// Scale.
    pub scale: f64,
    /// `cos(theta)`.
    pub cos: f64,
    /// `sin(theta)`.
    pub sin: f64,
    /// Translation x.
    pub tx: f64,
    /// Translation y.
    pub ty: f64,
}

impl Similarity2d {
    /// Identity.
    pub fn identity() -> Self {
        Similarity2d {
            scale: 1.0,
            cos: 1.0,
            sin: 0.0,
            tx: 0.0,
            ty: 0.0,
        }
    }

    /// Applies the transform.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.scale * (self.cos * x - self.sin * y) + self.tx,
            self.scale * (self.sin * x + self.cos * y) + self.ty,
        )
    }

    /// `(R^T (p - t)) / s`, the inverse map.
    pub fn apply_inverse(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.tx, y - self.ty);
        (
            (self.cos * dx + self.sin * dy) / self.scale,
            (-self.sin * dx + self.cos * dy) / self.scale,
        )
    }

    /// Least-squares similarity mapping `src` onto `dst` over the masked points (Umeyama 1991,
    /// closed form in 2D: `theta = atan2(sum a x b, sum a . b)` on centred points,
    /// `s = |(sum a . b, sum a x b)| / sum |a|^2`). Flat `[x0, y0, ...]` inputs. `None` when the
    /// masked source points coincide. No allocation.
    pub fn fit(src: &[f64], dst: &[f64], mask: &[bool; NUM_LANDMARKS]) -> Option<Self> {
        let (mut ma, mut mb, mut cnt) = ([0.0f64; 2], [0.0f64; 2], 0.0f64);
        for l in 0..NUM_LANDMARKS {
            if mask[l] {
                ma[0] += src[2 * l];
                ma[1] += src[2 * l + 1];
                mb[0] += dst[2 * l];
                mb[1] += dst[2 * l + 1];
                cnt += 1.0;
            }
        }
        if cnt < 2.0 {
            return None;
        }
        for v in ma.iter_mut().chain(mb.iter_mut()) {
            *v /= cnt;
        }
        let (mut dot, mut cross, mut aa) = (0.0, 0.0, 0.0);
        for l in 0..NUM_LANDMARKS {
            if mask[l] {
                let (ax, ay) = (src[2 * l] - ma[0], src[2 * l + 1] - ma[1]);
                let (bx, by) = (dst[2 * l] - mb[0], dst[2 * l + 1] - mb[1]);
                dot += ax * bx + ay * by;
                cross += ax * by - ay * bx;
                aa += ax * ax + ay * ay;
            }
        }
        let norm = (dot * dot + cross * cross).sqrt();
        if aa <= 0.0 || norm <= 0.0 || !norm.is_finite() {
            return None;
        }
        let (cos, sin) = (dot / norm, cross / norm);
        let scale = norm / aa;
        let tx = mb[0] - scale * (cos * ma[0] - sin * ma[1]);
        let ty = mb[1] - scale * (sin * ma[0] + cos * ma[1]);
        Some(Similarity2d {
            scale,
            cos,
            sin,
            tx,
            ty,
        })
    }
}

/// Flattens landmarks to `[x0, y0, ...]` into `out` (136).
pub fn flatten_landmarks(lm: &Landmarks68, out: &mut [f64]) {
    for (l, p) in lm.points.iter().enumerate() {
        out[2 * l] = p.x;
        out[2 * l + 1] = p.y;
    }
}

/// One example expression of a [`Shapes2d`] file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shape2dExample {
    /// Blendshape name.
    pub name: String,
    /// Where the landmarks came from (e.g. an image file name); informative.
    #[serde(default)]
    pub source: String,
    /// 68 landmarks `[x, y]`, 0-based pixels, as detected on the example image.
    pub landmarks: Vec<[f64; 2]>,
}

/// The seed's 2D pre-process, as a file: the neutral image's 68 landmarks plus one example
/// image's landmarks per blendshape.
///
/// JSON form (`format` must be `"facecap-shapes2d"`, `version` 1):
/// ```json
/// {"format": "facecap-shapes2d", "version": 1,
///  "neutral": [[x, y], ... 68],
///  "shapes": [{"name": "smile", "source": "smile.jpg", "landmarks": [[x, y], ... 68]}]}
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shapes2d {
    /// Must be [`Shapes2d::FORMAT`].
    pub format: String,
    /// Must be 1.
    pub version: u32,
    /// Neutral landmarks (68).
    pub neutral: Vec<[f64; 2]>,
    /// Examples, one per blendshape.
    pub shapes: Vec<Shape2dExample>,
}

impl Shapes2d {
    /// The `format` tag.
    pub const FORMAT: &'static str = "facecap-shapes2d";

    /// Builds the file content from detected landmarks.
    pub fn from_landmarks(neutral: &Landmarks68, examples: &[(String, String, Landmarks68)]) -> Result<Self> {
        let conv = |lm: &Landmarks68| lm.points.iter().map(|p: &Point2<f64>| [p.x, p.y]).collect::<Vec<_>>();
        let s = Shapes2d {
            format: Self::FORMAT.into(),
            version: 1,
            neutral: conv(neutral),
            shapes: examples
                .iter()
                .map(|(name, source, lm)| Shape2dExample {
                    name: name.clone(),
                    source: source.clone(),
                    landmarks: conv(lm),
                })
                .collect(),
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks format tag, version, 68 finite points everywhere, at least one shape, unique
    /// non-empty names.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| Error::Parse {
            format: "facecap-shapes2d JSON",
            path: Default::default(),
            reason,
        };
        if self.format != Self::FORMAT {
            return Err(bad(format!("format is {:?}, expected {:?}", self.format, Self::FORMAT)));
        }
        if self.version != 1 {
            return Err(bad(format!("version {} is not supported (expected 1)", self.version)));
        }
        let check = |what: &str, pts: &[[f64; 2]]| -> Result<()> {
            if pts.len() != NUM_LANDMARKS {
                return Err(bad(format!("{what} has {} landmarks, expected 68", pts.len())));
            }
            if pts.iter().flatten().any(|v| !v.is_finite()) {
                return Err(bad(format!("{what} has a non-finite coordinate")));
            }
            Ok(())
        };
        check("neutral", &self.neutral)?;
        if self.shapes.is_empty() {
            return Err(bad("no shapes".into()));
        }
        let mut seen = std::collections::HashSet::new();
        for s in &self.shapes {
            if s.name.trim().is_empty() {
                return Err(bad("a shape has an empty name".into()));
            }
            if !seen.insert(s.name.as_str()) {
                return Err(bad(format!("shape name {:?} appears twice", s.name)));
            }
            check(&format!("shape {:?}", s.name), &s.landmarks)?;
        }
        Ok(())
    }

    /// Parses and validates JSON text.
    pub fn from_json_str(text: &str) -> Result<Self> {
        let s: Shapes2d = serde_json::from_str(text).map_err(|e| Error::Parse {
            format: "facecap-shapes2d JSON",
            path: Default::default(),
            reason: e.to_string(),
        })?;
        s.validate()?;
        Ok(s)
    }

    /// Reads and validates a file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| facecap_core::Error::io(path, e))?;
        Self::from_json_str(&text).map_err(|e| match e {
            Error::Parse { format, reason, .. } => Error::Parse {
                format,
                path: path.to_path_buf(),
                reason,
            },
            other => other,
        })
    }

    /// Pretty JSON text.
    pub fn to_json_string(&self) -> Result<String> {
        serde_json::to_string_pretty(self).map_err(|e| Error::Parse {
            format: "facecap-shapes2d JSON",
            path: Default::default(),
            reason: e.to_string(),
        })
    }

    /// Validates and writes the file (atomically: temp file + rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        self.validate()?;
        let text = self.to_json_string()?;
        facecap_core::atomic::write_atomic(path, |w| w.write_all(text.as_bytes()))?;
        Ok(())
    }
}
