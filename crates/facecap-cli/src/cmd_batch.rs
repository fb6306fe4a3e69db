//! `facecap batch MANIFEST --out DIR [-- CAPTURE OPTIONS]`: the videos of a manifest,
//! each captured exactly as `facecap capture` does (the same set-up, skip rule and
//! outputs) into its own stable folder, in shards for Slurm job arrays, with a merged
//! `batch_summary.csv`. The batch logic (manifest, folders, shards, statuses, summary,
//! job script) is `facecap_pipeline::batch`; see docs/batch.md.

use std::collections::BTreeMap;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use clap::Parser;
use facecap_pipeline::batch::{self, Manifest, Row, RowState, RowStatus, Shard, SlurmPlan};
use rayon::prelude::*;

use crate::cmd_capture::{self, Outcome};

/// Per-video peak memory assumed for `--slurm` when no row could be measured, MiB
/// (the measured peak of the largest shared clip, docs/batch.md, with room to spare).
const FALLBACK_PEAK_MB: f64 = 1024.0;
/// Seconds per video assumed for `--slurm` when no row could be measured.
const FALLBACK_ROW_SECONDS: f64 = 3600.0;
/// Most tasks of one job array by default (Slurm's default `MaxArraySize` is 1001).
const DEFAULT_MAX_TASKS: usize = 1000;

/// Arguments of `facecap batch`.
#[derive(Debug, Clone, clap::Args)]
#[command(after_help = "Examples:\n  \
    facecap batch videos.csv --out runs/ -- --solver exact3d --obj\n  \
    facecap batch videos.txt --out runs/ --shard 0/2 & facecap batch videos.txt --out runs/ --shard 1/2\n  \
    facecap batch videos.csv --out runs/ --merge\n  \
    facecap batch videos.csv --out runs/ --slurm --submit --wait\n\
    The options after -- are capture's (same names and defaults); a manifest column overrides them per row.")]
pub struct Args {
    /// The videos: one path per line, or a CSV with the columns video, rig, landmark_map,
    /// camera, neutral, id (docs/batch.md).
    pub manifest: PathBuf,
    /// Output folder: each row gets `DIR/<id or video stem-hash>/`, and `DIR/batch_summary.csv`.
    #[arg(long)]
    pub out: PathBuf,
    /// Take rows I, I+N, I+2N, ... (0 <= I < N). Default: `SLURM_ARRAY_TASK_ID` /
    /// `SLURM_ARRAY_TASK_COUNT` inside a Slurm job array, else every row.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<Shard>,
    /// Only write the merged `batch_summary.csv` from the rows' status files.
    #[arg(long, conflicts_with_all = ["shard", "slurm"])]
    pub merge: bool,
    /// Rows processed at once in this process (default: number of cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Redo rows that are finished with the same input and settings.
    #[arg(long)]
    pub force: bool,
    /// Write a Slurm job-array script (`DIR/batch.sbatch`) instead of running the rows;
    /// memory and time come from a measured row (row 0 is captured first when no row is).
    #[arg(long)]
    pub slurm: bool,
    /// Submit the script with `sbatch`.
    #[arg(long, requires = "slurm")]
    pub submit: bool,
    /// Wait for the job array to end (`sbatch --wait`), then write and print the summary.
    #[arg(long, requires = "submit")]
    pub wait: bool,
    /// Array tasks (shards). Default: one per row, at most 1000.
    #[arg(long, requires = "slurm")]
    pub tasks: Option<usize>,
    /// `--cpus-per-task` of each array task.
    #[arg(long, requires = "slurm", default_value_t = 1)]
    pub cpus_per_task: usize,
    /// `--mem` per task in MiB (default: from the measured per-video peak).
    #[arg(long, requires = "slurm", value_name = "MIB")]
    pub mem: Option<u64>,
    /// `--time` per task in minutes (default: from the measured seconds per video).
    #[arg(long, requires = "slurm", value_name = "MINUTES")]
    pub time: Option<u64>,
    /// Slurm partition.
    #[arg(long, requires = "slurm")]
    pub partition: Option<String>,
    /// `facecap capture` options for every row (after `--`).
    #[arg(last = true, value_name = "CAPTURE OPTIONS")]
    pub capture: Vec<String>,
}

