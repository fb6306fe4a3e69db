//! # facecap-io
//!
//! File formats of the facecap workspace, on top of `facecap-core`'s vocabulary:
//!
//! | module | holds |
//! |---|---|
//! | [`video`] | `FrameSource` (ffmpeg child process, native Y4M, image folders), `Frame`, `VideoInfo`, Y'CbCr conversion, encoding through ffmpeg |
//! | [`image_io`] | still-image loading (grey and RGB) |
//! | [`gltf_io`] | glTF/GLB with morph targets and weight animation |
//! | [`obj`] | Wavefront OBJ read/write |
//! | [`csv`] | the per-frame CSV (`frame,timestamp,success,confidence,...`) |
//! | [`formats`] | iBUG `.pts`, dlib imglab XML, menpo `.ljson` |
//! | [`livelink`] | Live Link Face CSV (`livelink.csv`): ARKit curve order, timecodes, head angles |
//!
//! Errors are `facecap_core::Error` (re-exported here), so a caller that already converts
//! core's error needs nothing new. Every file is written through `facecap_core::atomic`.

pub use facecap_core::{Error, Result};

pub mod csv;
pub mod formats;
pub mod gltf_io;
pub mod image_io;
pub mod livelink;
pub mod obj;
pub mod video;
