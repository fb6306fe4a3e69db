//! Frame sources: shared clips against ffprobe, synthetic Y4M files and image folders,
//! and every kind of bad input.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use facecap_core::Error;
use facecap_io::video::ffmpeg::{locate_ffmpeg, locate_ffprobe, probe_frame_count, FfmpegSource};
use facecap_io::video::small::ColourTap;
use facecap_io::video::y4m::write_gray_y4m;
use facecap_io::video::{open_source, Frame, FrameSelect, FrameSource, Luma, SourceKind, SourceOptions};
use image::{GrayImage, Luma as Px, Rgb, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Longest a decode in these tests may take before it counts as a hang.
const HANG_TIMEOUT: Duration = Duration::from_secs(90);

fn ffmpeg_or_skip(test: &str) -> Option<PathBuf> {
    match locate_ffmpeg(None) {
        Ok(p) => Some(p),
        Err(e) => {
            facecap_core::paths::skip(&format!("{test}: {e}"));
            None
        }
    }
}

/// Decoded frames: (index, timestamp, grey bytes).
type Decoded = Vec<(u64, f64, Vec<u8>)>;

/// An ffmpeg command whose first input is its 64x48 test pattern at `rate` frames/s.
fn testsrc(ffmpeg: &Path, rate: u32) -> std::process::Command {
    let mut c = std::process::Command::new(ffmpeg);
    c.args(["-nostdin", "-v", "error", "-f", "lavfi", "-i"])
        .arg(format!("testsrc=size=64x48:rate={rate}"));
    c
}

/// Decodes a whole source on a helper thread; panics on a hang.
fn decode_all(path: PathBuf, opts: SourceOptions) -> (Decoded, Option<Error>) {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut out = Vec::new();
        let result = (|| -> Result<(), Error> {
            let mut src = open_source(&path, &opts)?;
            let mut f = Frame::default();
            while src.read_into(&mut f)? {
                out.push((f.index, f.timestamp_s, f.gray.as_raw().clone()));
            }
            Ok(())
        })();
        let _ = tx.send((out, result.err()));
    });
    rx.recv_timeout(HANG_TIMEOUT).expect("decoding hung")
}

/// ffprobe's per-frame presentation timestamps of the first video stream.
fn ffprobe_pts(ffprobe: &Path, file: &Path) -> Vec<f64> {
    let out = std::process::Command::new(ffprobe)
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "frame=pts_time",
            "-of",
            "csv=p=0",
        ])
        .arg(file)
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            l.split(',')
                .next()
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(|s| s.parse().unwrap())
        })
        .collect()
}

fn check_shared_clip(test: &str, name: &str, frames: u64, size: (u32, u32), fps: f64, codec: &str) {
    let Some(path) = facecap_core::paths::shared_data_file(test, &format!("videos/{name}")) else {
        return;
    };
    let Some(ffmpeg) = ffmpeg_or_skip(test) else { return };
    let src = open_source(&path, &SourceOptions::default()).unwrap();
    let info = src.info().clone();
    drop(src);
    assert_eq!(info.kind, SourceKind::Video);
    assert_eq!((info.width, info.height), size);
    assert_eq!(info.codec, codec);
    assert!((info.fps - fps).abs() < 1e-9, "fps {}", info.fps);
    // ffprobe decodes too: run it beside our decode.
    let probe = locate_ffprobe(&ffmpeg).map(|ffprobe| {
        let p = path.clone();
        std::thread::spawn(move || ffprobe_pts(&ffprobe, &p))
    });
    let (decoded, err) = decode_all(path.clone(), SourceOptions::default());
    assert!(err.is_none(), "{err:?}");
    assert_eq!(decoded.len() as u64, frames, "{name}: frames decoded");
    if let Some(n) = info.frame_count {
        assert_eq!(n, frames, "{name}: container frame count");
    }
    for (k, (i, _, g)) in decoded.iter().enumerate() {
        assert_eq!(*i, k as u64);
        assert_eq!(g.len(), (size.0 * size.1) as usize);
    }
    match probe {
        Some(probe) => {
            let pts = probe.join().unwrap();
            assert_eq!(pts.len() as u64, frames, "{name}: ffprobe frame count");
            for ((k, t, _), p) in decoded.iter().zip(&pts) {
                // ffprobe prints 6 decimals.
                assert!((t - p).abs() <= 6e-7, "{name} frame {k}: {t} vs ffprobe {p}");
            }
        }
        None => facecap_core::paths::skip(&format!("{test}: ffprobe not found, timestamps not compared")),
    }
}

