//! facecap-solve (see crate docs).
