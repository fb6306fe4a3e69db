//! `facecap muscle ...`: muscle-model commands (Mramornov 2015; crate `facecap-muscle`).
//!
//! * `facecap muscle bake --mesh MESH.glb|.obj --landmark-map MAP.json [--muscles SET.json]
//!   --out RIG.glb` — writes the mesh with one morph target per muscle at full contraction
//!   (named after the muscle) plus `jaw_open` (jaw at its largest angle): muscle-generated
//!   blendshapes for any mesh with a 68-landmark map. Existing targets are kept.
//! * `facecap muscle track VIDEO --mesh MESH.glb|.obj --landmark-map MAP.json
//!   [--muscles SET.json] --out DIR` — tracks landmarks (HOG + ERT + LK tracker), then
//!   contractions, jaw and head pose per frame (thesis Algorithm 2), and writes in `DIR`:
//!   `contractions.csv` (`frame,timestamp,success,confidence`, one column per muscle in
//!   `[0, 1]`, then `jaw` in radians; the same file as `capture --muscles`) and
//!   `posed.glb`, the baked rig animated with one keyframe per frame (at `frame / fps`) (muscle weights = contractions, `jaw_open` weight = jaw / max angle,
//!   a linearisation of the rotation). `--landmarks LANDMARKS.csv` (OpenFace-style
//!   `x_0..x_67,y_0..y_67`, as written by `facecap landmarks`) replaces the video's landmark
//!   tracking; then VIDEO is only used for the frame size when `--width/--height` are absent.
//!
//! Without `--muscles` the default 11-muscle set is placed from the mesh's landmarks. The
//! camera is `Intrinsics::default_for_frame` (f = max(width, height)).

use std::path::{Path, PathBuf};

use anyhow::Context;
use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::MorphMesh;
use facecap_io::gltf_io::MorphAnimation;
use facecap_muscle::retarget::{bake, JAW_TARGET};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::set::MuscleSet;
use facecap_muscle::track::SolveMode;
use facecap_pipeline::{MuscleFrame, MuscleSetup, MuscleSink, RunControl, TrackerPolicy, VideoTracker};
use nalgebra::Point3;

/// Muscle subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Track muscle contractions and jaw rotation from a video.
    Track(TrackArgs),
    /// Bake each muscle at full contraction (and the open jaw) into named morph targets.
    Bake(BakeArgs),
}

/// `facecap muscle bake`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap muscle bake --mesh ict.glb --landmark-map ict_landmarks68.json --out ict_muscles.glb"
)]
pub struct BakeArgs {
    /// Mesh (.glb/.gltf or .obj).
    #[arg(long)]
    pub mesh: PathBuf,
    /// iBUG-68 landmark -> vertex map (JSON).
    #[arg(long)]
    pub landmark_map: PathBuf,
    /// Muscle set JSON (default: the 11-muscle set placed from the landmarks).
    #[arg(long)]
    pub muscles: Option<PathBuf>,
    /// Output rig (.glb).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the muscle set used (JSON) to this path.
    #[arg(long)]
    pub write_set: Option<PathBuf>,
}

