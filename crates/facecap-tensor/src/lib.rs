//! facecap-tensor (see crate docs).
