#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Iris centres on the shared clips against MediaPipe FaceLandmarker (fixture
//! `testdata/gaze/mediapipe_iris.csv`): per clip and eye the median distance of the iris
//! centres, the Pearson r of our horizontal / vertical gaze offsets with MediaPipe's
//! `eyeLookOut - eyeLookIn` / `eyeLookDown - eyeLookUp`, the same r for MediaPipe's own
//! iris in our eye frame (the ceiling with our landmarks), and the `gaze_weights` gains
//! fitted to MediaPipe's scores. `--sweep` also compares a few parameter variants.
//!
//! ```text
//! cargo run --release -p facecap-landmarks --example gaze_eval [-- --sweep]
//! ```

#[path = "../tests/gaze_common/clips.rs"]
mod clips;

use clips::{eye_stats, fit_gain, median, read_fixture, run_clip, tracker, EyeStats, CLIPS};
use facecap_landmarks::gaze::{IrisEstimator, IrisParams};

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len().max(1) as f64
}

fn main() {
    let sweep = std::env::args().any(|a| a == "--sweep");
    let Some(tracker) = tracker("gaze_eval") else { return };
    let d = IrisParams::default();
    let mut variants: Vec<(String, IrisParams)> = vec![("default".into(), d)];
    if sweep {
        for s in [0.08, 0.11, 0.2, 0.25] {
            variants.push((format!("kernel_sigma {s}"), IrisParams { kernel_sigma: s, ..d }));
        }
        for t in [0.3, 0.4, 0.6, 0.7] {
            variants.push((
                format!("threshold_level {t}"),
                IrisParams {
                    threshold_level: t,
                    ..d
                },
            ));
        }
        for m in [0.0, 0.06, 0.1] {
            variants.push((format!("mask_margin {m}"), IrisParams { mask_margin: m, ..d }));
        }
        variants.push((
            "low_percentile 0.01".into(),
            IrisParams {
                low_percentile: 0.01,
                ..d
            },
        ));
        variants.push((
            "high_percentile 0.8".into(),
            IrisParams {
                high_percentile: 0.8,
                ..d
            },
        ));
        variants.push(("patch_width 32".into(), IrisParams { patch_width: 32, ..d }));
        variants.push(("patch_width 64".into(), IrisParams { patch_width: 64, ..d }));
        for (t, m, k) in [(0.6, 0.0, 0.15), (0.7, 0.0, 0.15), (0.6, 0.0, 0.12), (0.7, 0.03, 0.12)] {
            variants.push((
                format!("threshold_level {t}, mask_margin {m}, kernel_sigma {k}"),
                IrisParams {
                    threshold_level: t,
                    mask_margin: m,
                    kernel_sigma: k,
                    ..d
                },
            ));
        }
    }
    let ests: Vec<IrisEstimator> = variants.iter().map(|v| IrisEstimator::new(v.1).unwrap()).collect();
    let fx = read_fixture();
    // stats[variant] = (clip, width, eye name, stats)
    let mut stats: Vec<Vec<(String, u32, &str, EyeStats)>> = vec![Vec::new(); ests.len()];
    for clip in CLIPS {
        let Some(path) = facecap_core::paths::shared_data_file("gaze_eval", &format!("videos/{clip}.mp4")) else {
            continue;
        };
        let run = run_clip(&path, &tracker, &ests).unwrap();
        let mp = &fx[clip];
        assert_eq!(mp.len(), run.landmarks.len(), "{clip}: frame count");
        for (k, est) in run.estimates.iter().enumerate() {
            for (name, right) in [("right", true), ("left", false)] {
                stats[k].push((
                    clip.to_string(),
                    run.width,
                    name,
                    eye_stats(est, &run.landmarks, mp, right),
                ));
            }
        }
    }
    for (k, (vname, _)) in variants.iter().enumerate() {
        println!("== {vname}");
        if k == 0 {
            println!("clip eye | valid/tracked | median px | p90 px | median % width | r_h | r_v | r_h MP-iris | r_v MP-iris | r(u,u_mp) | r(v,v_mp) | median u-u_mp | median v-v_mp");
        }
        let fmt = |r: Option<f64>| r.map_or("-".to_string(), |r| format!("{r:.2}"));
        let (mut all_px, mut all_rel, mut px480, mut rel480) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut rh, mut rv, mut rhm, mut rvm) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (clip, w, eye, s) in &stats[k] {
            if k == 0 {
                let mut p = s.dist_px.clone();
                p.sort_by(f64::total_cmp);
                let p90 = p.get(p.len() * 9 / 10).copied().unwrap_or(f64::NAN);
                println!(
                    "{clip} {eye} | {}/{} | {:.2} | {:.2} | {:.1} | {} | {} | {} | {} | {:.2} | {:.2} | {:+.3} | {:+.3}",
                    s.frames,
                    s.tracked,
                    median(&s.dist_px),
                    p90,
                    100.0 * median(&s.dist_rel),
                    fmt(s.r_h),
                    fmt(s.r_v),
                    fmt(s.r_h_mp_iris),
                    fmt(s.r_v_mp_iris),
                    s.r_u_iris,
                    s.r_v_iris,
                    s.bias_uv[0],
                    s.bias_uv[1]
                );
            }
            all_px.extend(&s.dist_px);
            all_rel.extend(&s.dist_rel);
            if *w == 480 {
                px480.extend(&s.dist_px);
                rel480.extend(&s.dist_rel);
            }
            rh.extend(s.r_h);
            rv.extend(s.r_v);
            rhm.extend(s.r_h_mp_iris);
            rvm.extend(s.r_v_mp_iris);
        }
        println!(
            "summary: median px all {:.2} ({:.1} % width), 480x480 clips {:.2} ({:.1} %); mean r_h {:.3} over {} clip-eyes (MP iris {:.3}), mean r_v {:.3} over {} (MP iris {:.3})",
            median(&all_px),
            100.0 * median(&all_rel),
            median(&px480),
            100.0 * median(&rel480),
            mean(&rh),
            rh.len(),
            mean(&rhm),
            mean(&rv),
            rv.len(),
            mean(&rvm)
        );
    }
    // gains of gaze_weights, default estimator, pooled over clips and eyes
    let samples: Vec<_> = stats[0].iter().flat_map(|s| s.3.samples.iter().copied()).collect();
    let dirs = [
        ("look_in", 0usize, 0usize, 1.0),
        ("look_out", 1, 0, -1.0),
        ("look_up", 2, 1, -1.0),
        ("look_down", 3, 1, 1.0),
    ];
    for (name, score, axis, sign) in dirs {
        let xy: Vec<(f64, f64)> = samples.iter().map(|(d, s)| (sign * d[axis], s[score])).collect();
        let (g, rms) = fit_gain(&xy);
        println!(
            "gain {name}: {g:.2} per unit (weight 0.5 at an offset of {:.3} eye widths), RMS {rms:.3} over {} samples",
            0.5 / g,
            xy.len()
        );
    }
}
