//! Reader and writer for dlib's binary serialisation format (the subset used by
//! `dlib::shape_predictor`).
//!
//! Written from dlib's own source (`dlib/serialize.h`, `dlib/float_details.h`,
//! `dlib/matrix/matrix.h`, `dlib/geometry/vector.h`, dlib 19.24.6):
//!
//! * **Integers** are variable length: one control byte, then `size` little-endian
//!   magnitude bytes. For signed types the control byte is `size | 0x80` when the
//!   value is negative and `size = byte & 0x0F`; for unsigned types
//!   `size = byte & 0x8F` (so a set sign bit is an error). `size` must be in
//!   `1..=sizeof(T)`; zero is written as `[0x01, 0x00]`.
//! * **Floats** (`float`, `double`) are a `float_details` pair: an `int64` mantissa
//!   and an `int16` exponent, value `ldexp(mantissa, exponent)`; exponents 32000,
//!   32001, 32002 mean +inf, -inf, NaN. (A first byte with any of the bits `0x70`
//!   set marks dlib's old ASCII float format, which we reject.)
//! * **`matrix<T,0,1>`**: `long nr`, `long nc` (negated in the current format),
//!   then `nr*nc` elements row-major.
//! * **`std::vector<T>`**: `unsigned long` length, then the elements.
//! * **`dlib::vector<float,2>`**: `x`, `y`.

use std::fmt::Write as _;

/// Why decoding failed, with the byte offset where it happened.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecodeError {
    /// Byte offset of the value that could not be read.
    pub offset: usize,
    /// What went wrong.
    pub reason: String,
}

impl DecodeError {
    /// Formats as `"<reason> at byte <offset>"`.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        let _ = write!(s, "{} at byte {}", self.reason, self.offset);
        s
    }
}

/// Exponent value that encodes +infinity in `float_details`.
const FD_INF: i64 = 32000;
/// Exponent value that encodes -infinity.
const FD_NINF: i64 = 32001;
/// Exponent value that encodes NaN.
const FD_NAN: i64 = 32002;
/// Exponent dlib writes for 0.0 (see [`Writer::float`]).
const ZERO_EXPONENT: i64 = 40;
/// Bits of the first byte that are set only by dlib's old ASCII float format.
const OLD_FLOAT_FORMAT_BITS: u8 = 0x70;

