//! The TFLite model file (schema v3) read into a checked graph.
//!
//! Only what MediaPipe's float face models need is read: the first subgraph's tensors
//! (shape, type, constant data), operators with their builtin options, and the graph's
//! inputs and outputs. Float16 constants are widened to f32 and `DEQUANTIZE` ops on
//! constants are folded away at load. Every operator's shapes are then checked against
//! what the operator computes (see [`Graph::check`]), so the kernels can index without
//! further checks.
//!
//! Field numbers follow `tensorflow/lite/schema/schema.fbs` (a union field takes two
//! slots: its `_type` byte, then the value).

use super::flatbuf::{Buf, Table};
use crate::{Error, Result};

fn bad(reason: impl Into<String>) -> Error {
    Error::Model { reason: reason.into() }
}

/// Builtin operator codes (`BuiltinOperator` in the schema) that we run.
mod code {
    pub const ADD: i32 = 0;
    pub const CONCATENATION: i32 = 2;
    pub const CONV_2D: i32 = 3;
    pub const DEPTHWISE_CONV_2D: i32 = 4;
    pub const DEQUANTIZE: i32 = 6;
    pub const LOGISTIC: i32 = 14;
    pub const MAX_POOL_2D: i32 = 17;
    pub const RELU: i32 = 19;
    pub const RESHAPE: i32 = 22;
    pub const PAD: i32 = 34;
    pub const PRELU: i32 = 54;
}

/// `TensorType` values we accept.
mod ttype {
    pub const FLOAT32: u8 = 0;
    pub const FLOAT16: u8 = 1;
    pub const INT32: u8 = 2;
}

/// Upper bound on any tensor's element count (guards allocations driven by the file).
const MAX_ELEMENTS: usize = 1 << 24;
/// Upper bound on tensor rank.
const MAX_RANK: usize = 6;

/// Padding scheme of convolutions and pools.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Padding {
    /// Output size `ceil(in / stride)`, the excess split with the smaller half before.
    Same,
    /// No padding: output size `floor((in - effective_kernel) / stride) + 1`.
    Valid,
}

/// Activation fused into an operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// Identity.
    None,
    /// `max(x, 0)`.
    Relu,
    /// `clamp(x, -1, 1)`.
    ReluN1To1,
    /// `clamp(x, 0, 6)`.
    Relu6,
}

impl Activation {
    fn from_code(c: u8) -> Result<Self> {
        Ok(match c {
            0 => Activation::None,
            1 => Activation::Relu,
            2 => Activation::ReluN1To1,
            3 => Activation::Relu6,
            _ => return Err(bad(format!("unsupported fused activation {c}"))),
        })
    }
    /// Applies the activation to one value.
    #[inline(always)]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Activation::None => x,
            Activation::Relu => x.max(0.0),
            Activation::ReluN1To1 => x.clamp(-1.0, 1.0),
            Activation::Relu6 => x.clamp(0.0, 6.0),
        }
    }
}

/// Geometry of a 2-D window operator (convolution or pool).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// Kernel height and width.
    pub kh: usize,
    /// Kernel width.
    pub kw: usize,
    /// Vertical stride.
    pub sh: usize,
    /// Horizontal stride.
    pub sw: usize,
    /// Vertical dilation.
    pub dh: usize,
    /// Horizontal dilation.
    pub dw: usize,
    /// Padding scheme.
    pub padding: Padding,
}

impl Window {
    /// Output size and padding before, for an input extent `n` along one axis, as
    /// TFLite's `ComputePaddingHeightWidth` does.
    pub fn out_and_pad(n: usize, k: usize, s: usize, d: usize, padding: Padding) -> Option<(usize, usize)> {
        let eff = k.checked_sub(1)?.checked_mul(d)?.checked_add(1)?;
        if s == 0 {
            return None;
        }
        match padding {
            Padding::Same => {
                let out = n.div_ceil(s);
                let need = (out.checked_sub(1)?).checked_mul(s)?.checked_add(eff)?;
                let total = need.saturating_sub(n);
                Some((out, total / 2))
            }
            Padding::Valid => {
                if n < eff {
                    return None;
                }
                Some(((n - eff) / s + 1, 0))
            }
        }
    }
}

