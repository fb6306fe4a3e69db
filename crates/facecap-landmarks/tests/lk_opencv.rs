#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Agreement with OpenCV 4.14 `calcOpticalFlowPyrLK` on real frame pairs of two
//! shared videos (fixture `testdata/opencv_lk/fixture.json`, made by
//! `testdata/opencv_lk/make_fixture.py`): 68 dlib landmarks + 200 corners per pair,
//! window 21, maxLevel 3. Frames are decoded with the same ffmpeg command as the
//! script. Skips when the shared data or ffmpeg is absent.

use std::path::Path;
use std::process::Command;

use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use image::GrayImage;
use nalgebra::Point2;
use serde::Deserialize;

#[derive(Deserialize)]
struct Fixture {
    n_frames_decoded: usize,
    clips: Vec<Clip>,
}

#[derive(Deserialize)]
struct Clip {
    clip: String,
    width: u32,
    height: u32,
    pairs: Vec<Pair>,
}

#[derive(Deserialize)]
struct Pair {
    frame: usize,
    byte_sum_prev: u64,
    byte_sum_next: u64,
    prev: Vec<[f64; 2]>,
    next: Vec<[f64; 2]>,
    status: Vec<u8>,
}

/// Decodes the first `n` frames to grey exactly like the fixture script.
fn decode_gray(path: &Path, w: u32, h: u32, n: usize) -> Option<Vec<GrayImage>> {
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-i"])
        .arg(path)
        .args(["-frames:v", &n.to_string(), "-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let size = (w * h) as usize;
    Some(
        out.stdout
            .chunks_exact(size)
            .map(|c| GrayImage::from_raw(w, h, c.to_vec()).unwrap())
            .collect(),
    )
}

#[test]
fn matches_opencv_calc_optical_flow_pyr_lk() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/opencv_lk/fixture.json"
    ))
    .unwrap();
    let fx: Fixture = serde_json::from_str(&text).unwrap();
    let lk = PyramidLk::new(LkParams::default()).unwrap();
    let mut ws = LkWorkspace::new(&lk);
    let (mut diffs, mut agree, mut total, mut clips_run) = (Vec::new(), 0usize, 0usize, 0);
    for clip in &fx.clips {
        let Some(path) = facecap_core::paths::shared_data_file("lk_opencv", &clip.clip) else {
            continue;
        };
        let Some(frames) = decode_gray(&path, clip.width, clip.height, fx.n_frames_decoded) else {
            eprintln!("SKIP: lk_opencv: ffmpeg could not decode {}", clip.clip);
            continue;
        };
        clips_run += 1;
        for pair in &clip.pairs {
            let (a, b) = (&frames[pair.frame], &frames[pair.frame + 1]);
            let sum = |g: &GrayImage| g.as_raw().iter().map(|&v| v as u64).sum::<u64>();
            assert_eq!(
                sum(a),
                pair.byte_sum_prev,
                "decoded frame {} differs from the fixture's",
                pair.frame
            );
            assert_eq!(sum(b), pair.byte_sum_next);
            ws.reset();
            ws.push_frame(a).unwrap();
            ws.push_frame(b).unwrap();
            let pts: Vec<Point2<f64>> = pair.prev.iter().map(|p| Point2::new(p[0], p[1])).collect();
            let mut next = vec![Point2::origin(); pts.len()];
            let mut st = vec![TrackStatus::Tracked; pts.len()];
            let mut err = vec![0.0; pts.len()];
            lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap();
            for i in 0..pts.len() {
                let cv_ok = pair.status[i] == 1;
                total += 1;
                if cv_ok == st[i].is_tracked() {
                    agree += 1;
                }
                if cv_ok && st[i].is_tracked() {
                    let d = ((next[i].x - pair.next[i][0]).powi(2) + (next[i].y - pair.next[i][1]).powi(2)).sqrt();
                    diffs.push(d);
                }
            }
        }
    }
    if clips_run == 0 {
        return;
    }
    diffs.sort_by(f64::total_cmp);
    let median = diffs[diffs.len() / 2];
    let p99 = diffs[diffs.len() * 99 / 100];
    let exact = diffs.iter().filter(|&&d| d < 1e-3).count() as f64 / diffs.len() as f64;
    let agreement = agree as f64 / total as f64;
    eprintln!(
        "lk vs OpenCV: {} points both tracked, median |diff| {median:.5} px, p99 {p99:.4} px, max {:.4} px, within 1e-3 px {:.1} %, status agreement {:.2} % ({agree}/{total})",
        diffs.len(),
        diffs[diffs.len() - 1],
        100.0 * exact,
        100.0 * agreement
    );
    assert!(median <= 0.05, "median {median}");
    assert!(agreement >= 0.99, "status agreement {agreement}");
}

