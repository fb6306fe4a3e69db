//! Landmark inference with dlib-compatible ensembles of regression trees (ERT).
//!
//! Kazemi & Sullivan, "One millisecond face alignment with an ensemble of
//! regression trees", CVPR 2014, as implemented by dlib's `shape_predictor`
//! (`dlib/image_processing/shape_predictor.h`). We read dlib's model files
//! ([`ErtModel`], format in [`dlib_format`]) and reproduce dlib's arithmetic so the
//! landmarks are the same as dlib's.
//!
//! # The maths
//! A shape `S` is `P` points in **normalised box coordinates** `u = (x - l)/(r - l)`,
//! `v = (y - t)/(b - t)`, where `(l, t)` is the box's top-left and `(r, b)` its
//! bottom-right *pixel centre* (dlib's inclusive rectangle: `r = l + width - 1`).
//! Starting from the mean shape `S_0` (or a given shape), each cascade `c = 1..C`:
//!
//! 1. finds the similarity `A_c` (2x2, no translation) that best maps the mean
//!    shape onto the current shape in the least-squares sense (Umeyama 1991; for 2-D
//!    `A = [[a, -b], [b, a]]`, `a = Σ f·t / Σ|f|²`, `b = Σ f×t / Σ|f|²` over the
//!    centred points `f` of the mean shape and `t` of the current shape);
//! 2. places its `F` feature pixels: pixel `k` hangs off landmark `anchor[k]` with
//!    offset `delta[k]` in mean-shape space, so it sits at
//!    `q = A_c delta[k] + S[anchor[k]]` (f32), mapped to the image as
//!    `(l + (r-l) q_x, t + (b-t) q_y)` (f64) and rounded to the nearest pixel
//!    (`floor(x + 0.5)`); pixels outside the image read 0;
//! 3. runs each of its `T` trees: at node `i` go to `2i+1` if
//!    `I[idx1] - I[idx2] > thresh`, else `2i+2`, and adds the reached leaf's
//!    shape increment to `S` (f32, tree order).
//!
//! The final shape is mapped to pixels with the same box transform. dlib returns
//! integer points (`floor(x + 0.5)`); [`OutputPrecision::DlibIntegerPixels`] does the
//! same, [`OutputPrecision::SubPixel`] returns the unrounded coordinates.
//!
//! Pixel convention: the centre of the top-left pixel is `(0, 0)`.
//!
//! # Departures from dlib
//! * dlib computes the similarity with an SVD (Umeyama's formula) in f64 and the box
//!   transform with a pseudo-inverse; we use the closed forms in f64. Both are cast to
//!   the same f32 / f64 values except in the last bit, which can move a rounded
//!   pixel only when a coordinate lies within ~1e-13 px of a half-integer.
//! * Leaf indices for all trees of a cascade are found first, then the leaf
//!   vectors are added in tree order, four rows per pass over the coordinates:
//!   per coordinate the same f32 additions in the same order as dlib's loop.
//!
//! # Layout
//! Trees are stored as flat arrays per cascade (structure of arrays): split feature
//! indices `idx1`, `idx2` (u16 or u32), thresholds (f32), and all leaf vectors of
//! the cascade in one `Vec<f32>` (`leaf * 2P + coord`). The mean shape's centred
//! points and their squared norm are precomputed once.
//!
//! # Parameters ([`ErtParams`])
//! | name | default | meaning |
//! |---|---|---|
//! | `output` | `DlibIntegerPixels` | round the output to whole pixels like dlib, or keep sub-pixel values |
//! | `precision` | `Exact` | f32 leaves in dlib's order (dlib's landmarks), or `Fast`: 16-bit leaves (see `fast.rs`, `docs/landmarks.md`) |
//!
//! ```no_run
//! use facecap_core::landmarks::Rect;
//! use facecap_landmarks::ert::ShapePredictor;
//! # fn main() -> facecap_landmarks::Result<()> {
//! let sp = ShapePredictor::from_file(std::path::Path::new("shape_predictor_68_face_landmarks.dat"))?;
//! let img = image::GrayImage::new(640, 480);
//! let mut ws = sp.new_workspace();
//! let mut pts = vec![nalgebra::Point2::origin(); sp.num_parts()];
//! sp.predict_into(&img, &Rect::from_dlib(200, 120, 400, 320), &mut ws, &mut pts)?;
//! # Ok(()) }
//! ```