#[test]
fn shared_clip_d3() {
    check_shared_clip("shared_clip_d3", "liveportrait_d3.mp4", 354, (512, 512), 30.0, "h264");
}

#[test]
fn shared_clip_d6() {
    check_shared_clip("shared_clip_d6", "liveportrait_d6.mp4", 1008, (480, 480), 30.0, "h264");
}

#[test]
fn shared_clip_d9() {
    check_shared_clip("shared_clip_d9", "liveportrait_d9.mp4", 587, (512, 480), 30.0, "h264");
}

#[test]
fn shared_clip_d18() {
    check_shared_clip("shared_clip_d18", "liveportrait_d18.mp4", 216, (480, 480), 30.0, "h264");
}

#[test]
fn shared_clip_mpeg4_part2() {
    check_shared_clip(
        "shared_clip_mpeg4_part2",
        "sadtalker_WDA_KatieHill_000.mp4",
        200,
        (512, 512),
        25.0,
        "mpeg4",
    );
}

/// Raw frames straight from an ffmpeg command line (for comparisons).
fn ffmpeg_raw(ffmpeg: &Path, file: &Path, pix_fmt: &str, frames: u32) -> Vec<u8> {
    let out = std::process::Command::new(ffmpeg)
        .args(["-nostdin", "-v", "error", "-i"])
        .arg(file)
        .args([
            "-frames:v",
            &frames.to_string(),
            "-f",
            "rawvideo",
            "-pix_fmt",
            pix_fmt,
            "pipe:1",
        ])
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    assert!(out.status.success());
    out.stdout
}

/// Mean absolute difference of two byte buffers (over the shorter length's pairs,
/// divided by `b`'s length).
fn mean_abs_diff(a: &[u8], b: &[u8]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(x.abs_diff(*y))).sum::<f64>() / b.len() as f64
}

#[test]
fn luma_modes_and_rgb_on_shared_clip() {
    let test = "luma_modes_and_rgb_on_shared_clip";
    let Some(path) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d9.mp4") else {
        return;
    };
    let Some(ffmpeg) = ffmpeg_or_skip(test) else { return };
    let (w, h) = (512usize, 480usize);
    let yuv = ffmpeg_raw(&ffmpeg, &path, "yuv420p", 1);
    let full = ffmpeg_raw(&ffmpeg, &path, "gray", 1);
    let rgb_ref = ffmpeg_raw(&ffmpeg, &path, "rgb24", 1);

    let mut raw_src = open_source(
        &path,
        &SourceOptions {
            luma: Luma::AsStored,
            ..Default::default()
        },
    )
    .unwrap();
    let f = raw_src.next_frame().unwrap().unwrap();
    assert_eq!(f.gray.as_raw()[..], yuv[..w * h], "AsStored = the Y plane");
    assert!(f.rgb.is_none());

    let mut src = open_source(
        &path,
        &SourceOptions {
            rgb: true,
            ..Default::default()
        },
    )
    .unwrap();
    let f = src.next_frame().unwrap().unwrap();
    // Full = ffmpeg's own limited->full expansion (-pix_fmt gray), bit for bit.
    assert_eq!(f.gray.as_raw()[..], full[..]);
    let diff = mean_abs_diff(f.rgb.unwrap().as_raw(), &rgb_ref);
    assert!(diff < 2.0, "mean |RGB - ffmpeg rgb24| = {diff}");
}

