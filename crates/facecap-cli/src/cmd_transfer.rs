//! `facecap transfer SOURCE TARGET`: expression transfer with the tensor model
//! (Papanek 2010, ch. 5; Vlasic et al. 2005).
//!
//! Both videos are fitted (`cmd_tensor_fit`: tracker, first-frame alignment, LK feature
//! points, shared identity, per-frame pose and expression). Frame `f` of the result
//! combines the source's expression of frame `f` with the target's identity and the
//! pose of target frame `min(f, F_target - 1)`. Written into `--out`:
//!
//! * `transfer.glb`: the target identity's expression rig animated with the source's
//!   expression weights (one keyframe per source frame);
//! * `transfer.csv`: target pose, target identity, source expression per frame;
//! * `source_tensor.csv`, `target_tensor.csv`, `source_reprojection.csv`,
//!   `target_reprojection.csv`: the two fits;
//! * `obj/frame_NNNNNN.obj` with `--obj` (the one OBJ naming: 0-based frame, six digits);
//! * 2D reanimation (thesis sec. 5.2): `reanimation/frame_NNNNN.png`, the target frames
//!   with the source mouth region cloned in by Poisson seamless cloning
//!   (`facecap_tensor::reanimate::clone_mouth`), placed and sized by the transferred
//!   mesh's outer-lip vertices projected with the target pose; `--video FILE` also
//!   encodes them with ffmpeg. `--no-reanimation` skips this part.

use std::path::PathBuf;

use anyhow::{bail, Context};
use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_io::video::{open_source, Frame, SourceOptions};
use facecap_tensor::fit::FitState;
use facecap_tensor::model::TensorModel;
use facecap_tensor::poisson::PoissonParams;
use facecap_tensor::transfer::TransferFrame;
use nalgebra::Point2;

use crate::cmd_tensor_fit::{fit_video, print_summary, write_reprojection_csv, write_tensor_csv, FitOptions, Fitted};

