//! A TFLite flatbuffer reader and a small float32 interpreter for the operators of
//! MediaPipe's face detector and face landmark models.
//!
//! Supported: `DEQUANTIZE` of float16 constants (folded at load), `CONV_2D`,
//! `DEPTHWISE_CONV_2D` (depth multiplier 1), `MAX_POOL_2D`, `ADD` (same shapes), `PRELU`
//! (per-channel slopes), `RELU`, `LOGISTIC`, `PAD` (rank 4), `RESHAPE`, `CONCATENATION`;
//! fused activations NONE / RELU / RELU_N1_TO_1 / RELU6. Anything else is rejected at
//! load with an [`Error::Model`](crate::Error::Model) naming it.

pub(crate) mod flatbuf;
pub mod interp;
pub mod kernels;
pub mod model;

pub use interp::{Interpreter, Workspace};
pub use model::Graph;