mod cache;
pub mod dlib_format;
mod fast;
mod model;
pub mod reference;

use std::path::Path;
use std::sync::Arc;

use facecap_core::landmarks::Rect;
use image::GrayImage;
use nalgebra::Point2;

pub use cache::CacheStatus;
pub use model::{
    ErtModel, RegressionTree, SplitFeature, DLIB_SHAPE_PREDICTOR_VERSION, MAX_DELTA_ABS, MAX_LEAF_ABS,
    MEAN_SHAPE_RANGE, MIN_MEAN_SHAPE_SPREAD,
};

use crate::error::{Error, Result};

/// How output coordinates are produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutputPrecision {
    /// Round to the nearest pixel centre exactly as dlib's `full_object_detection`
    /// (`floor(x + 0.5)`).
    #[default]
    DlibIntegerPixels,
    /// Keep the sub-pixel coordinates of the final shape.
    SubPixel,
}

/// How the leaf vectors are stored and added.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ErtPrecision {
    /// f32 leaves added in dlib's order: the same landmarks as dlib (the reference).
    #[default]
    Exact,
    /// 16-bit leaves with a per-leaf scale in cache-line aligned rows, added in f32:
    /// about half the memory traffic per prediction; landmarks within a few hundredths
    /// of a pixel of [`ErtPrecision::Exact`] on average (see `docs/landmarks.md`).
    Fast,
}

impl ErtPrecision {
    /// The name used on the command line (`exact`, `fast`).
    pub fn name(self) -> &'static str {
        match self {
            ErtPrecision::Exact => "exact",
            ErtPrecision::Fast => "fast",
        }
    }
}

impl std::str::FromStr for ErtPrecision {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s {
            "exact" => Ok(ErtPrecision::Exact),
            "fast" => Ok(ErtPrecision::Fast),
            other => Err(format!("unknown ERT precision {other:?} (expected exact or fast)")),
        }
    }
}

/// Parameters of [`ShapePredictor`] (see the module's table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ErtParams {
    /// Output rounding.
    pub output: OutputPrecision,
    /// Leaf storage: exact f32 (default) or quantised.
    pub precision: ErtPrecision,
}

/// One cascade in flat (structure-of-arrays) form.
#[derive(Debug, Clone)]
struct Cascade {
    /// Per feature pixel: anchor landmark index times 2 (offset into the shape).
    anchor2: Vec<u32>,
    /// Per feature pixel: offset from the anchor in mean-shape space.
    delta: Vec<[f32; 2]>,
    /// Tree `t`'s splits are `split_start[t]..split_start[t+1]`.
    split_start: Vec<u32>,
    /// Tree `t`'s first leaf (leaf index, not float index).
    leaf_start: Vec<u32>,
    /// Split feature pixel indices.
    idx1: Vec<u32>,
    idx2: Vec<u32>,
    /// Split thresholds.
    thresh: Vec<f32>,
    /// All leaf vectors, `leaf * dim + coord`.
    leaves: Vec<f32>,
    /// All trees have this many splits (complete trees of equal depth), or `None`.
    uniform_splits: Option<usize>,
}

/// dlib-compatible ERT landmark predictor: immutable, `Send + Sync`, built once.
#[derive(Debug, Clone)]
pub struct ShapePredictor {
    params: ErtParams,
    /// `2P` mean shape.
    initial: Vec<f32>,
    /// Mean shape centred on its centroid (f64, `2P`).
    initial_centred: Vec<f64>,
    /// `Σ |f|²` of the centred mean shape.
    initial_norm2: f64,
    cascades: Vec<Cascade>,
    max_features: usize,
    max_trees: usize,
    /// Quantised leaves, built when [`ErtPrecision::Fast`] is first asked for.
    fast: Option<Arc<fast::FastLeaves>>,
}

