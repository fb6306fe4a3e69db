//! The interpreter: a checked [`Graph`] turned into a plan of kernel calls over a few
//! reused activation buffers.
//!
//! Buffers are assigned by liveness at load (an activation's buffer is returned to a
//! free list after its last reader runs), so the landmark model runs in a handful of
//! buffers instead of one per tensor. [`Workspace`] owns those buffers and the im2col
//! scratch; it is sized once and [`Interpreter::run`] allocates nothing.

use super::kernels::{self, Geom, Packed};
use super::model::{Activation, Graph, Op};
use crate::{Error, Result};
use std::sync::atomic::{AtomicU64, Ordering};

/// Upper bound on a workspace (activations plus im2col), in floats: 128 MiB, over
/// fifty times what the landmark model needs; guards against damaged shapes.
pub const MAX_WORKSPACE_FLOATS: usize = 1 << 25;

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

fn bad(reason: impl Into<String>) -> Error {
    Error::Model { reason: reason.into() }
}

/// The operators folded into a convolution's epilogue (see [`kernels::Epilogue`]).
#[derive(Debug, Clone)]
struct Fused {
    act: Activation,
    residual: Option<usize>,
    post: FusedPost,
}

#[derive(Debug, Clone)]
enum FusedPost {
    None,
    Relu,
    Prelu(Vec<f32>),
}

/// A convolution absorbing a following `ADD` (residual) and `RELU` / `PRELU`: the op
/// indices absorbed, the residual tensor, the post-activation op and the final output.
#[derive(Debug, Clone, Default)]
struct Fusion {
    absorbed: Vec<usize>,
    residual: Option<usize>,
    post_op: Option<usize>,
    output: usize,
}

/// The graph with every `PAD` that directly follows a convolution it does not read
/// moved in front of that convolution. Residual blocks whose shortcut is channel-padded
/// come as `CONV, PAD(shortcut), ADD(conv, pad)`; after the swap the `ADD` follows its
/// convolution and [`plan_fusions`] folds it (and the `RELU` after it) into the epilogue.
/// The swap keeps a valid execution order: the `PAD` reads nothing the convolution writes.
fn pads_before_convs(graph: &Graph) -> Graph {
    let mut g = graph.clone();
    for k in 0..g.ops.len().saturating_sub(1) {
        let conv_out = match &g.ops[k] {
            Op::Conv2d { output, .. } | Op::DepthwiseConv2d { output, .. } => *output,
            _ => continue,
        };
        if let Op::Pad { input, .. } = &g.ops[k + 1] {
            if *input != conv_out {
                g.ops.swap(k, k + 1);
            }
        }
    }
    g
}

/// Finds, for every convolution without a fused activation, the chain
/// `conv -> ADD(conv, r) -> RELU|PRELU` (or `conv -> RELU|PRELU`) where each
/// intermediate tensor is read only by the next operator and is not a graph output.
fn plan_fusions(graph: &Graph) -> Vec<Option<Fusion>> {
    let t = &graph.tensors;
    let mut readers = vec![0usize; t.len()];
    for op in &graph.ops {
        for i in op.inputs() {
            readers[i] += 1;
        }
    }
    for &o in &graph.outputs {
        readers[o] += 1000;
    }
    let ops = &graph.ops;
    let mut out: Vec<Option<Fusion>> = vec![None; ops.len()];
    let mut k = 0;
    while k < ops.len() {
        let conv_out = match &ops[k] {
            Op::Conv2d { output, act, .. } | Op::DepthwiseConv2d { output, act, .. } if *act == Activation::None => {
                Some(*output)
            }
            _ => None,
        };
        let Some(mut cur) = conv_out else {
            k += 1;
            continue;
        };
        let mut f = Fusion {
            output: cur,
            ..Default::default()
        };
        let mut next = k + 1;
        if readers[cur] == 1 {
            if let Some(Op::Add { a, b, output, act }) = ops.get(next) {
                if *act == Activation::None && a != b && (*a == cur || *b == cur) {
                    f.residual = Some(if *a == cur { *b } else { *a });
                    f.absorbed.push(next);
                    cur = *output;
                    f.output = cur;
                    next += 1;
                }
            }
        }
        if readers[cur] == 1 {
            match ops.get(next) {
                Some(Op::Relu { input, output }) | Some(Op::Prelu { input, output, .. }) if *input == cur => {
                    f.absorbed.push(next);
                    f.post_op = Some(next);
                    f.output = *output;
                    next += 1;
                }
                _ => {}
            }
        }
        if !f.absorbed.is_empty() {
            out[k] = Some(f);
        }
        k = next;
    }
    out
}

