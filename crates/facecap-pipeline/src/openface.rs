//! OpenFace 2.x interop: `openface.csv` in FeatureExtraction's layout, and reading
//! FeatureExtraction CSVs as landmark input.
//!
//! ## Writing (`openface.csv`)
//! The columns OpenFace 2.x `FeatureExtraction -pose -2Dfp -3Dfp` writes, in its order
//! and with its separators (`", "`) and precisions, so pandas scripts written for
//! OpenFace read the file unchanged:
//!
//! | columns | meaning |
//! |---|---|
//! | `frame` | 1-based frame number (OpenFace counts from 1; facecap's own CSVs from 0) |
//! | `face_id` | 0 (one face per video) |
//! | `timestamp` | seconds, 3 decimals |
//! | `confidence` | tracking confidence in [0, 1], 2 decimals |
//! | `success` | 1 when the frame has landmarks and a head pose, else 0 |
//! | `pose_Tx, pose_Ty, pose_Tz` | head position in millimetres in camera axes (x right, y down, z forward), 1 decimal |
//! | `pose_Rx, pose_Ry, pose_Rz` | head rotation relative to facing the camera ([`facecap_core::camera::head_rotation`]) as OpenFace's Euler angles, `R = Rx Ry Rz`, radians, 3 decimals |
//! | `x_0..x_67, y_0..y_67` | 2D landmarks in pixels, 1 decimal |
//! | `X_0..X_67, Y_0..Y_67, Z_0..Z_67` | 3D landmarks in millimetres in camera axes: the rig's landmark vertices posed with the frame's weights and head pose (0 where the rig maps no vertex) |
//!
//! Rows without a face or pose are written as OpenFace writes them, with `success = 0`
//! (and zeros rather than `nan`, which OpenFace never writes). Rig units are converted to
//! millimetres with the `rig_unit_mm` factor ([`RIG_UNIT_MM`] for the built-in and ICT
//! rigs, which are in centimetres).
//!
//! ## Reading ([`read_landmarks`])
//! facecap's own `landmarks.csv` and OpenFace CSVs: columns found by header name
//! (spaces after commas allowed, extra columns such as gaze, AUs or PDM parameters
//! ignored), frames converted to facecap's 0-based numbering when the file has OpenFace's
//! `face_id` column; only `face_id` 0 is read.

use std::fmt::Write as _;
use std::path::Path;

use facecap_core::camera::{euler_rx_ry_rz, head_rotation, ModelToCamera};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_io::csv::LandmarkRecord;
use facecap_solve::BlendshapeRig;

use crate::error::{Error, Result};
use crate::expression::SolvedFrame;

/// Millimetres per unit of the built-in rig and of ICT FaceKit (centimetres).
pub const RIG_UNIT_MM: f64 = 10.0;

/// The header of `openface.csv` (module docs).
pub fn header() -> String {
    let mut h = String::from("frame, face_id, timestamp, confidence, success");
    h.push_str(", pose_Tx, pose_Ty, pose_Tz, pose_Rx, pose_Ry, pose_Rz");
    for axis in ["x", "y", "X", "Y", "Z"] {
        for i in 0..NUM_LANDMARKS {
            let _ = write!(h, ", {axis}_{i}");
        }
    }
    h
}

/// Writes `openface.csv` for solved frames of `rig` (module docs).
///
/// # Errors
/// When the file cannot be written.
pub fn write_openface_csv(path: &Path, rig: &BlendshapeRig, frames: &[SolvedFrame], rig_unit_mm: f64) -> Result<()> {
    if !(rig_unit_mm.is_finite() && rig_unit_mm > 0.0) {
        return Err(Error::invalid("rig_unit_mm", rig_unit_mm, "a finite number > 0"));
    }
    let mut text = header();
    text.push('\n');
    let mut x3 = [[0.0f64; 3]; NUM_LANDMARKS];
    for f in frames {
        let pose = f.pose.filter(|_| f.success);
        let ok = pose.is_some() && f.landmarks.is_some();
        let _ = write!(
            text,
            "{}, 0, {:.3}, {:.2}, {}",
            f.index + 1,
            f.timestamp,
            f.confidence,
            u8::from(ok)
        );
        match pose.as_ref().filter(|_| ok) {
            Some(p) => {
                let t = p.tvec() * rig_unit_mm;
                let (a, b, c) = euler_rx_ry_rz(&head_rotation(p));
                let _ = write!(text, ", {:.1}, {:.1}, {:.1}, {a:.3}, {b:.3}, {c:.3}", t.x, t.y, t.z);
            }
            None => text.push_str(", 0.0, 0.0, 0.0, 0.000, 0.000, 0.000"),
        }
        match f.landmarks.as_ref().filter(|_| ok) {
            Some(l) => {
                for axis in 0..2 {
                    for p in &l.points {
                        let _ = write!(text, ", {:.1}", if axis == 0 { p.x } else { p.y });
                    }
                }
            }
            None => (0..2 * NUM_LANDMARKS).for_each(|_| text.push_str(", 0.0")),
        }
        match pose.as_ref().filter(|_| ok) {
            Some(p) => posed_landmarks(rig, &f.weights, p, rig_unit_mm, &mut x3),
            None => x3 = [[0.0; 3]; NUM_LANDMARKS],
        }
        for axis in 0..3 {
            for p in &x3 {
                let _ = write!(text, ", {:.1}", p[axis]);
            }
        }
        text.push('\n');
    }
    facecap_core::atomic::write_atomic(path, |w| w.write_all(text.as_bytes()))?;
    Ok(())
}