/// Scratch memory of [`ShapePredictor`]; reuse it across calls to avoid allocation.
#[derive(Debug, Clone, Default)]
pub struct ErtWorkspace {
    shape: Vec<f32>,
    features: Vec<f32>,
    leaf: Vec<u32>,
}

/// Box transform: image = (l + sx * u, t + sy * v).
#[derive(Debug, Clone, Copy)]
struct BoxTform {
    l: f64,
    t: f64,
    sx: f64,
    sy: f64,
}

impl BoxTform {
    fn new(rect: &Rect) -> Result<Self> {
        for (name, v) in [
            ("rect.left", rect.left),
            ("rect.top", rect.top),
            ("rect.width", rect.width),
            ("rect.height", rect.height),
        ] {
            if !v.is_finite() {
                return Err(Error::InvalidParameter {
                    name,
                    value: v.to_string(),
                    expected: "a finite number".into(),
                });
            }
        }
        if rect.width <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "rect.width",
                value: rect.width.to_string(),
                expected: "> 0".into(),
            });
        }
        if rect.height <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "rect.height",
                value: rect.height.to_string(),
                expected: "> 0".into(),
            });
        }
        Ok(BoxTform {
            l: rect.left,
            t: rect.top,
            sx: rect.width - 1.0,
            sy: rect.height - 1.0,
        })
    }
}

impl ShapePredictor {
    /// Builds the predictor from a parsed model: validates it and lays the trees out
    /// flat.
    ///
    /// # Errors
    /// [`Error::Model`] when the model breaks an invariant (see [`ErtModel::validate`]).
    pub fn new(model: &ErtModel, params: ErtParams) -> Result<Self> {
        model.validate()?;
        let dim = model.initial_shape.len();
        let (initial_centred, initial_norm2) = centred_mean_shape(&model.initial_shape);
        let mut cascades = Vec::with_capacity(model.forests.len());
        let (mut max_features, mut max_trees) = (0, 0);
        for ((trees, anchors), deltas) in model.forests.iter().zip(&model.anchor_idx).zip(&model.deltas) {
            let n_splits: usize = trees.iter().map(|t| t.splits.len()).sum();
            let n_leaves: usize = trees.iter().map(|t| t.leaf_values.len()).sum();
            if n_splits > u32::MAX as usize || n_leaves > u32::MAX as usize {
                return Err(Error::Model {
                    path: Default::default(),
                    reason: "cascade too large".into(),
                });
            }
            let mut c = Cascade {
                anchor2: anchors.iter().map(|&a| (a * 2) as u32).collect(),
                delta: deltas.clone(),
                split_start: Vec::with_capacity(trees.len() + 1),
                leaf_start: Vec::with_capacity(trees.len() + 1),
                idx1: Vec::with_capacity(n_splits),
                idx2: Vec::with_capacity(n_splits),
                thresh: Vec::with_capacity(n_splits),
                leaves: Vec::with_capacity(n_leaves * dim),
                uniform_splits: trees.first().map(|t| t.splits.len()),
            };
            for t in trees {
                c.split_start.push(c.idx1.len() as u32);
                c.leaf_start.push((c.leaves.len() / dim) as u32);
                if Some(t.splits.len()) != c.uniform_splits {
                    c.uniform_splits = None;
                }
                for s in &t.splits {
                    c.idx1.push(s.idx1 as u32);
                    c.idx2.push(s.idx2 as u32);
                    c.thresh.push(s.thresh);
                }
                for l in &t.leaf_values {
                    c.leaves.extend_from_slice(l);
                }
            }
            c.split_start.push(c.idx1.len() as u32);
            c.leaf_start.push((c.leaves.len() / dim) as u32);
            max_features = max_features.max(c.delta.len());
            max_trees = max_trees.max(trees.len());
            cascades.push(c);
        }
        Ok(ShapePredictor {
            params: ErtParams::default(),
            initial: model.initial_shape.clone(),
            initial_centred,
            initial_norm2,
            cascades,
            max_features,
            max_trees,
            fast: None,
        }
        .with_params(params))
    }