#[derive(Debug, Clone)]
enum Step {
    Conv {
        src: usize,
        dst: usize,
        g: Geom,
        w: Packed,
        fused: Fused,
    },
    Depthwise {
        src: usize,
        dst: usize,
        g: Geom,
        filter: Vec<f32>,
        bias: Vec<f32>,
        fused: Fused,
    },
    MaxPool {
        src: usize,
        dst: usize,
        g: Geom,
        act: Activation,
    },
    Add {
        a: usize,
        b: usize,
        dst: usize,
        len: usize,
        act: Activation,
    },
    Prelu {
        src: usize,
        dst: usize,
        len: usize,
        alpha: Vec<f32>,
    },
    Relu {
        src: usize,
        dst: usize,
        len: usize,
    },
    Logistic {
        src: usize,
        dst: usize,
        len: usize,
    },
    Pad {
        src: usize,
        dst: usize,
        shape: [usize; 4],
        pads: [[usize; 2]; 4],
        out_len: usize,
    },
    Copy {
        src: usize,
        dst: usize,
        len: usize,
    },
    Concat {
        srcs: Vec<(usize, usize)>,
        dst: usize,
        outer: usize,
        out_len: usize,
    },
}

/// A TFLite float model ready to run: immutable, `Send + Sync`, shared between threads;
/// each thread runs it with its own [`Workspace`].
#[derive(Debug, Clone)]
pub struct Interpreter {
    id: u64,
    steps: Vec<Step>,
    slot_len: Vec<usize>,
    im2col_len: usize,
    inputs: Vec<(usize, Vec<usize>)>,
    outputs: Vec<(usize, Vec<usize>)>,
    op_counts: Vec<(&'static str, usize)>,
}

/// Per-thread buffers of one [`Interpreter`].
#[derive(Debug, Clone)]
pub struct Workspace {
    id: u64,
    slots: Vec<Vec<f32>>,
    col: Vec<f32>,
}

impl Interpreter {
    /// Loads a TFLite flatbuffer (see [`Graph::parse`]) and plans it.
    ///
    /// # Errors
    /// [`Error::Model`] for a damaged or unsupported model.
    pub fn from_bytes(bytes: &[u8]) -> Result<Interpreter> {
        Interpreter::from_graph(&Graph::parse(bytes)?)
    }

    /// Reads and loads a `.tflite` file.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read, [`Error::Model`] as for
    /// [`Interpreter::from_bytes`] (the message then names the file).
    pub fn from_file(path: &std::path::Path) -> Result<Interpreter> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Interpreter::from_bytes(&bytes).map_err(|e| match e {
            Error::Model { reason } => Error::Model {
                reason: format!("{}: {reason}", path.display()),
            },
            e => e,
        })
    }