/// A full-range (`yuvj420p`, as MJPEG and many phones write) clip keeps its codes:
/// grey equals ffmpeg's own `-pix_fmt gray` bit for bit and RGB its `rgb24` (both made
/// by ffmpeg from the full-range planes), in grey-only and colour mode.
#[test]
fn full_range_video_keeps_its_codes() {
    let test = "full_range_video_keeps_its_codes";
    let Some(ffmpeg) = ffmpeg_or_skip(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.avi");
    let made = testsrc(&ffmpeg, 5)
        .args(["-frames:v", "2", "-pix_fmt", "yuvj420p", "-c:v", "mjpeg", "-q:v", "2"])
        .arg(&path)
        .stdin(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(made.success());
    let gray = ffmpeg_raw(&ffmpeg, &path, "gray", 1);
    let rgb_ref = ffmpeg_raw(&ffmpeg, &path, "rgb24", 1);
    assert_eq!(
        (gray.iter().min(), gray.iter().max()),
        (Some(&0), Some(&255)),
        "a full-range test clip"
    );
    for rgb in [false, true] {
        let mut src = open_source(
            &path,
            &SourceOptions {
                rgb,
                ..Default::default()
            },
        )
        .unwrap();
        let f = src.next_frame().unwrap().unwrap();
        assert_eq!(f.gray.as_raw()[..], gray[..], "grey, rgb {rgb}");
        if let Some(img) = f.rgb {
            let diff = mean_abs_diff(img.as_raw(), &rgb_ref);
            assert!(diff < 2.0, "mean |RGB - ffmpeg rgb24| = {diff}");
        }
    }
}

/// Decodes a whole source in colour (index, timestamp, RGB bytes).
fn decode_rgb(path: &Path, opts: &SourceOptions) -> Vec<(u64, f64, Vec<u8>)> {
    let mut src = open_source(path, opts).unwrap();
    let mut f = Frame::default();
    let mut out = Vec::new();
    while src.read_into(&mut f).unwrap() {
        out.push((f.index, f.timestamp_s, f.rgb.as_ref().unwrap().as_raw().clone()));
    }
    out
}

#[test]
fn colour_tap_keeps_small_copies_of_the_chosen_frames_as_ffmpeg_scales_them() {
    let test = "colour_tap_keeps_small_copies_of_the_chosen_frames_as_ffmpeg_scales_them";
    let Some(path) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d18.mp4") else {
        return;
    };
    if ffmpeg_or_skip(test).is_none() {
        return;
    }
    // what the preview decoded before: ffmpeg's own bilinear scaling to 360x360, in RGB
    let reference = decode_rgb(
        &path,
        &SourceOptions {
            rgb: true,
            scale: Some((360, 360)),
            ..Default::default()
        },
    );
    let select = FrameSelect {
        stride: 2,
        extra: vec![7, 101],
    };
    // the tracking pass: grey frames at full size, the tap on top
    let mut src = open_source(&path, &SourceOptions::default()).unwrap();
    assert!(src
        .tap_colour(ColourTap {
            size: (360, 360),
            select: select.clone(),
        })
        .unwrap());
    let mut f = Frame::default();
    let (mut copies, mut frames) = (0, 0);
    let mut rgb = RgbImage::new(1, 1);
    while src.read_into(&mut f).unwrap() {
        frames += 1;
        assert_eq!(
            (f.gray.width(), f.gray.height()),
            (480, 480),
            "the tracking frames stay full size"
        );
        let Some(small) = f.small.as_ref() else {
            assert!(!select.contains(f.index), "frame {} has no copy", f.index);
            continue;
        };
        assert!(select.contains(f.index), "frame {} was not asked for", f.index);
        copies += 1;
        small.to_rgb_into(&mut rgb);
        assert_eq!(rgb.dimensions(), (360, 360));
        let want = &reference[f.index as usize].2;
        let diff: f64 = rgb
            .as_raw()
            .iter()
            .zip(want)
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
            .sum::<f64>()
            / want.len() as f64;
        // a different scaler and 4:2:0 chroma: close, not equal
        assert!(
            diff < 3.0,
            "frame {}: mean difference {diff} to ffmpeg's scaling",
            f.index
        );
    }
    assert_eq!((frames, copies), (216, 108 + 2));
    // a tap larger than the video is refused
    let mut src = open_source(&path, &SourceOptions::default()).unwrap();
    assert!(src
        .tap_colour(ColourTap {
            size: (481, 360),
            select,
        })
        .is_err());
}

#[test]
fn selected_frames_keep_their_indices_timestamps_and_pixels() {
    let test = "selected_frames_keep_their_indices_timestamps_and_pixels";
    let Some(path) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d18.mp4") else {
        return;
    };
    if ffmpeg_or_skip(test).is_none() {
        return;
    }
    let base = SourceOptions {
        rgb: true,
        scale: Some((360, 360)),
        ..Default::default()
    };
    let all = decode_rgb(&path, &base);
    assert_eq!(all.len(), 216);
    let select = FrameSelect {
        stride: 3,
        extra: vec![7, 200, 3, 215],
    };
    let sel = decode_rgb(
        &path,
        &SourceOptions {
            select: Some(select.clone()),
            probe_frame_count: false,
            ..base.clone()
        },
    );
    let want: Vec<&(u64, f64, Vec<u8>)> = all.iter().filter(|f| select.contains(f.0)).collect();
    assert_eq!(want.len(), 72 + 3);
    assert_eq!(sel.len(), want.len());
    for (s, w) in sel.iter().zip(want) {
        assert_eq!((s.0, s.1), (w.0, w.1), "index and timestamp");
        assert!(s.2 == w.2, "frame {}: the pixels differ from the full decode", s.0);
    }
    // the frame count comes from the probe only when asked for
    let src = open_source(
        &path,
        &SourceOptions {
            probe_frame_count: false,
            ..base.clone()
        },
    )
    .unwrap();
    assert_eq!(src.info().frame_count, None);
    let src = open_source(&path, &base).unwrap();
    assert_eq!(src.info().frame_count, Some(216));
    assert_eq!((src.info().width, src.info().height), (360, 360));
    // a stride of 0 is refused
    let bad = SourceOptions {
        select: Some(FrameSelect {
            stride: 0,
            extra: vec![],
        }),
        ..Default::default()
    };
    assert!(matches!(open_source(&path, &bad), Err(Error::InvalidParameter { .. })));
}

