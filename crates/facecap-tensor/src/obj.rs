//! Minimal Wavefront OBJ reading/writing of positions and faces, enough for a
//! corresponded mesh database (`v` and `f` records; polygons are fan-triangulated,
//! negative (relative) indices are resolved; everything else is ignored).
//!
//! `facecap_core` is getting a full OBJ module; this one stays because the tensor
//! database only needs positions and must not wait for it.

use std::io::Write;
use std::path::Path;

use nalgebra::Point3;

use crate::error::{Error, Result};

const WHAT: &str = "OBJ";

/// Positions and triangles of an OBJ file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjGeometry {
    /// Vertex positions in file order.
    pub positions: Vec<Point3<f32>>,
    /// Triangles (0-based vertex indices), polygons fan-triangulated.
    pub triangles: Vec<[u32; 3]>,
}

/// Reads an OBJ file's positions and faces.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read, [`Error::Format`] naming the line when
/// a `v` or `f` record is malformed or a face index is out of range.
pub fn read_obj(path: &Path) -> Result<ObjGeometry> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_obj(&text).map_err(|reason| Error::Format {
        what: WHAT,
        path: path.to_path_buf(),
        reason,
    })
}

/// Parses OBJ text (see [`read_obj`]); the error is a message naming the line.
pub fn parse_obj(text: &str) -> std::result::Result<ObjGeometry, String> {
    let mut g = ObjGeometry::default();
    let mut faces: Vec<(usize, Vec<i64>)> = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut c = [0f32; 3];
                for (k, ck) in c.iter_mut().enumerate() {
                    let tok = it
                        .next()
                        .ok_or_else(|| format!("line {}: vertex has fewer than 3 coordinates", ln + 1))?;
                    *ck = tok
                        .parse::<f32>()
                        .map_err(|_| format!("line {}: coordinate {k} {tok:?} is not a number", ln + 1))?;
                    if !ck.is_finite() {
                        return Err(format!("line {}: coordinate {k} is not finite", ln + 1));
                    }
                }
                g.positions.push(Point3::new(c[0], c[1], c[2]));
            }
            Some("f") => {
                let mut idx = Vec::with_capacity(4);
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let v: i64 = first
                        .parse()
                        .map_err(|_| format!("line {}: face index {tok:?} is not an integer", ln + 1))?;
                    idx.push(v);
                }
                if idx.len() < 3 {
                    return Err(format!("line {}: face has fewer than 3 vertices", ln + 1));
                }
                faces.push((ln, idx));
            }
            _ => {}
        }
    }
    let n = g.positions.len() as i64;
    for (ln, idx) in faces {
        let mut res = Vec::with_capacity(idx.len());
        for v in idx {
            let r = if v > 0 { v - 1 } else { n + v };
            if v == 0 || r < 0 || r >= n {
                return Err(format!("line {}: face index {v} out of range for {n} vertices", ln + 1));
            }
            res.push(r as u32);
        }
        for k in 1..res.len() - 1 {
            g.triangles.push([res[0], res[k], res[k + 1]]);
        }
    }
    Ok(g)
}

/// Writes positions and triangles as OBJ (atomically: temp file + rename).
///
/// # Errors
/// [`Error::Io`] on write failure.
pub fn write_obj(path: &Path, positions: &[Point3<f32>], triangles: &[[u32; 3]]) -> Result<()> {
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut buf = Vec::with_capacity(positions.len() * 32 + triangles.len() * 24);
    writeln!(buf, "# facecap tensor model output").map_err(io)?;
    for p in positions {
        writeln!(buf, "v {} {} {}", p.x, p.y, p.z).map_err(io)?;
    }
    for t in triangles {
        writeln!(buf, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).map_err(io)?;
    }
    write_atomic(path, &buf)
}

/// Writes bytes to `path` through a temporary file in the same folder and a rename.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io(e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quads_are_fanned_and_bad_input_rejected() {
        let g = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1 2/2 3/3 4/4\n").unwrap_or_default();
        assert_eq!(g.positions.len(), 4);
        assert_eq!(g.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(parse_obj("v 0 0\n").is_err());
        assert!(parse_obj("v 0 0 0\nf 1 2 3\n").is_err());
        assert!(parse_obj("v 0 0 x\n").is_err());
        let g = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\n").unwrap_or_default();
        assert_eq!(g.triangles, vec![[0, 1, 2]]);
    }
}