    /// Loads a dlib `shape_predictor` file with default parameters.
    ///
    /// # Errors
    /// [`Error::Model`] for unreadable, malformed, truncated or wrong-version files.
    pub fn from_file(path: &Path) -> Result<Self> {
        Self::new(&ErtModel::from_file(path)?, ErtParams::default())
    }

    /// Like [`ShapePredictor::from_file`], through a binary cache beside the model
    /// file (`<file>.facecap-cache`): the first call parses the model and writes the
    /// cache atomically; later calls load the flat arrays from it, several times
    /// faster, as long as it matches the model file's size and modification time and
    /// passes its checksum and structural checks (otherwise the model is parsed again
    /// and the cache rewritten). The predictor is the same either way.
    ///
    /// A model file `scripts/setup.sh` installed (or a copy of it: same name and size)
    /// must match the sha256 setup recorded ([`facecap_core::checksum`]).
    ///
    /// # Errors
    /// As [`ShapePredictor::from_file`]; also a checksum mismatch. A cache that cannot be
    /// written is not an error: [`CacheStatus::NotWritten`] says why.
    pub fn from_file_cached(path: &Path) -> Result<(Self, CacheStatus)> {
        let stamp = cache::SourceStamp::of(path);
        let cache_file = cache::cache_path(path);
        if let Some(stamp) = stamp {
            if let Ok(bytes) = std::fs::read(&cache_file) {
                if let Some(sp) = cache::decode(&bytes, stamp, ErtParams::default()) {
                    return Ok((sp, CacheStatus::Hit));
                }
            }
        }
        // The cache is written only for a model that passed these checks, so a cache hit
        // (same size and modification time) needs no second sha256 of the model file.
        facecap_core::checksum::verify_model_file(path, None)?;
        let sp = Self::from_file(path)?;
        let status = match stamp {
            None => CacheStatus::NotWritten("the model file's size and time cannot be read".into()),
            Some(stamp) => {
                let bytes = cache::encode(&sp, stamp);
                match facecap_core::atomic::write_atomic(&cache_file, |w| w.write_all(&bytes)) {
                    Ok(()) => CacheStatus::Written,
                    Err(e) => CacheStatus::NotWritten(e.to_string()),
                }
            }
        };
        Ok((sp, status))
    }

