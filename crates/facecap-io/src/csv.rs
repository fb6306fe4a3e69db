//! Per-frame CSV output (and input, for tests and evaluation).
//!
//! One header line, then one row per frame:
//!
//! ```text
//! frame,timestamp,success,confidence,<named columns...>
//! ```
//!
//! | column | type | meaning |
//! |---|---|---|
//! | `frame` | integer >= 0 | 0-based frame index in the source |
//! | `timestamp` | seconds, finite, >= 0 | presentation time of the frame |
//! | `success` | `0` or `1` | whether the pipeline produced a result for this frame |
//! | `confidence` | finite number | pipeline confidence (usually 0..1) |
//! | named columns | finite number or `nan` | e.g. landmarks, pose, blendshape weights |
//!
//! Column groups used across facecap (build the list with these helpers):
//! * landmarks: [`landmark_columns`] = `x_0..x_67,y_0..y_67` (OpenFace order: all
//!   x, then all y; 0-based pixels, centre of the top-left pixel = (0, 0));
//! * face mesh: [`mesh_columns`] = `x_0,y_0,z_0,x_1,y_1,z_1,...,z_477` (the 478 points of
//!   the face mesh front end, point by point; x and y as the landmarks, z the model's
//!   relative depth in the same pixel scale as x, negative towards the camera); read with
//!   [`read_mesh_csv`], which checks that exactly the 478 points are there;
//! * head pose: [`POSE_COLUMNS`] = `pose_Tx,pose_Ty,pose_Tz,pose_Rx,pose_Ry,pose_Rz`;
//! * blendshape weights / other named values: [`named_columns`] (names used verbatim).
//!
//! Numbers are written with Rust's shortest round-trip representation (`{}` of
//! `f64`, never an exponent), so reading back gives bit-identical values. Missing
//! values (e.g. landmarks of a failed frame) are written as `nan`. The file is
//! written through an [`AtomicFile`]: it appears at its path only when
//! [`FrameCsvWriter::finish`] succeeds. `write_row` formats into a reused buffer and
//! does not allocate once the first row has been written.
//!
//! ```
//! use facecap_io::csv::{landmark_columns, landmark_values, read_landmarks_csv, FrameCsvWriter, FrameRow};
//! use facecap_core::landmarks::Landmarks68;
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("landmarks.csv");
//! let mut w = FrameCsvWriter::create(&path, &landmark_columns()).unwrap();
//! let lm = Landmarks68::from_fn(|i| (i as f64, 2.0 * i as f64));
//! let mut values = [0.0; 136];
//! for frame in 0..3u64 {
//!     let ok = frame != 1;
//!     landmark_values(ok.then_some(&lm), &mut values);
//!     let row = FrameRow { frame, timestamp: frame as f64 / 30.0, success: ok, confidence: 0.9, values: &values };
//!     w.write_row(&row).unwrap();
//! }
//! w.finish().unwrap();
//! let back = read_landmarks_csv(&path).unwrap();
//! assert_eq!(back[0].landmarks.as_ref(), Some(&lm));
//! assert!(back[1].landmarks.is_none());
//! ```

use std::collections::HashSet;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use facecap_core::atomic::AtomicFile;
use facecap_core::error::{Error, Result};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};

const FORMAT: &str = "per-frame CSV";

/// The four columns every facecap CSV starts with.
pub const FIXED_COLUMNS: [&str; 4] = ["frame", "timestamp", "success", "confidence"];

/// Head-pose columns (translation in the camera frame, then rotation as an
/// axis-angle/Euler triple as documented by the writer that fills them).
pub const POSE_COLUMNS: [&str; 6] = ["pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz"];

/// `x_0..x_67` then `y_0..y_67` (OpenFace style).
pub fn landmark_columns() -> Vec<String> {
    (0..NUM_LANDMARKS)
        .map(|i| format!("x_{i}"))
        .chain((0..NUM_LANDMARKS).map(|i| format!("y_{i}")))
        .collect()
}

/// Points of the face mesh layout ([`mesh_columns`]): MediaPipe's 468 face points and
/// 10 iris points (468 and 473 are the iris centres).
pub const MESH_POINTS: usize = 478;

/// `x_i,y_i,z_i` for each mesh point `i = 0..478`, point by point.
pub fn mesh_columns() -> Vec<String> {
    (0..MESH_POINTS)
        .flat_map(|i| [format!("x_{i}"), format!("y_{i}"), format!("z_{i}")])
        .collect()
}