    /// Plans a checked graph.
    ///
    /// # Errors
    /// [`Error::Model`] when the graph uses a layout the kernels do not cover.
    pub fn from_graph(graph: &Graph) -> Result<Interpreter> {
        graph.check()?;
        let reordered = pads_before_convs(graph);
        let graph = &reordered;
        let t = &graph.tensors;
        let n_ops = graph.ops.len();
        let fusions = plan_fusions(graph);
        let mut absorbed = vec![false; n_ops];
        for f in fusions.iter().flatten() {
            for &a in &f.absorbed {
                absorbed[a] = true;
            }
        }
        // Tensors each (fused) operator reads and writes.
        let reads = |k: usize| -> Vec<usize> {
            let mut v = graph.ops[k].inputs();
            if let Some(f) = &fusions[k] {
                v.extend(f.residual);
            }
            v
        };
        let writes = |k: usize| -> usize { fusions[k].as_ref().map_or(graph.ops[k].output(), |f| f.output) };
        // Last reader of every tensor; graph outputs live to the end.
        let mut last_use = vec![0usize; t.len()];
        for k in (0..n_ops).filter(|&k| !absorbed[k]) {
            for i in reads(k) {
                last_use[i] = k;
            }
        }
        for &o in &graph.outputs {
            last_use[o] = n_ops;
        }
        let mut slot_of: Vec<Option<usize>> = vec![None; t.len()];
        let mut slot_len: Vec<usize> = Vec::new();
        let mut free: Vec<usize> = Vec::new();
        let alloc = |len: usize, slot_len: &mut Vec<usize>, free: &mut Vec<usize>| -> usize {
            // Best fit among free slots, else grow the largest, else a new slot.
            let best = free
                .iter()
                .enumerate()
                .filter(|(_, &s)| slot_len[s] >= len)
                .min_by_key(|(_, &s)| slot_len[s])
                .map(|(i, _)| i)
                .or_else(|| (0..free.len()).max_by_key(|&i| slot_len[free[i]]));
            match best {
                Some(i) => {
                    let s = free.swap_remove(i);
                    slot_len[s] = slot_len[s].max(len);
                    s
                }
                None => {
                    slot_len.push(len);
                    slot_len.len() - 1
                }
            }
        };
        for &i in &graph.inputs {
            slot_of[i] = Some(alloc(t[i].len(), &mut slot_len, &mut free));
        }
        let mut steps = Vec::with_capacity(n_ops);
        let mut im2col_len = 0;
        let mut counts: Vec<(&'static str, usize)> = Vec::new();
        for (k, op) in graph.ops.iter().enumerate() {
            if absorbed[k] {
                continue;
            }
            let out = writes(k);
            let dst = alloc(t[out].len(), &mut slot_len, &mut free);
            slot_of[out] = Some(dst);
            let slot = |i: usize| slot_of[i].ok_or_else(|| bad(format!("operator {k}: input has no buffer")));
            let cdata = |i: usize| -> Result<&Vec<f32>> {
                t[i].data
                    .as_ref()
                    .ok_or_else(|| bad(format!("operator {k}: missing constant")))
            };
            let geom = |i: usize, win| -> Result<Geom> {
                let s = &t[i].shape;
                Geom::new(s[1], s[2], s[3], win).ok_or_else(|| bad(format!("operator {k}: window does not fit")))
            };
            let fused = |act: Activation| -> Result<Fused> {
                let Some(f) = &fusions[k] else {
                    return Ok(Fused {
                        act,
                        residual: None,
                        post: FusedPost::None,
                    });
                };
                let post = match f.post_op.map(|p| &graph.ops[p]) {
                    Some(Op::Relu { .. }) => FusedPost::Relu,
                    Some(Op::Prelu { alpha, .. }) => FusedPost::Prelu(cdata(*alpha)?.clone()),
                    _ => FusedPost::None,
                };
                Ok(Fused {
                    act,
                    residual: f.residual.map(slot).transpose()?,
                    post,
                })
            };
            let step = match op {
                Op::Conv2d {
                    input,
                    filter,
                    bias,
                    win,
                    act,
                    ..
                } => {
                    let g = geom(*input, *win)?;
                    let oc = t[*filter].shape[0];
                    let kk = win.kh * win.kw * g.ic;
                    let bias_data = match bias {
                        Some(b) => Some(cdata(*b)?.as_slice()),
                        None => None,
                    };
                    let w = Packed::new(cdata(*filter)?, bias_data, oc, kk);
                    if !g.is_pointwise() {
                        let rows = (g.oh * g.ow).min(kernels::im2col_chunk_rows(kk));
                        im2col_len = im2col_len.max(rows * kk);
                    }
                    Step::Conv {
                        src: slot(*input)?,
                        dst,
                        g,
                        w,
                        fused: fused(*act)?,
                    }
                }
                Op::DepthwiseConv2d {
                    input,
                    filter,
                    bias,
                    win,
                    act,
                    ..
                } => {
                    let g = geom(*input, *win)?;
                    let bias = match bias {
                        Some(b) => cdata(*b)?.clone(),
                        None => vec![0.0; g.ic],
                    };
                    Step::Depthwise {
                        src: slot(*input)?,
                        dst,
                        g,
                        filter: cdata(*filter)?.clone(),
                        bias,
                        fused: fused(*act)?,
                    }
                }
                Op::MaxPool2d { input, win, act, .. } => Step::MaxPool {
                    src: slot(*input)?,
                    dst,
                    g: geom(*input, *win)?,
                    act: *act,
                },
                Op::Add { a, b, act, .. } => Step::Add {
                    a: slot(*a)?,
                    b: slot(*b)?,
                    dst,
                    len: t[out].len(),
                    act: *act,
                },
                Op::Prelu { input, alpha, .. } => Step::Prelu {
                    src: slot(*input)?,
                    dst,
                    len: t[out].len(),
                    alpha: cdata(*alpha)?.clone(),
                },
                Op::Relu { input, .. } => Step::Relu {
                    src: slot(*input)?,
                    dst,
                    len: t[out].len(),
                },
                Op::Logistic { input, .. } => Step::Logistic {
                    src: slot(*input)?,
                    dst,
                    len: t[out].len(),
                },
                Op::Pad { input, pads, .. } => {
                    let s = &t[*input].shape;
                    if s.len() != 4 || pads.len() != 4 {
                        return Err(bad(format!("operator {k}: PAD supports rank-4 tensors only")));
                    }
                    Step::Pad {
                        src: slot(*input)?,
                        dst,
                        shape: [s[0], s[1], s[2], s[3]],
                        pads: [pads[0], pads[1], pads[2], pads[3]],
                        out_len: t[out].len(),
                    }
                }
                Op::Reshape { input, .. } => Step::Copy {
                    src: slot(*input)?,
                    dst,
                    len: t[out].len(),
                },
                Op::Concat { inputs, axis, act, .. } => {
                    if *act != Activation::None {
                        return Err(bad(format!("operator {k}: fused activation on CONCATENATION")));
                    }
                    let os = &t[out].shape;
                    let outer: usize = os[..*axis].iter().product();
                    let inner: usize = os[*axis + 1..].iter().product();
                    let srcs = inputs
                        .iter()
                        .map(|&i| Ok((slot(i)?, t[i].shape[*axis] * inner)))
                        .collect::<Result<Vec<_>>>()?;
                    Step::Concat {
                        srcs,
                        dst,
                        outer,
                        out_len: t[out].len(),
                    }
                }
            };
            match counts.iter_mut().find(|(n, _)| *n == op.name()) {
                Some(c) => c.1 += 1,
                None => counts.push((op.name(), 1)),
            }
            steps.push(step);
            // Release buffers whose last reader was this operator.
            let mut ins = reads(k);
            ins.sort_unstable();
            ins.dedup();
            for i in ins {
                if last_use[i] == k {
                    if let Some(s) = slot_of[i] {
                        free.push(s);
                    }
                }
            }
        }
        let total: usize = slot_len.iter().sum::<usize>() + im2col_len;
        if total > MAX_WORKSPACE_FLOATS {
            return Err(bad(format!(
                "the model needs {total} floats of activations, above the limit of {MAX_WORKSPACE_FLOATS}"
            )));
        }
        let io = |ids: &[usize]| -> Result<Vec<(usize, Vec<usize>)>> {
            ids.iter()
                .map(|&i| {
                    slot_of[i]
                        .map(|s| (s, t[i].shape.clone()))
                        .ok_or_else(|| bad("graph input/output has no buffer"))
                })
                .collect()
        };
        Ok(Interpreter {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            steps,
            slot_len,
            im2col_len,
            inputs: io(&graph.inputs)?,
            outputs: io(&graph.outputs)?,
            op_counts: counts,
        })
    }

    /// A workspace sized for this model.
    pub fn workspace(&self) -> Workspace {
        Workspace {
            id: self.id,
            slots: self.slot_len.iter().map(|&n| vec![0.0; n]).collect(),
            col: vec![0.0; self.im2col_len],
        }
    }

    /// Shape of graph input `i`.
    pub fn input_shape(&self, i: usize) -> Option<&[usize]> {
        self.inputs.get(i).map(|(_, s)| s.as_slice())
    }

    /// Shape of graph output `i`.
    pub fn output_shape(&self, i: usize) -> Option<&[usize]> {
        self.outputs.get(i).map(|(_, s)| s.as_slice())
    }

    /// Number of graph outputs.
    pub fn num_outputs(&self) -> usize {
        self.outputs.len()
    }

    /// Operator names and how often each occurs (DEQUANTIZE folded at load).
    pub fn op_counts(&self) -> &[(&'static str, usize)] {
        &self.op_counts
    }

    /// Floats held by a workspace (activation buffers plus im2col scratch).
    pub fn workspace_floats(&self) -> usize {
        self.slot_len.iter().sum::<usize>() + self.im2col_len
    }

    fn check_ws(&self, ws: &Workspace) -> Result<()> {
        if ws.id != self.id {
            return Err(Error::InvalidInput {
                what: "workspace belongs to another model".into(),
            });
        }
        Ok(())
    }

    /// The buffer of graph input `i` (NHWC, row-major), to be filled before [`run`].
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another model or a bad index.
    ///
    /// [`run`]: Interpreter::run
    pub fn input_mut<'w>(&self, ws: &'w mut Workspace, i: usize) -> Result<&'w mut [f32]> {
        self.check_ws(ws)?;
        let (slot, shape) = self.inputs.get(i).ok_or_else(|| Error::InvalidInput {
            what: format!("model has no input {i}"),
        })?;
        let n = shape.iter().product();
        Ok(&mut ws.slots[*slot][..n])
    }

