//! `facecap tensor build|generate|fit` and `facecap transfer` (tensor face model,
//! Papanek 2010 / Vlasic et al. 2005; see `docs/tensor.md`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use facecap_core::camera::Intrinsics;
use facecap_core::csv::{FrameCsvWriter, FrameRow, LandmarkRecord, POSE_COLUMNS};
use facecap_core::landmark_map::LandmarkMap;
use facecap_tensor::fit::{FitInput, FitParams, FitState, Fitter, Method, Projection};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::tensor::{DataTensor, RigSampling};
use nalgebra::Point2;

/// Tensor subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Build a tensor model from a corresponded mesh database.
    Build(BuildArgs),
    /// Write a face of the model for given identity/expression weights (OBJ or GLB).
    Generate(GenerateArgs),
    /// Fit the model to a video's landmarks: pose, identity and per-frame expression.
    Fit(FitArgs),
}

/// Arguments of `facecap tensor build`.
#[derive(Debug, clap::Args)]
pub struct BuildArgs {
    /// Folder of `<identity>_<expression>.obj` meshes (identity = text before the first `_`).
    #[arg(long, conflicts_with_all = ["identity_rig", "expression_rig"])]
    pub meshes: Option<PathBuf>,
    /// Identity rig (.glb/.gltf; morph targets = identity modes), e.g. ict_face_identity100.glb.
    #[arg(long, requires = "expression_rig")]
    pub identity_rig: Option<PathBuf>,
    /// Expression rig on the same topology, e.g. ict_face_arkit53.glb.
    #[arg(long, requires = "identity_rig")]
    pub expression_rig: Option<PathBuf>,
    /// Identities to sample from the identity rig.
    #[arg(long, default_value_t = 56)]
    pub identities: usize,
    /// Seed of the identity sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Standard deviation of the sampled identity-mode weights.
    #[arg(long, default_value_t = 1.0)]
    pub sigma: f64,
    /// Comma-separated expression targets to use (default: all), plus "neutral" first.
    #[arg(long, value_delimiter = ',')]
    pub expressions: Option<Vec<String>>,
    /// Fraction of identity-mode energy to keep (1 = no truncation).
    #[arg(long, default_value_t = 1.0)]
    pub energy_id: f64,
    /// Fraction of expression-mode energy to keep.
    #[arg(long, default_value_t = 1.0)]
    pub energy_exp: f64,
    /// Store f32 scalars (half the size) instead of f64.
    #[arg(long)]
    pub f32: bool,
    /// Output model file.
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `facecap tensor generate`.
#[derive(Debug, clap::Args)]
pub struct GenerateArgs {
    /// Model file from `facecap tensor build`.
    #[arg(long)]
    pub model: PathBuf,
    /// Identity database weights, comma-separated (I values; default: uniform 1/I).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub id: Option<Vec<f64>>,
    /// Expression database weights, comma-separated (E values; default: uniform 1/E).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub exp: Option<Vec<f64>>,
    /// Output mesh: .obj, or .glb (a rig of the identity with the expression weights set).
    #[arg(long)]
    pub out: PathBuf,
}

/// Options shared by `tensor fit` and `transfer`.
#[derive(Debug, Clone, clap::Args)]
pub struct FitOptions {
    /// Model file from `facecap tensor build`.
    #[arg(long)]
    pub model: PathBuf,
    /// iBUG-68 -> model vertex map (JSON, e.g. ict_landmarks68.json).
    #[arg(long)]
    pub landmark_map: PathBuf,
    /// Weight constraint: `regularised` (closed form) or `nnls` (non-negative).
    #[arg(long, default_value = "regularised")]
    pub method: String,
    /// Identity prior weight lambda_id (model units^2).
    #[arg(long, default_value_t = 1e-2)]
    pub lambda_id: f64,
    /// Expression prior weight lambda_exp (model units^2).
    #[arg(long, default_value_t = 1e-2)]
    pub lambda_exp: f64,
    /// Projection of the weight steps: `weak` (thesis, z_avg) or `perspective` (per-point depth).
    #[arg(long, default_value = "weak")]
    pub projection: String,
    /// Focal length in pixels (default: max(width, height)).
    #[arg(long)]
    pub focal: Option<f64>,
    /// Also fit the jaw contour landmarks 0-16 (off: contour points slide along the face).
    #[arg(long)]
    pub use_jaw: bool,
    /// Frames (evenly spaced successful ones) used to fit the shared identity.
    #[arg(long, default_value_t = 40)]
    pub identity_frames: usize,
}

/// Arguments of `facecap tensor fit`.
#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Input video (or image folder).
    pub video: PathBuf,
    /// Landmarks CSV of the video (from `facecap landmarks VIDEO --out DIR`).
    #[arg(long)]
    pub landmarks: Option<PathBuf>,
    #[command(flatten)]
    pub fit: FitOptions,
    /// Output folder (tensor.csv).
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `facecap transfer`.
#[derive(Debug, clap::Args)]
pub struct TransferArgs {
    /// Source video.
    pub source: PathBuf,
    /// Target video.
    pub target: PathBuf,
    /// Landmarks CSV of the source video.
    #[arg(long)]
    pub source_landmarks: Option<PathBuf>,
    /// Landmarks CSV of the target video.
    #[arg(long)]
    pub target_landmarks: Option<PathBuf>,
    #[command(flatten)]
    pub fit: FitOptions,
    /// Also write one OBJ per frame into OUT/obj/.
    #[arg(long)]
    pub obj: bool,
    /// Output folder (transfer.glb, transfer.csv, source/target tensor CSVs).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs a tensor subcommand.
pub fn run(cmd: Command) -> anyhow::Result<std::process::ExitCode> {
    match cmd {
        Command::Build(a) => run_build(a),
        Command::Generate(a) => run_generate(a),
        Command::Fit(a) => run_fit(a),
    }
}

fn run_build(a: BuildArgs) -> anyhow::Result<std::process::ExitCode> {
    let t0 = std::time::Instant::now();
    let data = if let Some(dir) = &a.meshes {
        DataTensor::from_mesh_folder(dir)?
    } else if let (Some(idr), Some(exr)) = (&a.identity_rig, &a.expression_rig) {
        let id_rig =
            facecap_core::gltf_io::read_morph_mesh(idr).with_context(|| format!("reading {}", idr.display()))?;
        let ex_rig =
            facecap_core::gltf_io::read_morph_mesh(exr).with_context(|| format!("reading {}", exr.display()))?;
        let s = RigSampling {
            identities: a.identities,
            seed: a.seed,
            sigma: a.sigma,
            expressions: a.expressions.clone(),
            include_neutral: true,
        };
        DataTensor::from_rigs(&id_rig, &ex_rig, &s)?
    } else {
        bail!("give --meshes DIR or --identity-rig ID.glb --expression-rig EXP.glb");
    };
    let t1 = std::time::Instant::now();
    let (model, rep) = TensorModel::build(
        &data,
        &HosvdParams {
            energy_id: a.energy_id,
            energy_exp: a.energy_exp,
        },
    )?;
    let t2 = std::time::Instant::now();
    model.save(&a.out, a.f32)?;
    println!(
        "tensor model: {} vertices, {} identities, {} expressions; kept {} x {} modes ({:.4} / {:.4} of the energy); database {:.2} s, HOSVD {:.2} s -> {}",
        data.num_vertices(),
        data.num_identities(),
        data.num_expressions(),
        rep.rank_id,
        rep.rank_exp,
        rep.energy_id,
        rep.energy_exp,
        (t1 - t0).as_secs_f64(),
        (t2 - t1).as_secs_f64(),
        a.out.display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

fn weights_or_uniform(w: Option<Vec<f64>>, n: usize, what: &str) -> anyhow::Result<Vec<f64>> {
    match w {
        None => Ok(vec![1.0 / n as f64; n]),
        Some(v) if v.len() == n => Ok(v),
        Some(v) => bail!("--{what} has {} values, the model has {n}", v.len()),
    }
}

fn run_generate(a: GenerateArgs) -> anyhow::Result<std::process::ExitCode> {
    let model = TensorModel::load(&a.model)?;
    let w_id = weights_or_uniform(a.id, model.num_identities(), "id")?;
    let w_exp = weights_or_uniform(a.exp, model.num_expressions(), "exp")?;
    write_mesh(&model, &w_id, &w_exp, &a.out)?;
    println!("wrote {}", a.out.display());
    Ok(std::process::ExitCode::SUCCESS)
}

fn write_mesh(model: &TensorModel, w_id: &[f64], w_exp: &[f64], out: &Path) -> anyhow::Result<()> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "obj" => {
            let pts = model.generate_points(w_id, w_exp)?;
            facecap_tensor::obj::write_obj(out, &pts, &model.triangles)?;
        }
        "glb" | "gltf" => {
            let rig = model.expression_rig(w_id)?;
            let anim = facecap_core::gltf_io::MorphAnimation {
                times_s: vec![0.0],
                weights: vec![w_exp.iter().map(|&w| w as f32).collect()],
            };
            facecap_core::gltf_io::write_morph_file(out, &rig, Some(&anim))?;
        }
        _ => bail!("output {} must end in .obj or .glb", out.display()),
    }
    Ok(())
}

/// A fitted sequence.
struct Fitted {
    records: Vec<LandmarkRecord>,
    states: Vec<Option<FitState>>,
    rms: Vec<f64>,
}

fn fit_params(o: &FitOptions) -> anyhow::Result<FitParams> {
    let method = match o.method.as_str() {
        "regularised" | "regularized" => Method::Regularised,
        "nnls" => Method::NonNegative,
        m => bail!("--method {m:?}: expected regularised or nnls"),
    };
    let projection = match o.projection.as_str() {
        "weak" => Projection::WeakPerspective,
        "perspective" => Projection::PerPointDepth,
        p => bail!("--projection {p:?}: expected weak or perspective"),
    };
    Ok(FitParams {
        lambda_id: o.lambda_id,
        lambda_exp: o.lambda_exp,
        method,
        projection,
        ..Default::default()
    })
}

fn frame_size(video: &Path) -> anyhow::Result<(u32, u32)> {
    let src = facecap_core::video::open_source(video, &facecap_core::video::SourceOptions::default())
        .with_context(|| format!("opening {}", video.display()))?;
    let info = src.info();
    Ok((info.width, info.height))
}

fn fit_video(video: &Path, landmarks: Option<&Path>, o: &FitOptions, model: &TensorModel) -> anyhow::Result<Fitted> {
    let Some(lm_path) = landmarks else {
        bail!(
            "{}: pass --landmarks CSV (run `facecap landmarks {} --out DIR` first; the tensor fit reads DIR/landmarks.csv)",
            video.display(),
            video.display()
        );
    };
    let records = facecap_core::csv::read_landmarks_csv(lm_path)?;
    let map = LandmarkMap::from_json_file(&o.landmark_map)?;
    map.validate(model.num_vertices())?;
    let pairs: Vec<(usize, u32)> = map.mapped().filter(|(i, _)| o.use_jaw || *i > 16).collect();
    if pairs.len() < 6 {
        bail!(
            "the landmark map maps only {} usable landmarks (need >= 6)",
            pairs.len()
        );
    }
    let vertices: Vec<u32> = pairs.iter().map(|p| p.1).collect();
    let (w, h) = frame_size(video)?;
    let k = match o.focal {
        Some(f) => Intrinsics::new(f, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0)?,
        None => Intrinsics::default_for_frame(w, h)?,
    };
    let params = fit_params(o)?;
    let images: Vec<Option<Vec<Point2<f64>>>> = records
        .iter()
        .map(|r| {
            r.landmarks
                .as_ref()
                .filter(|_| r.success)
                .map(|lm| pairs.iter().map(|(i, _)| lm.points[*i]).collect())
        })
        .collect();
    let good: Vec<usize> = (0..images.len()).filter(|&f| images[f].is_some()).collect();
    if good.is_empty() {
        bail!("{}: no frame with landmarks", lm_path.display());
    }
    let weights = vec![1.0; vertices.len()];
    // 1. Identity from evenly spaced frames (multi-frame fit).
    let nsel = o.identity_frames.clamp(1, good.len());
    let sel: Vec<usize> = (0..nsel).map(|j| good[j * good.len() / nsel]).collect();
    let fitter = Fitter::new(model, &vertices, params.clone())?;
    let mut ws = fitter.workspace();
    let inputs: Vec<FitInput> = sel
        .iter()
        .filter_map(|&f| images[f].as_ref())
        .map(|im| FitInput {
            image: im,
            weights: &weights,
            intrinsics: k,
        })
        .collect();
    let mut seq: Vec<FitState> = (0..inputs.len()).map(|_| fitter.initial_state()).collect();
    let rep = fitter.fit_sequence(&inputs, &mut seq, &mut ws)?;
    eprintln!(
        "{}: identity from {} frames: {} sweeps, cost {:.4} -> {:.4}, RMS {:.2} px",
        video.display(),
        inputs.len(),
        rep.sweeps,
        rep.initial_cost,
        rep.final_cost,
        rep.rms_px
    );
    let w_id = seq[0].w_id.clone();
    // 2. Per-frame expression and pose with the identity fixed, warm-started.
    let per_frame = Fitter::new(
        model,
        &vertices,
        FitParams {
            update_identity: false,
            prior_id: None,
            ..params
        },
    )?;
    let mut ws = per_frame.workspace();
    let mut st = per_frame.initial_state();
    st.w_id = w_id;
    let mut states = Vec::with_capacity(records.len());
    let mut rms = Vec::with_capacity(records.len());
    for im in &images {
        match im {
            Some(im) => {
                let input = FitInput {
                    image: im,
                    weights: &weights,
                    intrinsics: k,
                };
                match per_frame.solve_into(&input, &mut ws, &mut st) {
                    Ok(r) => {
                        states.push(Some(st.clone()));
                        rms.push(r.rms_px);
                    }
                    Err(e) => {
                        eprintln!("fit failed on a frame: {e}");
                        st.pose = None;
                        states.push(None);
                        rms.push(f64::NAN);
                    }
                }
            }
            None => {
                states.push(None);
                rms.push(f64::NAN);
            }
        }
    }
    Ok(Fitted { records, states, rms })
}

fn tensor_columns(model: &TensorModel) -> Vec<String> {
    let mut cols: Vec<String> = POSE_COLUMNS.iter().map(|s| s.to_string()).collect();
    cols.extend(model.identities.iter().map(|n| format!("id_{n}")));
    cols.extend(model.expressions.iter().map(|n| format!("exp_{n}")));
    cols
}

/// Confidence written to the CSV: `1 / (1 + RMS reprojection error in pixels)`.
fn confidence(rms_px: f64) -> f64 {
    if rms_px.is_finite() {
        1.0 / (1.0 + rms_px)
    } else {
        0.0
    }
}

fn write_tensor_csv(
    path: &Path,
    model: &TensorModel,
    records: &[LandmarkRecord],
    states: &[Option<FitState>],
    rms: &[f64],
) -> anyhow::Result<()> {
    let cols = tensor_columns(model);
    let mut wr = FrameCsvWriter::create(path, &cols)?;
    let mut values = vec![f64::NAN; cols.len()];
    for ((r, s), &e) in records.iter().zip(states).zip(rms) {
        values.iter_mut().for_each(|v| *v = f64::NAN);
        if let Some(s) = s {
            if let Some(p) = s.pose {
                let t = p.tvec();
                let (rx, ry, rz) = p.euler_xyz();
                values[..6].copy_from_slice(&[t.x, t.y, t.z, rx, ry, rz]);
            }
            values[6..6 + s.w_id.len()].copy_from_slice(&s.w_id);
            values[6 + s.w_id.len()..].copy_from_slice(&s.w_exp);
        }
        wr.write_row(&FrameRow {
            frame: r.frame,
            timestamp: r.timestamp,
            success: s.is_some(),
            confidence: if s.is_some() { confidence(e) } else { 0.0 },
            values: &values,
        })?;
    }
    wr.finish()?;
    Ok(())
}

fn run_fit(a: FitArgs) -> anyhow::Result<std::process::ExitCode> {
    let model = TensorModel::load(&a.fit.model)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let fitted = fit_video(&a.video, a.landmarks.as_deref(), &a.fit, &model)?;
    let path = a.out.join("tensor.csv");
    write_tensor_csv(&path, &model, &fitted.records, &fitted.states, &fitted.rms)?;
    let ok: Vec<f64> = fitted.rms.iter().copied().filter(|r| r.is_finite()).collect();
    let mean = ok.iter().sum::<f64>() / ok.len().max(1) as f64;
    println!(
        "{}: {} / {} frames fitted, mean landmark reprojection RMS {:.2} px -> {}",
        a.video.display(),
        ok.len(),
        fitted.records.len(),
        mean,
        path.display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

/// Runs `facecap transfer`.
pub fn run_transfer(a: TransferArgs) -> anyhow::Result<std::process::ExitCode> {
    let model = TensorModel::load(&a.fit.model)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let src = fit_video(&a.source, a.source_landmarks.as_deref(), &a.fit, &model)?;
    let tgt = fit_video(&a.target, a.target_landmarks.as_deref(), &a.fit, &model)?;
    write_tensor_csv(
        &a.out.join("source_tensor.csv"),
        &model,
        &src.records,
        &src.states,
        &src.rms,
    )?;
    write_tensor_csv(
        &a.out.join("target_tensor.csv"),
        &model,
        &tgt.records,
        &tgt.states,
        &tgt.rms,
    )?;
    // Carry the last good state over failed frames so every frame has weights.
    let fill = |states: &[Option<FitState>]| -> anyhow::Result<Vec<FitState>> {
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
    };
    let s_states = fill(&src.states)?;
    let t_states = fill(&tgt.states)?;
    let frames = facecap_tensor::transfer::combine(&s_states, &t_states)?;
    let w_id = frames[0].w_id.clone();
    // Animated GLB: the target identity's expression rig with the source's weights.
    let rig = model.expression_rig(&w_id)?;
    let fps_times: Vec<f32> = src.records.iter().map(|r| r.timestamp as f32).collect();
    let mut times: Vec<f32> = Vec::with_capacity(fps_times.len());
    let mut weights: Vec<Vec<f32>> = Vec::with_capacity(fps_times.len());
    for (t, f) in fps_times.iter().zip(&frames) {
        if times.last().is_some_and(|&l| *t <= l) {
            continue;
        }
        times.push(*t);
        weights.push(f.w_exp.iter().map(|&w| w as f32).collect());
    }
    let anim = facecap_core::gltf_io::MorphAnimation {
        times_s: times,
        weights,
    };
    facecap_core::gltf_io::write_glb(a.out.join("transfer.glb"), &rig, Some(&anim))?;
    // Parameters CSV: target pose, target identity, source expression.
    let tstates: Vec<Option<FitState>> = frames
        .iter()
        .map(|f| {
            Some(FitState {
                w_id: f.w_id.clone(),
                w_exp: f.w_exp.clone(),
                pose: f.pose,
                depth: Vec::new(),
            })
        })
        .collect();
    write_tensor_csv(&a.out.join("transfer.csv"), &model, &src.records, &tstates, &src.rms)?;
    if a.obj {
        let dir = a.out.join("obj");
        std::fs::create_dir_all(&dir)?;
        for (i, f) in frames.iter().enumerate() {
            let pts = model.generate_points(&f.w_id, &f.w_exp)?;
            facecap_tensor::obj::write_obj(&dir.join(format!("frame_{i:05}.obj")), &pts, &model.triangles)?;
        }
    }
    println!(
        "transfer: {} source frames onto the target identity -> {}",
        frames.len(),
        a.out.display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}
