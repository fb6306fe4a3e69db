//! CPU time per frame of the tracker on a shared clip (needs the model cache and
//! `../shared/data`); prints wall and CPU time so figures from a loaded machine can be
//! read:
//!
//!     cargo run --release -p facecap-mesh --example profile_tracker [clip] [frames]
use facecap_io::video::{open_source, Frame, SourceOptions};
use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshStatus, MeshTracker, RgbView};

/// CPU time of this thread in seconds (Linux `/proc/thread-self/schedstat`).
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let clip = args.next().unwrap_or_else(|| "videos/liveportrait_d9.mp4".into());
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(100);
    let Some(path) = facecap_core::paths::shared_data_file("profile_tracker", &clip) else {
        return Ok(());
    };
    let tracker = MeshTracker::new(MeshModels::from_cache()?, MeshParams::default())?;
    let opts = SourceOptions {
        rgb: true,
        ..SourceOptions::default()
    };
    let mut src = open_source(&path, &opts)?;
    let mut frames = Vec::new();
    let mut f = Frame::default();
    while frames.len() < n && src.read_into(&mut f)? {
        if let Some(rgb) = &f.rgb {
            frames.push((f.timestamp_s, rgb.clone()));
        }
    }
    let (mut ws, mut state, mut mesh) = (tracker.workspace(), tracker.state(), FaceMesh::default());
    let (mut detected, mut tracked) = (0, 0);
    let t0 = std::time::Instant::now();
    let c0 = cpu_seconds();
    for (t, img) in &frames {
        let r = tracker.track_into(&RgbView::from_image(img)?, *t, &mut ws, &mut state, &mut mesh)?;
        match r.status {
            MeshStatus::Detected => detected += 1,
            MeshStatus::Tracked => tracked += 1,
            _ => {}
        }
    }
    let wall = t0.elapsed().as_secs_f64() / frames.len() as f64;
    let cpu = match (c0, cpu_seconds()) {
        (Some(a), Some(b)) => format!("{:.3} ms", (b - a) / frames.len() as f64 * 1e3),
        _ => "n/a".into(),
    };
    println!(
        "{clip}: {} frames ({detected} detected, {tracked} tracked): wall {:.3} ms, CPU {cpu} per frame",
        frames.len(),
        wall * 1e3
    );
    Ok(())
}