    /// Graph output `i` after [`run`](Interpreter::run).
    ///
    /// # Errors
    /// As for [`Interpreter::input_mut`].
    pub fn output<'w>(&self, ws: &'w Workspace, i: usize) -> Result<&'w [f32]> {
        self.check_ws(ws)?;
        let (slot, shape) = self.outputs.get(i).ok_or_else(|| Error::InvalidInput {
            what: format!("model has no output {i}"),
        })?;
        let n = shape.iter().product();
        Ok(&ws.slots[*slot][..n])
    }

    /// Runs the model on the input buffers of `ws`. Allocates nothing.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace made by another model.
    pub fn run(&self, ws: &mut Workspace) -> Result<()> {
        self.check_ws(ws)?;
        let level = kernels::Level::detect();
        level.vectorize(Steps { steps: &self.steps, ws });
        Ok(())
    }
}

impl Interpreter {
    /// Runs the model once, timing each operator kind (for profiling; each step is
    /// dispatched separately, so the total is slightly above [`Interpreter::run`]'s).
    /// Returns `(operator, seconds, MACs or elements)` summed per kind.
    ///
    /// # Errors
    /// As for [`Interpreter::run`].
    pub fn profile(&self, ws: &mut Workspace) -> Result<Vec<(&'static str, f64)>> {
        let times = self.profile_steps(ws)?;
        let mut acc: Vec<(&'static str, f64)> = Vec::new();
        for (step, dt) in self.steps.iter().zip(times) {
            let name = step_name(step);
            match acc.iter_mut().find(|(n, _)| *n == name) {
                Some(a) => a.1 += dt,
                None => acc.push((name, dt)),
            }
        }
        Ok(acc)
    }
}

impl Interpreter {
    /// One line per step of the plan: operator kind, input and output shapes, kernel,
    /// and the multiply-accumulates of convolutions (for per-layer profiles).
    pub fn step_labels(&self) -> Vec<(String, usize)> {
        self.steps
            .iter()
            .map(|step| {
                let name = step_name(step);
                match step {
                    Step::Conv { g, w, fused, .. } => {
                        let macs = g.oh * g.ow * w.k * w.n;
                        (
                            format!(
                                "{name} {}x{}x{} -> {}x{}x{} k{}x{}/{}{}{}",
                                g.ih,
                                g.iw,
                                g.ic,
                                g.oh,
                                g.ow,
                                w.n,
                                g.win.kh,
                                g.win.kw,
                                g.win.sh,
                                if fused.residual.is_some() { " +add" } else { "" },
                                match fused.post {
                                    FusedPost::None => "",
                                    FusedPost::Relu => " +relu",
                                    FusedPost::Prelu(_) => " +prelu",
                                }
                            ),
                            macs,
                        )
                    }
                    Step::Depthwise { g, fused, .. } => (
                        format!(
                            "{name} {}x{}x{} -> {}x{} k{}x{}/{}{}",
                            g.ih,
                            g.iw,
                            g.ic,
                            g.oh,
                            g.ow,
                            g.win.kh,
                            g.win.kw,
                            g.win.sh,
                            if fused.residual.is_some() { " +add" } else { "" }
                        ),
                        g.oh * g.ow * g.ic * g.win.kh * g.win.kw,
                    ),
                    Step::MaxPool { g, .. } => (format!("{name} {}x{}x{} -> {}x{}", g.ih, g.iw, g.ic, g.oh, g.ow), 0),
                    Step::Pad { shape, pads, .. } => (format!("{name} {shape:?} {pads:?}"), 0),
                    Step::Add { len, .. }
                    | Step::Prelu { len, .. }
                    | Step::Relu { len, .. }
                    | Step::Logistic { len, .. }
                    | Step::Copy { len, .. } => (format!("{name} {len}"), 0),
                    Step::Concat { out_len, .. } => (format!("{name} {out_len}"), 0),
                }
            })
            .collect()
    }