/// Column names from arbitrary names (e.g. blendshape names), checked with
/// [`validate_columns`].
///
/// # Errors
/// As [`validate_columns`].
pub fn named_columns<S: AsRef<str>>(names: &[S]) -> Result<Vec<String>> {
    let cols: Vec<String> = names.iter().map(|s| s.as_ref().to_owned()).collect();
    validate_columns(&cols)?;
    Ok(cols)
}

/// Checks value-column names: non-empty, no `,` `"` or line breaks, no leading or
/// trailing whitespace, unique, and not one of [`FIXED_COLUMNS`].
///
/// # Errors
/// [`Error::InvalidParameter`] naming the offending column.
pub fn validate_columns<S: AsRef<str>>(columns: &[S]) -> Result<()> {
    let mut seen = HashSet::new();
    for c in columns {
        let c = c.as_ref();
        if c.is_empty() || c.trim() != c || c.contains([',', '"', '\n', '\r']) {
            return Err(Error::invalid(
                "CSV column name",
                format!("{c:?}"),
                "a non-empty name without commas, quotes, line breaks or surrounding spaces",
            ));
        }
        if FIXED_COLUMNS.contains(&c) {
            return Err(Error::invalid(
                "CSV column name",
                c,
                "a name other than frame/timestamp/success/confidence",
            ));
        }
        if !seen.insert(c) {
            return Err(Error::invalid("CSV column name", c, "unique column names"));
        }
    }
    Ok(())
}

/// One row to write.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameRow<'a> {
    /// 0-based frame index.
    pub frame: u64,
    /// Presentation time in seconds (finite, >= 0).
    pub timestamp: f64,
    /// Whether this frame produced a result.
    pub success: bool,
    /// Confidence (finite).
    pub confidence: f64,
    /// One value per named column (finite or NaN).
    pub values: &'a [f64],
}

/// Writes a per-frame CSV atomically; see the module docs.
#[derive(Debug)]
pub struct FrameCsvWriter {
    file: AtomicFile,
    path: PathBuf,
    columns: Vec<String>,
    line: String,
    rows: u64,
}

impl FrameCsvWriter {
    /// Starts a CSV at `path` with the fixed columns followed by `columns`, and
    /// writes the header.
    ///
    /// # Errors
    /// As [`validate_columns`] and [`AtomicFile::create`].
    pub fn create<S: AsRef<str>>(path: impl AsRef<Path>, columns: &[S]) -> Result<Self> {
        validate_columns(columns)?;
        let path = path.as_ref().to_path_buf();
        let mut file = AtomicFile::create(&path)?;
        let columns: Vec<String> = columns.iter().map(|c| c.as_ref().to_owned()).collect();
        let mut header = FIXED_COLUMNS.join(",");
        for c in &columns {
            header.push(',');
            header.push_str(c);
        }
        header.push('\n');
        file.write_all(header.as_bytes()).map_err(|e| Error::io(&path, e))?;
        let line = String::with_capacity(header.len() + 24 * (columns.len() + 4));
        Ok(FrameCsvWriter {
            file,
            path,
            columns,
            line,
            rows: 0,
        })
    }

    /// The value columns (without the fixed four).
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// Rows written so far.
    pub fn rows_written(&self) -> u64 {
        self.rows
    }

    /// Appends one row.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when `row.values` does not have one value per
    /// column; [`Error::InvalidParameter`] for a non-finite or negative timestamp, a
    /// non-finite confidence or an infinite value; [`Error::Io`] on write failure.
    pub fn write_row(&mut self, row: &FrameRow) -> Result<()> {
        if row.values.len() != self.columns.len() {
            return Err(Error::DimensionMismatch {
                what: format!("CSV values in row for frame {}", row.frame),
                expected: self.columns.len(),
                got: row.values.len(),
            });
        }
        if !row.timestamp.is_finite() || row.timestamp < 0.0 {
            return Err(Error::invalid(
                "timestamp",
                format!("{} at frame {}", row.timestamp, row.frame),
                "finite seconds >= 0",
            ));
        }
        if !row.confidence.is_finite() {
            return Err(Error::invalid(
                "confidence",
                format!("{} at frame {}", row.confidence, row.frame),
                "a finite number",
            ));
        }
        if let Some(i) = row.values.iter().position(|v| v.is_infinite()) {
            return Err(Error::invalid(
                "CSV value",
                format!("{} = {} at frame {}", self.columns[i], row.values[i], row.frame),
                "a finite number or NaN",
            ));
        }
        self.line.clear();
        // Writing into a String cannot fail.
        let _ = write!(
            self.line,
            "{},{},{},{}",
            row.frame,
            row.timestamp,
            u8::from(row.success),
            row.confidence
        );
        for &v in row.values {
            if v.is_nan() {
                self.line.push_str(",nan");
            } else {
                let _ = write!(self.line, ",{v}");
            }
        }
        self.line.push('\n');
        self.file
            .write_all(self.line.as_bytes())
            .map_err(|e| Error::io(&self.path, e))?;
        self.rows += 1;
        Ok(())
    }