#[test]
fn ffmpeg_child_is_reaped_on_drop() {
    let test = "ffmpeg_child_is_reaped_on_drop";
    let Some(path) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d6.mp4") else {
        return;
    };
    if ffmpeg_or_skip(test).is_none() {
        return;
    }
    let mut src = FfmpegSource::open(&path, &SourceOptions::default()).unwrap();
    let pid = src.child_id();
    assert!(src.next_frame().unwrap().is_some());
    assert!(Path::new(&format!("/proc/{pid}")).exists());
    drop(src);
    assert!(
        !Path::new(&format!("/proc/{pid}")).exists(),
        "ffmpeg {pid} still exists after drop"
    );
}

#[test]
fn truncated_videos_yield_good_frames_then_stop() {
    let test = "truncated_videos_yield_good_frames_then_stop";
    let Some(path) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d9.mp4") else {
        return;
    };
    let Some(ffmpeg) = ffmpeg_or_skip(test) else { return };
    let dir = tempfile::tempdir().unwrap();

    // 1. The clip as shipped keeps its index (moov) at the end: the first 60 % has no index.
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut60.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let (frames, err) = decode_all(cut.clone(), SourceOptions::default());
    assert!(frames.is_empty());
    let msg = err.expect("an index-less truncated file must be an error").to_string();
    assert!(msg.contains("cut60.mp4"), "{msg}");

    // 2. The same stream with its index first (faststart): the first 60 % holds ~350 frames.
    let fast = dir.path().join("fast.mp4");
    let st = std::process::Command::new(&ffmpeg)
        .args(["-nostdin", "-v", "error", "-y", "-i"])
        .arg(&path)
        .args(["-map", "0:v", "-c", "copy", "-movflags", "+faststart"])
        .arg(&fast)
        .stdin(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());
    let bytes = std::fs::read(&fast).unwrap();
    let cut = dir.path().join("fast_cut60.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let (full, err) = decode_all(fast, SourceOptions::default());
    assert!(err.is_none());
    assert_eq!(full.len(), 587);
    for strict in [true, false] {
        let (frames, err) = decode_all(
            cut.clone(),
            SourceOptions {
                strict,
                ..Default::default()
            },
        );
        assert!(
            frames.len() > 300 && frames.len() < 587,
            "strict={strict}: {} frames",
            frames.len()
        );
        for (k, (i, t, g)) in frames.iter().enumerate() {
            assert_eq!(*i, k as u64);
            if strict {
                // Strict: exactly the leading frames of the intact file.
                assert_eq!(*t, full[k].1, "frame {k} timestamp");
                assert!(*g == full[k].2, "frame {k} differs from the intact file's frame");
            } else {
                // Lenient: ffmpeg may drop a frame whose packet is damaged, but every frame it
                // delivers is the intact file's frame with the same timestamp.
                let same = full.iter().find(|f| f.1 == *t).expect("timestamp of the intact file");
                assert!(
                    *g == same.2,
                    "lenient: frame {k} (t={t}) differs from the intact file's frame"
                );
            }
        }
        if strict {
            let msg = err.expect("strict mode reports the damage").to_string();
            assert!(
                msg.contains("fast_cut60.mp4") && msg.contains(&format!("frame {}", frames.len())),
                "{msg}"
            );
        }
    }
}