    /// Runs the model once and returns the seconds each step took (same order as
    /// [`Interpreter::step_labels`]).
    ///
    /// # Errors
    /// As for [`Interpreter::run`].
    pub fn profile_steps(&self, ws: &mut Workspace) -> Result<Vec<f64>> {
        self.check_ws(ws)?;
        let mut times = Vec::with_capacity(self.steps.len());
        for step in &self.steps {
            let t0 = std::time::Instant::now();
            let level = kernels::Level::detect();
            level.vectorize(Steps {
                steps: std::slice::from_ref(step),
                ws,
            });
            times.push(t0.elapsed().as_secs_f64());
        }
        Ok(times)
    }
}

fn step_name(step: &Step) -> &'static str {
    match step {
        Step::Conv { g, .. } if g.is_pointwise() => "CONV_2D 1x1",
        Step::Conv { .. } => "CONV_2D KxK",
        Step::Depthwise { .. } => "DEPTHWISE_CONV_2D",
        Step::MaxPool { .. } => "MAX_POOL_2D",
        Step::Add { .. } => "ADD",
        Step::Prelu { .. } => "PRELU",
        Step::Relu { .. } => "RELU",
        Step::Logistic { .. } => "LOGISTIC",
        Step::Pad { .. } => "PAD",
        Step::Copy { .. } => "RESHAPE",
        Step::Concat { .. } => "CONCATENATION",
    }
}

