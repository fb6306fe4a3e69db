//! Quantised leaf tables for [`super::ErtPrecision::Fast`].
//!
//! The exact path's time is set by memory traffic: a 68-point prediction adds 7,500
//! leaf vectors of 136 f32 (544 B, ~9 cache lines each) picked from a 65 MB table.
//! Here every leaf is stored as 16-bit integers with its own scale
//! (`value = scale * q`, `q` in `-32767..=32767`, `scale = max |value| / 32767`), in
//! rows padded to whole 64-byte lines and aligned to them: the f32 scale sits in the
//! row's first two `i16`, the coordinates follow. A 68-point leaf is then 5 cache
//! lines instead of ~9, a 5-point leaf one line instead of one or two. The additions
//! convert to f32 and accumulate in f32, four rows per pass (plain loops the compiler
//! vectorises; on x86-64 compiled a second time for AVX2 and chosen at run time).
//!
//! The rounding error per coordinate and leaf is at most `scale / 2`, i.e.
//! `max |value| / 65534`; how far it moves the landmarks is measured against the exact
//! path in `tests/ert_fast.rs` and `docs/landmarks.md`.

/// `i16` per 64-byte line.
const LINE: usize = 32;

/// The quantised leaves of every cascade, one aligned row per leaf.
#[derive(Debug)]
pub(super) struct FastLeaves {
    /// Backing store; row `r` of cascade `c` starts at `base + (offset[c] + r) * stride`.
    data: Vec<i16>,
    /// Index of the first 64-byte aligned element of `data`.
    base: usize,
    /// `i16` per row (a multiple of [`LINE`]): two for the scale, then `dim` values.
    stride: usize,
    /// First row of each cascade.
    offset: Vec<usize>,
    /// Rows (leaves) per cascade.
    rows: Vec<usize>,
    dim: usize,
}

impl FastLeaves {
    /// Quantises `leaves` (per cascade, `leaf * dim + coord`).
    pub(super) fn new<'a>(cascades: impl Iterator<Item = &'a [f32]>, dim: usize) -> Self {
        let stride = (dim + 2).div_ceil(LINE) * LINE;
        let mut offset = Vec::new();
        let mut rows = Vec::new();
        let mut total = 0usize;
        let tables: Vec<&[f32]> = cascades.collect();
        for t in &tables {
            let n = t.len().checked_div(dim).unwrap_or(0);
            offset.push(total);
            rows.push(n);
            total += n;
        }
        let mut data = vec![0i16; total * stride + LINE];
        let misalign = (data.as_ptr() as usize / std::mem::size_of::<i16>()) % LINE;
        let base = (LINE - misalign) % LINE;
        for (c, t) in tables.iter().enumerate() {
            if dim == 0 {
                break;
            }
            for (r, leaf) in t.chunks_exact(dim).enumerate() {
                let start = base + (offset[c] + r) * stride;
                let row = &mut data[start..start + stride];
                let bits = quantise(leaf, &mut row[2..2 + dim]).to_bits();
                row[0] = (bits & 0xffff) as u16 as i16;
                row[1] = (bits >> 16) as u16 as i16;
            }
        }
        FastLeaves {
            data,
            base,
            stride,
            offset,
            rows,
            dim,
        }
    }

    /// Adds the leaves `leaf` (row indices within cascade `c`) to `shape`.
    pub(super) fn add(&self, c: usize, shape: &mut [f32], leaf: &[u32]) {
        let (Some(&off), Some(&n)) = (self.offset.get(c), self.rows.get(c)) else {
            return;
        };
        if shape.len() != self.dim {
            return;
        }
        let table = &self.data[self.base + off * self.stride..self.base + (off + n) * self.stride];
        AddRows {
            table,
            stride: self.stride,
            dim: self.dim,
            shape,
            leaf,
        }
        .dispatch();
    }
}

/// Per-leaf symmetric 16-bit quantisation: writes `q` and returns the scale.
fn quantise(leaf: &[f32], q: &mut [i16]) -> f32 {
    let max = leaf.iter().fold(0f32, |m, v| m.max(v.abs()));
    if max == 0.0 || !max.is_finite() {
        q.iter_mut().for_each(|v| *v = 0);
        return 0.0;
    }
    let scale = max / 32767.0;
    let inv = 1.0 / f64::from(scale);
    for (o, &v) in q.iter_mut().zip(leaf) {
        *o = (f64::from(v) * inv).round().clamp(-32767.0, 32767.0) as i16;
    }
    scale
}

/// The scale stored in a row's first two `i16`.
#[inline(always)]
fn row_scale(row: &[i16]) -> f32 {
    let lo = u32::from(row[0] as u16);
    let hi = u32::from(row[1] as u16);
    f32::from_bits(lo | (hi << 16))
}

struct AddRows<'a> {
    table: &'a [i16],
    stride: usize,
    dim: usize,
    shape: &'a mut [f32],
    leaf: &'a [u32],
}

impl AddRows<'_> {
    fn dispatch(self) {
        pulp::Arch::new().dispatch(self);
    }
}

impl pulp::WithSimd for AddRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let AddRows {
            table,
            stride,
            dim,
            shape,
            leaf,
        } = self;
        let row = |li: u32| {
            let start = li as usize * stride;
            table.get(start..start + 2 + dim)
        };
        let mut groups = leaf.chunks_exact(4);
        for g in &mut groups {
            if let (Some(a), Some(b), Some(c), Some(d)) = (row(g[0]), row(g[1]), row(g[2]), row(g[3])) {
                let (sa, sb, sc, sd) = (row_scale(a), row_scale(b), row_scale(c), row_scale(d));
                let (a, b, c, d) = (&a[2..], &b[2..], &c[2..], &d[2..]);
                for ((((s, a), b), c), d) in shape.iter_mut().zip(a).zip(b).zip(c).zip(d) {
                    let x = (f32::from(*a) * sa + f32::from(*b) * sb) + (f32::from(*c) * sc + f32::from(*d) * sd);
                    *s += x;
                }
            }
        }
        for &li in groups.remainder() {
            if let Some(a) = row(li) {
                let sa = row_scale(a);
                for (s, a) in shape.iter_mut().zip(&a[2..]) {
                    *s += f32::from(*a) * sa;
                }
            }
        }
    }
}
