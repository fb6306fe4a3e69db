//! Parser for dlib's serialised `object_detector<scan_fhog_pyramid<pyramid_down<6>>>`
//! (the file written by `dlib.get_frontal_face_detector().save(path)`).
//!
//! The layout is defined by dlib's `serialize` overloads (dlib 19.24 / 20.0 source:
//! `image_processing/object_detector.h`, `scan_fhog_pyramid.h`, `box_overlap_testing.h`,
//! `matrix/matrix.h`, `serialize.h`, `float_details.h`). We read it with our own code:
//!
//! | field | dlib type | encoding |
//! |---|---|---|
//! | detector version (= 2; 1 is also read) | `int` | packed int |
//! | scanner version (= 1) | `int` | packed int |
//! | feature extractor | `default_fhog_feature_extractor` | nothing |
//! | cached feature pyramid | `array<array<array2d<float>>>` | `max_size`, `size` (must be 0) |
//! | `cell_size` | `int` | packed int |
//! | `padding` | `unsigned long` | packed int |
//! | `window_width`, `window_height` | `unsigned long` | packed int |
//! | `max_pyramid_levels` | `unsigned long` | packed int |
//! | `min_pyramid_layer_width`, `_height` | `unsigned long` | packed int |
//! | `nuclear_norm_regularization_strength` | `double` | float details |
//! | number of dimensions (check) | `long` | packed int |
//! | overlap tester: `iou_thresh`, `percent_covered_thresh` | `double` x2 | float details |
//! | number of weight vectors `k` | `unsigned long` | packed int |
//! | `k` x weight vector `w` | `matrix<double,0,1>` | `-nr`, `-nc`, then `nr*nc` doubles |
//!
//! (version 1 stores the scanner, one `w`, then the overlap tester.)
//!
//! *Packed int*: one control byte (`0x80` = negative, low nibble = byte count 1..8), then
//! that many little-endian magnitude bytes. *Float details*: a packed `int64` mantissa
//! and a packed `int16` exponent, value = `mantissa * 2^exponent`; exponents 32000,
//! 32001, 32002 mean +inf, -inf, NaN (rejected here). Every weight vector has
//! `dims + 1` entries: the filter weights (plane-major, then row-major 31 x H x W
//! planes of the fHOG window) and the detection threshold (bias) last.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Number of fHOG feature planes (18 signed + 9 unsigned orientations + 4 texture).
pub const FHOG_PLANES: usize = 31;

/// Largest accepted window side in fHOG cells and largest weight-vector length, to
/// keep a malformed file from requesting absurd allocations.
const MAX_WINDOW_CELLS: usize = 256;
/// Largest accepted number of weight vectors (sub-detectors).
const MAX_DETECTORS: usize = 1024;

/// The contents of a dlib HOG detector file, validated.
#[derive(Debug, Clone, PartialEq)]
pub struct HogModel {
    /// fHOG cell size in pixels (8 for the frontal face detector).
    pub cell_size: usize,
    /// Padding of the fHOG window in cells (0 for the frontal face detector).
    pub padding: usize,
    /// Detection window width in pixels (80).
    pub window_width: usize,
    /// Detection window height in pixels (80).
    pub window_height: usize,
    /// Maximum number of pyramid levels (1000).
    pub max_pyramid_levels: usize,
    /// Smallest pyramid layer width in pixels (64).
    pub min_pyramid_layer_width: usize,
    /// Smallest pyramid layer height in pixels (64).
    pub min_pyramid_layer_height: usize,
    /// Training-time regulariser, kept for completeness (unused at detection time).
    pub nuclear_norm_regularization_strength: f64,
    /// Non-max suppression: boxes overlap when IoU (by bounding box) exceeds this.
    pub overlap_iou_thresh: f64,
    /// Non-max suppression: boxes overlap when one covers more than this share of the other.
    pub overlap_percent_covered_thresh: f64,
    /// fHOG window width in cells (filter width, 10).
    pub fhog_window_width: usize,
    /// fHOG window height in cells (filter height, 10).
    pub fhog_window_height: usize,
    /// One weight vector per sub-detector, `31 * H * W + 1` long (bias last).
    pub weights: Vec<Vec<f64>>,
}

impl HogModel {
    /// Number of filter weights per sub-detector (`31 * H * W`).
    pub fn num_dimensions(&self) -> usize {
        FHOG_PLANES * self.fhog_window_width * self.fhog_window_height
    }

