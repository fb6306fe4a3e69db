//! MediaPipe's canonical face model (Apache-2.0, The MediaPipe Authors): the 468
//! face-mesh vertices in centimetres, +Y up, +Z out of the face, in the face mesh's
//! landmark order. The dense solve maps these onto a rig's neutral to find where each
//! mesh landmark lies on the rig (docs/expressions.md, "Dense solve").
//!
//! The points are read from `geometry_pipeline_metadata_landmarks.binarypb`, which
//! `scripts/setup.sh` extracts from MediaPipe's `face_landmarker.task` bundle into the
//! model cache (sha256-checked). The file is a `GeometryPipelineMetadata` protobuf:
//! field 1 is the canonical mesh, whose field 3 (`vertex_buffer`, repeated float) holds
//! 5 floats per vertex (`x y z u v`) and field 4 (`index_buffer`, repeated uint32) three
//! vertex ids per triangle. Only these fields are read; every length is checked against
//! the bytes that remain before it is used, every index against the vertex count.

use std::path::Path;

use crate::{Error, Result};

/// File name of the face geometry metadata (with the canonical mesh) in the model cache.
pub const GEOMETRY_METADATA: &str = "geometry_pipeline_metadata_landmarks.binarypb";
/// Number of vertices of the canonical face (the face mesh without its 10 iris points).
pub const CANONICAL_VERTICES: usize = 468;
/// Floats per vertex in the vertex buffer (`x y z u v`).
const FLOATS_PER_VERTEX: usize = 5;
/// Most triangles accepted (the canonical face has 898).
const MAX_TRIANGLES: usize = 4 * CANONICAL_VERTICES;

/// The canonical face as a triangle mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct CanonicalMesh {
    /// The 468 vertices (cm, +Y up, +Z out of the face), face-mesh landmark order.
    pub positions: Vec<[f64; 3]>,
    /// Texture coordinates per vertex (`u v` as stored).
    pub uvs: Vec<[f64; 2]>,
    /// Triangles (vertex ids, each `< 468`), as stored.
    pub triangles: Vec<[u32; 3]>,
}

fn bad(reason: impl Into<String>) -> Error {
    Error::Model {
        reason: format!("{GEOMETRY_METADATA}: {}", reason.into()),
    }
}

fn varint(b: &[u8], i: &mut usize) -> Result<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = *b.get(*i).ok_or_else(|| bad("truncated varint"))?;
        *i += 1;
        v |= u64::from(byte & 0x7f) << shift;
        if byte < 0x80 {
            return Ok(v);
        }
    }
    Err(bad("varint longer than 10 bytes"))
}

/// Calls `f(field, wire_type, payload)` for every field of one protobuf message;
/// `payload` is the varint value's bytes for wire type 0, the 4/8 bytes
/// for types 5/1, the contents for type 2.
fn fields<'a>(b: &'a [u8], mut f: impl FnMut(u64, u64, &'a [u8]) -> Result<()>) -> Result<()> {
    let mut i = 0;
    while i < b.len() {
        let key = varint(b, &mut i)?;
        let (field, wire) = (key >> 3, key & 7);
        let start = i;
        let len = match wire {
            0 => {
                varint(b, &mut i)?;
                i - start
            }
            1 => 8,
            5 => 4,
            2 => {
                let n = varint(b, &mut i)?;
                usize::try_from(n).map_err(|_| bad("length does not fit in memory"))?
            }
            _ => return Err(bad(format!("unsupported wire type {wire} (field {field})"))),
        };
        let from = if wire == 0 { start } else { i };
        let to = from
            .checked_add(len)
            .filter(|&e| e <= b.len())
            .ok_or_else(|| bad("field runs past the end of the file"))?;
        f(field, wire, &b[from..to])?;
        i = to.max(i);
    }
    Ok(())
}

/// Parses the canonical face's vertices from the bytes of the metadata file.
///
/// # Errors
/// [`Error::Model`] for a malformed file or one without 468 vertices.
pub fn parse_canonical_face(bytes: &[u8]) -> Result<Vec<[f64; 3]>> {
    Ok(parse_mesh(bytes, false)?.positions)
}

