//! # facecap-landmarks
//!
//! Face detection, 68-point landmark inference with dlib-compatible ensembles of
//! regression trees (Kazemi & Sullivan 2014), pyramidal Lucas-Kanade optical flow
//! (Bouguet 2001), a video landmark tracker combining them, and iris centres for gaze
//! from the grey frame and the eye landmarks ([`gaze`]).

pub mod detect;
pub mod error;
pub mod ert;
pub mod gaze;
pub mod lk;
pub mod tracker;

pub use error::{Error, Result};
