//! `facecap rig [--rig R.glb --landmark-map M.json]`: what the 68 landmarks can see of a
//! rig's shapes (motion, independence, the most collinear other shape) and the default
//! priors `capture` solves with, as a Markdown table (or JSON with `--json`).
//!
//! Example: `facecap rig --rig ict_face_arkit53.glb --landmark-map ict_landmarks68.json`.

use std::path::PathBuf;

use facecap_core::landmark_map::LandmarkMap;
use facecap_solve::observability::{analyse, default_priors};
use facecap_solve::BlendshapeRig;
use serde_json::json;

/// Arguments of `facecap rig`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Blendshape rig (glTF/GLB with morph targets). Default: the built-in rig.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Landmark map of `--rig` (JSON: `vertex_by_ibug_0based`, or a list of 68 ids).
    #[arg(long)]
    pub landmark_map: Option<PathBuf>,
    /// Print JSON instead of a Markdown table.
    #[arg(long)]
    pub json: bool,
}

/// Runs `facecap rig`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let (mesh, map, name) = match &args.rig {
        Some(path) => {
            let map_path = args
                .landmark_map
                .as_ref()
                .ok_or_else(|| anyhow::anyhow!("--rig needs --landmark-map (68 iBUG landmarks -> vertex ids)"))?;
            let mesh = facecap_io::gltf_io::read_morph_mesh(path)?;
            (mesh, LandmarkMap::from_json_file(map_path)?, path.display().to_string())
        }
        None => {
            let (mesh, map) = crate::default_rig::default_rig()?;
            (mesh, map, "built-in default rig".to_string())
        }
    };
    let rig = BlendshapeRig::from_morph_mesh(mesh, &map, &name)?;
    let table = analyse(&rig);
    let priors = default_priors(&rig);
    let partners = |k: usize| -> Vec<String> {
        priors
            .exclusive
            .iter()
            .filter_map(|&(a, b)| {
                if a == k {
                    Some(rig.names[b].clone())
                } else if b == k {
                    Some(rig.names[a].clone())
                } else {
                    None
                }
            })
            .collect()
    };
    if args.json {
        let rows: Vec<_> = table
            .iter()
            .enumerate()
            .map(|(k, v)| {
                json!({
                    "name": v.name, "motion_iod": v.motion, "max_point_iod": v.max_point,
                    "independence": v.independence,
                    "closest": v.closest.as_ref().map(|(n, c)| json!({"name": n, "cos": c})),
                    "fixed": priors.fixed[k], "fixed_because": v.fixed_because,
                    "ridge": priors.ridge[k], "exclusive_with": partners(k),
                })
            })
            .collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(&json!({"rig": name, "shapes": rows}))?
        );
        return Ok(std::process::ExitCode::SUCCESS);
    }
    outln!(
        "Rig: {name} ({} shapes, {} mapped landmarks)\n",
        rig.num_shapes(),
        rig.num_mapped()
    );
    outln!("| shape | motion (IOD) | max point (IOD) | independence | most collinear (cos) | default prior | exclusive with |");
    outln!("|---|---|---|---|---|---|---|");
    for (k, v) in table.iter().enumerate() {
        let closest = v
            .closest
            .as_ref()
            .map_or("-".to_string(), |(n, c)| format!("{n} ({c:+.2})"));
        let prior = match v.fixed_because {
            Some(why) => format!("held at 0: {why}"),
            None => format!("ridge {:.0}", priors.ridge[k]),
        };
        let ex = partners(k);
        outln!(
            "| {} | {:.3} | {:.3} | {:.2} | {} | {} | {} |",
            v.name,
            v.motion,
            v.max_point,
            v.independence,
            closest,
            prior,
            if ex.is_empty() { "-".to_string() } else { ex.join(", ") }
        );
    }
    Ok(std::process::ExitCode::SUCCESS)
}
