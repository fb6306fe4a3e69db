//! A binary cache of a built [`ShapePredictor`], so a model file is parsed once.
//!
//! dlib's format stores every float as a variable-length (mantissa, exponent)
//! pair; the 68-point model's 16 M leaf values take ~0.4 s to read, parse and lay
//! out flat. The cache holds the flat arrays as little-endian bytes (`65 MB` for the
//! 68-point model) and loads in a fraction of that. It sits beside the model file
//! (`<model file>.facecap-cache`), is written atomically (temporary file and
//! rename), and is used only when it names the model file's exact size and
//! modification time, carries this format's version, passes its checksum and
//! every structural check the predictor relies on; otherwise the model file is
//! parsed again and the cache rewritten. A cache that cannot be written (read-only
//! folder) only costs the parse.
//!
//! Layout (all little endian): magic `FCERTC01`; `u64` model size, `i64` model
//! mtime seconds, `u32` nanoseconds; `u32` dim, `u32` cascades, `u32` max features,
//! `u32` max trees; `dim` f32 mean shape; per cascade the [`super::Cascade`] arrays,
//! each as `u64` length then values; trailer `u64` checksum of everything before.

use std::path::{Path, PathBuf};

use super::{centred_mean_shape, Cascade, ErtParams, ShapePredictor};

const MAGIC: &[u8; 8] = b"FCERTC01";

/// What [`ShapePredictor::from_file_cached`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CacheStatus {
    /// Loaded from a valid cache.
    Hit,
    /// Parsed the model and wrote a new cache (none was there, or it was stale or
    /// damaged).
    Written,
    /// Parsed the model; the cache could not be written (the reason).
    NotWritten(String),
}

/// Identity of the model file the cache was made from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct SourceStamp {
    len: u64,
    secs: i64,
    nanos: u32,
}

impl SourceStamp {
    pub(super) fn of(path: &Path) -> Option<Self> {
        let meta = std::fs::metadata(path).ok()?;
        let mtime = meta.modified().ok()?;
        let (secs, nanos) = match mtime.duration_since(std::time::UNIX_EPOCH) {
            Ok(d) => (i64::try_from(d.as_secs()).ok()?, d.subsec_nanos()),
            Err(e) => (
                -i64::try_from(e.duration().as_secs()).ok()?,
                e.duration().subsec_nanos(),
            ),
        };
        Some(SourceStamp {
            len: meta.len(),
            secs,
            nanos,
        })
    }
}

/// Where the cache of `model` lives.
pub(super) fn cache_path(model: &Path) -> PathBuf {
    let mut name = model.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(".facecap-cache");
    model.with_file_name(name)
}

/// A 64-bit checksum (FNV-style multiply-xor over 8-byte words, then the tail).
fn checksum(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        let mut b = [0u8; 8];
        b.copy_from_slice(w);
        h = (h ^ u64::from_le_bytes(b))
            .wrapping_mul(0x0000_0100_0000_01b3)
            .rotate_left(29);
    }
    for &b in words.remainder() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

struct Out(Vec<u8>);

impl Out {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
}

/// Serialises a predictor for the model file stamped `stamp`.
pub(super) fn encode(sp: &ShapePredictor, stamp: SourceStamp) -> Vec<u8> {
    let mut o = Out(Vec::new());
    o.0.extend_from_slice(MAGIC);
    o.u64(stamp.len);
    o.u64(stamp.secs as u64);
    o.u32(stamp.nanos);
    o.u32(sp.initial.len() as u32);
    o.u32(sp.cascades.len() as u32);
    o.u32(sp.max_features as u32);
    o.u32(sp.max_trees as u32);
    o.f32s(&sp.initial);
    for c in &sp.cascades {
        o.u32s(&c.anchor2);
        let flat: Vec<f32> = c.delta.iter().flatten().copied().collect();
        o.f32s(&flat);
        o.u32s(&c.split_start);
        o.u32s(&c.leaf_start);
        o.u32s(&c.idx1);
        o.u32s(&c.idx2);
        o.f32s(&c.thresh);
        o.f32s(&c.leaves);
        o.u64(c.uniform_splits.map_or(u64::MAX, |n| n as u64));
    }
    let sum = checksum(&o.0);
    o.u64(sum);
    o.0
}

struct In<'a> {
    b: &'a [u8],
    pos: usize,
}

