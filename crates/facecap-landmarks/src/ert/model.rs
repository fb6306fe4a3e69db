//! The parsed content of a dlib `shape_predictor` file, in dlib's own layout.

use std::path::Path;

use super::dlib_format::{DecodeError, Reader, Writer};
use crate::error::{Error, Result};

/// The only `shape_predictor` serialisation version dlib has written so far.
pub const DLIB_SHAPE_PREDICTOR_VERSION: i64 = 1;
/// Allowed range of mean-shape coordinates, face-box units (the box is [0, 1]^2).
pub const MEAN_SHAPE_RANGE: (f32, f32) = (-1.0, 2.0);
/// Smallest extent of a mean shape with more than one point along x and along y.
pub const MIN_MEAN_SHAPE_SPREAD: f32 = 1e-3;
/// Largest absolute leaf value (one tree's shape update), face-box units.
pub const MAX_LEAF_ABS: f32 = 1.0;
/// Largest absolute feature-pixel offset from its anchor, face-box units.
pub const MAX_DELTA_ABS: f32 = 2.0;

/// One split node: go left when `f[idx1] - f[idx2] > thresh`, where `f` are the
/// cascade's feature pixel intensities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitFeature {
    /// Index of the first feature pixel.
    pub idx1: u64,
    /// Index of the second feature pixel.
    pub idx2: u64,
    /// Threshold on the intensity difference (grey levels).
    pub thresh: f32,
}

/// One regression tree, stored breadth first as dlib does: node `i` has children
/// `2i+1` (left) and `2i+2` (right); `leaf_values.len() == splits.len() + 1`.
#[derive(Debug, Clone, PartialEq)]
pub struct RegressionTree {
    /// Split nodes in breadth-first order.
    pub splits: Vec<SplitFeature>,
    /// Per leaf, the shape increment (`2 * num_parts` values, x0 y0 x1 y1 ...,
    /// in normalised box coordinates).
    pub leaf_values: Vec<Vec<f32>>,
}

/// A dlib `shape_predictor` as stored on disk (Kazemi & Sullivan 2014 ERT).
///
/// Shapes are in **normalised box coordinates**: `(0,0)` is the box's top-left
/// corner and `(1,1)` its bottom-right corner (see [`super::ShapePredictor`]).
///
/// | field | shape | meaning |
/// |---|---|---|
/// | `initial_shape` | `2P` | mean shape, x0 y0 x1 y1 ... |
/// | `forests` | `C` cascades x `T` trees | regression trees per cascade |
/// | `anchor_idx` | `C` x `F` | landmark each feature pixel is attached to |
/// | `deltas` | `C` x `F` | feature pixel offset from its anchor in the mean shape |
#[derive(Debug, Clone, PartialEq)]
pub struct ErtModel {
    /// Mean shape, `2 * num_parts` values.
    pub initial_shape: Vec<f32>,
    /// `forests[c]` are the trees of cascade `c`.
    pub forests: Vec<Vec<RegressionTree>>,
    /// `anchor_idx[c][f]`: landmark index of feature pixel `f` of cascade `c`.
    pub anchor_idx: Vec<Vec<u64>>,
    /// `deltas[c][f]`: offset `(dx, dy)` of feature pixel `f` from its anchor.
    pub deltas: Vec<Vec<[f32; 2]>>,
}

fn model_err(reason: String) -> Error {
    Error::Model {
        path: Default::default(),
        reason,
    }
}

fn decode_err(e: DecodeError) -> Error {
    model_err(e.describe())
}

