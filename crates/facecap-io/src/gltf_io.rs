//! glTF 2.0 input and output of meshes with morph targets (blendshape rigs) and
//! animations of their weights.
//!
//! ## Reading ([`read_morph_mesh`])
//! `.glb` and `.gltf` (embedded `data:` URIs or external `.bin` files beside the
//! `.gltf`). The file must hold **one mesh with one primitive** (mode triangles,
//! triangle strip or triangle fan; without indices the vertices are taken in order).
//! Read: `POSITION`, `NORMAL` (optional), `TEXCOORD_0` (optional; float or normalised
//! u8/u16), indices (u8/u16/u32), and the `POSITION` deltas of every morph target
//! (targets without `POSITION` get zero deltas). Dense and sparse accessors are
//! supported. Target names come from `mesh.extras.targetNames` (an array of strings,
//! one per target, the de-facto convention of Blender, three.js and Babylon); when
//! absent the names are `target_<k>` (0-based). All accessor reads are bounds-checked:
//! a malformed file gives [`Error::Parse`], never a panic. Units are kept as in the
//! file (no conversion to metres).
//!
//! ## Writing ([`write_glb`], [`write_gltf`], [`write_morph_file`])
//! One buffer, one buffer view per accessor, little-endian:
//!
//! | accessor | type | notes |
//! |---|---|---|
//! | indices | `SCALAR` u32 | `ELEMENT_ARRAY_BUFFER` view |
//! | `POSITION` | `VEC3` f32 | `min`/`max` written (required by the spec) |
//! | `NORMAL` | `VEC3` f32 | only if the mesh has normals; re-normalised, zero normals become `+Z` |
//! | `TEXCOORD_0` | `VEC2` f32 | only if the mesh has UVs |
//! | target *k* `POSITION` | `VEC3` f32 | deltas, `min`/`max` written |
//! | animation input | `SCALAR` f32 | times in seconds, strictly increasing, `min`/`max` written |
//! | animation output | `SCALAR` f32 | `keyframes * targets` weights, keyframe-major |
//!
//! The scene has one node holding the mesh; the animation (if given) has one
//! `LINEAR` sampler driving the node's `weights`, and with [`write_glb_animated`] two
//! more driving the node's `translation` (`VEC3`) and `rotation` (`VEC4` quaternion)
//! on the same keyframe times, plus the frame rate in `animations[0].extras.fps`. Target names go to
//! `mesh.extras.targetNames`. Output passes the Khronos glTF validator with zero
//! errors (`scripts/validate_gltf.sh`, exercised by `tests/mesh_io.rs`). Files are
//! written atomically ([`facecap_core::atomic`]).

use std::path::Path;

use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use nalgebra::{Point3, Vector3};
use serde_json::{json, Value};

use facecap_core::atomic::write_atomic;
use facecap_core::error::{Error, Result};
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};

const FORMAT: &str = "glTF";
/// glTF `bufferView.target` for vertex attributes.
const ARRAY_BUFFER: u32 = 34962;
/// glTF `bufferView.target` for indices.
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// glTF `componentType` for f32.
const COMPONENT_F32: u32 = 5126;
/// glTF `componentType` for u32.
const COMPONENT_U32: u32 = 5125;
/// GLB magic `glTF`.
const GLB_MAGIC: u32 = 0x4654_6C67;
/// GLB chunk type `JSON`.
const GLB_CHUNK_JSON: u32 = 0x4E4F_534A;
/// GLB chunk type `BIN\0`.
const GLB_CHUNK_BIN: u32 = 0x004E_4942;
/// Generator string written to `asset.generator`.
const GENERATOR: &str = concat!("facecap ", env!("CARGO_PKG_VERSION"));

/// An animation of the morph weights: one keyframe per video frame.
///
/// `times_s[i]` is the presentation time of keyframe `i` in seconds (finite,
/// `>= 0`, strictly increasing); `weights[i]` holds one weight per morph target.
/// Interpolation between keyframes is linear.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MorphAnimation {
    /// Keyframe times in seconds.
    pub times_s: Vec<f32>,
    /// Per keyframe, one weight per morph target.
    pub weights: Vec<Vec<f32>>,
}

impl MorphAnimation {
    /// Checks the animation against a rig with `num_targets` targets.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for an empty animation, non-finite, negative or
    /// non-increasing times, or non-finite weights; [`Error::DimensionMismatch`] when
    /// the number of weight rows or of weights per row is wrong.
    pub fn validate(&self, num_targets: usize) -> Result<()> {
        if self.times_s.is_empty() {
            return Err(Error::invalid("animation.times_s", "[]", "at least one keyframe"));
        }
        if num_targets == 0 {
            return Err(Error::invalid(
                "animation",
                "a mesh without morph targets",
                "a mesh with at least one morph target",
            ));
        }
        if self.weights.len() != self.times_s.len() {
            return Err(Error::DimensionMismatch {
                what: "animation weight rows (one per keyframe)".into(),
                expected: self.times_s.len(),
                got: self.weights.len(),
            });
        }
        let mut prev = f32::NEG_INFINITY;
        for (i, &t) in self.times_s.iter().enumerate() {
            if !t.is_finite() || t < 0.0 {
                return Err(Error::invalid(
                    "animation.times_s",
                    format!("keyframe {i} = {t}"),
                    "finite seconds >= 0",
                ));
            }
            if t <= prev {
                return Err(Error::invalid(
                    "animation.times_s",
                    format!("keyframe {i} = {t} after {prev}"),
                    "strictly increasing times",
                ));
            }
            prev = t;
        }
        for (i, row) in self.weights.iter().enumerate() {
            if row.len() != num_targets {
                return Err(Error::DimensionMismatch {
                    what: format!("weights of keyframe {i} (one per morph target)"),
                    expected: num_targets,
                    got: row.len(),
                });
            }
            if let Some(k) = row.iter().position(|w| !w.is_finite()) {
                return Err(Error::invalid(
                    "animation.weights",
                    format!("keyframe {i} target {k} = {}", row[k]),
                    "finite numbers",
                ));
            }
        }
        Ok(())
    }
}