/// Parses the canonical face with its texture coordinates and triangles.
///
/// # Errors
/// [`Error::Model`] for a malformed file, one without 468 vertices, without triangles,
/// with an index buffer that is not whole triangles or an index past the vertices.
pub fn parse_canonical_mesh(bytes: &[u8]) -> Result<CanonicalMesh> {
    parse_mesh(bytes, true)
}

fn varint_field(payload: &[u8]) -> Result<u64> {
    let mut i = 0;
    varint(payload, &mut i)
}

fn parse_mesh(bytes: &[u8], with_triangles: bool) -> Result<CanonicalMesh> {
    let mut mesh: Option<&[u8]> = None;
    fields(bytes, |field, wire, payload| {
        if field == 1 && wire == 2 {
            mesh = Some(payload);
        }
        Ok(())
    })?;
    let mesh = mesh.ok_or_else(|| bad("no canonical mesh (field 1)"))?;
    let mut floats: Vec<f32> = Vec::new();
    let mut indices: Vec<u64> = Vec::new();
    fields(mesh, |field, wire, payload| {
        if field == 3 {
            match wire {
                5 => floats.push(f32::from_le_bytes([payload[0], payload[1], payload[2], payload[3]])),
                2 => {
                    if payload.len() % 4 != 0 {
                        return Err(bad("packed vertex buffer not a whole number of floats"));
                    }
                    floats.extend(
                        payload
                            .chunks_exact(4)
                            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                    );
                }
                _ => return Err(bad("vertex buffer of an unexpected wire type")),
            }
        }
        if field == 4 && with_triangles {
            match wire {
                0 => indices.push(varint_field(payload)?),
                2 => {
                    let mut i = 0;
                    while i < payload.len() {
                        indices.push(varint(payload, &mut i)?);
                        if indices.len() > 3 * MAX_TRIANGLES {
                            break;
                        }
                    }
                }
                _ => return Err(bad("index buffer of an unexpected wire type")),
            }
            if indices.len() > 3 * MAX_TRIANGLES {
                return Err(bad(format!("more than {MAX_TRIANGLES} triangles")));
            }
        }
        if floats.len() > CANONICAL_VERTICES * FLOATS_PER_VERTEX {
            return Err(bad("more vertices than the face mesh has"));
        }
        Ok(())
    })?;
    if floats.len() != CANONICAL_VERTICES * FLOATS_PER_VERTEX {
        return Err(bad(format!(
            "{} floats in the vertex buffer, expected {} ({CANONICAL_VERTICES} vertices x {FLOATS_PER_VERTEX})",
            floats.len(),
            CANONICAL_VERTICES * FLOATS_PER_VERTEX
        )));
    }
    if floats.iter().any(|c| !c.is_finite()) {
        return Err(bad("non-finite vertex coordinate"));
    }
    let positions: Vec<[f64; 3]> = floats
        .chunks_exact(FLOATS_PER_VERTEX)
        .map(|v| [f64::from(v[0]), f64::from(v[1]), f64::from(v[2])])
        .collect();
    let uvs: Vec<[f64; 2]> = floats
        .chunks_exact(FLOATS_PER_VERTEX)
        .map(|v| [f64::from(v[3]), f64::from(v[4])])
        .collect();
    let mut triangles = Vec::with_capacity(indices.len() / 3);
    if with_triangles {
        if indices.is_empty() || indices.len() % 3 != 0 {
            return Err(bad(format!(
                "index buffer of {} entries, expected whole triangles",
                indices.len()
            )));
        }
        for t in indices.chunks_exact(3) {
            let mut tri = [0u32; 3];
            for (o, &v) in tri.iter_mut().zip(t) {
                if v >= CANONICAL_VERTICES as u64 {
                    return Err(bad(format!(
                        "triangle index {v} past the {CANONICAL_VERTICES} vertices"
                    )));
                }
                *o = v as u32;
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err(bad(format!("degenerate triangle {tri:?}")));
            }
            triangles.push(tri);
        }
    }
    Ok(CanonicalMesh {
        positions,
        uvs,
        triangles,
    })
}

