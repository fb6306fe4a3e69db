//! Per-operator time of the two models (needs the model cache):
//!
//!     cargo run --release -p facecap-mesh --example profile_models [reps] [--layers]
//!
//! `--layers` also prints every step of the plan with its shapes, time and MAC rate;
//! `--model PATH` profiles that TFLite file instead of the two cached models;
//! `--run-only` skips the per-operator pass, so that the whole process times `reps`
//! plain runs of each model (for pairing against another engine).
use facecap_mesh::tflite::Interpreter;

/// CPU time of this thread in seconds (Linux `/proc/thread-self/schedstat`), so that
/// figures on a loaded machine count only the time the thread actually ran.
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn main() -> facecap_mesh::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let layers = args.iter().any(|a| a == "--layers");
    let run_only = args.iter().any(|a| a == "--run-only");
    let reps: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(50);
    let given = args.iter().position(|a| a == "--model").and_then(|i| args.get(i + 1));
    let paths: Vec<(String, std::path::PathBuf)> = match given {
        Some(p) => vec![(p.clone(), p.into())],
        None => [facecap_mesh::FACE_LANDMARKS_MODEL, facecap_mesh::FACE_DETECTOR_MODEL]
            .into_iter()
            .filter_map(|name| {
                let path = facecap_core::paths::model_file_or_skip("profile_models", name)?;
                Some((name.to_string(), path))
            })
            .collect(),
    };
    for (name, path) in paths {
        let it = Interpreter::from_file(&path)?;
        let mut ws = it.workspace();
        for (i, v) in it.input_mut(&mut ws, 0)?.iter_mut().enumerate() {
            *v = ((i * 7919) % 251) as f32 / 251.0;
        }
        let mut total: Vec<(&str, f64)> = Vec::new();
        for _ in 0..if run_only { 0 } else { reps } {
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
        if layers {
            let labels = it.step_labels();
            // Minimum over the repetitions: the least disturbed run of each step.
            let mut best = vec![f64::INFINITY; labels.len()];
            for _ in 0..reps {
                for (b, t) in best.iter_mut().zip(it.profile_steps(&mut ws)?) {
                    *b = b.min(t);
                }
            }
            for (i, ((label, macs), t)) in labels.iter().zip(&best).enumerate() {
                let rate = if *macs > 0 {
                    format!("{:6.2} M  {:5.1} GMAC/s", *macs as f64 * 1e-6, *macs as f64 / t * 1e-9)
                } else {
                    String::new()
                };
                println!("  {i:3} {:7.1} us  {label:<58} {rate}", t * 1e6);
            }
            println!("  sum of minima {:.3} ms", best.iter().sum::<f64>() * 1e3);
        }
    }
    Ok(())
}