/// `facecap muscle track`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap muscle track clip.mp4 --mesh ict.glb --landmark-map ict_landmarks68.json --out muscles/ --report"
)]
pub struct TrackArgs {
    /// Video file (or image folder).
    pub video: PathBuf,
    /// Mesh (.glb/.gltf or .obj).
    #[arg(long)]
    pub mesh: PathBuf,
    /// iBUG-68 landmark -> vertex map (JSON).
    #[arg(long)]
    pub landmark_map: PathBuf,
    /// Muscle set JSON (default: the 11-muscle set placed from the landmarks).
    #[arg(long)]
    pub muscles: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// `--ert-precision`.
    #[command(flatten)]
    pub ert: crate::ert_flag::ErtFlag,
    /// Use these landmarks (OpenFace-style CSV) instead of tracking the video.
    #[arg(long)]
    pub landmarks: Option<PathBuf>,
    /// Frame width for the default camera (with --landmarks; else read from the video).
    #[arg(long)]
    pub width: Option<u32>,
    /// Frame height for the default camera.
    #[arg(long)]
    pub height: Option<u32>,
    /// Contraction solver: `global` (joint pose/jaw/contractions) or `point` (thesis
    /// point-by-point).
    #[arg(long, default_value = "global")]
    pub solver: String,
    /// dlib 68-point model (default: the model cache).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Smooth landmarks with the One Euro filter (as `capture --smooth`; off by default).
    #[arg(long)]
    pub smooth: bool,
    /// Also write `DIR/report/`: per-muscle curves (`curves_*.svg`), the mesh posed at the
    /// rest frame and at each muscle's peak (`meshes.png`, one tile each) and `report.html`
    /// with captions. Only the model mesh is rendered, never the video frames.
    #[arg(long)]
    pub report: bool,
}

/// Runs a muscle subcommand.
pub fn run(cmd: Command) -> anyhow::Result<std::process::ExitCode> {
    match cmd {
        Command::Track(a) => run_track(a),
        Command::Bake(a) => run_bake(a),
    }
}

/// Reads a .glb/.gltf (with its targets) or an .obj (no targets).
fn read_mesh(path: &Path) -> anyhow::Result<MorphMesh> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let mm = match ext.as_str() {
        "glb" | "gltf" => facecap_io::gltf_io::read_morph_mesh(path)?,
        "obj" => MorphMesh {
            base: facecap_io::obj::read_obj(path)?,
            targets: Vec::new(),
        },
        _ => anyhow::bail!("--mesh {}: expected a .glb, .gltf or .obj file", path.display()),
    };
    Ok(mm)
}

/// Mesh, map, muscle set and rig.
fn load(
    mesh: &Path,
    map: &Path,
    muscles: Option<&Path>,
) -> anyhow::Result<(MorphMesh, LandmarkMap, MuscleSet, MuscleRig)> {
    let mm = read_mesh(mesh).with_context(|| format!("reading {}", mesh.display()))?;
    let map = LandmarkMap::from_json_file(map)?;
    map.validate(mm.base.num_vertices())?;
    let pos: Vec<Point3<f64>> = mm.base.positions.iter().map(|p| p.cast()).collect();
    let set = match muscles {
        Some(p) => MuscleSet::from_json_file(p)?,
        None => {
            let lm = facecap_muscle::defaults::landmark_positions(&map, &pos);
            facecap_muscle::defaults::default_muscle_set(&lm, &pos)
                .context("placing the default muscle set from the landmark map")?
        }
    };
    let rig = MuscleRig::from_mesh(&set, &mm.base)?;
    Ok((mm, map, set, rig))
}