#[test]
fn not_a_video_missing_and_empty_files() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.mp4");
    let e = open_source(&missing, &SourceOptions::default()).unwrap_err();
    assert!(
        matches!(e, Error::Io { .. }) && e.to_string().contains("missing.mp4"),
        "{e}"
    );

    let empty = dir.path().join("empty.mp4");
    std::fs::write(&empty, b"").unwrap();
    let e = open_source(&empty, &SourceOptions::default()).unwrap_err().to_string();
    assert!(e.contains("empty.mp4") && e.contains("0 bytes"), "{e}");

    if ffmpeg_or_skip("not_a_video_missing_and_empty_files").is_none() {
        return;
    }
    let text = dir.path().join("notes.mp4");
    std::fs::write(&text, "these are notes, not a video\n".repeat(50)).unwrap();
    let (frames, err) = decode_all(text, SourceOptions::default());
    assert!(frames.is_empty());
    let e = err.unwrap().to_string();
    assert!(e.contains("notes.mp4") && e.contains("not a readable video"), "{e}");
}

#[test]
fn missing_ffmpeg_gives_install_hint() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.mp4");
    std::fs::write(&p, b"0123456789").unwrap();
    let opts = SourceOptions {
        ffmpeg: Some(dir.path().join("no-ffmpeg")),
        ..Default::default()
    };
    let e = open_source(&p, &opts).unwrap_err();
    assert!(matches!(e, Error::Tool { .. }), "{e}");
    assert!(e.to_string().contains("apt-get install ffmpeg"), "{e}");
}

#[test]
fn options_are_validated() {
    let dir = tempfile::tempdir().unwrap();
    for fps in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
        let e = open_source(
            dir.path(),
            &SourceOptions {
                folder_fps: fps,
                ..Default::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("folder_fps"), "{e}");
    }
    let e = open_source(
        dir.path(),
        &SourceOptions {
            threads: 1000,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("threads"), "{e}");
}

/// Seeded random grey frames with luma in the limited range.
fn random_frames(n: usize, w: u32, h: u32, seed: u64) -> Vec<GrayImage> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| GrayImage::from_fn(w, h, |_, _| Px([rng.random_range(16..=235)])))
        .collect()
}