/// The rig's landmarks posed with `weights` and `pose`, in camera millimetres (zeros
/// where unmapped).
fn posed_landmarks(
    rig: &BlendshapeRig,
    weights: &[f64],
    pose: &ModelToCamera,
    unit_mm: f64,
    out: &mut [[f64; 3]; NUM_LANDMARKS],
) {
    for (i, o) in out.iter_mut().enumerate() {
        if !rig.mapped[i] {
            *o = [0.0; 3];
            continue;
        }
        let mut p = [rig.neutral[[i, 0]], rig.neutral[[i, 1]], rig.neutral[[i, 2]]];
        for (k, w) in weights.iter().enumerate() {
            for (c, v) in p.iter_mut().enumerate() {
                *v += w * rig.deltas[[k, i, c]];
            }
        }
        let c = pose.transform(&nalgebra::Point3::new(p[0], p[1], p[2]));
        *o = [c.x * unit_mm, c.y * unit_mm, c.z * unit_mm];
    }
}

fn csv_err(path: &Path, e: ::csv::Error) -> Error {
    match e.into_kind() {
        ::csv::ErrorKind::Io(io) => Error::Core(facecap_core::Error::io(path, io)),
        other => parse_err(path, format!("{other:?}")),
    }
}

fn parse_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Core(facecap_core::Error::parse("landmark CSV", path, reason.into()))
}

/// Reads per-frame landmarks from facecap's `landmarks.csv` or an OpenFace CSV (module
/// docs). Rows with `success = 0` have no landmarks; so do rows whose landmarks are
/// not all finite.
///
/// # Errors
/// An unreadable file, a missing column (`frame`, `timestamp`, `success`,
/// `confidence`, `x_i`, `y_i`), or an unparsable number (naming the line).
pub fn read_landmarks(path: &Path) -> Result<Vec<LandmarkRecord>> {
    let mut rdr = ::csv::ReaderBuilder::new()
        .trim(::csv::Trim::All)
        .flexible(false)
        .from_path(path)
        .map_err(|e| csv_err(path, e))?;
    let headers = rdr.headers().map_err(|e| csv_err(path, e))?.clone();
    let col = |name: &str| -> Result<usize> {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| parse_err(path, format!("column {name} missing")))
    };
    let (c_frame, c_time, c_success, c_conf) = (col("frame")?, col("timestamp")?, col("success")?, col("confidence")?);
    let c_face = headers.iter().position(|h| h == "face_id");
    let mut c_xy = Vec::with_capacity(2 * NUM_LANDMARKS);
    for axis in ["x", "y"] {
        for i in 0..NUM_LANDMARKS {
            c_xy.push(col(&format!("{axis}_{i}"))?);
        }
    }
    let openface = c_face.is_some();
    let mut out = Vec::new();
    for (k, rec) in rdr.records().enumerate() {
        let line = k + 2;
        let rec = rec.map_err(|e| parse_err(path, format!("line {line}: {e}")))?;
        let field = |c: usize| rec.get(c).unwrap_or("");
        let num = |c: usize| -> Result<f64> {
            field(c).parse::<f64>().map_err(|_| {
                parse_err(
                    path,
                    format!("line {line}: column {}: {:?} is not a number", &headers[c], field(c)),
                )
            })
        };
        if let Some(cf) = c_face {
            if num(cf)? != 0.0 {
                continue;
            }
        }
        let frame_raw = num(c_frame)?;
        if !(frame_raw.is_finite() && frame_raw >= 0.0 && frame_raw.fract() == 0.0) {
            return Err(parse_err(
                path,
                format!("line {line}: frame {frame_raw} is not a whole number >= 0"),
            ));
        }
        let frame = if openface {
            (frame_raw as u64)
                .checked_sub(1)
                .ok_or_else(|| parse_err(path, format!("line {line}: OpenFace frame numbers start at 1, found 0")))?
        } else {
            frame_raw as u64
        };
        let timestamp = num(c_time)?;
        if !(timestamp.is_finite() && timestamp >= 0.0) {
            return Err(parse_err(
                path,
                format!("line {line}: timestamp {timestamp} is not finite seconds >= 0"),
            ));
        }
        let success = match field(c_success) {
            "0" => false,
            "1" => true,
            s => return Err(parse_err(path, format!("line {line}: success {s:?} is not 0 or 1"))),
        };
        let confidence = num(c_conf)?;
        let landmarks = if success {
            let mut xy = Vec::with_capacity(NUM_LANDMARKS);
            for i in 0..NUM_LANDMARKS {
                xy.push((num(c_xy[i])?, num(c_xy[NUM_LANDMARKS + i])?));
            }
            Landmarks68::from_slice(&xy).ok()
        } else {
            None
        };
        out.push(LandmarkRecord {
            frame,
            timestamp,
            success: landmarks.is_some(),
            confidence: if confidence.is_finite() { confidence } else { 0.0 },
            landmarks,
        });
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn header_has_the_openface_columns_in_order() {
        let h = header();
        let cols: Vec<&str> = h.split(", ").collect();
        assert_eq!(cols.len(), 5 + 6 + 5 * 68);
        assert_eq!(&cols[..5], &["frame", "face_id", "timestamp", "confidence", "success"]);
        assert_eq!(cols[5], "pose_Tx");
        assert_eq!(cols[10], "pose_Rz");
        assert_eq!(cols[11], "x_0");
        assert_eq!(cols[11 + 68], "y_0");
        assert_eq!(cols[11 + 136], "X_0");
        assert_eq!(*cols.last().unwrap(), "Z_67");
    }
}
