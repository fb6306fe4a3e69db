//! Shared mutation strategy of the parser fuzz tests (proptest, bounded case counts).
//!
//! Each case starts from a valid file and applies up to 8 edits: overwrite a byte,
//! insert one, delete one, flip one bit, or splice in a hostile token (huge and negative
//! counts, `nan`, a 0xFF run that reads as a huge little-endian length); then, in one
//! case out of four, truncates. The property is "returns `Ok` or `Err`, never panics,
//! never aborts on a huge allocation" (an abort fails the test binary).
#![allow(dead_code)]

use proptest::prelude::*;
use proptest::test_runner::Config;

/// Tokens spliced into inputs.
const TOKENS: [&[u8]; 9] = [
    b"4294967295",
    b"18446744073709551615",
    b"-1",
    b"1e308",
    b"nan",
    b"\xff\xff\xff\xff\xff\xff\xff\x7f",
    b"\xff\xff\xff\xff",
    b"\x00\x00\x00\x80",
    b"\"",
];

/// A proptest configuration running `cases` inputs, with no regression files written.
pub fn config(cases: u32) -> Config {
    Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    }
}

/// Mutations of `seed` (module docs).
pub fn mutated(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let edits = proptest::collection::vec((any::<usize>(), any::<u8>(), 0u8..5), 0..8);
    (edits, any::<usize>(), 0u8..4).prop_map(move |(edits, cut, truncate)| {
        let mut b = seed.clone();
        for (pos, byte, kind) in edits {
            let i = pos % (b.len() + 1);
            match kind {
                0 if i < b.len() => b[i] = byte,
                1 => b.insert(i, byte),
                2 if i < b.len() => {
                    b.remove(i);
                }
                3 if i < b.len() => b[i] ^= 1 << (byte % 8),
                4 => {
                    let t = TOKENS[usize::from(byte) % TOKENS.len()];
                    b.splice(i..i, t.iter().copied());
                }
                _ => {}
            }
        }
        if truncate == 0 {
            b.truncate(cut % (b.len() + 1));
        }
        b
    })
}