fn write_y4m(dir: &Path, name: &str, frames: &[GrayImage], num: u32, den: u32, mono: bool) -> PathBuf {
    let p = dir.join(name);
    let mut bytes = Vec::new();
    write_gray_y4m(&mut bytes, frames, num, den, mono).unwrap();
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn y4m_round_trip_420_and_mono() {
    let dir = tempfile::tempdir().unwrap();
    // Odd size: chroma planes are ceil(w/2) x ceil(h/2).
    let frames = random_frames(5, 33, 17, 7);
    let p = write_y4m(dir.path(), "a.y4m", &frames, 30000, 1001, false);
    let mut src = open_source(
        &p,
        &SourceOptions {
            luma: Luma::AsStored,
            ..Default::default()
        },
    )
    .unwrap();
    let info = src.info().clone();
    assert_eq!(
        (info.width, info.height, info.frame_count, info.kind),
        (33, 17, Some(5), SourceKind::Y4m)
    );
    assert!((info.fps - 30000.0 / 1001.0).abs() < 1e-12);
    let mut f = Frame::default();
    let mut k = 0;
    while src.read_into(&mut f).unwrap() {
        assert_eq!(f.index, k);
        assert!((f.timestamp_s - k as f64 * 1001.0 / 30000.0).abs() < 1e-12);
        assert_eq!(f.gray, frames[k as usize]);
        k += 1;
    }
    assert_eq!(k, 5);
    assert!(!src.read_into(&mut f).unwrap(), "stays ended");

    // Full range expands 16..235 to 0..255.
    let mut src = open_source(&p, &SourceOptions::default()).unwrap();
    let f = src.next_frame().unwrap().unwrap();
    for (a, b) in f.gray.as_raw().iter().zip(frames[0].as_raw()) {
        let want = ((f64::from(*b) - 16.0) * 255.0 / 219.0).round() as u8;
        assert_eq!(*a, want);
    }

    // Mono files are full range and are not expanded.
    let pm = write_y4m(dir.path(), "m.y4m", &frames, 25, 1, true);
    let mut src = open_source(
        &pm,
        &SourceOptions {
            rgb: true,
            ..Default::default()
        },
    )
    .unwrap();
    let f = src.next_frame().unwrap().unwrap();
    assert_eq!(f.gray, frames[0]);
    let rgb = f.rgb.unwrap();
    assert_eq!(rgb.get_pixel(3, 4), &Rgb([frames[0].get_pixel(3, 4)[0]; 3]));
}

#[test]
fn y4m_444_colours_convert_to_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.y4m");
    // 2x1 pixels, BT.601 limited: white (235,128,128) and red (81,90,240).
    let mut b = b"YUV4MPEG2 W2 H1 F25:1 Ip C444 XYSCSS=444\nFRAME\n".to_vec();
    b.extend([235, 81, 128, 90, 128, 240]);
    std::fs::write(&p, &b).unwrap();
    let mut src = open_source(
        &p,
        &SourceOptions {
            rgb: true,
            ..Default::default()
        },
    )
    .unwrap();
    let f = src.next_frame().unwrap().unwrap();
    let rgb = f.rgb.unwrap();
    assert_eq!(rgb.get_pixel(0, 0), &Rgb([255, 255, 255]));
    let r = rgb.get_pixel(1, 0);
    assert!(r[0] >= 253 && r[1] <= 2 && r[2] <= 2, "{r:?}");
    assert_eq!(f.gray.as_raw(), &vec![255, 76]);
    assert!(src.next_frame().unwrap().is_none());
}

#[test]
fn y4m_every_truncation_is_frames_then_error_or_clean_end() {
    let dir = tempfile::tempdir().unwrap();
    let frames = random_frames(3, 4, 2, 11);
    let p = write_y4m(dir.path(), "t.y4m", &frames, 25, 1, false);
    let bytes = std::fs::read(&p).unwrap();
    let header_len = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
    let per_frame = 6 + 8 + 4;
    for cut in 0..bytes.len() {
        let q = dir.path().join("cut.y4m");
        std::fs::write(&q, &bytes[..cut]).unwrap();
        let res = open_source(
            &q,
            &SourceOptions {
                luma: Luma::AsStored,
                ..Default::default()
            },
        );
        let mut src = match res {
            Ok(s) => s,
            Err(e) => {
                assert!(cut < header_len, "cut {cut}: open failed: {e}");
                assert!(e.to_string().contains("cut.y4m"), "{e}");
                continue;
            }
        };
        let mut got = 0usize;
        let mut f = Frame::default();
        let ended = loop {
            match src.read_into(&mut f) {
                Ok(true) => {
                    assert_eq!(f.gray, frames[got], "cut {cut}: frame {got} garbage");
                    got += 1;
                }
                Ok(false) => break Ok(()),
                Err(e) => break Err(e),
            }
        };
        let whole = (cut - header_len) / per_frame;
        assert_eq!(got, whole, "cut {cut}");
        let at_boundary = (cut - header_len) % per_frame == 0;
        match ended {
            Ok(()) => assert!(at_boundary, "cut {cut}: clean end inside a frame"),
            Err(e) => {
                assert!(!at_boundary, "cut {cut}: error at a frame boundary: {e}");
                let m = e.to_string();
                assert!(m.contains("cut.y4m") && m.contains(&format!("frame {whole}")), "{m}");
            }
        }
    }
}