    /// Reads and parses a model file.
    ///
    /// # Errors
    /// [`Error::Core`] (I/O) when the file cannot be read, [`Error::Model`] when it is
    /// not a valid dlib HOG detector.
    pub fn from_file(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| {
            Error::Core(facecap_core::Error::Io {
                path: path.to_path_buf(),
                source,
            })
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses the serialised bytes; `path` only labels errors.
    ///
    /// # Errors
    /// [`Error::Model`] naming the byte offset on truncation, bad versions, bad sizes,
    /// non-finite numbers or trailing bytes. Never panics.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let mut r = Reader {
            bytes,
            pos: 0,
            path: path.to_path_buf(),
        };
        let version = r.int("detector version")?;
        if version != 1 && version != 2 {
            return Err(r.err(format!(
                "unsupported object_detector version {version} (expected 1 or 2)"
            )));
        }
        let scanner = read_scanner(&mut r)?;
        let (iou, pc, weights) = if version == 2 {
            let (iou, pc) = read_overlap(&mut r)?;
            let n = r.size("number of detectors", MAX_DETECTORS)?;
            if n == 0 {
                return Err(r.err("the detector holds no weight vectors".into()));
            }
            let mut ws = Vec::with_capacity(n);
            for _ in 0..n {
                ws.push(read_weights(&mut r, scanner.dims + 1)?);
            }
            (iou, pc, ws)
        } else {
            let w = read_weights(&mut r, scanner.dims + 1)?;
            let (iou, pc) = read_overlap(&mut r)?;
            (iou, pc, vec![w])
        };
        if r.pos != bytes.len() {
            return Err(r.err(format!("{} trailing bytes after the detector", bytes.len() - r.pos)));
        }
        Ok(HogModel {
            cell_size: scanner.cell_size,
            padding: scanner.padding,
            window_width: scanner.window_width,
            window_height: scanner.window_height,
            max_pyramid_levels: scanner.max_pyramid_levels,
            min_pyramid_layer_width: scanner.min_w,
            min_pyramid_layer_height: scanner.min_h,
            nuclear_norm_regularization_strength: scanner.nuclear,
            overlap_iou_thresh: iou,
            overlap_percent_covered_thresh: pc,
            fhog_window_width: scanner.fhog_w,
            fhog_window_height: scanner.fhog_h,
            weights,
        })
    }
}

struct ScannerFields {
    cell_size: usize,
    padding: usize,
    window_width: usize,
    window_height: usize,
    max_pyramid_levels: usize,
    min_w: usize,
    min_h: usize,
    nuclear: f64,
    fhog_w: usize,
    fhog_h: usize,
    dims: usize,
}

fn read_scanner(r: &mut Reader<'_>) -> Result<ScannerFields> {
    let v = r.int("scanner version")?;
    if v != 1 {
        return Err(r.err(format!("unsupported scan_fhog_pyramid version {v} (expected 1)")));
    }
    // default_fhog_feature_extractor serialises nothing; then the cached pyramid.
    let _max_size = r.int("feature pyramid max_size")?;
    let size = r.int("feature pyramid size")?;
    if size != 0 {
        return Err(r.err(format!(
            "serialised feature pyramid with {size} levels; only empty caches are supported"
        )));
    }
    let cell_size = r.size("cell_size", 64)?;
    if cell_size == 0 {
        return Err(r.err("cell_size is 0".into()));
    }
    let padding = r.size("padding", MAX_WINDOW_CELLS)?;
    let window_width = r.size("window_width", MAX_WINDOW_CELLS * 64)?;
    let window_height = r.size("window_height", MAX_WINDOW_CELLS * 64)?;
    if window_width == 0 || window_height == 0 {
        return Err(r.err("zero detection window size".into()));
    }
    let max_pyramid_levels = r.size("max_pyramid_levels", usize::MAX)?;
    if max_pyramid_levels == 0 {
        return Err(r.err("max_pyramid_levels is 0".into()));
    }
    let min_w = r.size("min_pyramid_layer_width", usize::MAX)?;
    let min_h = r.size("min_pyramid_layer_height", usize::MAX)?;
    let nuclear = r.f64("nuclear_norm_regularization_strength")?;
    let (fhog_w, fhog_h) = fhog_window_size(window_width, window_height, cell_size, padding);
    if fhog_w == 0 || fhog_h == 0 || fhog_w > MAX_WINDOW_CELLS || fhog_h > MAX_WINDOW_CELLS {
        return Err(r.err(format!("fHOG window of {fhog_w} x {fhog_h} cells is out of range")));
    }
    let dims = FHOG_PLANES * fhog_w * fhog_h;
    let stored = r.int("number of dimensions")?;
    if stored != dims as i64 {
        return Err(r.err(format!(
            "stored dimension count {stored} != 31 x {fhog_h} x {fhog_w} = {dims}"
        )));
    }
    Ok(ScannerFields {
        cell_size,
        padding,
        window_width,
        window_height,
        max_pyramid_levels,
        min_w,
        min_h,
        nuclear,
        fhog_w,
        fhog_h,
        dims,
    })
}

fn read_overlap(r: &mut Reader<'_>) -> Result<(f64, f64)> {
    let iou = r.f64("overlap iou_thresh")?;
    let pc = r.f64("overlap percent_covered_thresh")?;
    for (name, v) in [("iou_thresh", iou), ("percent_covered_thresh", pc)] {
        if !(0.0..=1.0).contains(&v) {
            return Err(r.err(format!("overlap tester {name} = {v} outside [0, 1]")));
        }
    }
    Ok((iou, pc))
}