/// A run of consecutive steps at one level: the whole plan ([`Interpreter::run`]) or one
/// step at a time ([`Interpreter::profile_steps`]). One body type for both, so that each
/// level's inlined kernels are compiled into one body, not two (they dominate the build).
struct Steps<'a> {
    steps: &'a [Step],
    ws: &'a mut Workspace,
}

impl kernels::WithLevel for Steps<'_> {
    type Output = ();

    #[inline(always)]
    fn with_level(self, level: kernels::Level) {
        let Steps { steps, ws } = self;
        for step in steps {
            exec(step, ws, level);
        }
    }
}

#[inline(always)]
fn epilogue<'a>(f: &'a Fused, slots: &'a [Vec<f32>]) -> kernels::Epilogue<'a> {
    kernels::Epilogue {
        act: f.act,
        residual: f.residual.map(|r| slots[r].as_slice()),
        post: match &f.post {
            FusedPost::None => kernels::Post::None,
            FusedPost::Relu => kernels::Post::Relu,
            FusedPost::Prelu(a) => kernels::Post::Prelu(a),
        },
    }
}

/// Runs one step. Buffer sizes were fixed by the plan, so slicing cannot fail for a
/// workspace made by the same interpreter.
#[inline(always)]
fn exec(step: &Step, ws: &mut Workspace, level: kernels::Level) {
    let dst_slot = match step {
        Step::Conv { dst, .. }
        | Step::Depthwise { dst, .. }
        | Step::MaxPool { dst, .. }
        | Step::Add { dst, .. }
        | Step::Prelu { dst, .. }
        | Step::Relu { dst, .. }
        | Step::Logistic { dst, .. }
        | Step::Pad { dst, .. }
        | Step::Copy { dst, .. }
        | Step::Concat { dst, .. } => *dst,
    };
    // Take the destination out so sources can be borrowed alongside it (no allocation:
    // `take` leaves an empty Vec and the buffer is put back below).
    let mut out = std::mem::take(&mut ws.slots[dst_slot]);
    let slots = &ws.slots;
    match step {
        Step::Conv { src, g, w, fused, .. } => {
            let rows = g.oh * g.ow;
            let o = &mut out[..rows * w.n];
            let ep = epilogue(fused, slots);
            if g.is_pointwise() {
                kernels::gemm_at(level, &slots[*src], rows, w, &ep, o);
            } else {
                kernels::conv_window(level, &slots[*src], g, w, &ep, &mut ws.col, o);
            }
        }
        Step::Depthwise {
            src,
            g,
            filter,
            bias,
            fused,
            ..
        } => kernels::depthwise_at(
            level,
            &slots[*src],
            g,
            filter,
            bias,
            &epilogue(fused, slots),
            &mut out[..g.oh * g.ow * g.ic],
        ),
        Step::MaxPool { src, g, act, .. } => kernels::max_pool(&slots[*src], g, *act, &mut out[..g.oh * g.ow * g.ic]),
        Step::Add { a, b, len, act, .. } => {
            kernels::add(&slots[*a][..*len], &slots[*b][..*len], *act, &mut out[..*len])
        }
        Step::Prelu { src, len, alpha, .. } => kernels::prelu(&slots[*src][..*len], alpha, &mut out[..*len]),
        Step::Relu { src, len, .. } => kernels::relu(&slots[*src][..*len], &mut out[..*len]),
        Step::Logistic { src, len, .. } => kernels::logistic(&slots[*src][..*len], &mut out[..*len]),
        Step::Pad {
            src,
            shape,
            pads,
            out_len,
            ..
        } => kernels::pad4(&slots[*src], *shape, *pads, &mut out[..*out_len]),
        Step::Copy { src, len, .. } => out[..*len].copy_from_slice(&slots[*src][..*len]),
        Step::Concat {
            srcs, outer, out_len, ..
        } => {
            let mut pos = 0;
            let o = &mut out[..*out_len];
            for b in 0..*outer {
                for &(s, chunk) in srcs {
                    o[pos..pos + chunk].copy_from_slice(&slots[s][b * chunk..(b + 1) * chunk]);
                    pos += chunk;
                }
            }
        }
    }
    ws.slots[dst_slot] = out;
}

