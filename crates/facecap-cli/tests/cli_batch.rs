#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Resuming and batches on small clips `facecap synth` makes: a rerun of `capture` keeps a
//! finished folder only for the same input and settings and clears the old outputs when it
//! redoes one; `batch` runs a manifest in two concurrent shards (one row broken), writes
//! every row's own folder (the same files as `capture`) and one merged `batch_summary.csv`,
//! skips finished rows and retries the failed one on the next run, and writes a Slurm
//! script sized from the measured rows. (The same on a real Slurm: scripts/test_slurm.sh.)

use std::path::{Path, PathBuf};
use std::process::Command;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn cache() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_CACHE") {
        return Some(p.into());
    }
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME") {
        return Some(PathBuf::from(x).join("facecap"));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache").join("facecap"))
}

/// The astronaut photo, when the models are there too.
fn inputs(test: &str) -> Option<PathBuf> {
    let c = cache()?;
    let models = std::env::var_os("FACECAP_MODELS").map_or(c.join("models"), PathBuf::from);
    let ok = models.join("shape_predictor_68_face_landmarks.dat").is_file()
        && models.join("dlib_frontal_face_detector.svm").is_file();
    let photo = c.join("data").join("astronaut.png");
    if ok && photo.is_file() {
        Some(photo)
    } else {
        facecap_core::paths::skip_missing_data(&format!(
            "{test}: astronaut.png or the dlib models not in the cache (run scripts/setup.sh)"
        ));
        None
    }
}

fn synth(photo: &Path, out: &Path, frames: u32, fps: u32) -> PathBuf {
    let st = facecap()
        .args([
            "--quiet",
            "synth",
            "--frames",
            &frames.to_string(),
            "--fps",
            &fps.to_string(),
        ])
        .arg("--photo")
        .arg(photo)
        .arg("--out")
        .arg(out)
        .status()
        .unwrap();
    assert!(st.success());
    out.join("synth.y4m")
}

fn capture(video: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let o = facecap()
        .args(["--quiet", "capture", "--json"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .arg(video)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn count(dir: &Path, prefix: &str, ext: &str) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| {
        d.filter_map(Result::ok)
            .filter(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                n.starts_with(prefix) && n.ends_with(ext)
            })
            .count()
    })
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn capture_redoes_a_video_only_for_another_input_or_other_settings() {
    let Some(photo) = inputs("capture_redoes_a_video_only_for_another_input_or_other_settings") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let video = synth(&photo, &dir.path().join("clip"), 8, 30);
    let out = dir.path().join("cap");
    let folder = out.join("synth");
    let status = |r: &serde_json::Value| r["videos"][0]["status"].as_str().unwrap().to_string();

    assert_eq!(status(&capture(&video, &out, &[])), "done");
    assert_eq!(count(&folder.join("report"), "frame_", ".png"), 8);
    assert_eq!(status(&capture(&video, &out, &[])), "skipped");
    // Other settings: redone, not skipped.
    assert_eq!(status(&capture(&video, &out, &["--obj"])), "done");
    assert_eq!(count(&folder.join("obj"), "frame_", ".obj"), 8);
    assert_eq!(json(&folder.join("summary.json"))["settings"]["obj"], "model");
    assert_eq!(status(&capture(&video, &out, &["--obj"])), "skipped");
    assert_eq!(status(&capture(&video, &out, &["--solver", "exact", "--obj"])), "done");
    assert_eq!(json(&folder.join("summary.json"))["settings"]["solver"], "exact");
    // --force with a smaller sheet and no --obj: nothing of the old runs is left.
    assert_eq!(
        status(&capture(&video, &out, &["--force", "--sheet-frames", "3"])),
        "done"
    );
    assert_eq!(count(&folder.join("report"), "frame_", ".png"), 3);
    assert!(!folder.join("obj").exists(), "stale OBJs left");
    let before = json(&folder.join("summary.json"));
    // The input replaced by another clip (another frame rate in its header) of the same
    // size and with the same modification time: redone, by the hash of its first MiB.
    let other = synth(&photo, &dir.path().join("other"), 8, 25);
    let meta = std::fs::metadata(&video).unwrap();
    assert_eq!(std::fs::metadata(&other).unwrap().len(), meta.len());
    assert_ne!(std::fs::read(&other).unwrap(), std::fs::read(&video).unwrap());
    std::fs::copy(&other, &video).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&video)
        .unwrap()
        .set_modified(meta.modified().unwrap())
        .unwrap();
    assert_eq!(status(&capture(&video, &out, &["--sheet-frames", "3"])), "done");
    let after = json(&folder.join("summary.json"));
    assert_eq!(after["fps"], 25.0);
    assert_eq!(
        before["resume"]["input"]["mtime_ns"],
        after["resume"]["input"]["mtime_ns"]
    );
    assert_ne!(
        before["resume"]["input"]["sha256_head_tail"],
        after["resume"]["input"]["sha256_head_tail"]
    );
    assert_eq!(status(&capture(&video, &out, &["--sheet-frames", "3"])), "skipped");
}