fn read_weights(r: &mut Reader<'_>, expected: usize) -> Result<Vec<f64>> {
    let nr = r.int("weight rows")?.unsigned_abs();
    let nc = r.int("weight cols")?.unsigned_abs();
    if nc != 1 || nr != expected as u64 {
        return Err(r.err(format!("weight vector is {nr} x {nc}, expected {expected} x 1")));
    }
    let mut w = Vec::with_capacity(expected);
    for _ in 0..expected {
        w.push(r.f64("weight")?);
    }
    Ok(w)
}

/// fHOG window size in cells, as dlib's `scan_fhog_pyramid::compute_fhog_window_size`:
/// the detection window centred on the origin mapped by `image_to_fhog`, grown by the
/// padding.
pub(crate) fn fhog_window_size(window_w: usize, window_h: usize, cell: usize, padding: usize) -> (usize, usize) {
    let (w, h, cell, pad) = (window_w as i64, window_h as i64, cell as i64, padding as i64);
    // centered_rect(point(0,0), w, h)
    let l = -(w / 2);
    let t = -(h / 2);
    let r = l + w - 1;
    let b = t + h - 1;
    // image_to_fhog with paddings 1: p -= (1,1); p / cell - (1,1)  (C++ truncating division)
    let map = |v: i64| (v - 1) / cell - 1;
    let (l, t, r, b) = (map(l) - pad, map(t) - pad, map(r) + pad, map(b) + pad);
    ((r - l + 1).max(0) as usize, (b - t + 1).max(0) as usize)
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: PathBuf,
}

impl Reader<'_> {
    fn err(&self, reason: String) -> Error {
        Error::Model {
            path: self.path.clone(),
            reason: format!("{reason} (at byte {})", self.pos),
        }
    }

    /// dlib's packed signed integer (also used for unsigned values, which never set
    /// the sign bit).
    fn int(&mut self, what: &str) -> Result<i64> {
        let Some(&ctrl) = self.bytes.get(self.pos) else {
            return Err(self.err(format!("truncated file: missing {what}")));
        };
        if ctrl & 0x70 != 0 {
            return Err(self.err(format!("bad integer control byte {ctrl:#04x} for {what}")));
        }
        let n = usize::from(ctrl & 0x0f);
        if n == 0 || n > 8 {
            return Err(self.err(format!("bad integer length {n} for {what}")));
        }
        let Some(body) = self.bytes.get(self.pos + 1..self.pos + 1 + n) else {
            return Err(self.err(format!("truncated file inside {what}")));
        };
        let mut mag: u64 = 0;
        for &b in body.iter().rev() {
            mag = (mag << 8) | u64::from(b);
        }
        if mag > i64::MAX as u64 {
            return Err(self.err(format!("{what} does not fit a signed 64-bit integer")));
        }
        self.pos += 1 + n;
        let v = mag as i64;
        Ok(if ctrl & 0x80 != 0 { -v } else { v })
    }

    fn size(&mut self, what: &str, max: usize) -> Result<usize> {
        let start = self.pos;
        let v = self.int(what)?;
        if v < 0 || (v as u64) > max as u64 {
            self.pos = start;
            return Err(self.err(format!("{what} = {v} out of range 0..={max}")));
        }
        Ok(v as usize)
    }

    /// dlib's `float_details` encoding; non-finite values are rejected.
    fn f64(&mut self, what: &str) -> Result<f64> {
        let start = self.pos;
        let mantissa = self.int(what)?;
        let exponent = self.int(what)?;
        if !(i64::from(i16::MIN)..=i64::from(i16::MAX)).contains(&exponent) {
            self.pos = start;
            return Err(self.err(format!("{what}: exponent {exponent} out of the int16 range")));
        }
        if exponent >= 32000 {
            self.pos = start;
            return Err(self.err(format!("{what} is not finite")));
        }
        let v = ldexp(mantissa as f64, exponent as i32);
        if !v.is_finite() {
            self.pos = start;
            return Err(self.err(format!("{what} overflows a double")));
        }
        Ok(v)
    }
}

/// `x * 2^e` without intermediate overflow for the exponents dlib writes.
fn ldexp(x: f64, e: i32) -> f64 {
    let mut x = x;
    let mut e = e;
    while e > 1000 {
        x *= 2f64.powi(1000);
        e -= 1000;
    }
    while e < -1000 {
        x *= 2f64.powi(-1000);
        e += 1000;
    }
    x * 2f64.powi(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fhog_window_of_frontal_detector_is_10_cells() {
        assert_eq!(fhog_window_size(80, 80, 8, 0), (10, 10));
        assert_eq!(fhog_window_size(80, 80, 8, 1), (12, 12));
    }

    #[test]
    fn packed_ints_and_floats_decode() {
        // 2, -3101, 9.0 = 18 * 2^-1
        let bytes = [0x01, 0x02, 0x82, 0x1d, 0x0c, 0x01, 0x12, 0x81, 0x01];
        let mut r = Reader {
            bytes: &bytes,
            pos: 0,
            path: PathBuf::new(),
        };
        assert_eq!(r.int("a").ok(), Some(2));
        assert_eq!(r.int("b").ok(), Some(-3101));
        assert_eq!(r.f64("c").ok(), Some(9.0));
        assert!(r.int("d").is_err());
    }
}
