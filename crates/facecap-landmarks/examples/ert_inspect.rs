//! Prints the structure of a dlib shape_predictor file and checks that re-serialising
//! it reproduces the file: `cargo run --example ert_inspect -- MODEL.dat`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use facecap_landmarks::ert::ErtModel;

fn main() {
    let path = std::env::args().nth(1).expect("usage: ert_inspect MODEL.dat");
    let bytes = std::fs::read(&path).unwrap();
    let m = ErtModel::from_bytes(&bytes).unwrap();
    let trees: usize = m.forests.iter().map(Vec::len).sum();
    println!(
        "{path}: {} parts, {} cascades, {trees} trees, {} splits/tree, {} feature pixels/cascade",
        m.num_parts(),
        m.forests.len(),
        m.forests[0][0].splits.len(),
        m.deltas[0].len()
    );
    let again = m.to_dlib_bytes();
    match again.iter().zip(&bytes).position(|(a, b)| a != b) {
        None if again.len() == bytes.len() => println!("re-serialisation: identical ({} bytes)", bytes.len()),
        None => println!("re-serialisation: lengths differ {} vs {}", again.len(), bytes.len()),
        Some(i) => {
            let lo = i.saturating_sub(16);
            println!("first difference at byte {i}");
            println!("file: {:02x?}", &bytes[lo..(i + 16).min(bytes.len())]);
            println!("ours: {:02x?}", &again[lo..(i + 16).min(again.len())]);
        }
    }
}