/// One operator of the graph (tensor ids index [`Graph::tensors`]).
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)]
pub enum Op {
    Conv2d {
        input: usize,
        filter: usize,
        bias: Option<usize>,
        output: usize,
        win: Window,
        act: Activation,
    },
    DepthwiseConv2d {
        input: usize,
        filter: usize,
        bias: Option<usize>,
        output: usize,
        win: Window,
        act: Activation,
    },
    MaxPool2d {
        input: usize,
        output: usize,
        win: Window,
        act: Activation,
    },
    Add {
        a: usize,
        b: usize,
        output: usize,
        act: Activation,
    },
    Prelu {
        input: usize,
        alpha: usize,
        output: usize,
    },
    Relu {
        input: usize,
        output: usize,
    },
    Logistic {
        input: usize,
        output: usize,
    },
    Pad {
        input: usize,
        output: usize,
        /// `[before, after]` per axis.
        pads: Vec<[usize; 2]>,
    },
    Reshape {
        input: usize,
        output: usize,
    },
    Concat {
        inputs: Vec<usize>,
        output: usize,
        axis: usize,
        act: Activation,
    },
}

impl Op {
    /// Short operator name for messages.
    pub fn name(&self) -> &'static str {
        match self {
            Op::Conv2d { .. } => "CONV_2D",
            Op::DepthwiseConv2d { .. } => "DEPTHWISE_CONV_2D",
            Op::MaxPool2d { .. } => "MAX_POOL_2D",
            Op::Add { .. } => "ADD",
            Op::Prelu { .. } => "PRELU",
            Op::Relu { .. } => "RELU",
            Op::Logistic { .. } => "LOGISTIC",
            Op::Pad { .. } => "PAD",
            Op::Reshape { .. } => "RESHAPE",
            Op::Concat { .. } => "CONCATENATION",
        }
    }

    /// Tensors read by the operator (activations and constants).
    pub fn inputs(&self) -> Vec<usize> {
        match self {
            Op::Conv2d {
                input, filter, bias, ..
            }
            | Op::DepthwiseConv2d {
                input, filter, bias, ..
            } => {
                let mut v = vec![*input, *filter];
                v.extend(bias.iter().copied());
                v
            }
            Op::MaxPool2d { input, .. }
            | Op::Relu { input, .. }
            | Op::Logistic { input, .. }
            | Op::Pad { input, .. }
            | Op::Reshape { input, .. } => vec![*input],
            Op::Add { a, b, .. } => vec![*a, *b],
            Op::Prelu { input, alpha, .. } => vec![*input, *alpha],
            Op::Concat { inputs, .. } => inputs.clone(),
        }
    }

    /// The tensor written.
    pub fn output(&self) -> usize {
        match self {
            Op::Conv2d { output, .. }
            | Op::DepthwiseConv2d { output, .. }
            | Op::MaxPool2d { output, .. }
            | Op::Add { output, .. }
            | Op::Prelu { output, .. }
            | Op::Relu { output, .. }
            | Op::Logistic { output, .. }
            | Op::Pad { output, .. }
            | Op::Reshape { output, .. }
            | Op::Concat { output, .. } => *output,
        }
    }
}

/// A tensor of the graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    /// Name in the model file.
    pub name: String,
    /// Shape (row-major, TFLite's NHWC for images).
    pub shape: Vec<usize>,
    /// Constant f32 data (float32 or widened float16 constants), if any.
    pub data: Option<Vec<f32>>,
    /// Constant int32 data (PAD paddings, RESHAPE shapes), if any.
    pub int_data: Option<Vec<i32>>,
}

impl Tensor {
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }
    /// Whether the tensor has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Whether the tensor is a constant.
    pub fn is_const(&self) -> bool {
        self.data.is_some() || self.int_data.is_some()
    }
}

/// A checked TFLite graph: tensors, operators in execution order, inputs and outputs.
#[derive(Debug, Clone, PartialEq)]
pub struct Graph {
    /// All tensors.
    pub tensors: Vec<Tensor>,
    /// Operators in execution order (DEQUANTIZE of constants already folded).
    pub ops: Vec<Op>,
    /// Graph input tensor ids.
    pub inputs: Vec<usize>,
    /// Graph output tensor ids.
    pub outputs: Vec<usize>,
}