    /// Parses an in-memory dlib `shape_predictor` with default parameters.
    ///
    /// # Errors
    /// As [`ShapePredictor::from_file`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        Self::new(&ErtModel::from_bytes(bytes)?, ErtParams::default())
    }

    /// The same predictor with other parameters. Asking for [`ErtPrecision::Fast`]
    /// the first time quantises the leaves (about 0.1 s and half the exact table's
    /// memory for the 68-point model); clones share them.
    pub fn with_params(mut self, params: ErtParams) -> Self {
        if params.precision == ErtPrecision::Fast && self.fast.is_none() {
            let dim = self.initial.len();
            self.fast = Some(Arc::new(fast::FastLeaves::new(
                self.cascades.iter().map(|c| c.leaves.as_slice()),
                dim,
            )));
        }
        self.params = params;
        self
    }

    /// The parameters in use.
    pub fn params(&self) -> ErtParams {
        self.params
    }

    /// Number of landmarks predicted.
    pub fn num_parts(&self) -> usize {
        self.initial.len() / 2
    }

    /// Number of cascades.
    pub fn num_cascades(&self) -> usize {
        self.cascades.len()
    }

    /// Total number of trees over all cascades.
    pub fn num_trees(&self) -> usize {
        self.cascades.iter().map(|c| c.split_start.len() - 1).sum()
    }

    /// The mean shape in normalised box coordinates (x0 y0 x1 y1 ...).
    pub fn mean_shape(&self) -> &[f32] {
        &self.initial
    }

    /// A workspace sized for this predictor.
    pub fn new_workspace(&self) -> ErtWorkspace {
        ErtWorkspace {
            shape: vec![0.0; self.initial.len()],
            features: vec![0.0; self.max_features],
            leaf: vec![0; self.max_trees],
        }
    }

    /// Predicts the landmarks of the face in `rect`, starting from the mean shape
    /// placed in the box (dlib's `shape_predictor::operator()`).
    ///
    /// `out` receives `num_parts()` points in 0-based pixel coordinates.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when `out.len() != num_parts()`;
    /// [`Error::InvalidParameter`] for a non-finite or empty `rect`.
    pub fn predict_into(
        &self,
        image: &GrayImage,
        rect: &Rect,
        ws: &mut ErtWorkspace,
        out: &mut [Point2<f64>],
    ) -> Result<()> {
        self.check_out(out)?;
        let bt = BoxTform::new(rect)?;
        self.prepare(ws);
        ws.shape.copy_from_slice(&self.initial);
        self.run(image, &bt, ws, out);
        Ok(())
    }

    /// Like [`ShapePredictor::predict_into`] but starts the cascade from `initial`
    /// (pixel coordinates, e.g. the previous video frame's landmarks) instead of
    /// the mean shape. `rect` still defines the normalisation (use a box that fits
    /// `initial` the way detector boxes fit faces).
    ///
    /// # Errors
    /// As [`ShapePredictor::predict_into`]; also when `initial.len() != num_parts()`,
    /// when a point is not finite, or when the box is not wider/taller than 1 px.
    pub fn predict_from_shape_into(
        &self,
        image: &GrayImage,
        rect: &Rect,
        initial: &[Point2<f64>],
        ws: &mut ErtWorkspace,
        out: &mut [Point2<f64>],
    ) -> Result<()> {
        self.check_out(out)?;
        if initial.len() != self.num_parts() {
            return Err(Error::DimensionMismatch {
                what: "initial shape points".into(),
                expected: self.num_parts(),
                got: initial.len(),
            });
        }
        let bt = BoxTform::new(rect)?;
        if bt.sx <= 0.0 || bt.sy <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "rect",
                value: format!("{}x{}", rect.width, rect.height),
                expected: "width and height > 1 px".into(),
            });
        }
        if let Some(i) = initial.iter().position(|p| !p.x.is_finite() || !p.y.is_finite()) {
            return Err(Error::InvalidParameter {
                name: "initial",
                value: format!("point {i}"),
                expected: "finite coordinates".into(),
            });
        }
        self.prepare(ws);
        for (s, p) in ws.shape.chunks_exact_mut(2).zip(initial) {
            s[0] = ((p.x - bt.l) / bt.sx) as f32;
            s[1] = ((p.y - bt.t) / bt.sy) as f32;
        }
        self.run(image, &bt, ws, out);
        Ok(())
    }

    fn check_out(&self, out: &[Point2<f64>]) -> Result<()> {
        if out.len() != self.num_parts() {
            return Err(Error::DimensionMismatch {
                what: "output points".into(),
                expected: self.num_parts(),
                got: out.len(),
            });
        }
        Ok(())
    }

    /// Sizes the workspace (allocates only the first time or for another model).
    fn prepare(&self, ws: &mut ErtWorkspace) {
        if ws.shape.len() != self.initial.len() {
            ws.shape.resize(self.initial.len(), 0.0);
        }
        if ws.features.len() < self.max_features {
            ws.features.resize(self.max_features, 0.0);
        }
        if ws.leaf.len() < self.max_trees {
            ws.leaf.resize(self.max_trees, 0);
        }
    }

    /// The 2x2 similarity (row-major, f32) mapping the mean shape onto `shape`.
    ///
    /// Kept here rather than on `facecap_geom::align` on purpose: it is the closed form of
    /// dlib's `find_similarity_transform` for this cascade only (interleaved f32 shape, the
    /// mean shape centred and its norm computed once per model, no translation), and its
    /// sums run in the order that keeps the f32 result equal to dlib's, which the dlib
    /// fixtures of the ERT tests check to the bit. A change of summation order (as a
    /// general fit over `Point2<f64>` would make) moves the cascade's features, and the
    /// regression trees amplify such last-bit changes.
    fn similarity(&self, shape: &[f32]) -> [f32; 4] {
        let parts = shape.len() / 2;
        if parts == 1 || self.initial_norm2 == 0.0 {
            return [1.0, 0.0, 0.0, 1.0];
        }
        let (mut mx, mut my) = (0f64, 0f64);
        for p in shape.chunks_exact(2) {
            mx += f64::from(p[0]);
            my += f64::from(p[1]);
        }
        mx /= parts as f64;
        my /= parts as f64;
        let (mut dot, mut cross) = (0f64, 0f64);
        for (t, f) in shape.chunks_exact(2).zip(self.initial_centred.chunks_exact(2)) {
            let (tx, ty) = (f64::from(t[0]) - mx, f64::from(t[1]) - my);
            dot += f[0] * tx + f[1] * ty;
            cross += f[0] * ty - f[1] * tx;
        }
        let a = dot / self.initial_norm2;
        let b = cross / self.initial_norm2;
        [a as f32, (-b) as f32, b as f32, a as f32]
    }

    fn run(&self, image: &GrayImage, bt: &BoxTform, ws: &mut ErtWorkspace, out: &mut [Point2<f64>]) {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let pixels: &[u8] = image.as_raw();
        let dim = self.initial.len();
        let ErtWorkspace { shape, features, leaf } = ws;
        let shape = &mut shape[..dim];
        let fast = match self.params.precision {
            ErtPrecision::Fast => self.fast.as_deref(),
            ErtPrecision::Exact => None,
        };
        for (ci, c) in self.cascades.iter().enumerate() {
            let m = self.similarity(shape);
            let feats = &mut features[..c.delta.len()];
            extract_features(pixels, w, h, bt, &m, shape, &c.anchor2, &c.delta, feats);
            let n_trees = c.split_start.len() - 1;
            let leaf = &mut leaf[..n_trees];
            find_leaves(c, feats, leaf);
            match fast {
                // leaf indices count from the cascade's first leaf, like the rows
                Some(f) => f.add(ci, shape, leaf),
                None => add_leaves(shape, &c.leaves, leaf, dim),
            }
        }
        let round = self.params.output == OutputPrecision::DlibIntegerPixels;
        for (o, s) in out.iter_mut().zip(shape.chunks_exact(2)) {
            let x = bt.sx * f64::from(s[0]) + bt.l;
            let y = bt.sy * f64::from(s[1]) + bt.t;
            *o = if round {
                Point2::new((x + 0.5).floor(), (y + 0.5).floor())
            } else {
                Point2::new(x, y)
            };
        }
    }
}