impl In<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.b.get(self.pos..self.pos.checked_add(n)?)?;
        self.pos += n;
        Some(s)
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn len(&mut self) -> Option<usize> {
        usize::try_from(self.u64()?).ok()
    }
    fn u32s(&mut self) -> Option<Vec<u32>> {
        let n = self.len()?;
        let raw = self.take(n.checked_mul(4)?)?;
        Some(
            raw.chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }
    fn f32s(&mut self) -> Option<Vec<f32>> {
        let n = self.len()?;
        let raw = self.take(n.checked_mul(4)?)?;
        Some(
            raw.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }
}

/// The predictor in `bytes` when they are a valid, matching cache; `None` otherwise.
pub(super) fn decode(bytes: &[u8], stamp: SourceStamp, params: ErtParams) -> Option<ShapePredictor> {
    let body_len = bytes.len().checked_sub(8)?;
    let (body, trailer) = bytes.split_at(body_len);
    if u64::from_le_bytes(trailer.try_into().ok()?) != checksum(body) {
        return None;
    }
    let mut r = In { b: body, pos: 0 };
    if r.take(8)? != MAGIC {
        return None;
    }
    let found = SourceStamp {
        len: r.u64()?,
        secs: r.u64()? as i64,
        nanos: r.u32()?,
    };
    if found != stamp {
        return None;
    }
    let dim = r.u32()? as usize;
    let n_cascades = r.u32()? as usize;
    let max_features = r.u32()? as usize;
    let max_trees = r.u32()? as usize;
    let initial = r.f32s()?;
    if initial.len() != dim || dim == 0 || dim % 2 != 0 || initial.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut cascades = Vec::with_capacity(n_cascades.min(1024));
    for _ in 0..n_cascades {
        let anchor2 = r.u32s()?;
        let flat = r.f32s()?;
        let delta: Vec<[f32; 2]> = flat.chunks_exact(2).map(|d| [d[0], d[1]]).collect();
        let c = Cascade {
            anchor2,
            delta,
            split_start: r.u32s()?,
            leaf_start: r.u32s()?,
            idx1: r.u32s()?,
            idx2: r.u32s()?,
            thresh: r.f32s()?,
            leaves: r.f32s()?,
            uniform_splits: match r.u64()? {
                u64::MAX => None,
                n => Some(usize::try_from(n).ok()?),
            },
        };
        if flat.len() != 2 * c.anchor2.len() || !cascade_is_consistent(&c, dim, max_features, max_trees) {
            return None;
        }
        cascades.push(c);
    }
    if r.pos != body.len() {
        return None;
    }
    let (initial_centred, initial_norm2) = centred_mean_shape(&initial);
    Some(
        ShapePredictor {
            params,
            initial,
            initial_centred,
            initial_norm2,
            cascades,
            max_features,
            max_trees,
            fast: None,
        }
        .with_params(params),
    )
}

/// Every invariant inference relies on (the same ones [`super::ErtModel::validate`]
/// and [`ShapePredictor::new`] establish).
fn cascade_is_consistent(c: &Cascade, dim: usize, max_features: usize, max_trees: usize) -> bool {
    let n_feat = c.anchor2.len();
    let n_splits = c.idx1.len();
    let n_trees = c.split_start.len().saturating_sub(1);
    if n_feat > max_features
        || n_trees > max_trees
        || c.split_start.is_empty()
        || c.leaf_start.len() != c.split_start.len()
        || c.idx2.len() != n_splits
        || c.thresh.len() != n_splits
        || c.delta.iter().any(|d| !d[0].is_finite() || !d[1].is_finite())
        || c.anchor2.iter().any(|&a| a % 2 != 0 || a as usize + 1 >= dim)
        || c.idx1.iter().chain(&c.idx2).any(|&i| i as usize >= n_feat)
        || c.leaves.len() % dim != 0
    {
        return false;
    }
    if c.split_start.first() != Some(&0) || c.leaf_start.first() != Some(&0) {
        return false;
    }
    for t in 0..n_trees {
        let (s0, s1) = (c.split_start[t] as usize, c.split_start[t + 1] as usize);
        let (l0, l1) = (c.leaf_start[t] as usize, c.leaf_start[t + 1] as usize);
        if s1 < s0 || l1 < l0 || l1 - l0 != s1 - s0 + 1 {
            return false;
        }
        if let Some(n) = c.uniform_splits {
            if s1 - s0 != n {
                return false;
            }
        }
    }
    c.split_start.last().is_some_and(|&s| s as usize == n_splits)
        && c.leaf_start.last().is_some_and(|&l| l as usize * dim == c.leaves.len())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;
    use crate::ert::{ErtModel, RegressionTree, SplitFeature};
    use facecap_core::landmarks::Rect;
    use nalgebra::Point2;

    fn model() -> ErtModel {
        let parts = 5;
        let mut x = 7u32;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let initial_shape: Vec<f32> = (0..2 * parts).map(|i| 0.2 + 0.06 * i as f32).collect();
        let forests = (0..3)
            .map(|_| {
                (0..4)
                    .map(|_| RegressionTree {
                        splits: (0..3)
                            .map(|_| SplitFeature {
                                idx1: u64::from(next() % 10),
                                idx2: u64::from(next() % 10),
                                thresh: (next() % 40) as f32 - 20.0,
                            })
                            .collect(),
                        leaf_values: (0..4)
                            .map(|_| (0..2 * parts).map(|_| (next() % 100) as f32 * 1e-3 - 0.05).collect())
                            .collect(),
                    })
                    .collect()
            })
            .collect();
        let anchor_idx = (0..3)
            .map(|_| (0..10).map(|_| u64::from(next() % 5)).collect())
            .collect();
        let deltas = (0..3)
            .map(|_| (0..10).map(|_| [(next() % 20) as f32 * 0.01 - 0.1, 0.05]).collect())
            .collect();
        ErtModel {
            initial_shape,
            forests,
            anchor_idx,
            deltas,
        }
    }

    fn image() -> image::GrayImage {
        image::GrayImage::from_fn(64, 48, |x, y| image::Luma([((x * 7 + y * 13) % 251) as u8]))
    }

    /// The test model, a stamp and its cache bytes.
    fn encoded() -> (ShapePredictor, SourceStamp, Vec<u8>) {
        let sp = ShapePredictor::new(&model(), ErtParams::default()).unwrap();
        let stamp = SourceStamp {
            len: 10,
            secs: 3,
            nanos: 4,
        };
        let bytes = encode(&sp, stamp);
        (sp, stamp, bytes)
    }

    #[test]
    fn round_trip_predicts_the_same() {
        let (sp, stamp, bytes) = encoded();
        let back = decode(&bytes, stamp, ErtParams::default()).unwrap();
        let other = SourceStamp { nanos: 5, ..stamp };
        assert!(
            decode(&bytes, other, ErtParams::default()).is_none(),
            "stale stamp accepted"
        );
        let img = image();
        let rect = Rect::from_dlib(5, 4, 50, 40);
        let (mut a, mut b) = (vec![Point2::origin(); 5], vec![Point2::origin(); 5]);
        let mut ws = sp.new_workspace();
        sp.predict_into(&img, &rect, &mut ws, &mut a).unwrap();
        back.predict_into(&img, &rect, &mut ws, &mut b).unwrap();
        assert_eq!(a, b);
        for cut in 0..bytes.len() {
            assert!(
                decode(&bytes[..cut], stamp, ErtParams::default()).is_none(),
                "cut at {cut}"
            );
        }
    }

    /// Damaged caches whose checksum was made to match (a crafted file) are
    /// rejected or, when structurally valid, predict without panicking.
    #[test]
    fn crafted_caches_never_panic() {
        let (_, stamp, bytes) = encoded();
        let body = bytes.len() - 8;
        let img = image();
        let rect = Rect::from_dlib(5, 4, 50, 40);
        let mut out = vec![Point2::origin(); 5];
        let mut x = 99u32;
        let mut accepted = 0;
        for i in 0..4000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let mut b = bytes.clone();
            let at = 8 + (x as usize % (body - 8));
            b[at] = if i % 3 == 0 { 0xFF } else { b[at] ^ (1 << (x % 8)) };
            let sum = checksum(&b[..body]);
            b[body..].copy_from_slice(&sum.to_le_bytes());
            if let Some(p) = decode(&b, stamp, ErtParams::default()) {
                accepted += 1;
                let mut ws = p.new_workspace();
                if p.num_parts() == out.len() {
                    let _ = p.predict_into(&img, &rect, &mut ws, &mut out);
                }
            }
        }
        // flips in float values keep the structure valid, so some are accepted
        assert!(accepted > 0);
    }
}