/// Rigid motion of the mesh's node, one transform per keyframe of a [`MorphAnimation`]
/// (the head pose): glTF `translation` and `rotation` channels beside the `weights`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NodeTrack {
    /// Per keyframe, the node translation (glTF axes: +Y up, +Z toward the viewer).
    pub translations: Vec<[f32; 3]>,
    /// Per keyframe, the node rotation as a unit quaternion `[x, y, z, w]`.
    pub rotations: Vec<[f32; 4]>,
}

/// What [`write_glb_animated`] adds to a morph-weight animation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AnimationExtras<'a> {
    /// Node motion (head pose); `None` keeps the node still.
    pub node: Option<&'a NodeTrack>,
    /// Frame rate of the source video, written to `animations[0].extras.fps` (glTF has
    /// no frame-rate field; importers that read extras, and facecap's Blender script,
    /// use it).
    pub fps: Option<f64>,
}

impl NodeTrack {
    fn validate(&self, keyframes: usize) -> Result<()> {
        for (what, got) in [
            ("node translations (one per keyframe)", self.translations.len()),
            ("node rotations (one per keyframe)", self.rotations.len()),
        ] {
            if got != keyframes {
                return Err(Error::DimensionMismatch {
                    what: what.into(),
                    expected: keyframes,
                    got,
                });
            }
        }
        if let Some(i) = self.translations.iter().position(|t| !t.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(
                "node translation",
                format!("keyframe {i}"),
                "finite numbers",
            ));
        }
        for (i, q) in self.rotations.iter().enumerate() {
            let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            if !(n.is_finite() && (n - 1.0).abs() < 1e-3) {
                return Err(Error::invalid(
                    "node rotation",
                    format!("keyframe {i}: |q| = {n}"),
                    "a unit quaternion",
                ));
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------- reading

/// Reads a mesh with morph targets from a `.glb` or `.gltf` file (see module docs).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Parse`] for anything
/// malformed (bad GLB/JSON, not exactly one mesh primitive, accessors of the
/// wrong type or out of bounds, bad `targetNames`, indices out of range,
/// non-finite positions).
pub fn read_morph_mesh(path: impl AsRef<Path>) -> Result<MorphMesh> {
    read_morph_file(path).map(|(m, _)| m)
}

/// Reads the mesh (as [`read_morph_mesh`]) and, when the file has one, the first
/// animation channel driving the `weights` of a node that holds the mesh, as a
/// [`MorphAnimation`] (times and weights as stored; any interpolation mode).
///
/// # Errors
/// As [`read_morph_mesh`]; also [`Error::Parse`] when the animation's accessors are
/// malformed or do not hold one weight per target per keyframe.
pub fn read_morph_file(path: impl AsRef<Path>) -> Result<(MorphMesh, Option<MorphAnimation>)> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let base = path
        .parent()
        .map(|p| if p.as_os_str().is_empty() { Path::new(".") } else { p });
    read_morph_file_from_slice(&bytes, base).map_err(|e| e.at_path(path))
}

/// Reads a mesh with morph targets from GLB or glTF-JSON bytes. External buffer
/// URIs are resolved against `base_dir` (refused when `None`).
///
/// # Errors
/// As [`read_morph_mesh`] (the error's path is empty).
pub fn read_morph_mesh_from_slice(bytes: &[u8], base_dir: Option<&Path>) -> Result<MorphMesh> {
    read_morph_file_from_slice(bytes, base_dir).map(|(m, _)| m)
}

/// In-memory version of [`read_morph_file`].
///
/// # Errors
/// As [`read_morph_file`] (the error's path is empty).
pub fn read_morph_file_from_slice(
    bytes: &[u8],
    base_dir: Option<&Path>,
) -> Result<(MorphMesh, Option<MorphAnimation>)> {
    // The `gltf` crate (1.4.1) unwraps in places its validation does not cover
    // (e.g. gltf-json indexes `accessors[POSITION]` before checking the index, an
    // unknown animation path panics on access). We check the known cases first;
    // this unwind guard turns any remaining one into a parse error, not a crash.
    std::panic::catch_unwind(|| read_unguarded(bytes, base_dir))
        .unwrap_or_else(|_| Err(Error::parse(FORMAT, "", "glTF parser failed on malformed input")))
}

fn read_unguarded(bytes: &[u8], base_dir: Option<&Path>) -> Result<(MorphMesh, Option<MorphAnimation>)> {
    let perr = |reason: String| Error::parse(FORMAT, "", reason);
    let (doc, blob) = parse_document(bytes)?;
    let doc = &doc;
    let buffers = gltf::import_buffers(doc, base_dir, blob).map_err(|e| perr(e.to_string()))?;
    let buffers: Vec<&[u8]> = buffers.iter().map(|b| b.0.as_slice()).collect();
    let mesh = read_mesh(doc, &buffers)?;
    let anim = read_animation(doc, &buffers, mesh.targets.len())?;
    Ok((mesh, anim))
}

/// Parses GLB/JSON without validation, pre-checks what gltf-json's validator
/// indexes unchecked, then validates.
fn parse_document(bytes: &[u8]) -> Result<(gltf::Document, Option<Vec<u8>>)> {
    let perr = |reason: String| Error::parse(FORMAT, "", reason);
    let raw = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| perr(e.to_string()))?;
    let root = raw.document.into_json();
    let n_acc = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let pos = prim
                .attributes
                .get(&gltf::json::validation::Checked::Valid(gltf::Semantic::Positions));
            if let Some(i) = pos {
                if i.value() >= n_acc {
                    return Err(perr(format!(
                        "meshes[{m}].primitives[{p}].attributes.POSITION = {} but there are {n_acc} accessors",
                        i.value()
                    )));
                }
            }
        }
    }
    let doc = gltf::Document::from_json(root).map_err(|e| perr(e.to_string()))?;
    Ok((doc, raw.blob))
}

