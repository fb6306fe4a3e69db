//! The FlatBuffers reader on hand-built buffers: fields, defaults, truncations and
//! garbled offsets (errors, never panics).

use facecap_tflite::flatbuf::Buf;
use facecap_tflite::Result;

/// A hand-built buffer: root table with field 0 = u32 7, field 1 = vector [1, -2].
fn sample() -> Vec<u8> {
    let mut b = vec![0u8; 0];
    // 0: root offset -> table at 16
    b.extend_from_slice(&16u32.to_le_bytes());
    // 4: vtable: len 8, table len 12, field0 at +4, field1 at +8
    b.extend_from_slice(&8u16.to_le_bytes());
    b.extend_from_slice(&12u16.to_le_bytes());
    b.extend_from_slice(&4u16.to_le_bytes());
    b.extend_from_slice(&8u16.to_le_bytes());
    b.extend_from_slice(&[0u8; 4]); // 12..16 padding
                                    // 16: table: soffset = 16 - 4 = 12
    b.extend_from_slice(&12i32.to_le_bytes());
    b.extend_from_slice(&7u32.to_le_bytes()); // 20: field0
    b.extend_from_slice(&4u32.to_le_bytes()); // 24: field1 -> 28
    b.extend_from_slice(&2u32.to_le_bytes()); // 28: len
    b.extend_from_slice(&1i32.to_le_bytes());
    b.extend_from_slice(&(-2i32).to_le_bytes());
    b
}

#[test]
fn reads_fields_and_defaults() -> Result<()> {
    let b = sample();
    let t = Buf::new(&b).root()?;
    assert_eq!(t.u32_or(0, 0, "f0")?, 7);
    assert_eq!(t.i32_vec(1, "f1")?, vec![1, -2]);
    assert_eq!(t.i32_or(5, 42, "absent")?, 42);
    assert!(t.table(7, "absent")?.is_none());
    Ok(())
}

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    let b = sample();
    for n in 0..b.len() {
        let r = Buf::new(&b[..n]).root().and_then(|t| {
            t.u32_or(0, 0, "f0")?;
            t.i32_vec(1, "f1")
        });
        assert!(r.is_err(), "truncation to {n} bytes was accepted");
    }
}

#[test]
fn garbled_offsets_are_errors() {
    let mut b = sample();
    b[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
    let t = Buf::new(&b).root().ok();
    assert!(t.map(|t| t.i32_vec(1, "f1").is_err()).unwrap_or(true));
    let mut b = sample();
    b[28..32].copy_from_slice(&0x4000_0000u32.to_le_bytes()); // huge vector length
    let t = Buf::new(&b).root().ok();
    assert!(t.map(|t| t.i32_vec(1, "f1").is_err()).unwrap_or(true));
}
