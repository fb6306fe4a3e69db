//! `facecap tensor build|generate|fit` and `facecap transfer` (tensor face model,
//! Papanek 2010 / Vlasic et al. 2005; see `docs/tensor.md`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::tensor::{DataTensor, RigSampling};

use crate::cmd_tensor_fit::{fit_video, print_summary, write_reprojection_csv, write_tensor_csv, FitOptions};

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
#[command(
    after_help = "Example:\n  facecap tensor build --identity-rig ict_face_identity100.glb --expression-rig ict_face_arkit53.glb --out ict.fctensor"
)]
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
#[command(after_help = "Example:\n  facecap tensor generate --model ict.fctensor --out face.obj")]
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

/// Arguments of `facecap tensor fit`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap tensor fit clip.mp4 --model ict.fctensor --landmark-map ict_landmarks68.json --out fit/"
)]
pub struct FitArgs {
    /// Input video (or image folder).
    pub video: PathBuf,
    /// Landmarks CSV of the video (from `facecap landmarks VIDEO --out DIR`) instead of
    /// tracking the video.
    #[arg(long)]
    pub landmarks: Option<PathBuf>,
    /// Also write the tracked landmarks to OUT/landmarks.csv.
    #[arg(long)]
    pub write_landmarks: bool,
    #[command(flatten)]
    pub fit: FitOptions,
    /// Output folder (tensor.csv, reprojection.csv).
    #[arg(long)]
    pub out: PathBuf,
}

pub use crate::cmd_transfer::TransferArgs;

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
        let id_rig = facecap_io::gltf_io::read_morph_mesh(idr).with_context(|| format!("reading {}", idr.display()))?;
        let ex_rig = facecap_io::gltf_io::read_morph_mesh(exr).with_context(|| format!("reading {}", exr.display()))?;
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
    outln!(
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
    outln!("wrote {}", a.out.display());
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
            facecap_io::obj::write_obj_positions(out, &pts, &model.triangles)?;
        }
        "glb" | "gltf" => {
            let rig = model.expression_rig(w_id)?;
            let anim = facecap_io::gltf_io::MorphAnimation {
                times_s: vec![0.0],
                weights: vec![w_exp.iter().map(|&w| w as f32).collect()],
            };
            facecap_io::gltf_io::write_morph_file(out, &rig, Some(&anim))?;
        }
        _ => bail!("output {} must end in .obj or .glb", out.display()),
    }
    Ok(())
}

fn run_fit(a: FitArgs) -> anyhow::Result<std::process::ExitCode> {
    let model = TensorModel::load(&a.fit.model)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let fitted = fit_video(&a.video, a.landmarks.as_deref(), &a.fit, &model)?;
    let path = a.out.join("tensor.csv");
    write_tensor_csv(&path, &model, &fitted)?;
    write_reprojection_csv(&a.out.join("reprojection.csv"), &fitted)?;
    if a.write_landmarks {
        write_landmarks_csv(&a.out.join("landmarks.csv"), &fitted.records)?;
    }
    print_summary(&a.video, &fitted);
    outln!(
        "wrote {} and {}",
        path.display(),
        a.out.join("reprojection.csv").display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

fn write_landmarks_csv(path: &Path, records: &[facecap_io::csv::LandmarkRecord]) -> anyhow::Result<()> {
    let cols = facecap_io::csv::landmark_columns();
    let mut wr = facecap_io::csv::FrameCsvWriter::create(path, &cols)?;
    let mut values = [0.0; 2 * facecap_core::landmarks::NUM_LANDMARKS];
    for r in records {
        facecap_io::csv::landmark_values(r.landmarks.as_ref(), &mut values);
        wr.write_row(&facecap_io::csv::FrameRow {
            frame: r.frame,
            timestamp: r.timestamp,
            success: r.success,
            confidence: r.confidence,
            values: &values,
        })?;
    }
    wr.finish()?;
    Ok(())
}

/// Runs `facecap transfer`.
pub fn run_transfer(a: TransferArgs) -> anyhow::Result<std::process::ExitCode> {
    crate::cmd_transfer::run(a)
}