fn read_animation(doc: &gltf::Document, buffers: &[&[u8]], num_targets: usize) -> Result<Option<MorphAnimation>> {
    let perr = |reason: String| Error::parse(FORMAT, "", reason);
    use gltf::json::validation::Checked;
    let json = doc.as_json();
    for (a, anim) in doc.animations().enumerate() {
        for (c, ch) in anim.channels().enumerate() {
            let Some(jch) = json.animations.get(a).and_then(|ja| ja.channels.get(c)) else {
                continue;
            };
            if jch.target.path != Checked::Valid(gltf::animation::Property::MorphTargetWeights) {
                continue;
            }
            // Check by hand what the gltf accessors below would unwrap.
            let node_has_mesh = json
                .nodes
                .get(jch.target.node.value())
                .is_some_and(|n| n.mesh.is_some_and(|m| m.value() < json.meshes.len()));
            if !node_has_mesh {
                continue;
            }
            let n_acc = json.accessors.len();
            let sampler_ok = json
                .animations
                .get(a)
                .and_then(|ja| ja.samplers.get(jch.sampler.value()))
                .is_some_and(|s| {
                    matches!(s.interpolation, Checked::Valid(_)) && s.input.value() < n_acc && s.output.value() < n_acc
                });
            if !sampler_ok {
                return Err(perr(format!("animations[{a}].channels[{c}] has an invalid sampler")));
            }
            let sampler = ch.sampler();
            let input = sampler.input();
            let output = sampler.output();
            if input.dimensions() != Dimensions::Scalar || input.data_type() != DataType::F32 {
                return Err(perr(format!(
                    "animation input accessor {} is not SCALAR F32",
                    input.index()
                )));
            }
            if output.dimensions() != Dimensions::Scalar || output.data_type() != DataType::F32 {
                return Err(perr(format!(
                    "animation output accessor {} is not SCALAR F32 (quantised weights are not supported)",
                    output.index()
                )));
            }
            let (tb, _) = accessor_bytes(&input, buffers, "animation input")?;
            let (wb, _) = accessor_bytes(&output, buffers, "animation output")?;
            let times: Vec<f32> = tb.chunks_exact(4).map(|c| f32_at(c, 0)).collect();
            let w: Vec<f32> = wb.chunks_exact(4).map(|c| f32_at(c, 0)).collect();
            let per_key = match sampler.interpolation() {
                gltf::animation::Interpolation::CubicSpline => 3 * num_targets,
                _ => num_targets,
            };
            if num_targets == 0 || w.len() != times.len() * per_key {
                return Err(perr(format!(
                    "animation output has {} values for {} keyframes and {num_targets} targets",
                    w.len(),
                    times.len()
                )));
            }
            // For cubic splines keep the value (middle third) of each keyframe.
            let skip = if per_key == num_targets { 0 } else { num_targets };
            let weights = w
                .chunks_exact(per_key)
                .map(|c| c[skip..skip + num_targets].to_vec())
                .collect();
            return Ok(Some(MorphAnimation {
                times_s: times,
                weights,
            }));
        }
    }
    Ok(None)
}

