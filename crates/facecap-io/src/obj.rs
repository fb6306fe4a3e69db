//! Wavefront OBJ input and output of triangle meshes.
//!
//! ## Reading ([`read_obj`], [`read_obj_with_sources`], [`parse_obj`])
//! Supported statements: `v x y z [w | r g b]`, `vt u [v [w]]`, `vn x y z`, and
//! `f` with corners `v`, `v/vt`, `v//vn` or `v/vt/vn` (1-based, or negative =
//! relative to the end of the list so far). Polygons with more than three corners
//! are triangulated as fans `(0, i, i+1)`; quads become `(0,1,2)` and `(0,2,3)`.
//! Objects and groups (`o`, `g`) are merged into one mesh; `mtllib`, `usemtl`,
//! `s`, `l`, `p` and unknown statements are ignored. Anything malformed is an
//! [`Error::Parse`] naming the file and the 1-based line, never a panic.
//!
//! **Vertex order is kept.** Vertex `i < number of v lines` *is* the file's `i`-th
//! `v` (0-based), also when unused, so vertex-index maps (MediaPipe's 468 ids, ICT's
//! landmark vertices, `ibug_to_sfm.txt`) stay valid. A glTF-style mesh needs one UV
//! and one normal per vertex: when a position is used with several different
//! `vt`/`vn` indices (a texture seam), the extra combinations are appended as
//! copies *after* the original vertices; [`read_obj_with_sources`] returns, for
//! every vertex, the OBJ position it came from. Unused vertices get UV `(0, 0)`
//! and a zero normal.
//!
//! Why not `tobj` (which we use as a reference in the tests): tobj re-numbers the
//! vertices in order of first use by a face and drops unused ones, in both of its
//! index modes, which breaks every vertex-index map above.
//!
//! ## Writing ([`write_obj`])
//! `v`, then `vt` and `vn` when present (one per vertex), then `f a/a/a b/b/b c/c/c`
//! with the same 1-based index for all attributes. Floats are written with Rust's
//! shortest round-trip representation, so reading back gives bit-identical values.
//! Written atomically ([`facecap_core::atomic`]).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Point3, Vector3};

use facecap_core::atomic::write_atomic;
use facecap_core::error::{Error, Result};
use facecap_core::mesh::Mesh;

const FORMAT: &str = "OBJ";

/// Reads an OBJ file into one triangle mesh (see module docs).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read, [`Error::Parse`] (with the line)
/// for malformed content or out-of-range indices.
pub fn read_obj(path: impl AsRef<Path>) -> Result<Mesh> {
    read_obj_with_sources(path).map(|(m, _)| m)
}

/// Reads an OBJ file; also returns, for every mesh vertex, the 0-based index of the
/// OBJ `v` it was made from (the identity for the first `v`-count vertices).
///
/// # Errors
/// As [`read_obj`].
pub fn read_obj_with_sources(path: impl AsRef<Path>) -> Result<(Mesh, Vec<u32>)> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&bytes);
    parse_obj(&text).map_err(|e| e.at_path(path))
}

#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct Corner {
    v: u32,
    vt: Option<u32>,
    vn: Option<u32>,
}

fn perr(line: usize, reason: impl std::fmt::Display) -> Error {
    Error::parse(FORMAT, "", format!("line {line}: {reason}"))
}

fn parse_floats<const N: usize>(
    fields: &mut std::str::SplitWhitespace,
    min: usize,
    line: usize,
    what: &str,
) -> Result<[f32; N]> {
    let mut out = [0.0f32; N];
    let mut got = 0;
    for f in fields.by_ref() {
        if got == N {
            break;
        }
        let x: f32 = f
            .parse()
            .map_err(|_| perr(line, format!("{what}: {f:?} is not a number")))?;
        if !x.is_finite() {
            return Err(perr(line, format!("{what}: {f:?} is not finite")));
        }
        out[got] = x;
        got += 1;
    }
    if got < min {
        return Err(perr(
            line,
            format!("{what}: expected at least {min} numbers, found {got}"),
        ));
    }
    Ok(out)
}

/// Resolves a 1-based or negative OBJ index against `count` elements so far.
fn resolve(token: &str, count: usize, line: usize, what: &str) -> Result<u32> {
    let i: i64 = token
        .parse()
        .map_err(|_| perr(line, format!("{what} index {token:?} is not an integer")))?;
    let zero_based = if i > 0 {
        i - 1
    } else if i < 0 {
        count as i64 + i
    } else {
        return Err(perr(line, format!("{what} index 0 (OBJ indices start at 1)")));
    };
    if zero_based < 0 || zero_based >= count as i64 || zero_based > u32::MAX as i64 {
        return Err(perr(line, format!("{what} index {token} out of range (have {count})")));
    }
    Ok(zero_based as u32)
}