/// The mean shape centred on its centroid (f64) and its squared norm.
fn centred_mean_shape(initial: &[f32]) -> (Vec<f64>, f64) {
    let parts = (initial.len() / 2).max(1);
    let mut mean = [0f64; 2];
    for p in initial.chunks_exact(2) {
        mean[0] += f64::from(p[0]);
        mean[1] += f64::from(p[1]);
    }
    mean[0] /= parts as f64;
    mean[1] /= parts as f64;
    let mut centred = Vec::with_capacity(initial.len());
    let mut norm2 = 0.0;
    for p in initial.chunks_exact(2) {
        let (x, y) = (f64::from(p[0]) - mean[0], f64::from(p[1]) - mean[1]);
        centred.push(x);
        centred.push(y);
        norm2 += x * x + y * y;
    }
    (centred, norm2)
}

/// `shape += leaves[l]` for every reached leaf `l`, in tree order.
///
/// Four leaves are added per pass over the coordinates (`x = s; x += a; x += b;
/// x += c; x += d; s = x`): per coordinate the f32 additions are the same, in the
/// same order, as adding one leaf vector after the other (dlib's loop), so the
/// sums are bit-identical, but the four rows are requested from memory together
/// and the shape stays in registers between them.
fn add_leaves(shape: &mut [f32], leaves: &[f32], leaf: &[u32], dim: usize) {
    let row = |li: u32| {
        let start = li as usize * dim;
        leaves.get(start..start + dim)
    };
    let mut groups = leaf.chunks_exact(4);
    for g in &mut groups {
        if let (Some(a), Some(b), Some(c), Some(d)) = (row(g[0]), row(g[1]), row(g[2]), row(g[3])) {
            for ((((s, a), b), c), d) in shape.iter_mut().zip(a).zip(b).zip(c).zip(d) {
                let mut x = *s;
                x += *a;
                x += *b;
                x += *c;
                x += *d;
                *s = x;
            }
        }
    }
    for &li in groups.remainder() {
        if let Some(a) = row(li) {
            for (s, a) in shape.iter_mut().zip(a) {
                *s += *a;
            }
        }
    }
}