/// Single kernel calls run through the interpreter's own compiled bodies (the plan's
/// per-level loop of [`Interpreter::run`]) at a chosen [`kernels::Level`], for tests and
/// benchmarks that compare levels or check a kernel against a reference.
///
/// They take the arguments of the [`kernels`] functions of the same names and give the
/// same results, but run the code the interpreter runs, with the level's target
/// features on; calling the inlined kernels directly from another crate would compile
/// them again there, outside those features. Each call copies its inputs into a
/// one-step workspace, so it allocates.
pub mod single {
    use super::{Fused, FusedPost, Step, Steps, Workspace};
    use crate::kernels::{Epilogue, Geom, Level, Packed, Post};
    use crate::model::{Padding, Window};

    /// The epilogue as the plan holds it, its residual (if any) in slot 2.
    fn fused(ep: &Epilogue<'_>) -> Fused {
        Fused {
            act: ep.act,
            residual: ep.residual.map(|_| 2),
            post: match ep.post {
                Post::None => FusedPost::None,
                Post::Relu => FusedPost::Relu,
                Post::Prelu(alpha) => FusedPost::Prelu(alpha.to_vec()),
            },
        }
    }

    /// Runs `step` (reading slot 0, the residual in slot 2, writing slot 1) and copies
    /// slot 1 into `out`.
    fn run(level: Level, step: Step, input: &[f32], ep: &Epilogue<'_>, col: usize, out: &mut [f32]) {
        let mut ws = Workspace {
            id: 0,
            slots: vec![
                input.to_vec(),
                vec![0.0; out.len()],
                ep.residual.map(<[f32]>::to_vec).unwrap_or_default(),
            ],
            col: vec![0.0; col],
        };
        level.vectorize(Steps {
            steps: std::slice::from_ref(&step),
            ws: &mut ws,
        });
        out.copy_from_slice(&ws.slots[1]);
    }