/// Reads the canonical face from a metadata file.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read, else as [`parse_canonical_face`].
pub fn read_canonical_face(path: &Path) -> Result<Vec<[f64; 3]>> {
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_canonical_face(&bytes)
}

/// Reads the canonical face from the model cache.
///
/// # Errors
/// [`Error::InvalidInput`] when the file is not in the cache, else as
/// [`read_canonical_face`].
pub fn canonical_face_from_cache() -> Result<Vec<[f64; 3]>> {
    let path = facecap_core::paths::model_file(GEOMETRY_METADATA).ok_or_else(|| Error::InvalidInput {
        what: format!("{GEOMETRY_METADATA} not in the model cache (run scripts/setup.sh)"),
    })?;
    read_canonical_face(&path)
}

/// Reads the canonical face mesh (vertices, texture coordinates, triangles) from the
/// model cache.
///
/// # Errors
/// As [`canonical_face_from_cache`], else as [`parse_canonical_mesh`].
pub fn canonical_mesh_from_cache() -> Result<CanonicalMesh> {
    let path = facecap_core::paths::model_file(GEOMETRY_METADATA).ok_or_else(|| Error::InvalidInput {
        what: format!("{GEOMETRY_METADATA} not in the model cache (run scripts/setup.sh)"),
    })?;
    let bytes = std::fs::read(&path).map_err(|source| Error::Io {
        path: path.clone(),
        source,
    })?;
    parse_canonical_mesh(&bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(field: u64, wire: u64) -> u8 {
        ((field << 3) | wire) as u8
    }

    fn file(n_vertices: usize) -> Vec<u8> {
        let mut mesh = vec![key(1, 0), 0, key(2, 0), 0];
        for v in 0..n_vertices {
            for k in 0..FLOATS_PER_VERTEX {
                mesh.push(key(3, 5));
                mesh.extend_from_slice(&((v * 10 + k) as f32).to_le_bytes());
            }
        }
        let mut out = vec![key(1, 2)];
        let mut n = mesh.len();
        while n >= 0x80 {
            out.push((n as u8 & 0x7f) | 0x80);
            n >>= 7;
        }
        out.push(n as u8);
        out.extend_from_slice(&mesh);
        out
    }

    #[test]
    fn reads_vertices_in_order() {
        let pts = parse_canonical_face(&file(CANONICAL_VERTICES)).unwrap();
        assert_eq!(pts.len(), CANONICAL_VERTICES);
        assert_eq!(pts[0], [0.0, 1.0, 2.0]);
        assert_eq!(pts[467], [4670.0, 4671.0, 4672.0]);
    }

    #[test]
    fn damaged_files_are_errors_not_panics() {
        let good = file(CANONICAL_VERTICES);
        assert!(parse_canonical_face(&file(10)).is_err());
        assert!(parse_canonical_face(&[]).is_err());
        for cut in [1, 2, 3, 100, good.len() - 1] {
            assert!(parse_canonical_face(&good[..cut]).is_err(), "cut at {cut}");
        }
        assert!(parse_canonical_face(&[key(1, 2), 0xff, 0xff, 0xff, 0xff, 0x0f]).is_err());
        assert!(parse_canonical_face(&[key(1, 3)]).is_err());
    }

    #[test]
    fn the_cached_file_has_the_canonical_face() {
        let Some(path) = facecap_core::paths::model_file_or_skip("canonical_face", GEOMETRY_METADATA) else {
            return;
        };
        let pts = read_canonical_face(&path).unwrap();
        assert_eq!(pts.len(), CANONICAL_VERTICES);
        // The nose tip (landmark 4) is on the midline, in front of the face.
        assert!(pts[4][0].abs() < 1e-6 && pts[4][2] > 7.0, "{:?}", pts[4]);
    }
}