fn read_mesh(doc: &gltf::Document, buffers: &[&[u8]]) -> Result<MorphMesh> {
    let perr = |reason: String| Error::parse(FORMAT, "", reason);
    let meshes: Vec<gltf::Mesh> = doc.meshes().collect();
    if meshes.len() != 1 {
        return Err(perr(format!("expected exactly one mesh, found {}", meshes.len())));
    }
    let mesh = &meshes[0];
    let prims: Vec<gltf::Primitive> = mesh.primitives().collect();
    if prims.len() != 1 {
        return Err(perr(format!(
            "expected exactly one primitive in mesh 0, found {}",
            prims.len()
        )));
    }
    let prim = &prims[0];

    let pos_acc = prim
        .get(&gltf::Semantic::Positions)
        .ok_or_else(|| perr("primitive has no POSITION attribute".into()))?;
    let positions = read_vec3(&pos_acc, buffers, "POSITION")?;
    let n = positions.len();
    if n == 0 {
        return Err(perr("POSITION accessor has no vertices".into()));
    }

    let normals = match prim.get(&gltf::Semantic::Normals) {
        Some(acc) => {
            let v = read_vec3(&acc, buffers, "NORMAL")?;
            check_count(v.len(), n, "NORMAL")?;
            v.into_iter().map(|a| Vector3::new(a[0], a[1], a[2])).collect()
        }
        None => Vec::new(),
    };
    let uvs = match prim.get(&gltf::Semantic::TexCoords(0)) {
        Some(acc) => {
            let v = read_texcoords(&acc, buffers)?;
            check_count(v.len(), n, "TEXCOORD_0")?;
            v
        }
        None => Vec::new(),
    };

    let indices: Vec<u32> = match prim.indices() {
        Some(acc) => read_indices(&acc, buffers)?,
        None => (0..n as u32).collect(),
    };
    let triangles = assemble_triangles(prim.mode(), &indices)?;

    let mut targets = Vec::new();
    for (k, target) in prim.morph_targets().enumerate() {
        let deltas = match target.positions() {
            Some(acc) => {
                let what = format!("morph target {k} POSITION");
                let v = read_vec3(&acc, buffers, &what)?;
                check_count(v.len(), n, &what)?;
                v.into_iter().map(|a| Vector3::new(a[0], a[1], a[2])).collect()
            }
            None => vec![Vector3::zeros(); n],
        };
        targets.push(MorphTarget {
            name: format!("target_{k}"),
            deltas,
        });
    }
    if let Some(names) = target_names(mesh, targets.len())? {
        for (t, name) in targets.iter_mut().zip(names) {
            t.name = name;
        }
    }

    let out = MorphMesh {
        base: Mesh {
            positions: positions.into_iter().map(|a| Point3::new(a[0], a[1], a[2])).collect(),
            triangles,
            normals,
            uvs,
        },
        targets,
    };
    out.validate().map_err(|e| perr(e.to_string()))?;
    Ok(out)
}

fn check_count(got: usize, expected: usize, what: &str) -> Result<()> {
    if got != expected {
        return Err(Error::parse(
            FORMAT,
            "",
            format!("{what} has {got} elements, POSITION has {expected}"),
        ));
    }
    Ok(())
}

fn target_names(mesh: &gltf::Mesh, count: usize) -> Result<Option<Vec<String>>> {
    let Some(raw) = mesh.extras() else {
        return Ok(None);
    };
    let extras: Value = serde_json::from_str(raw.get())
        .map_err(|e| Error::parse(FORMAT, "", format!("mesh.extras is not JSON: {e}")))?;
    let Some(names) = extras.get("targetNames") else {
        return Ok(None);
    };
    let arr = names
        .as_array()
        .ok_or_else(|| Error::parse(FORMAT, "", "mesh.extras.targetNames is not an array"))?;
    if arr.len() != count {
        return Err(Error::parse(
            FORMAT,
            "",
            format!(
                "mesh.extras.targetNames has {} names for {count} morph targets",
                arr.len()
            ),
        ));
    }
    arr.iter()
        .enumerate()
        .map(|(i, v)| {
            v.as_str()
                .map(str::to_owned)
                .ok_or_else(|| Error::parse(FORMAT, "", format!("mesh.extras.targetNames[{i}] is not a string")))
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

fn assemble_triangles(mode: Mode, idx: &[u32]) -> Result<Vec<[u32; 3]>> {
    let perr = |r: String| Error::parse(FORMAT, "", r);
    match mode {
        Mode::Triangles => {
            if idx.len() % 3 != 0 {
                return Err(perr(format!("{} triangle indices is not a multiple of 3", idx.len())));
            }
            Ok(idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        }
        Mode::TriangleStrip => Ok((2..idx.len())
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i - 2], idx[i - 1], idx[i]]
                } else {
                    [idx[i - 1], idx[i - 2], idx[i]]
                }
            })
            .collect()),
        Mode::TriangleFan => Ok((2..idx.len()).map(|i| [idx[0], idx[i - 1], idx[i]]).collect()),
        other => Err(perr(format!("primitive mode {other:?} is not a triangle mode"))),
    }
}

