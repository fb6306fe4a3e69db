#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The video tracker delivers every frame to every sink in order, with the images each
//! sink asked for; `end` comes once after the last frame; an interrupt stops the run;
//! a replayed landmarks CSV reaches the sinks as tracked frames.

use std::sync::atomic::AtomicBool;

use facecap_core::landmarks::Landmarks68;
use facecap_io::csv::LandmarkRecord;
use facecap_pipeline::{FrameImages, RunControl, Sink, TrackedFace, TrackerPolicy, VideoTracker};
use image::{GrayImage, Luma};

/// Records what it is given.
struct Probe {
    want: FrameImages,
    indices: Vec<u64>,
    images: Vec<u64>,
    faces: usize,
    ends: usize,
}

impl Probe {
    fn new(want: FrameImages) -> Self {
        Probe {
            want,
            indices: Vec::new(),
            images: Vec::new(),
            faces: 0,
            ends: 0,
        }
    }
}

impl Sink for Probe {
    fn name(&self) -> &str {
        "probe"
    }
    fn images(&self) -> FrameImages {
        self.want
    }
    fn frame(&mut self, face: &TrackedFace) -> facecap_pipeline::Result<()> {
        assert_eq!(self.ends, 0, "frame after end");
        self.indices.push(face.index);
        if let Some(g) = &face.gray {
            assert_eq!(g.dimensions(), (64, 48));
            self.images.push(face.index);
        }
        self.faces += usize::from(face.landmarks.is_some());
        Ok(())
    }
    fn end(&mut self) -> facecap_pipeline::Result<()> {
        self.ends += 1;
        Ok(())
    }
}

fn clip(dir: &std::path::Path, n: u8) -> std::path::PathBuf {
    let frames: Vec<GrayImage> = (0..n)
        .map(|k| GrayImage::from_fn(64, 48, |x, y| Luma([(x * 3 + y + u32::from(k) * 5) as u8])))
        .collect();
    let mut bytes = Vec::new();
    facecap_io::video::y4m::write_gray_y4m(&mut bytes, &frames, 25, 1, false).unwrap();
    let p = dir.join("clip.y4m");
    std::fs::write(&p, bytes).unwrap();
    p
}

fn tracker(test: &str) -> Option<VideoTracker> {
    facecap_core::paths::model_file_or_skip(test, facecap_core::paths::DLIB_68_MODEL)?;
    Some(VideoTracker::new(&TrackerPolicy::default()).unwrap())
}

#[test]
fn every_frame_reaches_every_sink_in_order_with_the_images_asked_for() {
    let Some(t) = tracker("every_frame_reaches_every_sink") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = clip(dir.path(), 23);
    let mut all = Probe::new(FrameImages::Every);
    let mut sample = Probe::new(FrameImages::Sample { every: 5, max: 3 });
    let mut none = Probe::new(FrameImages::None);
    let mut calls = 0;
    let mut count = || calls += 1;
    let report = t
        .run(
            facecap_pipeline::open_video(&path, 1).unwrap(),
            &mut [&mut all, &mut sample, &mut none],
            &mut RunControl {
                interrupted: None,
                on_frame: Some(&mut count),
                strict: false,
            },
        )
        .unwrap();
    assert_eq!(calls, 23);
    assert_eq!(report.frames, 23);
    assert_eq!(report.faces, 0, "no face in a gradient");
    assert_eq!(report.sink_seconds.len(), 3);
    let order: Vec<u64> = (0..23).collect();
    for p in [&all, &sample, &none] {
        assert_eq!(p.indices, order);
        assert_eq!(p.ends, 1);
        assert_eq!(p.faces, 0);
    }
    assert_eq!(all.images, order);
    assert_eq!(sample.images, vec![0, 5, 10]);
    assert!(none.images.is_empty());
}

#[test]
fn an_interrupt_stops_the_run_before_the_next_frame() {
    let Some(t) = tracker("an_interrupt_stops_the_run") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = clip(dir.path(), 5);
    let stop = AtomicBool::new(true);
    let mut p = Probe::new(FrameImages::None);
    let err = t
        .run(
            facecap_pipeline::open_video(&path, 1).unwrap(),
            &mut [&mut p],
            &mut RunControl {
                interrupted: Some(&stop),
                on_frame: None,
                strict: false,
            },
        )
        .unwrap_err();
    assert!(
        matches!(err, facecap_pipeline::Error::Interrupted { frame: 0 }),
        "{err}"
    );
    assert!(p.indices.is_empty());
}

#[test]
fn replayed_records_reach_the_sinks_as_tracked_frames() {
    let lm = Landmarks68::from_fn(|i| (i as f64, 2.0 * i as f64));
    let records: Vec<LandmarkRecord> = (0..4u64)
        .map(|f| LandmarkRecord {
            frame: 10 + f,
            timestamp: f as f64 / 30.0,
            success: f != 2,
            confidence: 0.5,
            landmarks: Some(lm.clone()),
        })
        .collect();
    let mut p = Probe::new(FrameImages::Every);
    let report = facecap_pipeline::replay(&records, &mut [&mut p]).unwrap();
    assert_eq!(report.frames, 4);
    assert_eq!(report.faces, 3);
    assert_eq!(p.indices, vec![10, 11, 12, 13]);
    assert_eq!(p.faces, 3, "a row with success = 0 has no landmarks");
    assert!(p.images.is_empty(), "a CSV has no images");
    assert_eq!(p.ends, 1);
}

#[test]
fn sample_policy_counts_taken_frames() {
    let s = FrameImages::Sample { every: 4, max: 2 };
    assert!(s.wants(0, 0) && s.wants(8, 1) && !s.wants(8, 2) && !s.wants(3, 0));
    assert!(FrameImages::Every.wants(7, 1000) && !FrameImages::None.wants(0, 0));
    // every = 0 is read as 1
    assert!(FrameImages::Sample { every: 0, max: 1 }.wants(3, 0));
}

#[test]
fn front_end_names_are_the_flag_values_and_parse_back() {
    use facecap_pipeline::FrontEnd;
    for (f, name) in [(FrontEnd::Dlib68, "dlib68"), (FrontEnd::Mesh, "mesh")] {
        assert_eq!(f.to_string(), name);
        assert_eq!(name.parse::<FrontEnd>().unwrap(), f);
    }
    assert!("Dlib68".parse::<FrontEnd>().is_err());
}