    /// Flushes, syncs and publishes the file at its path.
    ///
    /// # Errors
    /// [`Error::Io`]; on error nothing is published.
    pub fn finish(self) -> Result<()> {
        self.file.commit()
    }
}

/// One parsed row.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    /// Frame index.
    pub frame: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Success flag.
    pub success: bool,
    /// Confidence.
    pub confidence: f64,
    /// One value per value column (NaN where the file says `nan`).
    pub values: Vec<f64>,
}

/// A whole per-frame CSV.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameTable {
    /// Value column names (the fixed four are not repeated here).
    pub columns: Vec<String>,
    /// Rows in file order.
    pub rows: Vec<FrameRecord>,
}

impl FrameTable {
    /// Index of a value column by name.
    pub fn column_index(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// All values of a column, or `None` if there is no such column.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let i = self.column_index(name)?;
        Some(self.rows.iter().map(|r| r.values[i]).collect())
    }
}

/// One row of a landmark CSV.
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkRecord {
    /// Frame index.
    pub frame: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Success flag.
    pub success: bool,
    /// Confidence.
    pub confidence: f64,
    /// The 68 landmarks; `None` for rows with `success = 0`.
    pub landmarks: Option<Landmarks68>,
}

/// One row of a face mesh CSV ([`mesh_columns`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshRecord {
    /// Frame index.
    pub frame: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Success flag.
    pub success: bool,
    /// Confidence.
    pub confidence: f64,
    /// The [`MESH_POINTS`] points `[x, y, z]`; `None` for rows with `success = 0`.
    pub points: Option<Vec<[f32; 3]>>,
}

/// Reads a per-frame CSV written by [`FrameCsvWriter`] (or any CSV with the same
/// header convention; spaces around fields and `\r\n` line ends are accepted).
///
/// # Errors
/// [`Error::Io`]; [`Error::Parse`] naming the 1-based line for: a header not
/// starting with `frame,timestamp,success,confidence`, bad column names, a row with
/// the wrong number of fields, unparsable numbers, non-finite or negative
/// timestamps, non-finite confidences, a `success` other than 0/1, infinite values,
/// or a last line without a line end (a truncated file).
pub fn read_frame_csv(path: impl AsRef<Path>) -> Result<FrameTable> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_frame_csv(&bytes).map_err(|e| e.at_path(path))
}

fn perr(line: usize, reason: impl std::fmt::Display) -> Error {
    Error::parse(FORMAT, "", format!("line {line}: {reason}"))
}

/// In-memory version of [`read_frame_csv`] (errors carry an empty path).
///
/// # Errors
/// As [`read_frame_csv`].
pub fn parse_frame_csv(bytes: &[u8]) -> Result<FrameTable> {
    let text = std::str::from_utf8(bytes).map_err(|e| Error::parse(FORMAT, "", format!("not UTF-8: {e}")))?;
    if text.is_empty() {
        return Err(perr(1, "empty file (no header)"));
    }
    let ends_with_newline = text.ends_with('\n');
    let lines: Vec<&str> = text.split_terminator('\n').collect();
    if !ends_with_newline {
        return Err(perr(lines.len(), "last line has no line end (truncated file?)"));
    }
    let header: Vec<&str> = lines[0].trim_end_matches('\r').split(',').map(str::trim).collect();
    if header.len() < FIXED_COLUMNS.len() || header[..4] != FIXED_COLUMNS {
        return Err(perr(
            1,
            format!(
                "header must start with {}, found {:?}",
                FIXED_COLUMNS.join(","),
                lines[0]
            ),
        ));
    }
    let columns: Vec<String> = header[4..].iter().map(|s| (*s).to_owned()).collect();
    validate_columns(&columns).map_err(|e| perr(1, e))?;
    let mut rows = Vec::with_capacity(lines.len().saturating_sub(1));
    for (k, raw) in lines.iter().enumerate().skip(1) {
        let ln = k + 1;
        let raw = raw.trim_end_matches('\r');
        let fields: Vec<&str> = raw.split(',').map(str::trim).collect();
        if fields.len() != header.len() {
            return Err(perr(
                ln,
                format!("expected {} fields, found {}", header.len(), fields.len()),
            ));
        }
        let num = |i: usize| -> Result<f64> {
            fields[i]
                .parse::<f64>()
                .map_err(|_| perr(ln, format!("column {}: {:?} is not a number", header[i], fields[i])))
        };
        let frame: u64 = fields[0]
            .parse()
            .map_err(|_| perr(ln, format!("frame {:?} is not a non-negative integer", fields[0])))?;
        let timestamp = num(1)?;
        if !timestamp.is_finite() || timestamp < 0.0 {
            return Err(perr(ln, format!("timestamp {timestamp} is not finite seconds >= 0")));
        }
        let success = match fields[2] {
            "0" => false,
            "1" => true,
            other => return Err(perr(ln, format!("success {other:?} is not 0 or 1"))),
        };
        let confidence = num(3)?;
        if !confidence.is_finite() {
            return Err(perr(ln, format!("confidence {confidence} is not finite")));
        }
        let mut values = Vec::with_capacity(columns.len());
        for (name, field) in header.iter().zip(&fields).skip(4) {
            let v: f64 = field
                .parse()
                .map_err(|_| perr(ln, format!("column {name}: {field:?} is not a number")))?;
            if v.is_infinite() {
                return Err(perr(ln, format!("column {name}: infinite value")));
            }
            values.push(v);
        }
        rows.push(FrameRecord {
            frame,
            timestamp,
            success,
            confidence,
            values,
        });
    }
    Ok(FrameTable { columns, rows })
}

