//! A minimal, bounds-checked FlatBuffers reader: just what the TFLite schema needs.
//!
//! FlatBuffers layout (little-endian throughout):
//!
//! * the buffer starts with a `u32` offset to the root table;
//! * a table at position `t` starts with an `i32` `soffset`; its vtable is at `t - soffset`
//!   and holds `u16 vtable_len, u16 table_len, u16 field_offset[..]` (0 = field absent,
//!   the schema default applies);
//! * offset fields (tables, vectors, strings) hold a `u32` relative to their own position;
//! * a vector is a `u32` element count followed by the elements; a vector of tables holds
//!   `u32` offsets relative to each element's position; a string is a byte vector.
//!
//! Every read is checked against the buffer length with checked arithmetic: a damaged
//! file gives an [`Error::Model`](crate::Error::Model), never a panic or an out-of-bounds
//! read.

use crate::{Error, Result};

fn bad(reason: impl Into<String>) -> Error {
    Error::Model { reason: reason.into() }
}

/// A byte buffer with checked little-endian reads.
#[derive(Debug, Clone, Copy)]
pub struct Buf<'a> {
    bytes: &'a [u8],
}

impl<'a> Buf<'a> {
    /// The buffer over `bytes`.
    pub fn new(bytes: &'a [u8]) -> Self {
        Buf { bytes }
    }

    /// Length in bytes.
    pub fn len(&self) -> usize {
        self.bytes.len()
    }

    /// Whether the buffer holds no bytes.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// `n` bytes at `pos`, or an error naming `what`.
    pub fn slice(&self, pos: usize, n: usize, what: &str) -> Result<&'a [u8]> {
        let end = pos
            .checked_add(n)
            .ok_or_else(|| bad(format!("{what}: size overflow at offset {pos}")))?;
        self.bytes.get(pos..end).ok_or_else(|| {
            bad(format!(
                "{what}: {n} bytes at offset {pos} run past the end of the {}-byte buffer",
                self.bytes.len()
            ))
        })
    }

    fn array<const N: usize>(&self, pos: usize, what: &str) -> Result<[u8; N]> {
        let s = self.slice(pos, N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u8_at(&self, pos: usize, what: &str) -> Result<u8> {
        Ok(self.array::<1>(pos, what)?[0])
    }
    pub fn u16_at(&self, pos: usize, what: &str) -> Result<u16> {
        Ok(u16::from_le_bytes(self.array(pos, what)?))
    }
    pub fn u32_at(&self, pos: usize, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(pos, what)?))
    }
    pub fn i32_at(&self, pos: usize, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(pos, what)?))
    }
    pub fn u64_at(&self, pos: usize, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array(pos, what)?))
    }

    /// Follows a `u32` forward offset stored at `pos`.
    fn follow(&self, pos: usize, what: &str) -> Result<usize> {
        let rel = self.u32_at(pos, what)? as usize;
        let target = pos
            .checked_add(rel)
            .ok_or_else(|| bad(format!("{what}: offset overflow")))?;
        if target >= self.bytes.len() {
            return Err(bad(format!(
                "{what}: offset {target} past the end of the {}-byte buffer",
                self.bytes.len()
            )));
        }
        Ok(target)
    }

    /// The root table.
    pub fn root(&self) -> Result<Table<'a>> {
        let pos = self.follow(0, "root table offset")?;
        Table::at(*self, pos, "root table")
    }
}

/// A FlatBuffers table.
#[derive(Debug, Clone, Copy)]
pub struct Table<'a> {
    buf: Buf<'a>,
    pos: usize,
    vtable: usize,
    vtable_len: usize,
}

impl<'a> Table<'a> {
    fn at(buf: Buf<'a>, pos: usize, what: &str) -> Result<Self> {
        let soff = buf.i32_at(pos, what)? as i64;
        let vtable = pos as i64 - soff;
        if vtable < 0 || vtable as u64 >= buf.len() as u64 {
            return Err(bad(format!("{what}: vtable offset {vtable} outside the buffer")));
        }
        let vtable = vtable as usize;
        let vtable_len = buf.u16_at(vtable, what)? as usize;
        if vtable_len < 4 || vtable_len % 2 != 0 {
            return Err(bad(format!("{what}: vtable length {vtable_len} is invalid")));
        }
        buf.slice(vtable, vtable_len, what)?;
        let table_len = buf.u16_at(vtable + 2, what)? as usize;
        buf.slice(pos, table_len.max(4), what)?;
        Ok(Table {
            buf,
            pos,
            vtable,
            vtable_len,
        })
    }

