//! Landmark annotation file formats.
//!
//! Every reader converts to **one convention**: 0-based pixel coordinates, centre of
//! the top-left pixel at `(0, 0)`, `x` right, `y` down (see [`facecap_core::landmarks`]).
//!
//! | format | module | in the file | conversion on read |
//! |---|---|---|---|
//! | iBUG `.pts` (300-W, LFPW, HELEN, menpo) | [`pts`] | 1-based `x y` | subtract 1 |
//! | dlib imglab XML | [`dlib_xml`] | 0-based integer `x`, `y`; boxes `top left width height` | none |
//! | menpo `.ljson` (v1, v2, v3) | [`ljson`] | 2D: 0-based `(y, x)`; 3D: `(x, y, z)` model units | 2D: swap to `(x, y)` |
//!
//! All writers go through [`facecap_core::atomic`]. Parsers return [`crate::Error::Parse`]
//! with a line number for malformed or truncated input and never panic.

pub mod dlib_xml;
pub mod ljson;
pub mod pts;

/// 1-based line number of a byte offset in `text`.
pub(crate) fn line_of(text: &str, byte: usize) -> usize {
    let end = byte.min(text.len());
    text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() + 1
}