/// capture's arguments, parsed on their own.
#[derive(Debug, Parser)]
#[command(name = "facecap capture")]
struct CaptureCli {
    #[command(flatten)]
    args: cmd_capture::Args,
}

/// Runs `facecap batch`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    for a in &args.capture {
        for own in ["--out", "--jobs", "--json"] {
            if a == own || a.starts_with(&format!("{own}=")) {
                anyhow::bail!("{own} is an option of batch itself: give it before --, not among capture's options");
            }
        }
    }
    // Every capture option is checked once before any row runs.
    capture_args(&args, None)?;
    let manifest = Manifest::read(&args.manifest)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    if args.merge {
        return merge(&manifest, &args.out);
    }
    if args.slurm {
        return slurm(&args, &manifest);
    }
    let shard = match args.shard {
        Some(s) => s,
        None => Shard::from_slurm_env()?.unwrap_or(Shard::ALL),
    };
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    }
    let rows: Vec<&Row> = manifest.rows.iter().filter(|r| shard.owns(r.index)).collect();
    crate::out::info(&format!(
        "batch {}: shard {shard}: {} of {} rows",
        manifest.path.display(),
        rows.len(),
        manifest.rows.len()
    ));
    let results = run_rows(&args, &rows, shard, &interrupted);
    let mut failed = 0;
    for s in &results {
        match s.state {
            RowState::Failed => {
                failed += 1;
                eprintln!(
                    "error: row {} ({}): {}",
                    s.row,
                    s.video,
                    s.error.as_deref().unwrap_or("failed")
                );
            }
            state => crate::out::info(&format!(
                "row {} ({}): {}, {} frames, face on {}",
                s.row,
                s.video,
                state.name(),
                s.frames.unwrap_or(0),
                s.faces.unwrap_or(0)
            )),
        }
    }
    if interrupted.load(Ordering::SeqCst) {
        eprintln!("interrupted: unfinished rows keep no outputs and run again next time");
        return Ok(std::process::ExitCode::from(130));
    }
    // The merged summary: always for the whole manifest in one process; in a shard, by
    // the shard that finds every row finished and wins the claim.
    let statuses = batch::statuses(&manifest, &args.out);
    let summary = args.out.join(batch::SUMMARY_FILE);
    if shard == Shard::ALL || (batch::complete(&statuses) && batch::claim_merge(&args.out, &statuses)?) {
        let c = batch::write_summary(&args.out, &statuses)?;
        crate::out::info(&format!(
            "{}: {} done, {} skipped (finished earlier), {} failed, {} not finished",
            summary.display(),
            c.done,
            c.skipped,
            c.failed,
            c.pending
        ));
        list_failed(&statuses);
    } else {
        let pending = statuses.iter().filter(|s| !s.state.is_final()).count();
        crate::out::info(&format!(
            "shard {shard} finished; {pending} row(s) of other shards not finished: the last shard (or `facecap batch {} --out {} --merge`) writes {}",
            args.manifest.display(),
            args.out.display(),
            summary.display()
        ));
    }
    Ok(if failed == 0 {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    })
}

/// Prints the failed rows (they run again with the next run).
fn list_failed(statuses: &[RowStatus]) {
    let failed: Vec<&RowStatus> = statuses.iter().filter(|s| s.state == RowState::Failed).collect();
    if !failed.is_empty() {
        let list: Vec<String> = failed.iter().map(|s| format!("{} ({})", s.row, s.video)).collect();
        eprintln!(
            "failed rows, retried by the next run (errors in {}): {}",
            batch::SUMMARY_FILE,
            list.join(", ")
        );
    }
}