/// IEEE half -> single conversion (exact, including subnormals, inf and NaN).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h >> 15) as u32) << 31;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    let bits = if exp == 0 {
        if man == 0 {
            sign
        } else {
            // Subnormal: value = man * 2^-24.
            let v = man as f32 * (1.0 / 16_777_216.0);
            return if sign != 0 { -v } else { v };
        }
    } else if exp == 0x1f {
        sign | 0x7f80_0000 | (man << 13)
    } else {
        sign | ((exp + 112) << 23) | (man << 13)
    };
    f32::from_bits(bits)
}

fn tensor_id(raw: i32, n: usize, what: &str) -> Result<usize> {
    if raw < 0 || raw as usize >= n {
        return Err(bad(format!("{what}: tensor index {raw} out of range 0..{n}")));
    }
    Ok(raw as usize)
}

fn window(opts: &Table<'_>, kh: usize, kw: usize, fields: [usize; 5], what: &str) -> Result<Window> {
    // fields: padding, stride_w, stride_h, dilation_w, dilation_h
    let padding = match opts.u8_or(fields[0], 0, what)? {
        0 => Padding::Same,
        1 => Padding::Valid,
        p => return Err(bad(format!("{what}: unknown padding {p}"))),
    };
    let pos = |v: i32, name: &str| -> Result<usize> {
        if (1..=64).contains(&v) {
            Ok(v as usize)
        } else {
            Err(bad(format!("{what}: {name} = {v} outside 1..=64")))
        }
    };
    let sw = pos(opts.i32_or(fields[1], 0, what)?, "stride_w")?;
    let sh = pos(opts.i32_or(fields[2], 0, what)?, "stride_h")?;
    let (dw, dh) = if fields[3] == usize::MAX {
        (1, 1)
    } else {
        (
            pos(opts.i32_or(fields[3], 1, what)?, "dilation_w")?,
            pos(opts.i32_or(fields[4], 1, what)?, "dilation_h")?,
        )
    };
    Ok(Window {
        kh,
        kw,
        sh,
        sw,
        dh,
        dw,
        padding,
    })
}

