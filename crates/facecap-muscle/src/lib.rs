//! facecap-muscle (see crate docs).