/// Arguments of `facecap transfer`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap transfer performer.mp4 target.mp4 --model ict.fctensor --landmark-map ict_landmarks68.json --out xfer/"
)]
pub struct TransferArgs {
    /// Source video (the performance).
    pub source: PathBuf,
    /// Target video (the identity, pose and background).
    pub target: PathBuf,
    /// Landmarks CSV of the source video (default: track the video).
    #[arg(long)]
    pub source_landmarks: Option<PathBuf>,
    /// Landmarks CSV of the target video (default: track the video).
    #[arg(long)]
    pub target_landmarks: Option<PathBuf>,
    #[command(flatten)]
    pub fit: FitOptions,
    /// Also write one OBJ per frame into OUT/obj/.
    #[arg(long)]
    pub obj: bool,
    /// Skip the 2D reanimation (Poisson cloning of the source mouth into the target frames).
    #[arg(long)]
    pub no_reanimation: bool,
    /// Also encode the reanimated frames into this video file (ffmpeg, H.264).
    #[arg(long)]
    pub video: Option<PathBuf>,
    /// Margin (pixels) by which the mouth clone region is pushed out from the lips.
    #[arg(long, default_value_t = 8.0)]
    pub mouth_margin: f64,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Carries the last good state over failed frames so every frame has weights.
fn fill(states: &[Option<FitState>]) -> anyhow::Result<Vec<FitState>> {
    let first = states.iter().flatten().next().cloned().context("no fitted frame")?;
    let mut last = first;
    Ok(states
        .iter()
        .map(|s| {
            if let Some(s) = s {
                last = s.clone();
            }
            last.clone()
        })
        .collect())
}

/// Runs `facecap transfer`.
pub fn run(a: TransferArgs) -> anyhow::Result<std::process::ExitCode> {
    if !(a.mouth_margin.is_finite() && a.mouth_margin >= 0.0) {
        bail!("--mouth-margin {}: expected a finite number >= 0", a.mouth_margin);
    }
    let model = TensorModel::load(&a.fit.model)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let src = fit_video(&a.source, a.source_landmarks.as_deref(), &a.fit, &model)?;
    print_summary(&a.source, &src);
    let tgt = fit_video(&a.target, a.target_landmarks.as_deref(), &a.fit, &model)?;
    print_summary(&a.target, &tgt);
    for (name, f) in [("source", &src), ("target", &tgt)] {
        write_tensor_csv(&a.out.join(format!("{name}_tensor.csv")), &model, f)?;
        write_reprojection_csv(&a.out.join(format!("{name}_reprojection.csv")), f)?;
    }
    let s_states = fill(&src.states)?;
    let t_states = fill(&tgt.states)?;
    let frames = facecap_tensor::transfer::combine(&s_states, &t_states)?;
    let w_id = frames[0].w_id.clone();
    // Animated GLB: the target identity's expression rig with the source's weights.
    let rig = model.expression_rig(&w_id)?;
    let mut times: Vec<f32> = Vec::with_capacity(frames.len());
    let mut weights: Vec<Vec<f32>> = Vec::with_capacity(frames.len());
    let fps = facecap_pipeline::open_video(&a.source, 1)?.info().fps;
    let fps = facecap_io::livelink::rate_or_fallback(fps);
    for (r, f) in src.records.iter().zip(&frames) {
        let t = facecap_pipeline::outputs::keyframe_time(r.frame, fps) as f32;
        if times.last().is_some_and(|&l| t <= l) {
            continue;
        }
        times.push(t);
        weights.push(f.w_exp.iter().map(|&w| w as f32).collect());
    }
    let anim = facecap_io::gltf_io::MorphAnimation {
        times_s: times,
        weights,
    };
    facecap_io::gltf_io::write_glb(a.out.join("transfer.glb"), &rig, Some(&anim))?;
    // Parameters CSV: target pose, target identity, source expression.
    let tstates: Vec<Option<FitState>> = frames
        .iter()
        .enumerate()
        .map(|(f, x)| {
            src.states[f].as_ref().map(|_| FitState {
                w_id: x.w_id.clone(),
                w_exp: x.w_exp.clone(),
                pose: x.pose,
                depth: Vec::new(),
            })
        })
        .collect();
    facecap_pipeline::tensor::write_tensor_csv(&a.out.join("transfer.csv"), &model, &src.records, &tstates)?;
    if a.obj {
        let dir = a.out.join("obj");
        std::fs::create_dir_all(&dir)?;
        for (i, f) in frames.iter().enumerate() {
            let pts = model.generate_points(&f.w_id, &f.w_exp)?;
            let index = src.records.get(i).map_or(i as u64, |r| r.frame);
            facecap_io::obj::write_obj_positions(
                facecap_pipeline::outputs::obj_path(&a.out, index),
                &pts,
                &model.triangles,
            )?;
        }
    }
    outln!(
        "transfer: {} source frames onto the target identity -> {}",
        frames.len(),
        a.out.display()
    );
    if !a.no_reanimation {
        reanimate(&a, &model, &src, &tgt, &frames)?;
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// Outer-lip landmarks (iBUG 48-59, in polygon order).
const OUTER_LIPS: std::ops::RangeInclusive<usize> = 48..=59;

/// 2D reanimation: decodes both videos again in step and clones the source mouth into
/// each target frame.
fn reanimate(
    a: &TransferArgs,
    model: &TensorModel,
    src: &Fitted,
    tgt: &Fitted,
    frames: &[TransferFrame],
) -> anyhow::Result<()> {
    let map = LandmarkMap::from_json_file(&a.fit.landmark_map)?;
    let lip_vertices: Vec<u32> = OUTER_LIPS
        .filter_map(|i| map.mapped().find(|(l, _)| *l == i).map(|(_, v)| v))
        .collect();
    if lip_vertices.len() != OUTER_LIPS.count() {
        bail!("the landmark map must map all outer-lip landmarks 48-59 for the reanimation");
    }
    let dir = a.out.join("reanimation");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let opts = SourceOptions {
        rgb: true,
        ..SourceOptions::default()
    };
    let mut s_src = open_source(&a.source, &opts).with_context(|| format!("opening {}", a.source.display()))?;
    let mut t_src = open_source(&a.target, &opts).with_context(|| format!("opening {}", a.target.display()))?;
    let mut s_frame = Frame::default();
    let mut t_frame = Frame::default();
    let mut t_have = false;
    let params = PoissonParams {
        tol: 1e-6,
        ..PoissonParams::default()
    };
    let (mut cloned, mut written) = (0usize, 0usize);
    let t0 = std::time::Instant::now();
    for (f, xf) in frames.iter().enumerate() {
        if !s_src.read_into(&mut s_frame)? {
            break;
        }
        // The target holds its last frame when it is shorter than the source.
        if f < tgt.records.len() && t_src.read_into(&mut t_frame)? {
            t_have = true;
        }
        if !t_have {
            break;
        }
        let (Some(srgb), Some(trgb)) = (s_frame.rgb.as_ref(), t_frame.rgb.as_ref()) else {
            bail!("the video source did not deliver RGB frames");
        };
        let mut out = trgb.clone();
        let tf = f.min(tgt.records.len().saturating_sub(1));
        let src_lm = src.records[f].landmarks.as_ref().filter(|_| src.states[f].is_some());
        if let (Some(lm), Some(_), Some(pose)) = (src_lm, tgt.states.get(tf).and_then(|s| s.as_ref()), xf.pose) {
            let dst = project_lips(model, xf, &pose, &tgt.intrinsics, &lip_vertices)?;
            let src_pts: Vec<Point2<f64>> = OUTER_LIPS.map(|i| lm.points[i]).collect();
            if let Some(dst) = dst {
                let (tw, th) = (out.width() as usize, out.height() as usize);
                let (sw, sh) = (srgb.width() as usize, srgb.height() as usize);
                match facecap_tensor::reanimate::clone_mouth(
                    out.as_mut(),
                    tw,
                    th,
                    srgb.as_raw(),
                    sw,
                    sh,
                    &src_pts,
                    &dst,
                    a.mouth_margin,
                    &params,
                ) {
                    Ok(_) => cloned += 1,
                    Err(e) => eprintln!("reanimation frame {f}: {e}"),
                }
            }
        }
        crate::save_png_atomic(&out, &dir.join(format!("frame_{f:05}.png")))
            .with_context(|| format!("writing reanimation frame {f}"))?;
        written += 1;
    }
    outln!(
        "reanimation: {written} frames ({cloned} with the source mouth cloned in) in {:.1} s -> {}",
        t0.elapsed().as_secs_f64(),
        dir.display()
    );
    if let Some(video) = &a.video {
        let fps = {
            let s = open_source(&a.source, &SourceOptions::default())?;
            s.info().fps
        };
        let ffmpeg = facecap_io::video::ffmpeg::locate_ffmpeg(None)?;
        let tmp_video = facecap_core::atomic::temp_path_for(video);
        let st = std::process::Command::new(ffmpeg)
            .args(["-nostdin", "-y", "-loglevel", "error", "-framerate"])
            .arg(format!("{fps}"))
            .args(["-protocol_whitelist", "file"])
            .arg("-i")
            .arg(facecap_io::video::ffmpeg::file_url(&dir.join("frame_%05d.png")))
            .args([
                "-c:v",
                "libx264",
                "-pix_fmt",
                "yuv420p",
                "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            ])
            // Encoded beside the final name, then renamed: a kill leaves no partial
            // video under it, and the output name is a `file:` URL (never a protocol or
            // an option).
            .args(["-f", "mp4"])
            .arg(facecap_io::video::ffmpeg::file_url(&tmp_video))
            .stdin(std::process::Stdio::null())
            .status()
            .context("running ffmpeg")?;
        if !st.success() {
            let _ = std::fs::remove_file(&tmp_video);
            bail!("ffmpeg failed to encode {}", video.display());
        }
        std::fs::rename(&tmp_video, video)
            .with_context(|| format!("renaming {} to {}", tmp_video.display(), video.display()))?;
        outln!("reanimation video -> {}", video.display());
    }
    Ok(())
}

/// The transferred mesh's outer-lip vertices projected with the target pose.
fn project_lips(
    model: &TensorModel,
    xf: &TransferFrame,
    pose: &facecap_core::camera::ModelToCamera,
    k: &Intrinsics,
    lips: &[u32],
) -> anyhow::Result<Option<Vec<Point2<f64>>>> {
    let pts = model.generate_points(&xf.w_id, &xf.w_exp)?;
    Ok(lips
        .iter()
        .map(|&v| pose.project(k, &pts[v as usize].cast()))
        .collect::<Option<Vec<_>>>())
}