impl ErtModel {
    /// Reads a dlib `shape_predictor` file.
    ///
    /// # Errors
    /// [`Error::Model`] (with the path) when the file cannot be read or is
    /// malformed, truncated or of another version.
    pub fn from_file(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::Model {
            path: path.to_path_buf(),
            reason: format!("cannot read: {e}"),
        })?;
        Self::from_bytes(&bytes).map_err(|e| match e {
            Error::Model { reason, .. } => Error::Model {
                path: path.to_path_buf(),
                reason,
            },
            other => other,
        })
    }

    /// Parses dlib's serialisation of a `shape_predictor` and validates it.
    ///
    /// # Errors
    /// [`Error::Model`] for malformed, truncated or wrong-version data and for
    /// models whose indices are out of range; never panics.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let mut r = Reader::new(bytes);
        let version = r.signed(4, "version").map_err(decode_err)?;
        if version != DLIB_SHAPE_PREDICTOR_VERSION {
            return Err(model_err(format!(
                "unsupported shape_predictor version {version} (expected {DLIB_SHAPE_PREDICTOR_VERSION}); \
                 is this a dlib shape_predictor file?"
            )));
        }
        let mut initial_shape = Vec::new();
        r.float_column("initial_shape", &mut initial_shape)
            .map_err(decode_err)?;

        let n_cascades = r.length("number of cascades", 2).map_err(decode_err)?;
        let mut forests = Vec::with_capacity(n_cascades);
        for c in 0..n_cascades {
            let n_trees = r.length("number of trees", 4).map_err(decode_err)?;
            let mut trees = Vec::with_capacity(n_trees);
            for t in 0..n_trees {
                trees
                    .push(read_tree(&mut r).map_err(|e| model_err(format!("cascade {c} tree {t}: {}", e.describe())))?);
            }
            forests.push(trees);
        }

        let n_anchor = r.length("number of anchor lists", 2).map_err(decode_err)?;
        let mut anchor_idx = Vec::with_capacity(n_anchor);
        for _ in 0..n_anchor {
            let n = r.length("number of anchors", 2).map_err(decode_err)?;
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                v.push(r.ulong("anchor index").map_err(decode_err)?);
            }
            anchor_idx.push(v);
        }

        let n_delta = r.length("number of delta lists", 2).map_err(decode_err)?;
        let mut deltas = Vec::with_capacity(n_delta);
        for _ in 0..n_delta {
            let n = r.length("number of deltas", 8).map_err(decode_err)?;
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                let x = r.float("delta x").map_err(decode_err)?;
                let y = r.float("delta y").map_err(decode_err)?;
                v.push([x, y]);
            }
            deltas.push(v);
        }
        if r.remaining() != 0 {
            return Err(model_err(format!(
                "{} trailing bytes after the model at byte {}",
                r.remaining(),
                r.offset()
            )));
        }
        let model = ErtModel {
            initial_shape,
            forests,
            anchor_idx,
            deltas,
        };
        model.validate()?;
        Ok(model)
    }

    /// Checks every invariant inference relies on (see the type's table).
    ///
    /// # Errors
    /// [`Error::Model`] naming the first violated invariant.
    pub fn validate(&self) -> Result<()> {
        let dim = self.initial_shape.len();
        if dim == 0 || dim % 2 != 0 {
            return Err(model_err(format!(
                "initial shape has {dim} values, expected a positive even count"
            )));
        }
        if let Some(i) = self.initial_shape.iter().position(|v| !v.is_finite()) {
            return Err(model_err(format!("initial shape value {i} is not finite")));
        }
        let parts = (dim / 2) as u64;
        let c = self.forests.len();
        if self.anchor_idx.len() != c || self.deltas.len() != c {
            return Err(model_err(format!(
                "{c} forests but {} anchor lists and {} delta lists",
                self.anchor_idx.len(),
                self.deltas.len()
            )));
        }
        for (ci, ((trees, anchors), deltas)) in self.forests.iter().zip(&self.anchor_idx).zip(&self.deltas).enumerate()
        {
            let n_feat = anchors.len();
            if deltas.len() != n_feat {
                return Err(model_err(format!(
                    "cascade {ci}: {n_feat} anchors but {} deltas",
                    deltas.len()
                )));
            }
            if n_feat > u32::MAX as usize {
                return Err(model_err(format!("cascade {ci}: too many feature pixels")));
            }
            if let Some(a) = anchors.iter().find(|&&a| a >= parts) {
                return Err(model_err(format!("cascade {ci}: anchor index {a} >= {parts} parts")));
            }
            if let Some(d) = deltas.iter().position(|d| !d[0].is_finite() || !d[1].is_finite()) {
                return Err(model_err(format!("cascade {ci}: delta {d} is not finite")));
            }
            for (ti, tree) in trees.iter().enumerate() {
                if tree.leaf_values.len() != tree.splits.len() + 1 {
                    return Err(model_err(format!(
                        "cascade {ci} tree {ti}: {} leaves for {} splits (need splits + 1)",
                        tree.leaf_values.len(),
                        tree.splits.len()
                    )));
                }
                for s in &tree.splits {
                    if s.idx1 >= n_feat as u64 || s.idx2 >= n_feat as u64 {
                        return Err(model_err(format!(
                            "cascade {ci} tree {ti}: split feature ({}, {}) out of range ({n_feat} feature pixels)",
                            s.idx1, s.idx2
                        )));
                    }
                }
                if let Some(l) = tree.leaf_values.iter().position(|l| l.len() != dim) {
                    return Err(model_err(format!(
                        "cascade {ci} tree {ti} leaf {l}: {} values, expected {dim}",
                        tree.leaf_values[l].len()
                    )));
                }
            }
        }
        self.check_plausible()
    }

    /// Plausibility of the numbers (any model, known or not): dlib's mean shape and leaf
    /// values are in face-box units (the detection box is the unit square), so a mean
    /// shape outside [`MEAN_SHAPE_RANGE`], a degenerate mean shape, a leaf value above
    /// [`MAX_LEAF_ABS`] or a feature offset above [`MAX_DELTA_ABS`] means a damaged
    /// file (one flipped exponent bit makes a value thousands of times too large),
    /// not a model. dlib's models stay well inside these bounds (68 points: mean shape in
    /// [0.029, 1.070], leaves <= 0.061, offsets <= 0.187; 5 points: offsets <= 0.501;
    /// `tests/ert_plausibility.rs`).
    fn check_plausible(&self) -> Result<()> {
        let (lo, hi) = MEAN_SHAPE_RANGE;
        if let Some(i) = self.initial_shape.iter().position(|&v| !(lo..=hi).contains(&v)) {
            return Err(model_err(format!(
                "implausible model: mean shape value {i} = {} outside [{lo}, {hi}] face-box units (damaged file?)",
                self.initial_shape[i]
            )));
        }
        let spread = |k: usize| {
            let v = self.initial_shape.iter().skip(k).step_by(2);
            let (mn, mx) = v.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            mx - mn
        };
        if self.num_parts() > 1 && (spread(0) < MIN_MEAN_SHAPE_SPREAD || spread(1) < MIN_MEAN_SHAPE_SPREAD) {
            return Err(model_err(format!(
                "implausible model: mean shape spans {} x {} face-box units (degenerate)",
                spread(0),
                spread(1)
            )));
        }
        for (ci, (trees, deltas)) in self.forests.iter().zip(&self.deltas).enumerate() {
            if let Some(d) = deltas
                .iter()
                .position(|d| d[0].abs() > MAX_DELTA_ABS || d[1].abs() > MAX_DELTA_ABS)
            {
                return Err(model_err(format!(
                    "implausible model: cascade {ci} feature offset {d} = {:?} above {MAX_DELTA_ABS} face-box units",
                    deltas[d]
                )));
            }
            for (ti, tree) in trees.iter().enumerate() {
                for (li, leaf) in tree.leaf_values.iter().enumerate() {
                    if let Some(v) = leaf.iter().find(|v| !v.is_finite() || v.abs() > MAX_LEAF_ABS) {
                        return Err(model_err(format!(
                            "implausible model: cascade {ci} tree {ti} leaf {li} value {v} above {MAX_LEAF_ABS} face-box units"
                        )));
                    }
                }
                if let Some(s) = tree.splits.iter().find(|s| !s.thresh.is_finite()) {
                    return Err(model_err(format!(
                        "cascade {ci} tree {ti}: split threshold {} is not finite",
                        s.thresh
                    )));
                }
            }
        }
        Ok(())
    }

    /// Number of landmarks.
    pub fn num_parts(&self) -> usize {
        self.initial_shape.len() / 2
    }

    /// Serialises in dlib's format (`dlib::serialize(shape_predictor)`), so the
    /// output can be read by dlib and by [`ErtModel::from_bytes`].
    pub fn to_dlib_bytes(&self) -> Vec<u8> {
        let mut w = Writer::default();
        w.signed(DLIB_SHAPE_PREDICTOR_VERSION);
        w.float_column(&self.initial_shape);
        w.unsigned(self.forests.len() as u64);
        for trees in &self.forests {
            w.unsigned(trees.len() as u64);
            for t in trees {
                w.unsigned(t.splits.len() as u64);
                for s in &t.splits {
                    w.unsigned(s.idx1);
                    w.unsigned(s.idx2);
                    w.float(s.thresh);
                }
                w.unsigned(t.leaf_values.len() as u64);
                for l in &t.leaf_values {
                    w.float_column(l);
                }
            }
        }
        w.unsigned(self.anchor_idx.len() as u64);
        for a in &self.anchor_idx {
            w.unsigned(a.len() as u64);
            for &i in a {
                w.unsigned(i);
            }
        }
        w.unsigned(self.deltas.len() as u64);
        for d in &self.deltas {
            w.unsigned(d.len() as u64);
            for p in d {
                w.float(p[0]);
                w.float(p[1]);
            }
        }
        w.bytes
    }
}

fn read_tree(r: &mut Reader<'_>) -> Result<RegressionTree, DecodeError> {
    let n_splits = r.length("number of splits", 6)?;
    let mut splits = Vec::with_capacity(n_splits);
    for _ in 0..n_splits {
        let idx1 = r.ulong("split idx1")?;
        let idx2 = r.ulong("split idx2")?;
        let thresh = r.float("split threshold")?;
        splits.push(SplitFeature { idx1, idx2, thresh });
    }
    let n_leaves = r.length("number of leaves", 4)?;
    let mut leaf_values = Vec::with_capacity(n_leaves);
    for _ in 0..n_leaves {
        let mut v = Vec::new();
        r.float_column("leaf values", &mut v)?;
        leaf_values.push(v);
    }
    Ok(RegressionTree { splits, leaf_values })
}
