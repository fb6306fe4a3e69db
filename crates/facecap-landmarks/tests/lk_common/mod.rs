//! Shared by the LK integration tests: one two-frame LK call of ours and of the
//! `optical-flow-lk` crate (the second oracle) with the same window and levels.
#![allow(dead_code, clippy::unwrap_used)]

use facecap_landmarks::lk::{LkParams, LkReport, LkWorkspace, PyramidLk, TrackStatus};
use image::GrayImage;
use nalgebra::Point2;

/// Our tracked points, statuses and report for `pts` from `a` to `b`.
pub struct Ours {
    pub next: Vec<Point2<f64>>,
    pub status: Vec<TrackStatus>,
    pub report: LkReport,
}

/// Tracks `pts` from `a` to `b` with `lk`, reusing `ws`.
pub fn track_ours(lk: &PyramidLk, ws: &mut LkWorkspace, a: &GrayImage, b: &GrayImage, pts: &[Point2<f64>]) -> Ours {
    ws.reset();
    ws.push_frame(a).unwrap();
    ws.push_frame(b).unwrap();
    let mut next = vec![Point2::origin(); pts.len()];
    let mut status = vec![TrackStatus::Tracked; pts.len()];
    let mut error = vec![0.0; pts.len()];
    let report = lk.track_into(ws, pts, &mut next, &mut status, &mut error).unwrap();
    Ours { next, status, report }
}

/// The `optical-flow-lk` crate on the same pair: window and levels from `params`
/// (`max_level` levels above the base), its default stopping rules; positions as f64,
/// `None` where the crate did not call the point tracked.
pub fn track_crate(params: &LkParams, a: &GrayImage, b: &GrayImage, pts: &[Point2<f64>]) -> Vec<Option<Point2<f64>>> {
    let track = optical_flow_lk::TrackParams {
        window_size: params.window,
        max_iterations: params.max_iterations,
        min_eigen_threshold: optical_flow_lk::DEFAULT_MIN_EIGEN_THRESHOLD,
    };
    let pa = optical_flow_lk::build_pyramid(a, params.max_level + 1);
    let pb = optical_flow_lk::build_pyramid(b, params.max_level + 1);
    let start: Vec<(f32, f32)> = pts.iter().map(|p| (p.x as f32, p.y as f32)).collect();
    optical_flow_lk::calc_optical_flow_ex(&pa, &pb, &start, None, track)
        .iter()
        .map(|r| {
            (r.status == optical_flow_lk::TrackStatus::Tracked)
                .then(|| Point2::new(f64::from(r.pos.0), f64::from(r.pos.1)))
        })
        .collect()
}