/// A cursor over dlib-serialised bytes. Every read is checked; nothing panics.
#[derive(Debug)]
pub struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// Starts reading at the first byte.
    pub fn new(data: &'a [u8]) -> Self {
        Reader { data, pos: 0 }
    }

    /// Current byte offset.
    pub fn offset(&self) -> usize {
        self.pos
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn err<T>(&self, at: usize, reason: impl Into<String>) -> Result<T, DecodeError> {
        Err(DecodeError {
            offset: at,
            reason: reason.into(),
        })
    }

    fn byte(&mut self) -> Result<u8, DecodeError> {
        match self.data.get(self.pos) {
            Some(&b) => {
                self.pos += 1;
                Ok(b)
            }
            None => self.err(self.pos, "unexpected end of file"),
        }
    }

    /// Reads the magnitude bytes of an integer of `size` bytes.
    fn magnitude(&mut self, size: usize, start: usize) -> Result<u64, DecodeError> {
        let Some(bytes) = self.data.get(self.pos..self.pos + size) else {
            return self.err(start, "unexpected end of file inside an integer");
        };
        self.pos += size;
        Ok(bytes.iter().rev().fold(0u64, |acc, &b| (acc << 8) | u64::from(b)))
    }

    /// Reads an unsigned integer serialised from a C++ type of `type_size` bytes.
    pub fn unsigned(&mut self, type_size: usize, what: &str) -> Result<u64, DecodeError> {
        let start = self.pos;
        let control = self.byte()? & 0x8F;
        let size = usize::from(control);
        if size == 0 || size > type_size {
            return self.err(start, format!("bad integer control byte 0x{control:02x} for {what}"));
        }
        self.magnitude(size, start)
    }

    /// Reads a signed integer serialised from a C++ type of `type_size` bytes.
    pub fn signed(&mut self, type_size: usize, what: &str) -> Result<i64, DecodeError> {
        let start = self.pos;
        let control = self.byte()?;
        let negative = control & 0x80 != 0;
        let size = usize::from(control & 0x0F);
        if size == 0 || size > type_size {
            return self.err(start, format!("bad integer control byte 0x{control:02x} for {what}"));
        }
        let mag = self.magnitude(size, start)?;
        let Ok(mag) = i64::try_from(mag) else {
            return self.err(start, format!("{what} out of range"));
        };
        Ok(if negative { -mag } else { mag })
    }

    /// `unsigned long` (8 bytes on the LP64 platforms dlib models are made on).
    pub fn ulong(&mut self, what: &str) -> Result<u64, DecodeError> {
        self.unsigned(8, what)
    }

    /// A `std::vector` length, checked against the bytes left (each element needs
    /// at least `min_elem_bytes`), so hostile lengths cannot trigger huge allocations.
    pub fn length(&mut self, what: &str, min_elem_bytes: usize) -> Result<usize, DecodeError> {
        let start = self.pos;
        let n = self.ulong(what)?;
        let fits = usize::try_from(n).ok().filter(|&n| {
            n.checked_mul(min_elem_bytes.max(1))
                .is_some_and(|b| b <= self.remaining())
        });
        match fits {
            Some(n) => Ok(n),
            None => self.err(
                start,
                format!("{what} = {n} does not fit in the {} bytes left", self.remaining()),
            ),
        }
    }

    /// A `float` (dlib `float_details`), converted exactly as dlib does
    /// (`ldexp((float)mantissa, exponent)`).
    pub fn float(&mut self, what: &str) -> Result<f32, DecodeError> {
        if let Some(v) = self.fast_float() {
            return Ok(v);
        }
        let start = self.pos;
        match self.data.get(self.pos) {
            None => return self.err(start, format!("unexpected end of file reading {what}")),
            Some(&b) if b & OLD_FLOAT_FORMAT_BITS != 0 => {
                return self.err(start, format!("{what}: old ASCII float format is not supported"))
            }
            Some(_) => {}
        }
        let mantissa = self.signed(8, what)?;
        let exponent = self.signed(2, what)?;
        Ok(match exponent {
            FD_INF => f32::INFINITY,
            FD_NINF => f32::NEG_INFINITY,
            e if e >= FD_NAN => f32::NAN,
            e => ldexp_f32(mantissa as f32, e),
        })
    }

    /// The common case of [`Reader::float`] in one pass over the bytes: a
    /// well-formed finite value. Anything else (end of data, bad control bytes, the
    /// old format, infinities, NaN) returns `None` without moving, and the checked
    /// path then decodes it or reports the error. Same value as the checked path.
    #[inline]
    fn fast_float(&mut self) -> Option<f32> {
        // the longest float is 12 bytes; the last few floats of a file take the
        // checked path
        let d = self.data.get(self.pos..self.pos.checked_add(12)?)?;
        let c1 = *d.first()?;
        let n1 = u32::from(c1 & 0x0F);
        if c1 & OLD_FLOAT_FORMAT_BITS != 0 || n1 == 0 || n1 > 8 {
            return None;
        }
        let raw = u64::from_le_bytes(d.get(1..9)?.try_into().ok()?);
        let m = if n1 == 8 { raw } else { raw & ((1u64 << (8 * n1)) - 1) };
        let at = 1 + n1 as usize;
        let c2 = *d.get(at)?;
        let n2 = u32::from(c2 & 0x0F);
        if n2 == 0 || n2 > 2 {
            return None;
        }
        let raw = u16::from_le_bytes(d.get(at + 1..at + 3)?.try_into().ok()?);
        let e = i64::from(if n2 == 2 { raw } else { raw & 0xFF });
        let m = i64::try_from(m).ok()?;
        let mantissa = if c1 & 0x80 != 0 { -m } else { m };
        let exponent = if c2 & 0x80 != 0 { -e } else { e };
        if exponent >= FD_INF {
            return None;
        }
        self.pos += at + 1 + n2 as usize;
        Some(ldexp_f32(mantissa as f32, exponent))
    }

    /// A column vector `matrix<float,0,1>`.
    pub fn float_column(&mut self, what: &str, out: &mut Vec<f32>) -> Result<(), DecodeError> {
        let start = self.pos;
        let nr = self.signed(8, what)?.unsigned_abs();
        let nc = self.signed(8, what)?.unsigned_abs();
        if nc != 1 && nr != 0 {
            return self.err(start, format!("{what}: expected a column vector, got {nr}x{nc}"));
        }
        let n = nr.saturating_mul(nc);
        // every float takes at least 4 bytes (two control bytes + two value bytes)
        if n.saturating_mul(4) > self.remaining() as u64 {
            return self.err(
                start,
                format!("{what}: {n} values do not fit in the {} bytes left", self.remaining()),
            );
        }
        out.clear();
        out.reserve(n as usize);
        for _ in 0..n {
            let v = match self.fast_float() {
                Some(v) => v,
                None => self.float(what)?,
            };
            out.push(v);
        }
        Ok(())
    }
}