/// Reads an OBJ file's positions in file order and its faces by position index (UVs,
/// normals and seams are not split out): the first `max_vertices` `v` statements (all
/// when `None`), faces touching a dropped vertex left out. For corresponded mesh
/// databases and vertex-indexed rigs, where vertex `i` must be the file's `i`-th `v`.
///
/// # Errors
/// As [`read_obj`].
pub fn read_obj_positions(path: impl AsRef<Path>, max_vertices: Option<usize>) -> Result<Mesh> {
    let (mesh, sources) = read_obj_with_sources(path)?;
    // Vertices 0..v_count are the file's `v`s; seam copies follow them.
    let v_count = sources
        .iter()
        .enumerate()
        .position(|(i, &s)| s as usize != i)
        .unwrap_or(sources.len());
    let keep = max_vertices.map_or(v_count, |m| m.min(v_count));
    let triangles = mesh
        .triangles
        .iter()
        .map(|t| t.map(|v| sources[v as usize]))
        .filter(|t| t.iter().all(|&v| (v as usize) < keep))
        .collect();
    let mut positions = mesh.positions;
    positions.truncate(keep);
    Ok(Mesh {
        positions,
        triangles,
        normals: Vec::new(),
        uvs: Vec::new(),
    })
}

/// Parses OBJ text (see module docs); returns the mesh and the source position
/// of every vertex. Errors carry an empty path.
///
/// # Errors
/// [`Error::Parse`] with the 1-based line number.
pub fn parse_obj(text: &str) -> Result<(Mesh, Vec<u32>)> {
    let mut positions: Vec<Point3<f32>> = Vec::new();
    let mut texcoords: Vec<[f32; 2]> = Vec::new();
    let mut normals_in: Vec<Vector3<f32>> = Vec::new();
    let mut faces: Vec<[Corner; 3]> = Vec::new();
    let mut corners: Vec<Corner> = Vec::new();
    let mut has_vt: Option<bool> = None;
    let mut has_vn: Option<bool> = None;

    for (ln0, raw) in text.lines().enumerate() {
        let line = ln0 + 1;
        let content = raw.split('#').next().unwrap_or("");
        let mut fields = content.split_whitespace();
        let Some(kw) = fields.next() else { continue };
        match kw {
            "v" => {
                let [x, y, z] = parse_floats::<3>(&mut fields, 3, line, "vertex")?;
                positions.push(Point3::new(x, y, z));
            }
            "vt" => {
                let [u, v] = parse_floats::<2>(&mut fields, 1, line, "texture coordinate")?;
                texcoords.push([u, v]);
            }
            "vn" => {
                let [x, y, z] = parse_floats::<3>(&mut fields, 3, line, "normal")?;
                normals_in.push(Vector3::new(x, y, z));
            }
            "f" => {
                corners.clear();
                for tok in fields {
                    let mut parts = tok.split('/');
                    let v = resolve(parts.next().unwrap_or(""), positions.len(), line, "vertex")?;
                    let vt = match parts.next() {
                        None | Some("") => None,
                        Some(t) => Some(resolve(t, texcoords.len(), line, "texture coordinate")?),
                    };
                    let vn = match parts.next() {
                        None | Some("") => None,
                        Some(t) => Some(resolve(t, normals_in.len(), line, "normal")?),
                    };
                    if parts.next().is_some() {
                        return Err(perr(line, format!("face corner {tok:?} has more than 3 parts")));
                    }
                    for (flag, present, what) in [
                        (&mut has_vt, vt.is_some(), "texture coordinate"),
                        (&mut has_vn, vn.is_some(), "normal"),
                    ] {
                        match *flag {
                            None => *flag = Some(present),
                            Some(p) if p != present => {
                                return Err(perr(
                                    line,
                                    format!(
                                        "face corner {tok:?}: some face corners have a {what} index and others do not"
                                    ),
                                ))
                            }
                            _ => {}
                        }
                    }
                    corners.push(Corner { v, vt, vn });
                }
                if corners.len() < 3 {
                    return Err(perr(
                        line,
                        format!("face with {} corners (need at least 3)", corners.len()),
                    ));
                }
                for i in 1..corners.len() - 1 {
                    faces.push([corners[0], corners[i], corners[i + 1]]);
                }
            }
            _ => {} // o, g, s, mtllib, usemtl, l, p, vp, ...: not needed for geometry
        }
    }

    let n = positions.len();
    let with_uv = has_vt == Some(true);
    let with_n = has_vn == Some(true);
    let mut sources: Vec<u32> = (0..n as u32).collect();
    let mut uvs = if with_uv { vec![[0.0f32; 2]; n] } else { Vec::new() };
    let mut normals = if with_n { vec![Vector3::zeros(); n] } else { Vec::new() };
    // The attribute combination that owns each original vertex, and extra copies.
    let mut owner: Vec<Option<Corner>> = vec![None; n];
    let mut extra: HashMap<Corner, u32> = HashMap::new();
    let mut triangles = Vec::with_capacity(faces.len());
    for face in &faces {
        let mut tri = [0u32; 3];
        for (k, c) in face.iter().enumerate() {
            let vi = c.v as usize;
            let idx = match owner[vi] {
                None => {
                    owner[vi] = Some(*c);
                    if let Some(t) = c.vt {
                        uvs[vi] = texcoords[t as usize];
                    }
                    if let Some(t) = c.vn {
                        normals[vi] = normals_in[t as usize];
                    }
                    c.v
                }
                Some(o) if o == *c => c.v,
                Some(_) => match extra.get(c) {
                    Some(&i) => i,
                    None => {
                        let i = u32::try_from(positions.len())
                            .map_err(|_| Error::parse(FORMAT, "", "more than 2^32 vertices"))?;
                        positions.push(positions[vi]);
                        sources.push(c.v);
                        if let Some(t) = c.vt {
                            uvs.push(texcoords[t as usize]);
                        }
                        if let Some(t) = c.vn {
                            normals.push(normals_in[t as usize]);
                        }
                        extra.insert(*c, i);
                        i
                    }
                },
            };
            tri[k] = idx;
        }
        triangles.push(tri);
    }
    let mesh = Mesh {
        positions,
        triangles,
        normals,
        uvs,
    };
    debug_assert!(mesh.validate().is_ok());
    Ok((mesh, sources))
}