impl Graph {
    /// Parses and checks a TFLite flatbuffer.
    ///
    /// # Errors
    /// [`Error::Model`] for a damaged file, an unsupported operator, tensor type or
    /// option, or shapes that do not agree with the operators.
    pub fn parse(bytes: &[u8]) -> Result<Graph> {
        let buf = Buf::new(bytes);
        if bytes.len() >= 8 && &bytes[4..8] != b"TFL3" {
            return Err(bad("not a TFLite model (file identifier is not TFL3)"));
        }
        let model = buf.root()?;
        let version = model.u32_or(0, 0, "model version")?;
        if version != 3 {
            return Err(bad(format!("unsupported schema version {version} (expected 3)")));
        }
        // Operator codes.
        let mut codes = Vec::new();
        if let Some(v) = model.vector(1, 4, "operator_codes")? {
            for i in 0..v.len() {
                let oc = v.table_at(i, "operator code")?;
                let deprecated = oc.u8_or(0, 0, "deprecated_builtin_code")? as i8 as i32;
                let builtin = oc.i32_or(3, 0, "builtin_code")?;
                codes.push(builtin.max(deprecated));
            }
        }
        // Buffers: (start, len) into `bytes`.
        let mut buffers = Vec::new();
        if let Some(v) = model.vector(4, 4, "buffers")? {
            for i in 0..v.len() {
                let b = v.table_at(i, "buffer")?;
                if let Some(d) = b.vector(0, 1, "buffer data")? {
                    buffers.push(d.bytes());
                } else {
                    let off = b.u64_or(1, 0, "buffer offset")?;
                    let size = b.u64_or(2, 0, "buffer size")?;
                    if off > 1 && size > 0 {
                        let s = buf.slice(
                            usize::try_from(off).map_err(|_| bad("buffer offset too large"))?,
                            usize::try_from(size).map_err(|_| bad("buffer size too large"))?,
                            "external buffer",
                        )?;
                        buffers.push(s);
                    } else {
                        buffers.push(&[][..]);
                    }
                }
            }
        }
        let subgraphs = model
            .vector(2, 4, "subgraphs")?
            .ok_or_else(|| bad("model has no subgraphs"))?;
        if subgraphs.len() != 1 {
            return Err(bad(format!("expected one subgraph, found {}", subgraphs.len())));
        }
        let sg = subgraphs.table_at(0, "subgraph")?;
        // Tensors.
        let tv = sg
            .vector(0, 4, "tensors")?
            .ok_or_else(|| bad("subgraph has no tensors"))?;
        let n = tv.len();
        let mut tensors = Vec::with_capacity(n);
        let mut f16_data: Vec<Option<Vec<f32>>> = Vec::with_capacity(n);
        for i in 0..n {
            let t = tv.table_at(i, "tensor")?;
            let name = t.string(3, "tensor name")?.unwrap_or_default();
            let raw_shape = t.i32_vec(0, "tensor shape")?;
            if raw_shape.len() > MAX_RANK {
                return Err(bad(format!("tensor {name}: rank {} above {MAX_RANK}", raw_shape.len())));
            }
            let mut shape = Vec::with_capacity(raw_shape.len());
            let mut count: usize = 1;
            for &d in &raw_shape {
                if d < 0 {
                    return Err(bad(format!("tensor {name}: negative dimension {d}")));
                }
                count = count
                    .checked_mul(d as usize)
                    .filter(|&c| c <= MAX_ELEMENTS)
                    .ok_or_else(|| bad(format!("tensor {name}: more than {MAX_ELEMENTS} elements")))?;
                shape.push(d as usize);
            }
            let ty = t.u8_or(1, 0, "tensor type")?;
            let bi = t.u32_or(2, 0, "tensor buffer")? as usize;
            let data_bytes = if bi == 0 {
                &[][..]
            } else {
                buffers
                    .get(bi)
                    .copied()
                    .ok_or_else(|| bad(format!("tensor {name}: buffer {bi} out of range")))?
            };
            let mut tensor = Tensor {
                name: name.clone(),
                shape,
                data: None,
                int_data: None,
            };
            let mut half = None;
            if !data_bytes.is_empty() {
                let elem = match ty {
                    ttype::FLOAT32 | ttype::INT32 => 4,
                    ttype::FLOAT16 => 2,
                    _ => return Err(bad(format!("tensor {name}: unsupported constant type {ty}"))),
                };
                if data_bytes.len() != count * elem {
                    return Err(bad(format!(
                        "tensor {name}: {} data bytes for {count} elements of {elem} bytes",
                        data_bytes.len()
                    )));
                }
                match ty {
                    ttype::FLOAT32 => {
                        tensor.data = Some(
                            data_bytes
                                .chunks_exact(4)
                                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                                .collect(),
                        )
                    }
                    ttype::INT32 => {
                        tensor.int_data = Some(
                            data_bytes
                                .chunks_exact(4)
                                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                                .collect(),
                        )
                    }
                    _ => {
                        half = Some(
                            data_bytes
                                .chunks_exact(2)
                                .map(|c| f16_to_f32(u16::from_le_bytes([c[0], c[1]])))
                                .collect(),
                        )
                    }
                }
            } else if ty != ttype::FLOAT32 && ty != ttype::INT32 {
                return Err(bad(format!("tensor {name}: unsupported activation type {ty}")));
            }
            tensors.push(tensor);
            f16_data.push(half);
        }
        let inputs = sg
            .i32_vec(1, "subgraph inputs")?
            .into_iter()
            .map(|t| tensor_id(t, n, "subgraph input"))
            .collect::<Result<Vec<_>>>()?;
        let outputs = sg
            .i32_vec(2, "subgraph outputs")?
            .into_iter()
            .map(|t| tensor_id(t, n, "subgraph output"))
            .collect::<Result<Vec<_>>>()?;
        // Operators.
        let mut ops = Vec::new();
        if let Some(ov) = sg.vector(3, 4, "operators")? {
            for i in 0..ov.len() {
                let o = ov.table_at(i, "operator")?;
                let ci = o.u32_or(0, 0, "opcode_index")? as usize;
                let c = *codes
                    .get(ci)
                    .ok_or_else(|| bad(format!("operator {i}: opcode index {ci} out of range")))?;
                let ins_raw = o.i32_vec(1, "operator inputs")?;
                let outs_raw = o.i32_vec(2, "operator outputs")?;
                let what = format!("operator {i}");
                let ins: Vec<Option<usize>> = ins_raw
                    .iter()
                    .map(|&t| {
                        if t < 0 {
                            Ok(None)
                        } else {
                            tensor_id(t, n, &what).map(Some)
                        }
                    })
                    .collect::<Result<_>>()?;
                let outs = outs_raw
                    .iter()
                    .map(|&t| tensor_id(t, n, &what))
                    .collect::<Result<Vec<_>>>()?;
                let input = |k: usize| -> Result<usize> {
                    ins.get(k)
                        .copied()
                        .flatten()
                        .ok_or_else(|| bad(format!("{what}: missing input {k}")))
                };
                let output = *outs.first().ok_or_else(|| bad(format!("{what}: no output")))?;
                if outs.len() != 1 {
                    return Err(bad(format!("{what}: {} outputs, expected 1", outs.len())));
                }
                let opts = o.table(4, "builtin options")?;
                let opt_u8 = |id: usize, d: u8| -> Result<u8> {
                    match &opts {
                        Some(t) => t.u8_or(id, d, &what),
                        None => Ok(d),
                    }
                };
                let need_opts = || opts.ok_or_else(|| bad(format!("{what}: missing builtin options")));
                let filter_hw = |f: usize| -> Result<(usize, usize)> {
                    let s = &tensors[f].shape;
                    if s.len() != 4 {
                        return Err(bad(format!("{what}: filter rank {} (expected 4)", s.len())));
                    }
                    Ok((s[1], s[2]))
                };
                let op = match c {
                    code::DEQUANTIZE => {
                        let src = input(0)?;
                        match f16_data[src].take() {
                            Some(d) => {
                                if tensors[output].len() != d.len() {
                                    return Err(bad(format!("{what}: DEQUANTIZE size mismatch")));
                                }
                                tensors[output].data = Some(d);
                                continue;
                            }
                            None => {
                                return Err(bad(format!(
                                    "{what}: DEQUANTIZE of a non-constant or non-float16 tensor"
                                )))
                            }
                        }
                    }
                    code::CONV_2D => {
                        let t = need_opts()?;
                        let filter = input(1)?;
                        let (kh, kw) = filter_hw(filter)?;
                        Op::Conv2d {
                            input: input(0)?,
                            filter,
                            bias: ins.get(2).copied().flatten(),
                            output,
                            win: window(&t, kh, kw, [0, 1, 2, 4, 5], &what)?,
                            act: Activation::from_code(t.u8_or(3, 0, &what)?)?,
                        }
                    }
                    code::DEPTHWISE_CONV_2D => {
                        let t = need_opts()?;
                        let filter = input(1)?;
                        let (kh, kw) = filter_hw(filter)?;
                        let dm = t.i32_or(3, 1, &what)?;
                        let in_c = tensors[input(0)?].shape.last().copied().unwrap_or(0);
                        let out_c = tensors[output].shape.last().copied().unwrap_or(0);
                        if in_c != out_c {
                            return Err(bad(format!(
                                "{what}: depthwise with depth multiplier {dm} ({in_c} -> {out_c} channels) is not supported"
                            )));
                        }
                        Op::DepthwiseConv2d {
                            input: input(0)?,
                            filter,
                            bias: ins.get(2).copied().flatten(),
                            output,
                            win: window(&t, kh, kw, [0, 1, 2, 5, 6], &what)?,
                            act: Activation::from_code(t.u8_or(4, 0, &what)?)?,
                        }
                    }
                    code::MAX_POOL_2D => {
                        let t = need_opts()?;
                        let fw = t.i32_or(3, 0, &what)?;
                        let fh = t.i32_or(4, 0, &what)?;
                        if !(1..=64).contains(&fw) || !(1..=64).contains(&fh) {
                            return Err(bad(format!("{what}: pool size {fh}x{fw} outside 1..=64")));
                        }
                        Op::MaxPool2d {
                            input: input(0)?,
                            output,
                            win: window(&t, fh as usize, fw as usize, [0, 1, 2, usize::MAX, usize::MAX], &what)?,
                            act: Activation::from_code(t.u8_or(5, 0, &what)?)?,
                        }
                    }
                    code::ADD => Op::Add {
                        a: input(0)?,
                        b: input(1)?,
                        output,
                        act: Activation::from_code(opt_u8(0, 0)?)?,
                    },
                    code::PRELU => Op::Prelu {
                        input: input(0)?,
                        alpha: input(1)?,
                        output,
                    },
                    code::RELU => Op::Relu {
                        input: input(0)?,
                        output,
                    },
                    code::LOGISTIC => Op::Logistic {
                        input: input(0)?,
                        output,
                    },
                    code::PAD => {
                        let p = input(1)?;
                        let d = tensors[p]
                            .int_data
                            .as_ref()
                            .ok_or_else(|| bad(format!("{what}: PAD paddings are not an int32 constant")))?;
                        let mut pads = Vec::new();
                        for pair in d.chunks(2) {
                            if pair.len() != 2 || pair[0] < 0 || pair[1] < 0 || pair[0] > 4096 || pair[1] > 4096 {
                                return Err(bad(format!("{what}: invalid paddings {d:?}")));
                            }
                            pads.push([pair[0] as usize, pair[1] as usize]);
                        }
                        Op::Pad {
                            input: input(0)?,
                            output,
                            pads,
                        }
                    }
                    code::RESHAPE => Op::Reshape {
                        input: input(0)?,
                        output,
                    },
                    code::CONCATENATION => {
                        let axis = match &opts {
                            Some(t) => t.i32_or(0, 0, &what)?,
                            None => 0,
                        };
                        let rank = tensors[output].shape.len() as i32;
                        let axis = if axis < 0 { axis + rank } else { axis };
                        if axis < 0 || axis >= rank {
                            return Err(bad(format!("{what}: concatenation axis out of range")));
                        }
                        let inputs = ins
                            .iter()
                            .map(|t| t.ok_or_else(|| bad(format!("{what}: missing input"))))
                            .collect::<Result<Vec<_>>>()?;
                        Op::Concat {
                            inputs,
                            output,
                            axis: axis as usize,
                            act: Activation::from_code(opt_u8(1, 0)?)?,
                        }
                    }
                    other => return Err(bad(format!("{what}: unsupported builtin operator code {other}"))),
                };
                ops.push(op);
            }
        }
        let g = Graph {
            tensors,
            ops,
            inputs,
            outputs,
        };
        g.check()?;
        Ok(g)
    }

