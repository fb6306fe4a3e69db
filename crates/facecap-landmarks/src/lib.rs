//! facecap-landmarks (see crate docs).