fn run_bake(a: BakeArgs) -> anyhow::Result<std::process::ExitCode> {
    let (mm, _map, set, rig) = load(&a.mesh, &a.landmark_map, a.muscles.as_deref())?;
    let baked = bake(&rig, &mm)?;
    facecap_io::gltf_io::write_glb(&a.out, &baked, None).with_context(|| format!("writing {}", a.out.display()))?;
    if let Some(p) = &a.write_set {
        let text = set.to_json_string()?;
        facecap_core::atomic::write_atomic(p, |w| w.write_all(text.as_bytes()))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    eprintln!(
        "{}: {} muscles + {} baked as morph targets ({} vertices); wrote {}",
        a.mesh.display(),
        rig.num_muscles(),
        if rig.jaw().is_some() { JAW_TARGET } else { "no jaw" },
        rig.base().len(),
        a.out.display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

fn run_track(a: TrackArgs) -> anyhow::Result<std::process::ExitCode> {
    let mode = match a.solver.as_str() {
        "global" => SolveMode::Global,
        "point" => SolveMode::PointByPoint,
        s => anyhow::bail!("--solver {s:?}: expected \"global\" or \"point\""),
    };
    let (mm, map, _set, rig) = load(&a.mesh, &a.landmark_map, a.muscles.as_deref())?;
    let setup = MuscleSetup::from_rig(rig.clone(), &map, mode)?;
    // posed.glb's rig is baked before any tracking: a mesh that cannot be baked (an OBJ
    // cut in half) fails here, before contractions.csv is written.
    let baked = bake(&rig, &mm)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    // The landmarks: a CSV replayed, or the video tracked (the pipeline's one tracker).
    let (records, source) = match &a.landmarks {
        Some(p) => (
            Some(facecap_pipeline::openface::read_landmarks(p).with_context(|| format!("reading {}", p.display()))?),
            None,
        ),
        None => (
            None,
            Some(facecap_pipeline::open_video(&a.video, 1).with_context(|| format!("opening {}", a.video.display()))?),
        ),
    };
    let (width, height) = match (a.width, a.height, &source) {
        (Some(w), Some(h), _) => (w, h),
        (_, _, Some(src)) => (src.info().width, src.info().height),
        _ => facecap_pipeline::tensor_fit::frame_size(&a.video).with_context(|| {
            format!(
                "opening {} for the frame size (or give --width/--height)",
                a.video.display()
            )
        })?,
    };
    let camera = Intrinsics::default_for_frame(width, height)?;
    let mut sink = MuscleSink::create(&a.out, &setup, camera)?.keep_history();
    let report = match (records, source) {
        (Some(r), _) => facecap_pipeline::replay(&r, &mut [&mut sink])?,
        (None, Some(src)) => {
            let tracker = VideoTracker::new(&TrackerPolicy {
                smooth: a.smooth,
                shape_model: a.model.clone(),
                upsample: facecap_landmarks::detect::Upsample::Auto,
                ert_precision: a.ert.ert_precision,
                ..TrackerPolicy::default()
            })?;
            tracker.run(src, &mut [&mut sink], &mut RunControl::default())?
        }
        (None, None) => anyhow::bail!("no landmark source"),
    };
    let history = sink.finish()?;
    // posed.glb: the baked rig, muscle weights = contractions, jaw_open = jaw / max angle
    // (a linearisation of the rotation); one keyframe per frame at frame / fps.
    let n_old = mm.targets.len();
    let max_jaw = rig.max_jaw();
    let fps = report
        .info
        .as_ref()
        .map(|i| i.fps)
        .filter(|f| f.is_finite() && *f > 0.0)
        .unwrap_or(facecap_io::livelink::FALLBACK_FPS);
    let mut anim = MorphAnimation::default();
    for f in &history {
        let t = facecap_pipeline::outputs::keyframe_time(f.index, fps) as f32;
        if anim.times_s.last().is_some_and(|&l| t <= l) {
            continue;
        }
        let mut w = vec![0.0f32; baked.targets.len()];
        for (i, c) in f.contractions.iter().enumerate() {
            w[n_old + i] = *c as f32;
        }
        if rig.jaw().is_some() && max_jaw > 0.0 {
            w[n_old + rig.num_muscles()] = (f.jaw / max_jaw) as f32;
        }
        anim.times_s.push(t);
        anim.weights.push(w);
    }
    let glb = a.out.join("posed.glb");
    if !anim.times_s.is_empty() {
        facecap_io::gltf_io::write_glb(&glb, &baked, Some(&anim))
            .with_context(|| format!("writing {}", glb.display()))?;
    }
    if a.report {
        write_muscle_report(&a.out.join("report"), &a.video, &rig, &mm, &map, &history)?;
    }
    let ok = history.iter().filter(|f| f.success).count();
    crate::out::info(&format!(
        "{}: {} frames, contractions on {ok}; wrote {} and {}",
        a.video.display(),
        history.len(),
        a.out.join("contractions.csv").display(),
        glb.display()
    ));
    Ok(std::process::ExitCode::SUCCESS)
}

/// Per-muscle curves, the mesh posed at the rest frame and at each muscle's peak, and an
/// HTML page tying them together (see [`TrackArgs::report`]).
fn write_muscle_report(
    dir: &Path,
    video: &Path,
    rig: &MuscleRig,
    mesh: &MorphMesh,
    map: &LandmarkMap,
    frames: &[MuscleFrame],
) -> anyhow::Result<()> {
    use crate::report;
    let (face_vertices, face_triangles) = face_region(rig.base(), &mesh.base.triangles, map);
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let solved: Vec<&MuscleFrame> = frames.iter().filter(|f| f.success).collect();
    let times: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
    let m = rig.num_muscles();
    let max_jaw = rig.max_jaw();
    let series = |k: usize| -> Vec<f64> {
        frames
            .iter()
            .map(|f| {
                if !f.success {
                    f64::NAN
                } else if k < m {
                    f.contractions[k]
                } else if max_jaw > 0.0 {
                    f.jaw / max_jaw
                } else {
                    f.jaw
                }
            })
            .collect()
    };
    // Group the curves: left side, right side, the rest (sphincter, unsided muscles, jaw).
    let names = rig.names();
    type Series = Vec<(String, Vec<f64>)>;
    let mut groups: [(&str, &str, Series); 3] = [
        ("curves_left.svg", "Left-side muscles (contraction)", Vec::new()),
        ("curves_right.svg", "Right-side muscles (contraction)", Vec::new()),
        (
            "curves_other.svg",
            "Other muscles (contraction) and jaw (angle / max angle)",
            Vec::new(),
        ),
    ];
    for (k, name) in names.iter().enumerate() {
        let g = if name.ends_with("_L") {
            0
        } else if name.ends_with("_R") {
            1
        } else {
            2
        };
        groups[g].2.push((name.clone(), series(k)));
    }
    if rig.jaw().is_some() {
        groups[2].2.push(("jaw".into(), series(m)));
    }
    let mut plots = Vec::new();
    for (file, title, s) in &groups {
        if s.is_empty() {
            continue;
        }
        let svg = report::svg_line_plot(title, &times, s, 1000, 300);
        facecap_core::atomic::write_atomic(dir.join(file), |w| w.write_all(svg.as_bytes()))?;
        plots.push((*file).to_string());
    }

    // Tiles: the least active solved frame, then each muscle's and the jaw's peak frame.
    let activity =
        |f: &MuscleFrame| f.contractions.iter().sum::<f64>() + if max_jaw > 0.0 { f.jaw / max_jaw } else { 0.0 };
    let mut picks: Vec<(String, &MuscleFrame)> = Vec::new();
    if let Some(rest) = solved.iter().min_by(|a, b| activity(a).total_cmp(&activity(b))) {
        picks.push(("least active frame".into(), rest));
    }
    #[allow(clippy::needless_range_loop)] // k == m is the jaw, not a name
    for k in 0..=m {
        if k == m && rig.jaw().is_none() {
            break;
        }
        let value = |f: &MuscleFrame| if k < m { f.contractions[k] } else { f.jaw };
        if let Some(peak) = solved.iter().max_by(|a, b| value(a).total_cmp(&value(b))) {
            let label = if k < m { names[k].as_str() } else { "jaw" };
            picks.push((format!("peak {label} = {:.2}", value(peak)), peak));
        }
    }
    const TILE: u32 = 300;
    const PER_ROW: u32 = 4;
    let rows = (picks.len() as u32).div_ceil(PER_ROW).max(1);
    let mut sheet = image::RgbImage::from_pixel(PER_ROW * TILE, rows * TILE, image::Rgb([255, 255, 255]));
    let mut posed = vec![nalgebra::Point3::<f64>::origin(); rig.base().len()];
    let mut captions = Vec::new();
    for (i, (label, f)) in picks.iter().enumerate() {
        rig.pose_into(&f.contractions, f.jaw, &mut posed)?;
        let pts: Vec<nalgebra::Point3<f32>> = face_vertices.iter().map(|&v| posed[v].cast()).collect();
        let tile = report::render_mesh(&pts, &face_triangles, &report::camera_view(&f.rotation), TILE);
        let (x, y) = ((i as u32 % PER_ROW) * TILE, (i as u32 / PER_ROW) * TILE);
        image::imageops::overlay(&mut sheet, &tile, x as i64, y as i64);
        captions.push(format!(
            "tile {} (row {}, column {}): {label}, frame {}, t = {:.2} s",
            i + 1,
            i as u32 / PER_ROW + 1,
            i as u32 % PER_ROW + 1,
            f.index,
            f.timestamp
        ));
    }
    let png = report::png_bytes_fast(&sheet)?;
    facecap_core::atomic::write_atomic(dir.join("meshes.png"), |w| w.write_all(&png))?;
    let summary = vec![
        ("video".to_string(), video.display().to_string()),
        ("frames".to_string(), frames.len().to_string()),
        ("frames with a solve".to_string(), solved.len().to_string()),
        ("muscles".to_string(), names.join(", ")),
        (
            "meshes.png".to_string(),
            "the rig posed with the solved contractions, jaw and head rotation (no video pixels)".to_string(),
        ),
    ];
    let sheets = vec![("meshes.png".to_string(), captions.join("; "))];
    report::write_report_html(
        dir,
        "facecap muscle track",
        &summary,
        "The model mesh posed with the solved contractions, jaw angle and head rotation, at the least active frame and at each muscle's peak (tiles left to right, top to bottom).",
        &sheets,
        &plots,
    )
}

/// The part of the mesh around the face: vertices whose rest position lies inside the
/// landmarks' x/y bounding box grown by 15 % on each side and by 30 % above (+Y is up in
/// the model: room for the forehead), with the triangles made only of them, re-indexed. Falls back to the
/// whole mesh when the map yields no usable box.
fn face_region(
    base: &[nalgebra::Point3<f64>],
    triangles: &[[u32; 3]],
    map: &LandmarkMap,
) -> (Vec<usize>, Vec<[u32; 3]>) {
    let lm = facecap_muscle::defaults::landmark_positions(map, base);
    let pts: Vec<&nalgebra::Point3<f64>> = lm.iter().flatten().collect();
    let all = || ((0..base.len()).collect::<Vec<_>>(), triangles.to_vec());
    if pts.len() < 3 {
        return all();
    }
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for p in &pts {
        x0 = x0.min(p.x);
        x1 = x1.max(p.x);
        y0 = y0.min(p.y);
        y1 = y1.max(p.y);
    }
    let (mx, my) = (0.15 * (x1 - x0), 0.15 * (y1 - y0));
    if !(mx > 0.0 && my > 0.0) {
        return all();
    }
    let inside = |p: &nalgebra::Point3<f64>| p.x >= x0 - mx && p.x <= x1 + mx && p.y >= y0 - my && p.y <= y1 + 2.0 * my;
    let mut new_index = vec![u32::MAX; base.len()];
    let mut kept = Vec::new();
    for (i, p) in base.iter().enumerate() {
        if inside(p) {
            new_index[i] = kept.len() as u32;
            kept.push(i);
        }
    }
    let tris: Vec<[u32; 3]> = triangles
        .iter()
        .filter_map(|t| {
            let m = t.map(|v| new_index.get(v as usize).copied().unwrap_or(u32::MAX));
            m.iter().all(|&v| v != u32::MAX).then_some(m)
        })
        .collect();
    if tris.is_empty() {
        return all();
    }
    (kept, tris)
}