fn read_summary(out: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(out.join("batch_summary.csv")).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("row,video,status,frames,faces,seconds,error"));
    lines
        .map(|l| {
            // The error (last column) may be quoted and hold commas.
            let mut cells: Vec<String> = l.splitn(7, ',').map(str::to_string).collect();
            cells.resize(7, String::new());
            cells
        })
        .collect()
}

fn row_status(out: &Path, folder: &str) -> serde_json::Value {
    json(&out.join(folder).join("batch_row.json"))
}

#[test]
fn batch_runs_two_shards_merges_once_and_retries_the_failed_row() {
    let Some(photo) = inputs("batch_runs_two_shards_merges_once_and_retries_the_failed_row") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    synth(&photo, &dir.path().join("clips"), 8, 30);
    std::fs::write(dir.path().join("broken.mp4"), b"not a video").unwrap();
    let manifest = dir.path().join("videos.csv");
    // Rows 0 and 1: one clip with two settings (two folders); row 2: broken.
    std::fs::write(
        &manifest,
        "video,neutral,id\nclips/synth.y4m,,\nclips/synth.y4m,none,\nbroken.mp4,,bad\n",
    )
    .unwrap();
    let out = dir.path().join("runs");
    let batch = |extra: &[&str]| {
        let mut c = facecap();
        c.args(["--quiet", "batch"])
            .arg(&manifest)
            .arg("--out")
            .arg(&out)
            .args(extra);
        c
    };
    let shards: Vec<_> = ["0/2", "1/2"]
        .iter()
        .map(|s| batch(&["--shard", s, "--", "--sheet-frames", "2"]).spawn().unwrap())
        .collect();
    let codes: Vec<bool> = shards.into_iter().map(|mut c| c.wait().unwrap().success()).collect();
    assert_eq!(codes, vec![false, true], "shard 0 holds the broken row");

    let rows = read_summary(&out);
    assert_eq!(rows.len(), 3);
    assert_eq!(rows[0][..5], ["0", "clips/synth.y4m", "done", "8", "8"]);
    assert_eq!(rows[1][..5], ["1", "clips/synth.y4m", "done", "8", "8"]);
    assert_eq!(rows[2][..3], ["2", "broken.mp4", "failed"]);
    assert!(rows[2][6].contains("broken.mp4"), "{:?}", rows[2]);
    // Only the shard that completed the manifest merged it.
    assert_eq!(count(&out.join(".batch"), "merge-", ""), 1);
    // Every row in its own folder, written by its own shard.
    let folders: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.path().join("batch_row.json").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(folders.len(), 3, "{folders:?}");
    assert!(folders.contains(&"bad".to_string()));
    for f in &folders {
        let s = row_status(&out, f);
        let row = s["row"].as_u64().unwrap();
        assert_eq!(s["shard"], format!("{}/2", row % 2), "{f}");
        if row < 2 {
            let summary = json(&out.join(f).join("summary.json"));
            assert_eq!(summary["frames"], 8);
            assert_eq!(count(&out.join(f).join("report"), "frame_", ".png"), 2);
            let neutral = if row == 0 { "auto" } else { "none" };
            assert_eq!(summary["settings"]["neutral"], neutral, "{f}: the row's own setting");
            assert!(s["peak_rss_mb"].as_f64().unwrap() > 10.0);
        }
    }
    let failed_before = row_status(&out, "bad")["written_unix"].as_f64().unwrap();
    // A row is the ordinary capture: the same files, byte for byte.
    let alone = dir.path().join("alone");
    capture(
        &dir.path().join("clips").join("synth.y4m"),
        &alone,
        &["--sheet-frames", "2"],
    );
    let folder0 = folders.iter().find(|f| row_status(&out, f)["row"] == 0).unwrap();
    for f in [
        "landmarks.csv",
        "pose.csv",
        "weights.csv",
        "livelink.csv",
        "animation.glb",
    ] {
        assert_eq!(
            std::fs::read(out.join(folder0).join(f)).unwrap(),
            std::fs::read(alone.join("synth").join(f)).unwrap(),
            "{f} differs from capture's"
        );
    }

    // The next run: finished rows are kept, the failed one is tried again.
    let o = batch(&["--jobs", "2", "--", "--sheet-frames", "2"]).output().unwrap();
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("row 2") && stderr.contains("broken.mp4"), "{stderr}");
    let rows = read_summary(&out);
    let states: Vec<&str> = rows.iter().map(|r| r[2].as_str()).collect();
    assert_eq!(states, ["skipped", "skipped", "failed"]);
    assert!(row_status(&out, "bad")["written_unix"].as_f64().unwrap() > failed_before);
    // Other capture settings redo the rows.
    let o = batch(&["--shard", "1/2", "--", "--sheet-frames", "3"])
        .output()
        .unwrap();
    assert!(o.status.success());
    let folder1 = folders.iter().find(|f| row_status(&out, f)["row"] == 1).unwrap();
    assert_eq!(row_status(&out, folder1)["status"], "done");
    assert_eq!(count(&out.join(folder1).join("report"), "frame_", ".png"), 3);

    // --merge alone.
    let o = batch(&["--merge"]).output().unwrap();
    assert!(!o.status.success(), "a failed row makes --merge exit non-zero");
    let states: Vec<String> = read_summary(&out).into_iter().map(|r| r[2].clone()).collect();
    assert_eq!(states, ["skipped", "done", "failed"]);

    // The Slurm script, sized from the measured rows.
    let o = batch(&["--slurm", "--cpus-per-task", "2"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let script = std::fs::read_to_string(out.join("batch.sbatch")).unwrap();
    let peak = folders
        .iter()
        .filter_map(|f| row_status(&out, f)["peak_rss_mb"].as_f64().filter(|_| f != "bad"))
        .fold(0.0f64, f64::max);
    let mem = ((peak * 1.5 + 256.0) / 64.0).ceil() as u64 * 64;
    for want in [
        "#SBATCH --array=0-2\n".to_string(),
        "#SBATCH --cpus-per-task=2\n".to_string(),
        format!("#SBATCH --mem={mem}M\n"),
        "#SBATCH --time=0:10:00\n".to_string(),
        "# memory: measured per-video peak".to_string(),
        "--shard \"${SLURM_ARRAY_TASK_ID}/3\"".to_string(),
    ] {
        assert!(script.contains(&want), "no {want:?} in\n{script}");
    }

    // Bad manifests and misplaced options are refused before anything runs.
    std::fs::write(&manifest, "video,camera\nclips/synth.y4m,1 2 3\n").unwrap();
    let o = batch(&[]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("videos.csv:2: camera"));
    let o = batch(&["--", "--out", "elsewhere"]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("--out is an option of batch itself"));
    let o = batch(&["--", "--solver", "nonsense"]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("capture options after --"));
}