/// `--merge`.
fn merge(manifest: &Manifest, out: &Path) -> anyhow::Result<std::process::ExitCode> {
    let statuses = batch::statuses(manifest, out);
    let c = batch::write_summary(out, &statuses)?;
    crate::out::println(&format!(
        "{}: {} rows: {} done, {} skipped (finished earlier), {} failed, {} not finished",
        out.join(batch::SUMMARY_FILE).display(),
        statuses.len(),
        c.done,
        c.skipped,
        c.failed,
        c.pending
    ));
    list_failed(&statuses);
    Ok(if c.all_ok() {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    })
}

/// capture's arguments for the batch's options and a row's own settings.
fn capture_args(args: &Args, row: Option<&Row>) -> anyhow::Result<cmd_capture::Args> {
    let mut argv: Vec<std::ffi::OsString> = vec!["capture".into(), "--out".into(), args.out.clone().into()];
    argv.extend(args.capture.iter().map(Into::into));
    // capture needs a video to parse; the rows give the real ones.
    argv.push("--".into());
    argv.push(args.manifest.clone().into());
    let mut a = CaptureCli::try_parse_from(argv)
        .map_err(|e| anyhow::anyhow!("capture options after --: {}", e.to_string().trim()))?
        .args;
    a.force |= args.force;
    if let Some(r) = row {
        if let Some(rig) = &r.rig {
            a.solve.rig = Some(rig.clone());
        }
        if let Some(map) = &r.landmark_map {
            a.solve.landmark_map = Some(map.clone());
        }
        if let Some(c) = &r.camera {
            a.solve.camera = Some(c.clone());
        }
        if let Some(n) = &r.neutral {
            a.neutral = n.clone();
        }
    }
    Ok(a)
}

/// Captures `rows` (grouped by their own settings, one set-up per group), writing each
/// row's status; a failing row, even a panicking one, is recorded and the others go on.
fn run_rows(args: &Args, rows: &[&Row], shard: Shard, interrupted: &AtomicBool) -> Vec<RowStatus> {
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .clamp(1, rows.len().max(1));
    let pool = match rayon::ThreadPoolBuilder::new().num_threads(jobs).build() {
        Ok(p) => p,
        Err(e) => {
            return rows
                .iter()
                .map(|r| failed(args, r, shard, format!("thread pool: {e}")))
                .collect()
        }
    };
    let progress = crate::progress::Progress::new(crate::out::quiet());
    let mut groups: BTreeMap<String, Vec<&Row>> = BTreeMap::new();
    for r in rows {
        groups.entry(format!("{:?}", r.overrides())).or_default().push(r);
    }
    let mut results = Vec::with_capacity(rows.len());
    for group in groups.values() {
        if interrupted.load(Ordering::SeqCst) {
            break;
        }
        let setup = capture_args(args, Some(group[0])).and_then(|a| {
            let s = cmd_capture::build_setup(&a)?;
            Ok((a, s))
        });
        let (cargs, setup) = match setup {
            Ok(x) => x,
            Err(e) => {
                let msg = crate::error_text(&e);
                results.extend(group.iter().map(|r| failed(args, r, shard, msg.clone())));
                continue;
            }
        };
        let done: Vec<Option<RowStatus>> = pool.install(|| {
            group
                .par_iter()
                .map(|row| {
                    if interrupted.load(Ordering::SeqCst) {
                        return None;
                    }
                    let dir = args.out.join(&row.folder);
                    let _ = RowStatus::new(row, RowState::Running, shard).write(&dir);
                    let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
                        cmd_capture::capture_video(&row.video, &dir, &cargs, &setup, interrupted, &progress)
                    }))
                    .unwrap_or_else(|_| Outcome::Failed("internal error (panic) while capturing this video".into()));
                    let status = row_status(row, shard, &dir, outcome);
                    if let Err(e) = status.write(&dir) {
                        eprintln!("error: row {}: writing its status: {e}", row.index);
                    }
                    Some(status)
                })
                .collect()
        });
        results.extend(done.into_iter().flatten());
    }
    results.sort_by_key(|s| s.row);
    results
}