/// `ldexp` for `f32` with a single rounding (as C's `ldexpf`): `x * 2^e`.
fn ldexp_f32(x: f32, e: i64) -> f32 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    // |x| is in [2^-149, 2^128); clamping e keeps x * 2^e exact in f64 and the
    // clamped results still over/underflow f32 exactly as the unclamped ones.
    let e = e.clamp(-400, 400);
    // 2^e built from its bits (exact, as `powi` but without the loop)
    let scale = f64::from_bits(((e + 1023) as u64) << 52);
    let y = f64::from(x) * scale;
    y as f32
}

/// Serialises values in dlib's format (used to make synthetic models and to
/// round-trip real ones).
#[derive(Debug, Default)]
pub struct Writer {
    /// The bytes written so far.
    pub bytes: Vec<u8>,
}

impl Writer {
    /// Control byte `flags | size` then the `size` low bytes of `m`, little endian
    /// (`size` >= 1: zero is one zero byte).
    fn int_bytes(&mut self, m: u64, flags: u8) {
        let le = m.to_le_bytes();
        let size = le.iter().rposition(|&b| b != 0).map_or(1, |i| i + 1);
        self.bytes.push(flags | size as u8);
        self.bytes.extend_from_slice(&le[..size]);
    }

    /// Writes an unsigned integer.
    pub fn unsigned(&mut self, v: u64) {
        self.int_bytes(v, 0);
    }

    /// Writes a signed integer.
    pub fn signed(&mut self, v: i64) {
        self.int_bytes(v.unsigned_abs(), if v < 0 { 0x80 } else { 0 });
    }

    /// Writes a float as dlib's `float_details` (mantissa, exponent).
    pub fn float(&mut self, v: f32) {
        let (mantissa, exponent) = if v.is_nan() {
            (0i64, FD_NAN)
        } else if v == f32::INFINITY {
            (0, FD_INF)
        } else if v == f32::NEG_INFINITY {
            (0, FD_NINF)
        } else if v == 0.0 {
            // frexp(0) = (0, 0): exponent -24, then eight byte-shifts of the zero
            // mantissa add 64 (dlib writes zero as mantissa 0, exponent 40)
            (0, ZERO_EXPONENT)
        } else {
            // frexp: v = f * 2^exp with 0.5 <= |f| < 1; mantissa = f * 2^24
            let bits = v.to_bits();
            let raw_exp = i64::from((bits >> 23) & 0xFF);
            let frac = i64::from(bits & 0x7F_FFFF);
            let (m, e2) = if raw_exp == 0 {
                (frac, -149i64) // subnormal: v = frac * 2^-149
            } else {
                (frac | 0x80_0000, raw_exp - 127 - 23)
            };
            // normalise m to 24 significant bits like frexp(...)*2^24 does
            let lz = i64::from((m as u32).leading_zeros()) - 8;
            let mut m = m << lz;
            let mut e = e2 - lz;
            if v < 0.0 {
                m = -m;
            }
            for _ in 0..8 {
                if m & 0xFF != 0 {
                    break;
                }
                m >>= 8;
                e += 8;
            }
            (m, e)
        };
        self.signed(mantissa);
        self.signed(exponent);
    }