/// Reads the landmark columns (`x_0..x_67`, `y_0..y_67`, anywhere among the value
/// columns) of a per-frame CSV. Rows with `success = 1` must have 68 finite points;
/// rows with `success = 0` give `None`.
///
/// # Errors
/// As [`read_frame_csv`]; also [`Error::Parse`] when a landmark column is missing
/// or a successful row has a NaN landmark (naming the line).
pub fn read_landmarks_csv(path: impl AsRef<Path>) -> Result<Vec<LandmarkRecord>> {
    let path = path.as_ref();
    let table = read_frame_csv(path)?;
    landmarks_from_table(&table).map_err(|e| e.at_path(path))
}

/// Extracts landmarks from a parsed table (see [`read_landmarks_csv`]).
///
/// # Errors
/// As [`read_landmarks_csv`] (errors carry an empty path).
pub fn landmarks_from_table(table: &FrameTable) -> Result<Vec<LandmarkRecord>> {
    if table.column_index(&format!("x_{NUM_LANDMARKS}")).is_some() || table.column_index("z_0").is_some() {
        return Err(Error::parse(
            FORMAT,
            "",
            format!(
                "a face mesh CSV (column x_{NUM_LANDMARKS} or z_0), not the 68-point landmark layout; \
                 its x_0..y_67 are mesh points, not iBUG points"
            ),
        ));
    }
    let names = landmark_columns();
    let idx: Vec<usize> = names
        .iter()
        .map(|n| {
            table
                .column_index(n)
                .ok_or_else(|| Error::parse(FORMAT, "", format!("landmark column {n} missing")))
        })
        .collect::<Result<_>>()?;
    table
        .rows
        .iter()
        .enumerate()
        .map(|(r, row)| {
            let landmarks = if row.success {
                let xy: Vec<(f64, f64)> = (0..NUM_LANDMARKS)
                    .map(|i| (row.values[idx[i]], row.values[idx[NUM_LANDMARKS + i]]))
                    .collect();
                Some(Landmarks68::from_slice(&xy).map_err(|e| perr(r + 2, e))?)
            } else {
                None
            };
            Ok(LandmarkRecord {
                frame: row.frame,
                timestamp: row.timestamp,
                success: row.success,
                confidence: row.confidence,
                landmarks,
            })
        })
        .collect()
}

/// Reads a face mesh CSV ([`mesh_columns`], anywhere among the value columns). Rows with
/// `success = 1` must have [`MESH_POINTS`] finite points; rows with `success = 0` give
/// `None`.
///
/// # Errors
/// As [`read_frame_csv`]; also [`Error::Parse`] when a mesh column is missing, when the
/// file has points beyond the mesh's (a column `x_478`, `y_478` or `z_478`), or when a
/// successful row has a NaN value or one outside the range of `f32` (naming the line).
pub fn read_mesh_csv(path: impl AsRef<Path>) -> Result<Vec<MeshRecord>> {
    let path = path.as_ref();
    let table = read_frame_csv(path)?;
    mesh_from_table(&table).map_err(|e| e.at_path(path))
}