/// Bounds-checked access to one accessor's elements (dense or sparse).
/// Returns the raw little-endian bytes of each element, concatenated, `elem` bytes each.
fn accessor_bytes(acc: &gltf::Accessor, buffers: &[&[u8]], what: &str) -> Result<(Vec<u8>, usize)> {
    let perr = |r: String| Error::parse(FORMAT, "", format!("{what} accessor {}: {r}", acc.index()));
    let elem = acc.size();
    let count = acc.count();
    let total = count
        .checked_mul(elem)
        .ok_or_else(|| perr(format!("count {count} too large")))?;
    // Every size read from the file is checked against the bytes present before
    // anything is allocated: a dense accessor's last element must lie inside its view;
    // an accessor without a view (zeros plus sparse values) may not claim more bytes
    // than all buffers hold together (nothing else bounds it).
    let dense = match acc.view() {
        Some(view) => {
            let stride = view.stride().unwrap_or(elem);
            if stride < elem {
                return Err(perr(format!("byteStride {stride} smaller than element size {elem}")));
            }
            let data = view_slice(&view, buffers).ok_or_else(|| perr("buffer view out of buffer bounds".into()))?;
            if count > 0 {
                let end = (count - 1)
                    .checked_mul(stride)
                    .and_then(|x| x.checked_add(acc.offset()))
                    .and_then(|x| x.checked_add(elem));
                match end {
                    Some(end) if end <= data.len() => {}
                    _ => {
                        return Err(perr(format!(
                            "count {count} x stride {stride} + offset {} exceeds its buffer view of {} bytes",
                            acc.offset(),
                            data.len()
                        )))
                    }
                }
            }
            Some((data, stride))
        }
        None => {
            let present: usize = buffers.iter().map(|b| b.len()).sum();
            if total > present {
                return Err(perr(format!(
                    "count {count} without a buffer view needs {total} bytes, the file's buffers hold {present}"
                )));
            }
            None
        }
    };
    if let Some(sparse) = acc.sparse() {
        let m = sparse.count();
        if m > count {
            return Err(perr(format!("sparse count {m} > accessor count {count}")));
        }
    }
    let mut out = vec![0u8; total];
    if let Some((data, stride)) = dense {
        for i in 0..count {
            let start = acc
                .offset()
                .checked_add(i.checked_mul(stride).ok_or_else(|| perr("offset overflow".into()))?)
                .ok_or_else(|| perr("offset overflow".into()))?;
            let src = data
                .get(start..start.saturating_add(elem))
                .ok_or_else(|| perr(format!("element {i} lies outside its buffer view")))?;
            out[i * elem..(i + 1) * elem].copy_from_slice(src);
        }
    }
    if let Some(sparse) = acc.sparse() {
        let m = sparse.count();
        let ind = sparse.indices();
        let isize_ = ind.index_type().size();
        let idata = view_slice(&ind.view(), buffers).ok_or_else(|| perr("sparse index view out of bounds".into()))?;
        let vals = sparse.values();
        let vdata = view_slice(&vals.view(), buffers).ok_or_else(|| perr("sparse value view out of bounds".into()))?;
        for j in 0..m {
            let at = ind.offset().saturating_add(j.saturating_mul(isize_));
            let ib = idata
                .get(at..at.saturating_add(isize_))
                .ok_or_else(|| perr(format!("sparse index {j} out of bounds")))?;
            let target = match isize_ {
                1 => ib[0] as usize,
                2 => u16::from_le_bytes([ib[0], ib[1]]) as usize,
                _ => u32::from_le_bytes([ib[0], ib[1], ib[2], ib[3]]) as usize,
            };
            if target >= count {
                return Err(perr(format!("sparse index {target} >= count {count}")));
            }
            let vat = vals.offset().saturating_add(j.saturating_mul(elem));
            let vb = vdata
                .get(vat..vat.saturating_add(elem))
                .ok_or_else(|| perr(format!("sparse value {j} out of bounds")))?;
            out[target * elem..(target + 1) * elem].copy_from_slice(vb);
        }
    }
    Ok((out, elem))
}

fn view_slice<'b>(view: &gltf::buffer::View, buffers: &[&'b [u8]]) -> Option<&'b [u8]> {
    let buf = buffers.get(view.buffer().index())?;
    let start = view.offset();
    buf.get(start..start.checked_add(view.length())?)
}

fn read_vec3(acc: &gltf::Accessor, buffers: &[&[u8]], what: &str) -> Result<Vec<[f32; 3]>> {
    if acc.dimensions() != Dimensions::Vec3 || acc.data_type() != DataType::F32 {
        return Err(Error::parse(
            FORMAT,
            "",
            format!(
                "{what} accessor {} is {:?} {:?}, expected Vec3 F32",
                acc.index(),
                acc.dimensions(),
                acc.data_type()
            ),
        ));
    }
    let (bytes, _) = accessor_bytes(acc, buffers, what)?;
    Ok(bytes
        .chunks_exact(12)
        .map(|c| [f32_at(c, 0), f32_at(c, 4), f32_at(c, 8)])
        .collect())
}

fn f32_at(c: &[u8], o: usize) -> f32 {
    f32::from_le_bytes([c[o], c[o + 1], c[o + 2], c[o + 3]])
}

