//! A TFLite flatbuffer reader and a small float32 interpreter for the operators of
//! MediaPipe's face detector and face landmark models.
//!
//! Supported: `DEQUANTIZE` of float16 constants (folded at load), `CONV_2D`,
//! `DEPTHWISE_CONV_2D` (depth multiplier 1), `MAX_POOL_2D`, `ADD` (same shapes), `PRELU`
//! (per-channel slopes), `RELU`, `LOGISTIC`, `PAD` (rank 4), `RESHAPE`, `CONCATENATION`;
//! fused activations NONE / RELU / RELU_N1_TO_1 / RELU6. Anything else is rejected at
//! load with an [`Error::Model`] naming it.
//!
//! * [`flatbuf`]: the bounds-checked FlatBuffers reader;
//! * [`model`]: the TFLite schema read into a checked [`Graph`] (float16 weights
//!   dequantised at load);
//! * [`kernels`]: the operators' kernels, portable and SIMD (AVX2+FMA and AVX-512 levels
//!   chosen at run time, every level giving the portable kernels' bits);
//! * [`interp`]: the [`Interpreter`] (a fixed plan of fused ops) and its [`Workspace`].
//!
//! `facecap-mesh` runs MediaPipe's face detector and face landmark models with it.
//!
//! ```no_run
//! use facecap_tflite::Interpreter;
//! # fn main() -> facecap_tflite::Result<()> {
//! let model = Interpreter::from_file("face_landmarks_detector.tflite".as_ref())?;
//! let mut ws = model.workspace();
//! model.input_mut(&mut ws, 0)?.fill(0.0); // the input image, NHWC float32
//! model.run(&mut ws)?;
//! println!("{} outputs", model.output(&ws, 0)?.len());
//! # Ok(())
//! # }
//! ```

pub mod error;
pub mod flatbuf;
pub mod interp;
pub mod kernels;
pub mod model;

pub use error::{Error, Result};
pub use interp::{Interpreter, Workspace};
pub use model::Graph;
