//! `facecap solve`: blendshape weights (and head pose) from a landmarks CSV against a rig.
//!
//! ```text
//! facecap solve LANDMARKS.csv --rig RIG.glb --landmark-map MAP.json [--width W --height H]
//!     [--camera fx,fy,cx,cy] [--method exact3d|exact|bobyqa|region|pca] [--l1 1] [--temporal 0]
//!     [--shapes NAME,NAME,...] --out DIR [--obj]
//! ```
//!
//! Input: the OpenFace-style per-frame CSV our tracker writes (`frame,timestamp,success,
//! confidence,x_0..x_67,y_0..y_67`, 0-based pixels). Rows with `success = 0` get `nan` weights
//! and reset the warm start.
//!
//! Outputs in `DIR` (each written atomically):
//! * `weights.csv`: `frame,timestamp`, then one column per blendshape, named as in the rig;
//! * `pose.csv` (method `exact3d`): the per-frame CSV with `pose_Tx..pose_Tz` (rig units, camera
//!   frame) and `pose_Rx..pose_Rz` (Euler angles in radians, `R = Rz Ry Rx`);
//! * `animation.glb`: the rig with one morph-weight keyframe per solved frame;
//! * with `--obj`: `meshes/frame_NNNNNN.obj`, the posed mesh of every solved frame.
//!
//! Camera (method `exact3d`): `--camera fx,fy,cx,cy` in pixels, else the default camera
//! `fx = fy = max(W, H)`, principal point `((W - 1) / 2, (H - 1) / 2)` from `--width/--height`
//! (a ~53 degree horizontal field of view for landscape frames).
//!
//! The landmark map is the shared JSON (`vertex_by_ibug_0based`, `vertex_by_ibug_1based`) or a
//! plain list of 68 vertex ids (`null`/`-1` = unmapped; unmapped landmarks are ignored).

use std::path::PathBuf;

use anyhow::{bail, Context};
use facecap_core::camera::Intrinsics;
use facecap_core::csv::{read_landmarks_csv, FrameCsvWriter, FrameRow, POSE_COLUMNS};
use facecap_core::gltf_io::{write_glb, MorphAnimation};
use facecap_core::mesh::Mesh;
use facecap_solve::{AnySolver, BlendshapeRig, ExpressionSolver, Method, ObjectiveParams, Solution, SolveState};

/// Arguments of `facecap solve`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Landmarks CSV (OpenFace style, as written by `facecap landmarks`).
    #[arg(value_name = "LANDMARKS.csv")]
    pub landmarks: PathBuf,
    /// Rig: glTF/GLB with morph targets.
    #[arg(long, value_name = "RIG.glb")]
    pub rig: PathBuf,
    /// Landmark-to-vertex map JSON (`vertex_by_ibug_0based` object or a list of 68 ids).
    #[arg(long, value_name = "MAP.json")]
    pub landmark_map: PathBuf,
    /// Frame width in pixels (for the default camera).
    #[arg(long, requires = "height")]
    pub width: Option<u32>,
    /// Frame height in pixels (for the default camera).
    #[arg(long, requires = "width")]
    pub height: Option<u32>,
    /// Camera intrinsics `fx,fy,cx,cy` in pixels (overrides the default camera).
    #[arg(long, value_name = "fx,fy,cx,cy")]
    pub camera: Option<String>,
    /// Solver: exact3d (pose + weights, needs a camera), exact, bobyqa, region or pca.
    #[arg(long, default_value = "exact3d")]
    pub method: String,
    /// L1 weight lambda (px^2 per unit weight).
    #[arg(long, default_value_t = 1.0)]
    pub l1: f64,
    /// Temporal weight mu on ||e_t - e_{t-1}||^2 (px^2).
    #[arg(long, default_value_t = 0.0)]
    pub temporal: f64,
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Also write one posed OBJ per frame under DIR/meshes.
    #[arg(long)]
    pub obj: bool,
    /// Solve for these blendshapes only (comma-separated rig names, in this order; default: all).
    #[arg(long, value_name = "NAME,NAME,...")]
    pub shapes: Option<String>,
}

fn parse_camera(text: &str) -> anyhow::Result<Intrinsics> {
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--camera {text:?}: expected four numbers fx,fy,cx,cy"))?;
    if v.len() != 4 {
        bail!("--camera {text:?}: expected four numbers fx,fy,cx,cy, got {}", v.len());
    }
    Ok(Intrinsics::new(v[0], v[1], v[2], v[3])?)
}

