//! iBUG `.pts` landmark files (300-W, LFPW, HELEN, menpo).
//!
//! ```text
//! version: 1
//! n_points: 68
//! {
//! 115.167660 220.807529
//! ...
//! }
//! ```
//!
//! Coordinates in the file are **1-based** (MATLAB convention: the centre of the
//! top-left pixel is `(1, 1)`); in memory they are 0-based, so reading subtracts 1
//! from `x` and `y` and writing adds 1 (as menpo does). Header lines are `key: value`
//! before `{`; `n_points` is required, `version` must be `1` when present, other keys
//! are ignored. Exactly `n_points` lines of two finite numbers follow, then `}` and
//! nothing but blank lines. Writing uses Rust's shortest round-trip float format.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Point2;

use facecap_core::atomic::write_atomic;
use facecap_core::error::{Error, Result};
use facecap_core::landmarks::Landmarks68;

const FORMAT: &str = "iBUG .pts";
/// The offset between the file's 1-based and our 0-based coordinates.
const PTS_ORIGIN: f64 = 1.0;

fn perr(line: usize, reason: impl std::fmt::Display) -> Error {
    Error::parse(FORMAT, "", format!("line {line}: {reason}"))
}

/// Parses `.pts` text into 0-based points (any number of points).
///
/// # Errors
/// [`Error::Parse`] with the 1-based line for a missing/invalid header, a wrong
/// number of points, non-numeric or non-finite coordinates, a missing `}`, or
/// content after it.
pub fn parse_pts(text: &str) -> Result<Vec<Point2<f64>>> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    let mut n_points: Option<usize> = None;
    let mut last = 0;
    // Header up to "{".
    loop {
        let Some((ln, l)) = lines.next() else {
            return Err(perr(last + 1, "missing '{' (truncated file?)"));
        };
        last = ln;
        if l.is_empty() {
            continue;
        }
        if l == "{" {
            break;
        }
        let Some((key, value)) = l.split_once(':') else {
            return Err(perr(ln, format!("expected 'key: value' or '{{', found {l:?}")));
        };
        match key.trim() {
            "version" if value.trim() != "1" => {
                return Err(perr(ln, format!("unsupported version {:?} (expected 1)", value.trim())));
            }
            "n_points" => {
                let n: usize = value
                    .trim()
                    .parse()
                    .map_err(|_| perr(ln, format!("n_points {:?} is not a count", value.trim())))?;
                n_points = Some(n);
            }
            _ => {}
        }
    }
    let n = n_points.ok_or_else(|| perr(last, "no n_points line before '{'"))?;
    let mut points = Vec::with_capacity(n.min(1 << 16));
    loop {
        let Some((ln, l)) = lines.next() else {
            return Err(perr(
                last + 1,
                format!("missing '}}' after {} of {n} points (truncated file?)", points.len()),
            ));
        };
        last = ln;
        if l.is_empty() {
            continue;
        }
        if l == "}" {
            break;
        }
        let mut f = l.split_whitespace();
        let (Some(xs), Some(ys), None) = (f.next(), f.next(), f.next()) else {
            return Err(perr(ln, format!("expected two numbers 'x y', found {l:?}")));
        };
        let parse = |s: &str| -> Result<f64> {
            let v: f64 = s.parse().map_err(|_| perr(ln, format!("{s:?} is not a number")))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(perr(ln, format!("{s:?} is not finite")))
            }
        };
        let (x, y) = (parse(xs)?, parse(ys)?);
        if points.len() == n {
            return Err(perr(ln, format!("more than n_points = {n} points")));
        }
        points.push(Point2::new(x - PTS_ORIGIN, y - PTS_ORIGIN));
    }
    if points.len() != n {
        return Err(perr(last, format!("found {} points, n_points says {n}", points.len())));
    }
    if let Some((ln, l)) = lines.find(|(_, l)| !l.is_empty()) {
        return Err(perr(ln, format!("unexpected content after '}}': {l:?}")));
    }
    Ok(points)
}

/// Reads a `.pts` file into 0-based points (any number of points).
///
/// # Errors
/// [`Error::Io`], or as [`parse_pts`] with the path filled in.
pub fn read_pts_points(path: impl AsRef<Path>) -> Result<Vec<Point2<f64>>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = std::str::from_utf8(&bytes).map_err(|e| Error::parse(FORMAT, path, format!("not UTF-8: {e}")))?;
    parse_pts(text).map_err(|e| e.at_path(path))
}

/// Reads a 68-point `.pts` file.
///
/// # Errors
/// As [`read_pts_points`]; [`Error::Parse`] when the file does not hold 68 points.
pub fn read_pts(path: impl AsRef<Path>) -> Result<Landmarks68> {
    let path = path.as_ref();
    let pts = read_pts_points(path)?;
    let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.x, p.y)).collect();
    Landmarks68::from_slice(&xy).map_err(|e| Error::parse(FORMAT, path, e.to_string()))
}

/// The `.pts` text for 0-based points (written 1-based).
///
/// # Errors
/// [`Error::InvalidParameter`] for a non-finite coordinate.
pub fn pts_to_string(points: &[Point2<f64>]) -> Result<String> {
    let mut s = String::with_capacity(32 + points.len() * 24);
    let _ = write!(s, "version: 1\nn_points: {}\n{{\n", points.len());
    for (i, p) in points.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite()) {
            return Err(Error::invalid(
                "landmark coordinate",
                format!("point {i} = ({}, {})", p.x, p.y),
                "finite numbers",
            ));
        }
        let _ = writeln!(s, "{} {}", p.x + PTS_ORIGIN, p.y + PTS_ORIGIN);
    }
    s.push_str("}\n");
    Ok(s)
}

/// Writes 0-based points as a `.pts` file (atomically).
///
/// # Errors
/// As [`pts_to_string`], or [`Error::Io`].
pub fn write_pts_points(path: impl AsRef<Path>, points: &[Point2<f64>]) -> Result<()> {
    let text = pts_to_string(points)?;
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Writes 68 landmarks as a `.pts` file (atomically).
///
/// # Errors
/// As [`write_pts_points`].
pub fn write_pts(path: impl AsRef<Path>, landmarks: &Landmarks68) -> Result<()> {
    write_pts_points(path, &landmarks.points)
}