    /// [`kernels::gemm_at`](crate::kernels::gemm_at): `a` is `rows x w.k`, `out` is
    /// `rows x w.n` (run as a 1x1 convolution).
    ///
    /// # Panics
    /// When a length does not fit (`a`, `out` or the residual shorter than the shapes
    /// say), as the kernel does.
    pub fn gemm_at(level: Level, a: &[f32], rows: usize, w: &Packed, ep: &Epilogue<'_>, out: &mut [f32]) {
        let win = Window {
            kh: 1,
            kw: 1,
            sh: 1,
            sw: 1,
            dh: 1,
            dw: 1,
            padding: Padding::Valid,
        };
        // A 1x1 window fits every input with at least one row and one channel; with none
        // there is nothing to compute.
        let Some(g) = Geom::new(rows, 1, w.k, win) else {
            return;
        };
        let step = Step::Conv {
            src: 0,
            dst: 1,
            g,
            w: w.clone(),
            fused: fused(ep),
        };
        run(level, step, a, ep, 0, out)
    }

    /// [`kernels::conv_window`](crate::kernels::conv_window); `col` gives the size of
    /// the scratch (its contents are not used).
    ///
    /// # Panics
    /// As [`gemm_at`].
    pub fn conv_window(
        level: Level,
        input: &[f32],
        g: &Geom,
        w: &Packed,
        ep: &Epilogue<'_>,
        col: &mut [f32],
        out: &mut [f32],
    ) {
        let step = Step::Conv {
            src: 0,
            dst: 1,
            g: *g,
            w: w.clone(),
            fused: fused(ep),
        };
        run(level, step, input, ep, col.len(), out)
    }

    /// [`kernels::depthwise_at`](crate::kernels::depthwise_at).
    ///
    /// # Panics
    /// As [`gemm_at`].
    pub fn depthwise_at(
        level: Level,
        input: &[f32],
        g: &Geom,
        filter: &[f32],
        bias: &[f32],
        ep: &Epilogue<'_>,
        out: &mut [f32],
    ) {
        let step = Step::Depthwise {
            src: 0,
            dst: 1,
            g: *g,
            filter: filter.to_vec(),
            bias: bias.to_vec(),
            fused: fused(ep),
        };
        run(level, step, input, ep, 0, out)
    }
}