/// Second oracle on the same real frame pairs and points: the `optical-flow-lk` crate
/// (0.6; fixed-point windows like OpenCV, but a 2x2 box pyramid instead of OpenCV's
/// Gaussian one, so it agrees with us less tightly than OpenCV does). Window 21,
/// 3 levels above the base, both with their default stopping rules.
#[test]
fn agrees_with_the_optical_flow_lk_crate_on_real_frames() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/opencv_lk/fixture.json"
    ))
    .unwrap();
    let fx: Fixture = serde_json::from_str(&text).unwrap();
    let params = LkParams::default();
    let lk = PyramidLk::new(params).unwrap();
    let mut ws = LkWorkspace::new(&lk);
    let theirs_params = optical_flow_lk::TrackParams {
        window_size: params.window,
        max_iterations: params.max_iterations,
        min_eigen_threshold: optical_flow_lk::DEFAULT_MIN_EIGEN_THRESHOLD,
    };
    let (mut diffs, mut agree, mut total, mut clips_run) = (Vec::new(), 0usize, 0usize, 0);
    for clip in &fx.clips {
        let Some(path) = facecap_core::paths::shared_data_file("lk_crate_oracle", &clip.clip) else {
            continue;
        };
        let Some(frames) = decode_gray(&path, clip.width, clip.height, fx.n_frames_decoded) else {
            eprintln!("SKIP: lk_crate_oracle: ffmpeg could not decode {}", clip.clip);
            continue;
        };
        clips_run += 1;
        for pair in &clip.pairs {
            let (a, b) = (&frames[pair.frame], &frames[pair.frame + 1]);
            ws.reset();
            ws.push_frame(a).unwrap();
            ws.push_frame(b).unwrap();
            let pts: Vec<Point2<f64>> = pair.prev.iter().map(|p| Point2::new(p[0], p[1])).collect();
            let mut next = vec![Point2::origin(); pts.len()];
            let mut st = vec![TrackStatus::Tracked; pts.len()];
            let mut err = vec![0.0; pts.len()];
            lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap();
            let pa = optical_flow_lk::build_pyramid(a, params.max_level + 1);
            let pb = optical_flow_lk::build_pyramid(b, params.max_level + 1);
            let start: Vec<(f32, f32)> = pts.iter().map(|p| (p.x as f32, p.y as f32)).collect();
            let theirs = optical_flow_lk::calc_optical_flow_ex(&pa, &pb, &start, None, theirs_params);
            for i in 0..pts.len() {
                let theirs_ok = theirs[i].status == optical_flow_lk::TrackStatus::Tracked;
                total += 1;
                if theirs_ok == st[i].is_tracked() {
                    agree += 1;
                }
                if theirs_ok && st[i].is_tracked() {
                    let (tx, ty) = theirs[i].pos;
                    diffs.push(((next[i].x - f64::from(tx)).powi(2) + (next[i].y - f64::from(ty)).powi(2)).sqrt());
                }
            }
        }
    }
    if clips_run == 0 {
        return;
    }
    diffs.sort_by(f64::total_cmp);
    let median = diffs[diffs.len() / 2];
    let p90 = diffs[diffs.len() * 9 / 10];
    let agreement = agree as f64 / total as f64;
    eprintln!(
        "lk vs optical-flow-lk: {} points both tracked, median |diff| {median:.4} px, p90 {p90:.4} px, max {:.3} px, status agreement {:.2} % ({agree}/{total})",
        diffs.len(),
        diffs[diffs.len() - 1],
        100.0 * agreement
    );
    // measured: median 0.0002 px, p90 0.0015 px, status agreement 96 % (the crate
    // reports points that hit the iteration cap as `Diverged`; we keep them tracked
    // unless `require_convergence`, as OpenCV does)
    assert!(median <= 0.01, "median {median}");
    assert!(p90 <= 0.05, "p90 {p90}");
    assert!(agreement >= 0.94, "status agreement {agreement}");
}