#[test]
fn y4m_native_reader_equals_ffmpeg() {
    let test = "y4m_native_reader_equals_ffmpeg";
    if ffmpeg_or_skip(test).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let frames = random_frames(4, 64, 48, 3);
    let p = write_y4m(dir.path(), "e.y4m", &frames, 30, 1, false);
    let native = decode_all(p.clone(), SourceOptions::default());
    let mut ff = FfmpegSource::open(&p, &SourceOptions::default()).unwrap();
    let mut f = Frame::default();
    let mut k = 0;
    while ff.read_into(&mut f).unwrap() {
        assert_eq!(f.gray.as_raw(), &native.0[k].2);
        assert!((f.timestamp_s - native.0[k].1).abs() < 1e-9);
        k += 1;
    }
    assert_eq!(k, 4);
}

fn save_png(dir: &Path, name: &str, w: u32, h: u32, seed: u8) -> PathBuf {
    let p = dir.join(name);
    RgbImage::from_fn(w, h, |x, y| Rgb([seed.wrapping_add(x as u8), y as u8 * 3, 200]))
        .save(&p)
        .unwrap();
    p
}

#[test]
fn image_folder_sorted_by_name_with_timestamps() {
    let dir = tempfile::tempdir().unwrap();
    save_png(dir.path(), "frame_002.png", 8, 6, 2);
    save_png(dir.path(), "frame_000.png", 8, 6, 0);
    save_png(dir.path(), "frame_001.PNG", 8, 6, 1);
    std::fs::write(dir.path().join("notes.txt"), "ignored").unwrap();
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    let opts = SourceOptions {
        rgb: true,
        folder_fps: 10.0,
        ..Default::default()
    };
    let mut src = open_source(dir.path(), &opts).unwrap();
    assert_eq!(src.info().kind, SourceKind::ImageFolder);
    assert_eq!(src.info().frame_count, Some(3));
    let mut f = Frame::default();
    for k in 0..3u64 {
        assert!(src.read_into(&mut f).unwrap());
        assert_eq!(f.index, k);
        assert!((f.timestamp_s - k as f64 * 0.1).abs() < 1e-12);
        let rgb = f.rgb.as_ref().unwrap();
        assert_eq!(rgb.get_pixel(0, 0)[0], k as u8, "sorted by name");
        let p = rgb.get_pixel(1, 1);
        assert_eq!(
            f.gray.get_pixel(1, 1)[0],
            facecap_io::image_io::bt601_luma(p[0], p[1], p[2])
        );
    }
    assert!(!src.read_into(&mut f).unwrap());

    // A single image is a one-frame source.
    let one = open_source(dir.path().join("frame_000.png"), &SourceOptions::default()).unwrap();
    assert_eq!((one.info().kind, one.info().frame_count), (SourceKind::Image, Some(1)));
}

#[test]
fn image_folder_errors_name_folder_file_and_frame() {
    let dir = tempfile::tempdir().unwrap();
    let e = open_source(dir.path(), &SourceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no images") && e.contains(&dir.path().display().to_string()),
        "{e}"
    );

    save_png(dir.path(), "a.png", 8, 6, 0);
    std::fs::write(dir.path().join("b.png"), b"").unwrap();
    std::fs::write(dir.path().join("c.jpg"), b"garbage, not a jpeg").unwrap();
    save_png(dir.path(), "d.png", 9, 6, 0);
    let mut src = open_source(dir.path(), &SourceOptions::default()).unwrap();
    let mut f = Frame::default();
    assert!(src.read_into(&mut f).unwrap());
    let e = src.read_into(&mut f).unwrap_err().to_string();
    assert!(
        e.contains("b.png") && e.contains("frame 1") && e.contains("0 bytes"),
        "{e}"
    );
    let e = src.read_into(&mut f).unwrap_err().to_string();
    assert!(e.contains("c.jpg") && e.contains("frame 2"), "{e}");
    let e = src.read_into(&mut f).unwrap_err().to_string();
    assert!(e.contains("d.png") && e.contains("frame 3") && e.contains("9x6"), "{e}");
    assert!(!src.read_into(&mut f).unwrap());

    // A folder whose first image is empty fails at open, naming that file.
    let dir2 = tempfile::tempdir().unwrap();
    std::fs::write(dir2.path().join("0.png"), b"").unwrap();
    let e = open_source(dir2.path(), &SourceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("0.png") && e.contains("0 bytes"), "{e}");
}