fn failed(args: &Args, row: &Row, shard: Shard, error: String) -> RowStatus {
    let mut s = RowStatus::new(row, RowState::Failed, shard);
    s.error = Some(error);
    let _ = s.write(&args.out.join(&row.folder));
    s
}

/// A row's status from its capture's outcome.
fn row_status(row: &Row, shard: Shard, dir: &Path, outcome: Outcome) -> RowStatus {
    let from_summary = |s: &mut RowStatus, v: &serde_json::Value| {
        s.frames = v["frames"].as_u64();
        s.faces = v["faces_found"].as_u64();
        s.seconds = v["seconds"].as_f64();
    };
    match outcome {
        Outcome::Done(v) => {
            let mut s = RowStatus::new(row, RowState::Done, shard);
            from_summary(&mut s, &v);
            s
        }
        Outcome::Skipped(_) => {
            let mut s = RowStatus::new(row, RowState::Skipped, shard);
            let summary = std::fs::read(dir.join(facecap_pipeline::resume::MARKER))
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
            if let Some(v) = summary {
                from_summary(&mut s, &v);
            }
            // Keep the measured peak of the run that made the outputs.
            let before = std::fs::read(dir.join(batch::STATUS_FILE))
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
                .and_then(|v| RowStatus::from_json(&v));
            if let Some(b) = before.filter(|b| b.state.is_ok()) {
                s.peak_rss_mb = b.peak_rss_mb;
            }
            s
        }
        Outcome::Failed(e) => {
            let mut s = RowStatus::new(row, RowState::Failed, shard);
            s.error = Some(e);
            s
        }
    }
}