    /// Absolute position of field `id`, or `None` when absent.
    fn field(&self, id: usize, what: &str) -> Result<Option<usize>> {
        let entry = 4 + 2 * id;
        if entry + 2 > self.vtable_len {
            return Ok(None);
        }
        let off = self.buf.u16_at(self.vtable + entry, what)? as usize;
        if off == 0 {
            return Ok(None);
        }
        Ok(Some(self.pos + off))
    }

    pub fn u8_or(&self, id: usize, default: u8, what: &str) -> Result<u8> {
        match self.field(id, what)? {
            Some(p) => self.buf.u8_at(p, what),
            None => Ok(default),
        }
    }
    pub fn i32_or(&self, id: usize, default: i32, what: &str) -> Result<i32> {
        match self.field(id, what)? {
            Some(p) => self.buf.i32_at(p, what),
            None => Ok(default),
        }
    }
    pub fn u32_or(&self, id: usize, default: u32, what: &str) -> Result<u32> {
        match self.field(id, what)? {
            Some(p) => self.buf.u32_at(p, what),
            None => Ok(default),
        }
    }
    pub fn u64_or(&self, id: usize, default: u64, what: &str) -> Result<u64> {
        match self.field(id, what)? {
            Some(p) => self.buf.u64_at(p, what),
            None => Ok(default),
        }
    }

    /// A sub-table field.
    pub fn table(&self, id: usize, what: &str) -> Result<Option<Table<'a>>> {
        match self.field(id, what)? {
            Some(p) => {
                let t = self.buf.follow(p, what)?;
                Table::at(self.buf, t, what).map(Some)
            }
            None => Ok(None),
        }
    }

    /// A vector field whose elements are `elem_size` bytes each.
    pub fn vector(&self, id: usize, elem_size: usize, what: &str) -> Result<Option<Vector<'a>>> {
        match self.field(id, what)? {
            Some(p) => {
                let v = self.buf.follow(p, what)?;
                let len = self.buf.u32_at(v, what)? as usize;
                let bytes = len
                    .checked_mul(elem_size)
                    .ok_or_else(|| bad(format!("{what}: vector length {len} overflows")))?;
                self.buf.slice(v + 4, bytes, what)?;
                Ok(Some(Vector {
                    buf: self.buf,
                    start: v + 4,
                    len,
                    elem_size,
                }))
            }
            None => Ok(None),
        }
    }

    /// A string field (lossy UTF-8).
    pub fn string(&self, id: usize, what: &str) -> Result<Option<String>> {
        Ok(self
            .vector(id, 1, what)?
            .map(|v| String::from_utf8_lossy(v.bytes()).into_owned()))
    }

    /// An `[int]` vector field.
    pub fn i32_vec(&self, id: usize, what: &str) -> Result<Vec<i32>> {
        match self.vector(id, 4, what)? {
            Some(v) => (0..v.len()).map(|i| v.i32_at(i, what)).collect(),
            None => Ok(Vec::new()),
        }
    }
}

/// A FlatBuffers vector whose byte extent has been checked.
#[derive(Debug, Clone, Copy)]
pub struct Vector<'a> {
    buf: Buf<'a>,
    start: usize,
    len: usize,
    elem_size: usize,
}

impl<'a> Vector<'a> {
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the vector has no elements.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The raw element bytes.
    pub fn bytes(&self) -> &'a [u8] {
        // Checked in `Table::vector`; `get` keeps this panic-free regardless.
        self.buf
            .bytes
            .get(self.start..self.start + self.len * self.elem_size)
            .unwrap_or(&[])
    }
    pub fn i32_at(&self, i: usize, what: &str) -> Result<i32> {
        self.buf.i32_at(self.start + 4 * i, what)
    }
    /// Element `i` of a vector of tables.
    pub fn table_at(&self, i: usize, what: &str) -> Result<Table<'a>> {
        if i >= self.len {
            return Err(bad(format!("{what}: index {i} out of {}", self.len)));
        }
        let t = self.buf.follow(self.start + 4 * i, what)?;
        Table::at(self.buf, t, what)
    }
}