/// Writes a mesh as OBJ atomically (see module docs).
///
/// # Errors
/// The errors of [`Mesh::validate`] (inconsistent sizes, indices out of range,
/// non-finite positions), [`Error::InvalidParameter`] for non-finite normals or
/// UVs, [`Error::Io`] on write failure.
pub fn write_obj(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let text = obj_to_string(mesh)?;
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Writes positions and triangles (no UVs or normals) as OBJ, atomically.
///
/// # Errors
/// As [`write_obj`].
pub fn write_obj_positions(path: impl AsRef<Path>, positions: &[Point3<f32>], triangles: &[[u32; 3]]) -> Result<()> {
    let mesh = Mesh {
        positions: positions.to_vec(),
        triangles: triangles.to_vec(),
        normals: Vec::new(),
        uvs: Vec::new(),
    };
    write_obj(path, &mesh)
}

/// The OBJ text [`write_obj`] writes.
///
/// # Errors
/// As [`write_obj`] without the I/O.
pub fn obj_to_string(mesh: &Mesh) -> Result<String> {
    mesh.validate()?;
    if let Some(i) = mesh
        .normals
        .iter()
        .position(|v| !(v.x.is_finite() && v.y.is_finite() && v.z.is_finite()))
    {
        return Err(Error::invalid(
            "vertex normal",
            format!("vertex {i}"),
            "finite components",
        ));
    }
    if let Some(i) = mesh.uvs.iter().position(|u| !(u[0].is_finite() && u[1].is_finite())) {
        return Err(Error::invalid("vertex uv", format!("vertex {i}"), "finite components"));
    }
    let mut s = String::with_capacity(mesh.positions.len() * 40 + mesh.triangles.len() * 30);
    let _ = writeln!(s, "# written by facecap {}", env!("CARGO_PKG_VERSION"));
    for p in &mesh.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in &mesh.uvs {
        let _ = writeln!(s, "vt {} {}", t[0], t[1]);
    }
    for n in &mesh.normals {
        let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
    }
    let (uv, nn) = (!mesh.uvs.is_empty(), !mesh.normals.is_empty());
    for tri in &mesh.triangles {
        s.push('f');
        for &i in tri {
            let i = i as u64 + 1;
            let _ = match (uv, nn) {
                (false, false) => write!(s, " {i}"),
                (true, false) => write!(s, " {i}/{i}"),
                (false, true) => write!(s, " {i}//{i}"),
                (true, true) => write!(s, " {i}/{i}/{i}"),
            };
        }
        s.push('\n');
    }
    Ok(s)
}