fn read_texcoords(acc: &gltf::Accessor, buffers: &[&[u8]]) -> Result<Vec<[f32; 2]>> {
    if acc.dimensions() != Dimensions::Vec2 {
        return Err(Error::parse(
            FORMAT,
            "",
            format!(
                "TEXCOORD_0 accessor {} is {:?}, expected Vec2",
                acc.index(),
                acc.dimensions()
            ),
        ));
    }
    let (bytes, elem) = accessor_bytes(acc, buffers, "TEXCOORD_0")?;
    let conv: fn(&[u8]) -> [f32; 2] = match acc.data_type() {
        DataType::F32 => |c| [f32_at(c, 0), f32_at(c, 4)],
        DataType::U8 if acc.normalized() => |c| [c[0] as f32 / 255.0, c[1] as f32 / 255.0],
        DataType::U16 if acc.normalized() => |c| {
            [
                u16::from_le_bytes([c[0], c[1]]) as f32 / 65535.0,
                u16::from_le_bytes([c[2], c[3]]) as f32 / 65535.0,
            ]
        },
        other => {
            return Err(Error::parse(
                FORMAT,
                "",
                format!(
                    "TEXCOORD_0 component type {other:?} (normalized = {}) not allowed",
                    acc.normalized()
                ),
            ))
        }
    };
    Ok(bytes.chunks_exact(elem).map(conv).collect())
}

fn read_indices(acc: &gltf::Accessor, buffers: &[&[u8]]) -> Result<Vec<u32>> {
    if acc.dimensions() != Dimensions::Scalar {
        return Err(Error::parse(FORMAT, "", "index accessor is not SCALAR"));
    }
    let (bytes, elem) = accessor_bytes(acc, buffers, "indices")?;
    match acc.data_type() {
        DataType::U8 => Ok(bytes.into_iter().map(u32::from).collect()),
        DataType::U16 => Ok(bytes
            .chunks_exact(elem)
            .map(|c| u32::from(u16::from_le_bytes([c[0], c[1]])))
            .collect()),
        DataType::U32 => Ok(bytes
            .chunks_exact(elem)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()),
        other => Err(Error::parse(
            FORMAT,
            "",
            format!("index component type {other:?} not allowed"),
        )),
    }
}

// ---------------------------------------------------------------- writing

/// Writes a binary glTF (`.glb`) file atomically (see module docs).
///
/// # Errors
/// [`Error::InvalidParameter`]/[`Error::DimensionMismatch`] when the mesh is
/// empty, inconsistent or non-finite, or the animation does not fit it (see
/// [`MorphAnimation::validate`]); [`Error::Io`] on write failure.
pub fn write_glb(path: impl AsRef<Path>, mesh: &MorphMesh, animation: Option<&MorphAnimation>) -> Result<()> {
    let (json, bin) = build_document(mesh, animation, None)?;
    let bytes = glb_bytes(&json, &bin)?;
    write_atomic(path, |w| w.write_all(&bytes))
}

/// Writes a binary glTF file atomically with a morph-weight animation plus the node's
/// rigid motion and the frame rate ([`AnimationExtras`]).
///
/// # Errors
/// As [`write_glb`]; also when the node track does not have one finite transform (unit
/// quaternion) per keyframe, or the frame rate is not finite and positive.
pub fn write_glb_animated(
    path: impl AsRef<Path>,
    mesh: &MorphMesh,
    animation: &MorphAnimation,
    extras: &AnimationExtras<'_>,
) -> Result<()> {
    let (json, bin) = build_document_with(mesh, Some(animation), None, extras)?;
    let bytes = glb_bytes(&json, &bin)?;
    write_atomic(path, |w| w.write_all(&bytes))
}

/// Writes a JSON glTF (`.gltf`) file atomically with its buffer embedded as a
/// base64 `data:` URI (a single self-contained file).
///
/// # Errors
/// As [`write_glb`].
pub fn write_gltf(path: impl AsRef<Path>, mesh: &MorphMesh, animation: Option<&MorphAnimation>) -> Result<()> {
    let (mut json, bin) = build_document(mesh, animation, None)?;
    json["buffers"][0]["uri"] = Value::String(format!("data:application/octet-stream;base64,{}", base64(&bin)));
    let text =
        serde_json::to_string_pretty(&json).map_err(|e| Error::invalid("glTF document", e, "serialisable JSON"))?;
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Writes `.glb` or `.gltf` according to the extension of `path` (case-insensitive).
///
/// # Errors
/// [`Error::InvalidParameter`] for another extension; otherwise as [`write_glb`].
pub fn write_morph_file(path: impl AsRef<Path>, mesh: &MorphMesh, animation: Option<&MorphAnimation>) -> Result<()> {
    let path = path.as_ref();
    match path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .as_deref()
    {
        Some("glb") => write_glb(path, mesh, animation),
        Some("gltf") => write_gltf(path, mesh, animation),
        _ => Err(Error::invalid(
            "output path",
            path.display(),
            "a file ending in .glb or .gltf",
        )),
    }
}

/// Serialises into GLB bytes in memory (for callers that stream elsewhere).
///
/// # Errors
/// As [`write_glb`] without the I/O.
pub fn glb_to_vec(mesh: &MorphMesh, animation: Option<&MorphAnimation>) -> Result<Vec<u8>> {
    let (json, bin) = build_document(mesh, animation, None)?;
    glb_bytes(&json, &bin)
}

struct BinBuilder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl BinBuilder {
    /// Appends a tightly packed view and one accessor over it; returns the accessor index.
    fn push(
        &mut self,
        data: &[u8],
        target: Option<u32>,
        component: u32,
        count: usize,
        ty: &str,
        minmax: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        debug_assert_eq!(self.bin.len() % 4, 0);
        let offset = self.bin.len();
        self.bin.extend_from_slice(data);
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let mut view = json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len()});
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.views.push(view);
        let mut acc = json!({
            "bufferView": self.views.len() - 1,
            "componentType": component,
            "count": count,
            "type": ty,
        });
        if let Some((min, max)) = minmax {
            acc["min"] = json!(min.iter().map(|&v| f64::from(v)).collect::<Vec<f64>>());
            acc["max"] = json!(max.iter().map(|&v| f64::from(v)).collect::<Vec<f64>>());
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }
}