/// Extracts the mesh points from a parsed table (see [`read_mesh_csv`]).
///
/// # Errors
/// As [`read_mesh_csv`] (errors carry an empty path).
pub fn mesh_from_table(table: &FrameTable) -> Result<Vec<MeshRecord>> {
    for axis in ["x", "y", "z"] {
        let extra = format!("{axis}_{MESH_POINTS}");
        if table.column_index(&extra).is_some() {
            return Err(Error::parse(
                FORMAT,
                "",
                format!("column {extra}: more than the {MESH_POINTS} points of the face mesh"),
            ));
        }
    }
    let idx: Vec<usize> = mesh_columns()
        .iter()
        .map(|n| {
            table.column_index(n).ok_or_else(|| {
                Error::parse(
                    FORMAT,
                    "",
                    format!("face mesh column {n} missing ({MESH_POINTS} points x_i,y_i,z_i expected)"),
                )
            })
        })
        .collect::<Result<_>>()?;
    table
        .rows
        .iter()
        .enumerate()
        .map(|(r, row)| {
            let points = if row.success {
                let mut pts = Vec::with_capacity(MESH_POINTS);
                for (i, c) in idx.chunks_exact(3).enumerate() {
                    let mut p = [0.0f32; 3];
                    for (k, (slot, &j)) in p.iter_mut().zip(c).enumerate() {
                        let v = row.values[j];
                        // within f32's range, so the narrowing below is exact for our own files
                        if !(v.is_finite() && v.abs() <= f64::from(f32::MAX)) {
                            return Err(perr(
                                r + 2,
                                format!(
                                    "{}_{i}: {v} is not a finite f32 in a successful row",
                                    ["x", "y", "z"][k]
                                ),
                            ));
                        }
                        *slot = v as f32;
                    }
                    pts.push(p);
                }
                Some(pts)
            } else {
                None
            };
            Ok(MeshRecord {
                frame: row.frame,
                timestamp: row.timestamp,
                success: row.success,
                confidence: row.confidence,
                points,
            })
        })
        .collect()
}

/// Mesh values in [`mesh_columns`] order for [`FrameRow::values`]; `None` gives NaNs (a
/// failed frame). Each `f32` is written as the `f64` of its shortest decimal form
/// (`0.1f32` becomes `0.1`, not `0.10000000149011612`), so the file stays short and
/// reading a value back and narrowing it to `f32` gives the same bits.
///
/// # Errors
/// [`Error::DimensionMismatch`] when `points` does not have [`MESH_POINTS`] points or
/// `out` does not have `3 * MESH_POINTS` values.
pub fn mesh_values(points: Option<&[[f32; 3]]>, out: &mut [f64]) -> Result<()> {
    if out.len() != 3 * MESH_POINTS {
        return Err(Error::DimensionMismatch {
            what: "face mesh CSV values".into(),
            expected: 3 * MESH_POINTS,
            got: out.len(),
        });
    }
    let Some(points) = points else {
        out.fill(f64::NAN);
        return Ok(());
    };
    if points.len() != MESH_POINTS {
        return Err(Error::DimensionMismatch {
            what: "face mesh points".into(),
            expected: MESH_POINTS,
            got: points.len(),
        });
    }
    for (o, v) in out.iter_mut().zip(points.iter().flatten()) {
        *o = shortest_f64(*v);
    }
    Ok(())
}

/// The `f64` whose shortest form is the shortest form of `v` (no allocation: formats into
/// a stack buffer). Non-finite values are passed through.
fn shortest_f64(v: f32) -> f64 {
    if !v.is_finite() {
        return f64::from(v);
    }
    let mut buf = [0u8; 64];
    let mut cur = std::io::Cursor::new(&mut buf[..]);
    // `{}` of a finite f32 has at most ~48 characters (no exponent form); on any
    // failure the exact widening is the fallback
    if write!(cur, "{v}").is_err() {
        return f64::from(v);
    }
    let n = cur.position() as usize;
    std::str::from_utf8(&buf[..n])
        .ok()
        .and_then(|t| t.parse::<f64>().ok())
        .unwrap_or(f64::from(v))
}

/// Landmark values in [`landmark_columns`] order (all x, then all y), for
/// [`FrameRow::values`]; `None` gives NaNs (a failed frame).
pub fn landmark_values(landmarks: Option<&Landmarks68>, out: &mut [f64; 2 * NUM_LANDMARKS]) {
    match landmarks {
        Some(lm) => {
            for (i, p) in lm.points.iter().enumerate() {
                out[i] = p.x;
                out[NUM_LANDMARKS + i] = p.y;
            }
        }
        None => out.fill(f64::NAN),
    }
}
