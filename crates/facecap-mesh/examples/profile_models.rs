//! Per-operator time of the two models (needs the model cache):
//!
//!     cargo run --release -p facecap-mesh --example profile_models
use facecap_mesh::tflite::Interpreter;

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
        let reps = 20;
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
        for _ in 0..reps {
            it.run(&mut ws)?;
        }
        let run = t0.elapsed().as_secs_f64() / reps as f64;
        println!("{name}: run {:.3} ms", run * 1e3);
        for (n, t) in total {
            println!("  {n:<20} {:.3} ms", t / reps as f64 * 1e3);
        }
    }
    Ok(())
}