fn vec3_bytes_minmax(v: impl Iterator<Item = [f32; 3]>) -> (Vec<u8>, Vec<f32>, Vec<f32>) {
    let mut bytes = Vec::new();
    let mut min = vec![f32::INFINITY; 3];
    let mut max = vec![f32::NEG_INFINITY; 3];
    for p in v {
        for (k, c) in p.into_iter().enumerate() {
            bytes.extend_from_slice(&c.to_le_bytes());
            min[k] = min[k].min(c);
            max[k] = max[k].max(c);
        }
    }
    (bytes, min, max)
}

fn check_finite_attrs(mesh: &MorphMesh) -> Result<()> {
    let bad3 = |v: &Vector3<f32>| !(v.x.is_finite() && v.y.is_finite() && v.z.is_finite());
    if let Some(i) = mesh.base.normals.iter().position(bad3) {
        return Err(Error::invalid(
            "vertex normal",
            format!("vertex {i}"),
            "finite components",
        ));
    }
    if let Some(i) = mesh
        .base
        .uvs
        .iter()
        .position(|u| !(u[0].is_finite() && u[1].is_finite()))
    {
        return Err(Error::invalid("vertex uv", format!("vertex {i}"), "finite components"));
    }
    for t in &mesh.targets {
        if let Some(i) = t.deltas.iter().position(bad3) {
            return Err(Error::invalid(
                "morph target delta",
                format!("target {:?} vertex {i}", t.name),
                "finite components",
            ));
        }
    }
    Ok(())
}

/// Builds the glTF JSON (with a `byteLength` but no `uri` on the buffer) and the binary payload.
fn build_document(
    mesh: &MorphMesh,
    animation: Option<&MorphAnimation>,
    name: Option<&str>,
) -> Result<(Value, Vec<u8>)> {
    build_document_with(mesh, animation, name, &AnimationExtras::default())
}