    /// Checks every operator's tensor shapes against what it computes, that activations
    /// are written before they are read, and that constants have data.
    ///
    /// # Errors
    /// [`Error::Model`] naming the operator.
    pub fn check(&self) -> Result<()> {
        let t = &self.tensors;
        // Graphs can be built by hand (public fields): check ids before indexing.
        let in_range = |i: usize| i < t.len();
        if !self.inputs.iter().chain(&self.outputs).all(|&i| in_range(i))
            || !self
                .ops
                .iter()
                .all(|op| op.inputs().into_iter().all(in_range) && in_range(op.output()))
        {
            return Err(bad("a tensor index is out of range"));
        }
        let mut written = vec![false; t.len()];
        for &i in &self.inputs {
            if t[i].is_const() {
                return Err(bad("a graph input is a constant"));
            }
            written[i] = true;
        }
        for (k, op) in self.ops.iter().enumerate() {
            let what = format!("operator {k} ({})", op.name());
            let out = op.output();
            if t[out].is_const() || written[out] {
                return Err(bad(format!("{what}: output tensor written twice or constant")));
            }
            let act_in = |i: usize| -> Result<&[usize]> {
                if t[i].is_const() || !written[i] {
                    return Err(bad(format!(
                        "{what}: input tensor {} is not computed before use",
                        t[i].name
                    )));
                }
                Ok(&t[i].shape)
            };
            let const_f = |i: usize, len: usize| -> Result<()> {
                match &t[i].data {
                    Some(d) if d.len() == len => Ok(()),
                    _ => Err(bad(format!(
                        "{what}: tensor {} is not a float constant of {len} values",
                        t[i].name
                    ))),
                }
            };
            let os = &t[out].shape;
            let nhwc = |s: &[usize]| -> Result<[usize; 4]> {
                if s.len() != 4 || s[0] != 1 {
                    return Err(bad(format!("{what}: expected a [1, H, W, C] tensor, got {s:?}")));
                }
                Ok([s[0], s[1], s[2], s[3]])
            };
            let mismatch = |exp: &[usize]| -> Error { bad(format!("{what}: output shape {os:?}, expected {exp:?}")) };
            match op {
                Op::Conv2d {
                    input,
                    filter,
                    bias,
                    win,
                    ..
                }
                | Op::DepthwiseConv2d {
                    input,
                    filter,
                    bias,
                    win,
                    ..
                } => {
                    let [_, h, w, c] = nhwc(act_in(*input)?)?;
                    let fs = &t[*filter].shape;
                    if fs.len() != 4 {
                        return Err(bad(format!("{what}: filter rank {} (expected 4)", fs.len())));
                    }
                    let depthwise = matches!(op, Op::DepthwiseConv2d { .. });
                    let oc = if depthwise {
                        if fs[0] != 1 || fs[3] != c {
                            return Err(bad(format!("{what}: depthwise filter {fs:?} for {c} channels")));
                        }
                        c
                    } else {
                        if fs[3] != c {
                            return Err(bad(format!("{what}: filter {fs:?} for {c} input channels")));
                        }
                        fs[0]
                    };
                    const_f(*filter, fs.iter().product())?;
                    if let Some(b) = bias {
                        const_f(*b, oc)?;
                    }
                    let (oh, _) = Window::out_and_pad(h, win.kh, win.sh, win.dh, win.padding)
                        .ok_or_else(|| bad(format!("{what}: window does not fit")))?;
                    let (ow, _) = Window::out_and_pad(w, win.kw, win.sw, win.dw, win.padding)
                        .ok_or_else(|| bad(format!("{what}: window does not fit")))?;
                    if os[..] != [1, oh, ow, oc] {
                        return Err(mismatch(&[1, oh, ow, oc]));
                    }
                }
                Op::MaxPool2d { input, win, .. } => {
                    let [_, h, w, c] = nhwc(act_in(*input)?)?;
                    let (oh, _) = Window::out_and_pad(h, win.kh, win.sh, 1, win.padding)
                        .ok_or_else(|| bad(format!("{what}: window does not fit")))?;
                    let (ow, _) = Window::out_and_pad(w, win.kw, win.sw, 1, win.padding)
                        .ok_or_else(|| bad(format!("{what}: window does not fit")))?;
                    if os[..] != [1, oh, ow, c] {
                        return Err(mismatch(&[1, oh, ow, c]));
                    }
                }
                Op::Add { a, b, .. } => {
                    let sa = act_in(*a)?;
                    let sb = act_in(*b)?;
                    if sa != sb || os != sa {
                        return Err(bad(format!(
                            "{what}: shapes {sa:?} + {sb:?} -> {os:?} (no broadcasting)"
                        )));
                    }
                }
                Op::Prelu { input, alpha, .. } => {
                    let s = act_in(*input)?;
                    let c = s.last().copied().unwrap_or(0);
                    const_f(*alpha, c)?;
                    let asz = &t[*alpha].shape;
                    if asz.last() != Some(&c) {
                        return Err(bad(format!("{what}: alpha {asz:?} is not per-channel for {s:?}")));
                    }
                    if os != s {
                        return Err(mismatch(s));
                    }
                }
                Op::Relu { input, .. } | Op::Logistic { input, .. } => {
                    let s = act_in(*input)?;
                    if os != s {
                        return Err(mismatch(s));
                    }
                }
                Op::Pad { input, pads, .. } => {
                    let s = act_in(*input)?;
                    if pads.len() != s.len() {
                        return Err(bad(format!("{what}: {} paddings for rank {}", pads.len(), s.len())));
                    }
                    let exp: Vec<usize> = s.iter().zip(pads).map(|(d, p)| d + p[0] + p[1]).collect();
                    if os != &exp {
                        return Err(mismatch(&exp));
                    }
                }
                Op::Reshape { input, .. } => {
                    let s = act_in(*input)?;
                    if s.iter().product::<usize>() != os.iter().product::<usize>() {
                        return Err(bad(format!(
                            "{what}: reshape {s:?} -> {os:?} changes the element count"
                        )));
                    }
                }
                Op::Concat { inputs, axis, .. } => {
                    if *axis >= os.len() {
                        return Err(bad(format!("{what}: axis {axis} for rank {}", os.len())));
                    }
                    let mut sum = 0;
                    for &i in inputs {
                        let s = act_in(i)?;
                        if s.len() != os.len()
                            || s.iter()
                                .zip(os.iter())
                                .enumerate()
                                .any(|(d, (a, b))| d != *axis && a != b)
                        {
                            return Err(bad(format!("{what}: input {s:?} does not fit output {os:?}")));
                        }
                        sum += s[*axis];
                    }
                    if sum != os[*axis] {
                        return Err(bad(format!(
                            "{what}: inputs sum to {sum} along axis {axis}, output has {}",
                            os[*axis]
                        )));
                    }
                }
            }
            written[out] = true;
        }
        for &o in &self.outputs {
            if !written[o] {
                return Err(bad(format!("graph output {} is never computed", t[o].name)));
            }
        }
        Ok(())
    }
}