/// Runs `facecap solve`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let method: Method = args.method.parse()?;
    let camera = match (&args.camera, args.width, args.height) {
        (Some(c), _, _) => Some(parse_camera(c)?),
        (None, Some(w), Some(h)) => Some(Intrinsics::default_for_frame(w, h)?),
        _ => None,
    };
    let camera = match (method, camera) {
        (_, Some(c)) => c,
        (Method::Exact3d, None) => {
            bail!("method exact3d needs a camera: pass --width W --height H (default camera) or --camera fx,fy,cx,cy, or choose --method exact")
        }
        // unused by the 2D methods
        (_, None) => Intrinsics::new(1.0, 1.0, 0.0, 0.0)?,
    };
    let rig = BlendshapeRig::from_gltf(&args.rig, &args.landmark_map).with_context(|| {
        format!(
            "loading rig {} with map {}",
            args.rig.display(),
            args.landmark_map.display()
        )
    })?;
    let rig = match &args.shapes {
        Some(list) => {
            let names: Vec<&str> = list.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
            if names.is_empty() {
                bail!("--shapes {list:?}: no blendshape names given");
            }
            rig.select(&names).with_context(|| format!("--shapes {list:?}"))?
        }
        None => rig,
    };
    let records = read_landmarks_csv(&args.landmarks)?;
    if records.is_empty() {
        bail!("{} has no frames", args.landmarks.display());
    }
    let objective = ObjectiveParams {
        l1: args.l1,
        temporal: args.temporal,
    };
    let solver = AnySolver::new(method, &rig, camera, objective)?;
    let n = solver.num_shapes();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mesh_dir = args.out.join("meshes");
    if args.obj {
        std::fs::create_dir_all(&mesh_dir).with_context(|| format!("creating {}", mesh_dir.display()))?;
    }

    let mut ws = solver.workspace();
    let mut state = SolveState::new(n);
    let mut sol = Solution::new(n);
    let mut rows: Vec<(u64, f64, Option<Vec<f64>>)> = Vec::with_capacity(records.len());
    let mut pose_writer = if method == Method::Exact3d {
        Some(FrameCsvWriter::create(args.out.join("pose.csv"), &POSE_COLUMNS)?)
    } else {
        None
    };
    let mut anim = MorphAnimation::default();
    let mut posed = Vec::new();
    let (mut solved, mut err_sum) = (0usize, 0.0f64);
    let mut times_us: Vec<f64> = Vec::with_capacity(records.len());
    for rec in &records {
        let Some(lm) = rec.landmarks.as_ref().filter(|_| rec.success) else {
            state.reset();
            rows.push((rec.frame, rec.timestamp, None));
            if let Some(w) = pose_writer.as_mut() {
                w.write_row(&FrameRow {
                    frame: rec.frame,
                    timestamp: rec.timestamp,
                    success: false,
                    confidence: 0.0,
                    values: &[f64::NAN; 6],
                })?;
            }
            continue;
        };
        let t0 = std::time::Instant::now();
        let report = solver
            .solve_into(lm, &mut ws, &mut state, &mut sol)
            .with_context(|| format!("frame {}", rec.frame))?;
        times_us.push(t0.elapsed().as_secs_f64() * 1e6);
        solved += 1;
        err_sum += sol.reprojection_error(lm);
        rows.push((rec.frame, rec.timestamp, Some(sol.weights.clone())));
        if let (Some(w), Some(p)) = (pose_writer.as_mut(), sol.pose) {
            let t = p.tvec();
            let (rx, ry, rz) = p.euler_xyz();
            w.write_row(&FrameRow {
                frame: rec.frame,
                timestamp: rec.timestamp,
                success: true,
                confidence: 1.0 / (1.0 + report.cost.max(0.0).sqrt()),
                values: &[t.x, t.y, t.z, rx, ry, rz],
            })?;
        }
        let ts = rec.timestamp as f32;
        if anim.times_s.last().map_or(true, |&last| ts > last) {
            anim.times_s.push(ts);
            anim.weights.push(sol.weights.iter().map(|&v| v as f32).collect());
        }
        if args.obj {
            if let Some(mesh) = rig.mesh.as_ref() {
                mesh.pose_into(&sol.weights, &mut posed)?;
                let m = Mesh {
                    positions: posed.clone(),
                    triangles: mesh.base.triangles.clone(),
                    normals: Vec::new(),
                    uvs: mesh.base.uvs.clone(),
                };
                facecap_core::obj::write_obj(mesh_dir.join(format!("frame_{:06}.obj", rec.frame)), &m)?;
            }
        }
    }
    if let Some(w) = pose_writer {
        w.finish()?;
    }
    write_weights_csv(&args.out.join("weights.csv"), solver.names(), &rows)?;
    if let (Some(mesh), false) = (rig.mesh.as_ref(), anim.times_s.is_empty()) {
        write_glb(args.out.join("animation.glb"), mesh, Some(&anim))?;
    }
    times_us.sort_by(f64::total_cmp);
    eprintln!(
        "solve: method {}, {} shapes, {solved}/{} frames solved, mean landmark error {:.2} px, median solve time {:.1} us/frame; wrote {}",
        method.name(),
        n,
        records.len(),
        if solved > 0 { err_sum / solved as f64 } else { f64::NAN },
        times_us.get(times_us.len() / 2).copied().unwrap_or(f64::NAN),
        args.out.display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

/// `frame,timestamp,<names...>`; `nan` weights for unsolved frames. Atomic.
fn write_weights_csv(
    path: &std::path::Path,
    names: &[String],
    rows: &[(u64, f64, Option<Vec<f64>>)],
) -> anyhow::Result<()> {
    for n in names {
        if n.contains([',', '\n', '\r', '"']) {
            bail!("blendshape name {n:?} cannot be a CSV column name");
        }
    }
    facecap_core::atomic::write_atomic(path, |w| {
        let mut line = String::from("frame,timestamp");
        for n in names {
            line.push(',');
            line.push_str(n);
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
        for (frame, ts, weights) in rows {
            line.clear();
            line.push_str(&format!("{frame},{ts}"));
            match weights {
                Some(ws) => ws.iter().for_each(|v| line.push_str(&format!(",{v}"))),
                None => names.iter().for_each(|_| line.push_str(",nan")),
            }
            line.push('\n');
            w.write_all(line.as_bytes())?;
        }
        Ok(())
    })?;
    Ok(())
}
