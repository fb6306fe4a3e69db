//! Sizes read from a file are checked against the bytes present before anything is
//! allocated: each case claims billions of elements in a file of a few hundred bytes and
//! must be a parse error (before the check, the first case aborted the process with
//! "memory allocation of 25769803776 bytes failed").
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use facecap_core::Error;
use facecap_io::gltf_io::{read_morph_file_from_slice, read_morph_mesh_from_slice};
use facecap_io::video::{open_source, Frame, SourceOptions};

/// Three vertices (36 bytes of f32) as a base64 data URI.
const TRI: &str = "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";

fn doc(accessors: &str, prim: &str, extra: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":36,"uri":"{TRI}"}}],
           "bufferViews":[{{"buffer":0,"byteLength":36}}],
           "accessors":[{accessors}],
           "meshes":[{{"primitives":[{prim}]}}]{extra}}}"#
    )
}

/// One sparse value (index 0) read from the start of the buffer.
const SPARSE1: &str =
    r#""sparse":{"count":1,"indices":{"bufferView":0,"componentType":5125},"values":{"bufferView":0}}"#;

const GOOD_POS: &str = r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#;

#[test]
fn huge_counts_are_parse_errors_not_allocations() {
    let big = 1u64 << 31;
    let cases = [
        // POSITION claims 2^31 elements in a 36-byte view.
        doc(
            &format!(
                r#"{{"bufferView":0,"componentType":5126,"count":{big},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}"#
            ),
            r#"{"attributes":{"POSITION":0}}"#,
            "",
        ),
        // POSITION without a buffer view (zeros plus one sparse value) claiming 2^31 elements.
        doc(
            &format!(r#"{{"componentType":5126,"count":{big},"type":"VEC3","min":[0,0,0],"max":[1,1,0],{SPARSE1}}}"#),
            r#"{"attributes":{"POSITION":0}}"#,
            "",
        ),
        // A morph target without a view claiming 2^31 deltas.
        doc(
            &format!(
                r#"{GOOD_POS},{{"componentType":5126,"count":{big},"type":"VEC3","min":[0,0,0],"max":[1,1,0],{SPARSE1}}}"#
            ),
            r#"{"attributes":{"POSITION":0},"targets":[{"POSITION":1}]}"#,
            "",
        ),
        // Indices claiming 2^31 u32 values.
        doc(
            &format!(r#"{GOOD_POS},{{"bufferView":0,"componentType":5125,"count":{big},"type":"SCALAR"}}"#),
            r#"{"attributes":{"POSITION":0},"indices":1}"#,
            "",
        ),
        // A sparse accessor with more sparse values than elements.
        doc(
            &format!(
                r#"{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0],
                   "sparse":{{"count":{big},"indices":{{"bufferView":0,"componentType":5125}},"values":{{"bufferView":0}}}}}}"#
            ),
            r#"{"attributes":{"POSITION":0}}"#,
            "",
        ),
        // Animation times claiming 2^31 keyframes.
        doc(
            &format!(r#"{GOOD_POS},{{"bufferView":0,"componentType":5126,"count":{big},"type":"SCALAR"}}"#),
            r#"{"attributes":{"POSITION":0},"targets":[{"POSITION":0}]}"#,
            r#","nodes":[{"mesh":0}],"animations":[{"samplers":[{"input":1,"output":1}],"channels":[{"sampler":0,"target":{"node":0,"path":"weights"}}]}]"#,
        ),
    ];
    for (i, c) in cases.iter().enumerate() {
        let r = read_morph_file_from_slice(c.as_bytes(), None);
        match r {
            Err(Error::Parse { reason, .. }) => {
                assert!(
                    reason.contains("exceeds") || reason.contains("needs") || reason.contains("sparse count"),
                    "case {i}: the error should name the size check: {reason}"
                );
            }
            other => panic!("case {i}: expected a parse error, got {other:?}"),
        }
    }
    // The same base with a count that fits reads (the check is not over-eager).
    let ok = doc(GOOD_POS, r#"{"attributes":{"POSITION":0}}"#, "");
    let m = read_morph_mesh_from_slice(ok.as_bytes(), None).unwrap();
    assert_eq!(m.base.positions.len(), 3);
}

#[test]
fn y4m_frame_size_is_checked_against_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("huge.y4m");
    let mut bytes = b"YUV4MPEG2 W32768 H32768 F25:1 C420jpeg\nFRAME\n".to_vec();
    bytes.extend_from_slice(&[16u8; 100]);
    std::fs::write(&p, &bytes).unwrap();
    let mut src = open_source(&p, &SourceOptions::default()).unwrap();
    let mut f = Frame::default();
    let e = src.read_into(&mut f).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("bytes after the header"), "{e}");
    // No frame buffer was allocated for the claimed size.
    assert_eq!(f.gray.len(), 0);
}
