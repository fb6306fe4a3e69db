//! Per-operator time of the two models (needs the model cache):
//!
//!     cargo run --release -p facecap-mesh --example profile_models
use facecap_mesh::tflite::Interpreter;

/// CPU time of this thread in seconds (Linux `/proc/thread-self/schedstat`), so that
/// figures on a loaded machine count only the time the thread actually ran.
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn main() -> facecap_mesh::Result<()> {
    for name in [facecap_mesh::FACE_LANDMARKS_MODEL, facecap_mesh::FACE_DETECTOR_MODEL] {
        let Some(path) = facecap_core::paths::model_file_or_skip("profile_models", name) else {
            continue;
        };
        let it = Interpreter::from_file(&path)?;
        let mut ws = it.workspace();
        for (i, v) in it.input_mut(&mut ws, 0)?.iter_mut().enumerate() {
            *v = ((i * 7919) % 251) as f32 / 251.0;
        }
        let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(50);
        let mut total: Vec<(&str, f64)> = Vec::new();
        for _ in 0..reps {
            for (n, t) in it.profile(&mut ws)? {
                match total.iter_mut().find(|(m, _)| *m == n) {
                    Some(a) => a.1 += t,
                    None => total.push((n, t)),
                }
            }
        }
        let t0 = std::time::Instant::now();
        let c0 = cpu_seconds();
        for _ in 0..reps {
            it.run(&mut ws)?;
        }
        let run = t0.elapsed().as_secs_f64() / reps as f64;
        let cpu = match (c0, cpu_seconds()) {
            (Some(a), Some(b)) => format!(", CPU time {:.3} ms", (b - a) / reps as f64 * 1e3),
            _ => String::new(),
        };
        println!("{name}: wall {:.3} ms{cpu} per run", run * 1e3);
        for (n, t) in total {
            println!("  {n:<20} {:.3} ms", t / reps as f64 * 1e3);
        }
    }
    Ok(())
}