    /// Writes a `matrix<float,0,1>` in the current (negated size) format.
    pub fn float_column(&mut self, v: &[f32]) {
        self.signed(-(v.len() as i64));
        self.signed(-1);
        for &x in v {
            self.float(x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_round_trip() {
        for v in [0u64, 1, 255, 256, 65535, 1 << 40, u64::MAX] {
            let mut w = Writer::default();
            w.unsigned(v);
            assert_eq!(Reader::new(&w.bytes).ulong("v"), Ok(v));
        }
        for v in [0i64, 1, -1, 127, -128, 32000, -40000, i64::MAX, -i64::MAX] {
            let mut w = Writer::default();
            w.signed(v);
            assert_eq!(Reader::new(&w.bytes).signed(8, "v"), Ok(v));
        }
        assert_eq!(Writer::default().bytes.len(), 0);
        let mut w = Writer::default();
        w.unsigned(0);
        assert_eq!(w.bytes, vec![1, 0]);
    }

    #[test]
    fn floats_round_trip() {
        for v in [
            0.0f32,
            1.0,
            -1.0,
            0.1,
            -123.456,
            1e-40,
            -1e-45,
            f32::MAX,
            f32::MIN_POSITIVE,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            let mut w = Writer::default();
            w.float(v);
            let back = Reader::new(&w.bytes).float("v");
            assert_eq!(back.map(f32::to_bits), Ok(v.to_bits()), "{v}");
        }
        let mut w = Writer::default();
        w.float(f32::NAN);
        assert!(Reader::new(&w.bytes).float("v").is_ok_and(f32::is_nan));
    }

    #[test]
    fn bad_control_bytes_are_errors() {
        assert!(Reader::new(&[0x00]).ulong("v").is_err());
        assert!(Reader::new(&[0x09, 0, 0, 0, 0, 0, 0, 0, 0, 0]).ulong("v").is_err());
        assert!(Reader::new(&[0x81, 1]).ulong("v").is_err());
        assert!(Reader::new(&[0x03, 1, 2]).signed(2, "v").is_err());
        assert!(Reader::new(&[0x30]).float("v").is_err());
        assert!(Reader::new(&[]).float("v").is_err());
    }

    #[test]
    fn ldexp_matches_powi_over_the_whole_range() {
        for &x in &[
            1.0f32,
            -1.0,
            0.75,
            8_388_607.0,
            -12_345_678.0,
            f32::MIN_POSITIVE,
            3.0e38,
            1.0e-45,
        ] {
            for e in -500i64..=500 {
                let want = (f64::from(x) * 2f64.powi(e.clamp(-400, 400) as i32)) as f32;
                let got = ldexp_f32(x, e);
                assert!(
                    got.to_bits() == want.to_bits(),
                    "ldexp({x}, {e}) = {got}, powi gives {want}"
                );
            }
        }
        assert_eq!(ldexp_f32(0.0, 7), 0.0);
        assert!(ldexp_f32(f32::NAN, 1).is_nan());
    }

    #[test]
    fn fast_float_equals_the_checked_decoding() {
        let mut w = Writer::default();
        let mut values = vec![
            0.0f32,
            -0.0,
            1.0,
            -2.5,
            1e-40,
            -3.0e38,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let mut x = 0x1234_5678u32;
        for _ in 0..2000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            values.push(f32::from_bits(x));
        }
        for &v in &values {
            w.float(v);
        }
        let mut fast = Reader::new(&w.bytes);
        let mut slow = Reader::new(&w.bytes);
        for &v in &values {
            let got = fast.float("v").unwrap();
            let m = slow.signed(8, "m").unwrap();
            let e = slow.signed(2, "e").unwrap();
            let want = match e {
                FD_INF => f32::INFINITY,
                FD_NINF => f32::NEG_INFINITY,
                e if e >= FD_NAN => f32::NAN,
                e => ldexp_f32(m as f32, e),
            };
            assert!(
                got.to_bits() == want.to_bits() || got.is_nan() && want.is_nan(),
                "{v}: {got} vs {want}"
            );
            assert!(got == v || v.is_nan() && got.is_nan(), "{v} read back as {got}");
        }
        assert_eq!(fast.remaining(), 0);
    }
}