/// `--slurm`: measure (if needed), write the job script, submit and wait.
fn slurm(args: &Args, manifest: &Manifest) -> anyhow::Result<std::process::ExitCode> {
    let out = std::fs::canonicalize(&args.out).with_context(|| format!("resolving {}", args.out.display()))?;
    let manifest_path = std::fs::canonicalize(&manifest.path)?;
    let measured = |st: &[RowStatus]| -> (Option<f64>, Option<f64>) {
        let done = st.iter().filter(|s| s.state.is_ok());
        let peak = done.clone().filter_map(|s| s.peak_rss_mb).reduce(f64::max);
        let secs = done.filter_map(|s| s.seconds).reduce(f64::max);
        (peak, secs)
    };
    let mut statuses = batch::statuses(manifest, &args.out);
    if measured(&statuses).0.is_none() && (args.mem.is_none() || args.time.is_none()) {
        let first = &manifest.rows[0];
        crate::out::info(&format!(
            "measuring memory and time on row 0 ({}) first; its outputs are kept",
            first.video_text
        ));
        let never = AtomicBool::new(false);
        let local = Args {
            jobs: Some(1),
            ..args.clone()
        };
        run_rows(&local, &[first], Shard::ALL, &never);
        statuses = batch::statuses(manifest, &args.out);
    }
    let (peak, secs) = measured(&statuses);
    let rows = manifest.rows.len();
    let tasks = args.tasks.unwrap_or(rows.min(DEFAULT_MAX_TASKS)).clamp(1, rows);
    let per_task = rows.div_ceil(tasks);
    let mut notes = vec![format!(
        "Written by `facecap batch --slurm`: {rows} rows of {} in {tasks} tasks ({per_task} row(s) per task at most).",
        manifest_path.display()
    )];
    let mem_mb = match (args.mem, peak) {
        (Some(m), _) => {
            notes.push("memory: --mem".into());
            m
        }
        (None, Some(p)) => {
            notes.push(format!(
                "memory: measured per-video peak {p:.0} MiB x {} + {} MiB",
                batch::MEM_FACTOR,
                batch::MEM_MARGIN_MB
            ));
            SlurmPlan::mem_for_peak(p)
        }
        (None, None) => {
            crate::out::info("warning: no row could be measured; memory and time limits are generous guesses");
            notes.push(format!("memory: no row measured, assumed peak {FALLBACK_PEAK_MB} MiB"));
            SlurmPlan::mem_for_peak(FALLBACK_PEAK_MB)
        }
    };
    let time_minutes = match (args.time, secs) {
        (Some(t), _) => {
            notes.push("time: --time".into());
            t
        }
        (None, Some(s)) => {
            notes.push(format!(
                "time: measured {s:.1} s per video x {per_task} x {} + 5 min (at least {} min)",
                batch::TIME_FACTOR,
                batch::MIN_TIME_MINUTES
            ));
            SlurmPlan::time_for(per_task, s)
        }
        (None, None) => {
            notes.push(format!(
                "time: no row measured, assumed {FALLBACK_ROW_SECONDS} s per video"
            ));
            SlurmPlan::time_for(per_task, FALLBACK_ROW_SECONDS)
        }
    };
    let log_dir = out.join(batch::STATE_DIR).join("logs");
    std::fs::create_dir_all(&log_dir).with_context(|| format!("creating {}", log_dir.display()))?;
    let exe = std::env::current_exe().context("the facecap executable's path")?;
    let mut command = vec![
        exe.display().to_string(),
        "batch".into(),
        manifest_path.display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--jobs".into(),
        "1".into(),
    ];
    if crate::out::quiet() {
        command.insert(1, "--quiet".into());
    }
    let mut trailing = Vec::new();
    if !args.capture.is_empty() {
        trailing.push("--".to_string());
        trailing.extend(args.capture.iter().cloned());
    }
    let plan = SlurmPlan {
        tasks,
        cpus_per_task: args.cpus_per_task.max(1),
        mem_mb,
        time_minutes,
        partition: args.partition.clone(),
        job_name: "facecap-batch".into(),
        log_dir,
        command,
        trailing,
        notes,
    };
    let script = out.join("batch.sbatch");
    let text = plan.script();
    facecap_core::atomic::write_atomic(&script, |w| w.write_all(text.as_bytes()))?;
    crate::out::println(&format!(
        "{}: {tasks} tasks, {} cpu(s), {mem_mb} MiB, {} min each",
        script.display(),
        plan.cpus_per_task,
        time_minutes
    ));
    if !args.submit {
        crate::out::info(&format!("submit it with: sbatch {}", script.display()));
        return Ok(std::process::ExitCode::SUCCESS);
    }
    let mut cmd = std::process::Command::new("sbatch");
    cmd.arg("--parsable");
    if args.wait {
        cmd.arg("--wait");
    }
    cmd.arg(&script).stdin(std::process::Stdio::null());
    if args.wait {
        crate::out::info("submitted; waiting for the job array to end (sbatch --wait)");
    }
    let output = cmd
        .output()
        .context("running sbatch (is Slurm installed and on PATH?)")?;
    let job = String::from_utf8_lossy(&output.stdout).trim().to_string();
    if !args.wait {
        if !output.status.success() {
            anyhow::bail!("sbatch failed: {}", String::from_utf8_lossy(&output.stderr).trim());
        }
        crate::out::println(&format!("submitted job {job}"));
        return Ok(std::process::ExitCode::SUCCESS);
    }
    if job.is_empty() {
        anyhow::bail!("sbatch failed: {}", String::from_utf8_lossy(&output.stderr).trim());
    }
    crate::out::println(&format!(
        "job {job} ended ({})",
        if output.status.success() {
            "every task succeeded".to_string()
        } else {
            format!("some task failed: sbatch exit {}", output.status.code().unwrap_or(-1))
        }
    ));
    merge(manifest, &args.out)
}
