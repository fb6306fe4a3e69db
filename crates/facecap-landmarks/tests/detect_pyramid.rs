#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Our `pyramid_down<6>` equals dlib's to the pixel (checksums of dlib's
//! `dlib.pyramid_down(6)` output on synthetic patterns, in the fixture).

use std::path::PathBuf;

use facecap_landmarks::detect::pyramid::{down6, Gray};

fn synthetic(w: usize, h: usize) -> Gray {
    let mut g = Gray::default();
    g.set_size(w, h);
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            g.data[(y as usize) * w + x as usize] = ((x * 7 + y * 13 + (x * y) % 31 + (x * x) % 17) % 256) as u8;
        }
    }
    g
}

fn checksum(g: &Gray) -> [u64; 2] {
    let mut s = 0u64;
    let mut ws = 0u64;
    for (i, &v) in g.data.iter().enumerate() {
        s += u64::from(v);
        ws += u64::from(v) * (i as u64 % 251 + 1);
    }
    [s, ws]
}

#[test]
fn pyramid_down6_matches_dlib_bit_for_bit() {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_hog/fixture.json");
    let fx: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    let cases = fx["pyramid_down6"].as_array().unwrap();
    assert!(!cases.is_empty());
    for case in cases {
        let (w, h) = (
            case["width"].as_u64().unwrap() as usize,
            case["height"].as_u64().unwrap() as usize,
        );
        let mut img = synthetic(w, h);
        for (k, lvl) in case["levels"].as_array().unwrap().iter().enumerate() {
            let mut next = Gray::default();
            down6(img.view(), &mut next);
            let want = [
                lvl["checksum"][0].as_u64().unwrap(),
                lvl["checksum"][1].as_u64().unwrap(),
            ];
            assert_eq!(
                (next.width as u64, next.height as u64),
                (lvl["width"].as_u64().unwrap(), lvl["height"].as_u64().unwrap()),
                "{w}x{h} level {k}"
            );
            assert_eq!(checksum(&next), want, "{w}x{h} level {}", k + 1);
            img = next;
        }
    }
}