fn build_document_with(
    mesh: &MorphMesh,
    animation: Option<&MorphAnimation>,
    name: Option<&str>,
    extras: &AnimationExtras<'_>,
) -> Result<(Value, Vec<u8>)> {
    mesh.validate()?;
    check_finite_attrs(mesh)?;
    let n = mesh.base.num_vertices();
    if n == 0 {
        return Err(Error::invalid("mesh", "0 vertices", "at least one vertex"));
    }
    if mesh.base.triangles.is_empty() {
        return Err(Error::invalid("mesh", "0 triangles", "at least one triangle"));
    }
    if n > u32::MAX as usize {
        return Err(Error::invalid(
            "mesh",
            format!("{n} vertices"),
            "fewer than 2^32 vertices",
        ));
    }
    if let Some(anim) = animation {
        anim.validate(mesh.targets.len())?;
        if let Some(track) = extras.node {
            track.validate(anim.times_s.len())?;
        }
    }
    if let Some(fps) = extras.fps {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Error::invalid("animation fps", fps, "a finite number > 0"));
        }
    }
    let mut b = BinBuilder {
        bin: Vec::new(),
        views: Vec::new(),
        accessors: Vec::new(),
    };

    let idx: Vec<u8> = mesh
        .base
        .triangles
        .iter()
        .flat_map(|t| t.iter().flat_map(|i| i.to_le_bytes()))
        .collect();
    let idx_acc = b.push(
        &idx,
        Some(ELEMENT_ARRAY_BUFFER),
        COMPONENT_U32,
        mesh.base.triangles.len() * 3,
        "SCALAR",
        None,
    );

    let (pos, min, max) = vec3_bytes_minmax(mesh.base.positions.iter().map(|p| [p.x, p.y, p.z]));
    let pos_acc = b.push(&pos, Some(ARRAY_BUFFER), COMPONENT_F32, n, "VEC3", Some((min, max)));
    let mut attributes = json!({ "POSITION": pos_acc });

    if !mesh.base.normals.is_empty() {
        let unit = mesh.base.normals.iter().map(|v| {
            let len = v.norm();
            if len > 0.0 && len.is_finite() {
                let u = v / len;
                [u.x, u.y, u.z]
            } else {
                [0.0, 0.0, 1.0]
            }
        });
        let (bytes, _, _) = vec3_bytes_minmax(unit);
        attributes["NORMAL"] = json!(b.push(&bytes, Some(ARRAY_BUFFER), COMPONENT_F32, n, "VEC3", None));
    }
    if !mesh.base.uvs.is_empty() {
        let bytes: Vec<u8> = mesh
            .base
            .uvs
            .iter()
            .flat_map(|uv| uv.iter().flat_map(|c| c.to_le_bytes()))
            .collect();
        attributes["TEXCOORD_0"] = json!(b.push(&bytes, Some(ARRAY_BUFFER), COMPONENT_F32, n, "VEC2", None));
    }

    let mut targets = Vec::with_capacity(mesh.targets.len());
    for t in &mesh.targets {
        let (bytes, min, max) = vec3_bytes_minmax(t.deltas.iter().map(|d| [d.x, d.y, d.z]));
        let acc = b.push(&bytes, Some(ARRAY_BUFFER), COMPONENT_F32, n, "VEC3", Some((min, max)));
        targets.push(json!({ "POSITION": acc }));
    }

    let mut primitive = json!({ "attributes": attributes, "indices": idx_acc, "mode": 4 });
    let mut gltf_mesh = json!({ "name": name.unwrap_or("face"), "primitives": [] });
    if !targets.is_empty() {
        primitive["targets"] = Value::Array(targets);
        gltf_mesh["weights"] = json!(vec![0.0f64; mesh.targets.len()]);
        gltf_mesh["extras"] = json!({ "targetNames": mesh.target_names() });
    }
    gltf_mesh["primitives"] = json!([primitive]);

    let mut root = json!({
        "asset": { "version": "2.0", "generator": GENERATOR },
        "scene": 0,
        "scenes": [ { "nodes": [0] } ],
        "nodes": [ { "name": name.unwrap_or("face"), "mesh": 0 } ],
        "meshes": [ gltf_mesh ],
    });

    if let Some(anim) = animation {
        let times: Vec<u8> = anim.times_s.iter().flat_map(|t| t.to_le_bytes()).collect();
        let tmin = anim.times_s.first().copied().unwrap_or(0.0);
        let tmax = anim.times_s.last().copied().unwrap_or(0.0);
        let in_acc = b.push(
            &times,
            None,
            COMPONENT_F32,
            anim.times_s.len(),
            "SCALAR",
            Some((vec![tmin], vec![tmax])),
        );
        let weights: Vec<u8> = anim
            .weights
            .iter()
            .flat_map(|row| row.iter().flat_map(|w| w.to_le_bytes()))
            .collect();
        let out_acc = b.push(
            &weights,
            None,
            COMPONENT_F32,
            anim.times_s.len() * mesh.targets.len(),
            "SCALAR",
            None,
        );
        let mut samplers = vec![json!({ "input": in_acc, "output": out_acc, "interpolation": "LINEAR" })];
        let mut channels = vec![json!({ "sampler": 0, "target": { "node": 0, "path": "weights" } })];
        if let Some(track) = extras.node {
            let (tb, tmin, tmax) = vec3_bytes_minmax(track.translations.iter().copied());
            let t_acc = b.push(
                &tb,
                None,
                COMPONENT_F32,
                track.translations.len(),
                "VEC3",
                Some((tmin, tmax)),
            );
            let rb: Vec<u8> = track
                .rotations
                .iter()
                .flat_map(|q| q.iter().flat_map(|c| c.to_le_bytes()))
                .collect();
            let r_acc = b.push(&rb, None, COMPONENT_F32, track.rotations.len(), "VEC4", None);
            samplers.push(json!({ "input": in_acc, "output": t_acc, "interpolation": "LINEAR" }));
            samplers.push(json!({ "input": in_acc, "output": r_acc, "interpolation": "LINEAR" }));
            channels.push(json!({ "sampler": 1, "target": { "node": 0, "path": "translation" } }));
            channels.push(json!({ "sampler": 2, "target": { "node": 0, "path": "rotation" } }));
        }
        let mut animation = json!({
            "name": "morph_weights",
            "samplers": samplers,
            "channels": channels,
        });
        if let Some(fps) = extras.fps {
            animation["extras"] = json!({ "fps": fps, "frames": anim.times_s.len() });
        }
        root["animations"] = json!([animation]);
    }

    root["accessors"] = Value::Array(b.accessors);
    root["bufferViews"] = Value::Array(b.views);
    root["buffers"] = json!([ { "byteLength": b.bin.len() } ]);
    Ok((root, b.bin))
}

fn glb_bytes(json: &Value, bin: &[u8]) -> Result<Vec<u8>> {
    let mut js = serde_json::to_vec(json).map_err(|e| Error::invalid("glTF document", e, "serialisable JSON"))?;
    while js.len() % 4 != 0 {
        js.push(b' ');
    }
    let mut bin = bin.to_vec();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let total32 = u32::try_from(total).map_err(|_| Error::invalid("GLB size", total, "< 4 GiB"))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&GLB_MAGIC.to_le_bytes());
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(&GLB_CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&GLB_CHUNK_BIN.to_le_bytes());
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Standard base64 (RFC 4648) with padding.
fn base64(data: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for chunk in data.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let v = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[((v >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn strip_and_fan_assembly() {
        assert_eq!(
            assemble_triangles(Mode::TriangleStrip, &[0, 1, 2, 3]).unwrap(),
            vec![[0, 1, 2], [2, 1, 3]]
        );
        assert_eq!(
            assemble_triangles(Mode::TriangleFan, &[0, 1, 2, 3]).unwrap(),
            vec![[0, 1, 2], [0, 2, 3]]
        );
        assert!(assemble_triangles(Mode::Triangles, &[0, 1]).is_err());
        assert!(assemble_triangles(Mode::Lines, &[0, 1]).is_err());
    }
}