/// Feature pixel intensities for one cascade (see step 2 of the module docs).
#[allow(clippy::too_many_arguments)]
fn extract_features(
    pixels: &[u8],
    w: usize,
    h: usize,
    bt: &BoxTform,
    m: &[f32; 4],
    shape: &[f32],
    anchor2: &[u32],
    delta: &[[f32; 2]],
    out: &mut [f32],
) {
    let (wf, hf) = (w as f64, h as f64);
    for ((o, &a), d) in out.iter_mut().zip(anchor2).zip(delta) {
        let a = a as usize;
        let (ax, ay) = match shape.get(a..a + 2) {
            Some(s) => (s[0], s[1]),
            None => (0.0, 0.0),
        };
        let qx = (m[0] * d[0] + m[1] * d[1]) + ax;
        let qy = (m[2] * d[0] + m[3] * d[1]) + ay;
        // nearest pixel `floor(v + 0.5)`: for `v + 0.5 >= 0` the truncating cast is the
        // floor, and `floor(u) >= 0 <=> u >= 0`, `floor(u) < w <=> u < w` for integer
        // `w` (NaN fails both), so this is dlib's rounding and bounds test without a
        // call to `floor`
        let x = bt.sx * f64::from(qx) + bt.l + 0.5;
        let y = bt.sy * f64::from(qy) + bt.t + 0.5;
        *o = if x >= 0.0 && x < wf && y >= 0.0 && y < hf {
            pixels.get(y as usize * w + x as usize).map_or(0.0, |&p| f32::from(p))
        } else {
            0.0
        };
    }
}

/// Leaf index (into the cascade's leaf table) reached by every tree.
fn find_leaves(c: &Cascade, feats: &[f32], leaf: &mut [u32]) {
    match c.uniform_splits {
        Some(n) if n > 0 => {
            let trees = c
                .idx1
                .chunks_exact(n)
                .zip(c.idx2.chunks_exact(n))
                .zip(c.thresh.chunks_exact(n));
            for ((l, &start), ((i1, i2), th)) in leaf.iter_mut().zip(&c.leaf_start).zip(trees) {
                let mut i = 0usize;
                while i < n {
                    let f1 = feats.get(i1[i] as usize).copied().unwrap_or(0.0);
                    let f2 = feats.get(i2[i] as usize).copied().unwrap_or(0.0);
                    i = if f1 - f2 > th[i] { 2 * i + 1 } else { 2 * i + 2 };
                }
                *l = start + (i - n) as u32;
            }
        }
        _ => {
            for (t, l) in leaf.iter_mut().enumerate() {
                let (s0, s1) = (c.split_start[t] as usize, c.split_start[t + 1] as usize);
                let n = s1 - s0;
                let (i1, i2, th) = (&c.idx1[s0..s1], &c.idx2[s0..s1], &c.thresh[s0..s1]);
                let mut i = 0usize;
                while i < n {
                    let f1 = feats.get(i1[i] as usize).copied().unwrap_or(0.0);
                    let f2 = feats.get(i2[i] as usize).copied().unwrap_or(0.0);
                    i = if f1 - f2 > th[i] { 2 * i + 1 } else { 2 * i + 2 };
                }
                *l = c.leaf_start[t] + (i - n) as u32;
            }
        }
    }
}