/// The MP4 box reader's frame count is ffprobe's `nb_frames` wherever it gives one (the
/// shared clips, MP4 / MOV / M4V / 3GP files with audio first, B-frames, an edit list,
/// a `moov` at the front), and it gives none for fragmented MP4 and other containers.
#[test]
fn mp4_frame_count_equals_ffprobe() {
    let test = "mp4_frame_count_equals_ffprobe";
    let Some(ffmpeg) = ffmpeg_or_skip(test) else { return };
    let Some(ffprobe) = locate_ffprobe(&ffmpeg) else {
        facecap_core::paths::skip(&format!("{test}: ffprobe not found"));
        return;
    };
    let count = facecap_io::video::mp4::video_frame_count;
    for name in [
        "liveportrait_d3.mp4",
        "liveportrait_d6.mp4",
        "liveportrait_d9.mp4",
        "liveportrait_d18.mp4",
        "sadtalker_WDA_KatieHill_000.mp4",
    ] {
        let Some(path) = facecap_core::paths::shared_data_file(test, &format!("videos/{name}")) else {
            continue;
        };
        let n = count(&path);
        assert!(n.is_some(), "{name}: no count");
        assert_eq!(n, probe_frame_count(&ffprobe, &path), "{name}");
    }
    let dir = tempfile::tempdir().unwrap();
    let make = |name: &str, args: &[&str]| -> PathBuf {
        let p = dir.path().join(name);
        let ok = testsrc(&ffmpeg, 25)
            .args(["-f", "lavfi", "-i", "sine=frequency=440:sample_rate=8000"])
            .args(args)
            .arg(&p)
            .stdin(std::process::Stdio::null())
            .status()
            .unwrap()
            .success();
        assert!(ok, "making {name}");
        p
    };
    // (name, ffmpeg options, H.264 with B-frames, counted from the boxes)
    let specs: [(&str, &[&str], bool, bool); 8] = [
        ("plain.mp4", &["-t", "2", "-map", "1:a", "-map", "0:v"], true, true),
        ("front.mp4", &["-frames:v", "37", "-movflags", "+faststart"], true, true),
        ("mpeg4.mov", &["-frames:v", "23", "-c:v", "mpeg4"], false, true),
        ("clip.m4v", &["-frames:v", "11", "-an"], true, true),
        (
            "phone.3gp",
            &["-frames:v", "9", "-s", "176x144", "-c:v", "mpeg4", "-c:a", "aac"],
            false,
            true,
        ),
        (
            "frag.mp4",
            &["-frames:v", "30", "-movflags", "frag_keyframe+empty_moov"],
            true,
            false,
        ),
        ("other.mkv", &["-frames:v", "10", "-c:v", "mpeg4"], false, false),
        ("other.avi", &["-frames:v", "10", "-c:v", "mpeg4"], false, false),
    ];
    let h264 = ["-c:v", "libx264", "-bf", "2", "-g", "12"];
    let cases: Vec<(PathBuf, bool)> = specs
        .iter()
        .map(|&(name, opts, b_frames, counted)| {
            let codec: &[&str] = if b_frames { &h264 } else { &[] };
            (make(name, &[opts, codec].concat()), counted)
        })
        .collect();
    // an edit list: cut without re-encoding, starting between keyframes
    let cut = dir.path().join("cut.mp4");
    let ok = std::process::Command::new(&ffmpeg)
        .args(["-nostdin", "-v", "error", "-ss", "0.5", "-i"])
        .arg(&cases[0].0)
        .args(["-c", "copy"])
        .arg(&cut)
        .stdin(std::process::Stdio::null())
        .status()
        .unwrap()
        .success();
    assert!(ok);
    for (p, counted) in cases.iter().cloned().chain([(cut, true)]) {
        let ours = count(&p);
        assert_eq!(ours.is_some(), counted, "{}: {ours:?}", p.display());
        if let Some(n) = ours {
            assert_eq!(Some(n), probe_frame_count(&ffprobe, &p), "{}", p.display());
        }
    }
}
