//! Batches of videos: the manifest, one stable output folder per row, shards, per-row
//! status files, the merged `batch_summary.csv`, and Slurm job-array scripts.
//!
//! The capture of each row is the ordinary capture (the CLI's `capture` path); this
//! module holds what is batch-specific and has no video in it, so it is tested without
//! any.
//!
//! **Manifest.** Either one video path per line, or a CSV whose first line is a header with
//! the columns
//! `video` (required), `rig`, `landmark_map`, `camera` (`fx,fy,cx,cy`, quoted, or
//! `fx fy cx cy`), `neutral` (`auto`, `none` or a frame index) and `id` (the output
//! folder's name). Empty cells take the batch's own settings. Lines starting with `#`
//! and blank lines are ignored; relative paths are relative to the manifest's folder.
//!
//! **Output folders.** Row `r` writes only into `OUT/<folder>/`, where `<folder>` is the
//! row's `id` or `<video stem>-<8 hex digits>`, the digits from the SHA-256 of the row's
//! video and settings as written in the manifest: unique per row, and the same on every
//! run however rows are added, removed or reordered.
//!
//! **Shards.** Shard `I/N` takes rows `I, I+N, I+2N, ...`; a row's folder, including its
//! status file [`STATUS_FILE`], is written only by the shard that owns the row, so shards
//! never write the same file. The merged [`SUMMARY_FILE`] is written by `--merge`, or by
//! the shard that completes the manifest, which first claims that merge with an
//! exclusively created file ([`claim_merge`]).

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use crate::error::{Error, Result};

/// The merged summary in the batch's output folder.
pub const SUMMARY_FILE: &str = "batch_summary.csv";
/// The columns of [`SUMMARY_FILE`].
pub const SUMMARY_COLUMNS: [&str; 7] = ["row", "video", "status", "frames", "faces", "seconds", "error"];
/// Each row's status, in its output folder.
pub const STATUS_FILE: &str = "batch_row.json";
/// The batch's own bookkeeping folder (merge claims, job scripts, Slurm logs).
pub const STATE_DIR: &str = ".batch";
/// Columns a manifest CSV may have.
pub const MANIFEST_COLUMNS: [&str; 6] = ["video", "rig", "landmark_map", "camera", "neutral", "id"];
/// Longest output folder name made from a video's stem.
const MAX_STEM_CHARS: usize = 64;

/// One manifest row.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// 0-based row index (data rows only, in file order).
    pub index: usize,
    /// 1-based line in the manifest.
    pub line: usize,
    /// The video as written in the manifest.
    pub video_text: String,
    /// The video's path (relative paths resolved against the manifest's folder).
    pub video: PathBuf,
    /// Per-row rig.
    pub rig: Option<PathBuf>,
    /// Per-row landmark map of the rig.
    pub landmark_map: Option<PathBuf>,
    /// Per-row camera `fx,fy,cx,cy`.
    pub camera: Option<String>,
    /// Per-row neutral (`auto`, `none` or a frame index).
    pub neutral: Option<String>,
    /// The output folder's name inside the batch's output folder.
    pub folder: String,
}

impl Row {
    /// The settings a row sets itself (for grouping rows that share one set-up).
    pub fn overrides(&self) -> (Option<&Path>, Option<&Path>, Option<&str>, Option<&str>) {
        (
            self.rig.as_deref(),
            self.landmark_map.as_deref(),
            self.camera.as_deref(),
            self.neutral.as_deref(),
        )
    }
}

/// A parsed manifest.
#[derive(Debug, Clone)]
pub struct Manifest {
    /// The manifest file.
    pub path: PathBuf,
    /// Its rows.
    pub rows: Vec<Row>,
}

impl Manifest {
    /// Reads and checks a manifest file (see the module docs).
    ///
    /// # Errors
    /// [`Error::Core`] when it cannot be read; [`Error::Manifest`] naming the line of
    /// the first problem (unknown column, bad camera or neutral, duplicate row or id, no
    /// rows).
    pub fn read(path: &Path) -> Result<Manifest> {
        let text = std::fs::read_to_string(path).map_err(|e| facecap_core::Error::io(path, e))?;
        let base = path.parent().unwrap_or(Path::new("")).to_path_buf();
        Self::parse(&text, path, &base)
    }

    /// Parses manifest text; `path` names it in errors, `base` resolves relative paths.
    ///
    /// # Errors
    /// As [`Manifest::read`].
    pub fn parse(text: &str, path: &Path, base: &Path) -> Result<Manifest> {
        let err = |line: usize, message: String| Error::Manifest {
            path: path.to_path_buf(),
            line,
            message,
        };
        let resolve = |s: &str| -> PathBuf {
            let p = PathBuf::from(s);
            if p.is_absolute() || base.as_os_str().is_empty() {
                p
            } else {
                base.join(p)
            }
        };
        let first = text
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty() && !l.starts_with('#'));
        let is_csv = first.is_some_and(|l| {
            l.split(',')
                .any(|f| f.trim().trim_matches('"').eq_ignore_ascii_case("video"))
        });
        // (line, video, rig, map, camera, neutral, id), all as written.
        type Raw = (usize, String, [Option<String>; 5]);
        let mut raw: Vec<Raw> = Vec::new();
        if is_csv {
            let mut reader = csv::ReaderBuilder::new()
                .has_headers(true)
                .comment(Some(b'#'))
                .trim(csv::Trim::All)
                .flexible(false)
                .from_reader(text.as_bytes());
            let header = reader.headers().map_err(|e| err(0, format!("header: {e}")))?.clone();
            let mut col = [None; 6];
            for (k, name) in header.iter().enumerate() {
                let Some(c) = MANIFEST_COLUMNS.iter().position(|m| m.eq_ignore_ascii_case(name)) else {
                    return Err(err(
                        1,
                        format!("unknown column {name:?} (columns: {})", MANIFEST_COLUMNS.join(", ")),
                    ));
                };
                if col[c].is_some() {
                    return Err(err(1, format!("column {name:?} given twice")));
                }
                col[c] = Some(k);
            }
            for record in reader.records() {
                let record = record.map_err(|e| {
                    let line = e.position().map_or(0, |p| p.line() as usize);
                    err(line, e.to_string())
                })?;
                let line = record.position().map_or(0, |p| p.line() as usize);
                let cell = |c: usize| -> Option<String> {
                    col[c]
                        .and_then(|k| record.get(k))
                        .filter(|s| !s.is_empty())
                        .map(str::to_string)
                };
                let Some(video) = cell(0) else {
                    return Err(err(line, "empty video".into()));
                };
                raw.push((line, video, [cell(1), cell(2), cell(3), cell(4), cell(5)]));
            }
        } else {
            for (k, l) in text.lines().enumerate() {
                let l = l.trim();
                if l.is_empty() || l.starts_with('#') {
                    continue;
                }
                raw.push((k + 1, l.to_string(), Default::default()));
            }
        }
        if raw.is_empty() {
            return Err(err(0, "no videos in the manifest".into()));
        }
        let mut rows = Vec::with_capacity(raw.len());
        let mut keys: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        let mut folders: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        for (index, (line, video, [rig, map, camera, neutral, id])) in raw.into_iter().enumerate() {
            let camera = camera
                .map(|c| normalise_camera(&c).map_err(|m| err(line, m)))
                .transpose()?;
            if let Some(n) = &neutral {
                if !(n == "auto" || n == "none" || n.parse::<u64>().is_ok()) {
                    return Err(err(
                        line,
                        format!("neutral {n:?}: expected auto, none or a frame index"),
                    ));
                }
            }
            let key = [
                Some(video.as_str()),
                rig.as_deref(),
                map.as_deref(),
                camera.as_deref(),
                neutral.as_deref(),
            ]
            .iter()
            .map(|s| s.unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\u{1f}");
            if let Some(first) = keys.insert(key.clone(), line) {
                return Err(err(
                    line,
                    format!("the same video and settings as line {first}; a row must differ from every other"),
                ));
            }
            let folder = match &id {
                Some(id) => {
                    let s = sanitise(id);
                    if s != *id {
                        return Err(err(
                            line,
                            format!("id {id:?}: use letters, digits, '.', '_' and '-' only (not starting with '.')"),
                        ));
                    }
                    s
                }
                None => {
                    let digest = Sha256::digest(key.as_bytes());
                    let stem = Path::new(&video)
                        .file_stem()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    format!("{}-{}", sanitise(&stem), crate::resume::hex(&digest[..4]))
                }
            };
            if let Some(first) = folders.insert(folder.clone(), line) {
                return Err(err(
                    line,
                    format!("output folder {folder:?} is also line {first}'s; give one of them another id"),
                ));
            }
            rows.push(Row {
                index,
                line,
                video: resolve(&video),
                video_text: video,
                rig: rig.as_deref().map(resolve),
                landmark_map: map.as_deref().map(resolve),
                camera,
                neutral,
                folder,
            });
        }
        Ok(Manifest {
            path: path.to_path_buf(),
            rows,
        })
    }
}

/// `fx,fy,cx,cy` or `fx fy cx cy` -> `fx,fy,cx,cy`, four finite numbers.
fn normalise_camera(s: &str) -> std::result::Result<String, String> {
    let parts: Vec<&str> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .collect();
    let ok = parts.len() == 4 && parts.iter().all(|p| p.parse::<f64>().is_ok_and(f64::is_finite));
    if ok {
        Ok(parts.join(","))
    } else {
        Err(format!("camera {s:?}: expected four numbers fx,fy,cx,cy"))
    }
}

/// A name safe as one path component: letters, digits, `.`, `_`, `-` (others become
/// `_`), no leading dot, at most 64 characters, never empty.
pub fn sanitise(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .take(MAX_STEM_CHARS)
        .collect();
    while s.starts_with('.') {
        s.replace_range(0..1, "_");
    }
    if s.is_empty() {
        s = "video".into();
    }
    s
}

/// Shard `index` of `count`: rows `index, index + count, ...`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// 0-based shard index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

impl Shard {
    /// The whole manifest in one shard.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Whether row `row` belongs to this shard.
    pub fn owns(&self, row: usize) -> bool {
        row % self.count == self.index
    }

    /// The shard of a Slurm job-array task: `SLURM_ARRAY_TASK_ID` (minus
    /// `SLURM_ARRAY_TASK_MIN` when set) of `SLURM_ARRAY_TASK_COUNT`; `None` outside an
    /// array.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when the variables are set but not a valid shard.
    pub fn from_slurm_env() -> Result<Option<Shard>> {
        let get = |k: &str| std::env::var(k).ok().filter(|v| !v.trim().is_empty());
        let (Some(id), Some(count)) = (get("SLURM_ARRAY_TASK_ID"), get("SLURM_ARRAY_TASK_COUNT")) else {
            return Ok(None);
        };
        let num = |name: &'static str, v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|_| Error::invalid(name, v, "a non-negative integer"))
        };
        let id = num("SLURM_ARRAY_TASK_ID", &id)?;
        let count = num("SLURM_ARRAY_TASK_COUNT", &count)?;
        let min = get("SLURM_ARRAY_TASK_MIN")
            .map(|m| num("SLURM_ARRAY_TASK_MIN", &m))
            .transpose()?
            .unwrap_or(0);
        let index = id
            .checked_sub(min)
            .ok_or_else(|| Error::invalid("SLURM_ARRAY_TASK_ID", id, format!(">= SLURM_ARRAY_TASK_MIN = {min}")))?;
        format!("{index}/{count}").parse().map(Some)
    }
}

impl FromStr for Shard {
    type Err = Error;
    fn from_str(s: &str) -> Result<Shard> {
        let bad = || Error::invalid("--shard", s, "I/N with 0 <= I < N, e.g. 0/4");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What happened to a row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowState {
    /// Being processed now (or its process died: see `host`/`pid`).
    Running,
    /// Captured by this run.
    Done,
    /// Finished earlier with the same input and settings; kept.
    Skipped,
    /// Failed (the error says why); the next run retries it.
    Failed,
    /// No status yet: its shard has not run.
    Missing,
}

impl RowState {
    /// The word in [`SUMMARY_FILE`].
    pub fn name(self) -> &'static str {
        match self {
            RowState::Running => "running",
            RowState::Done => "done",
            RowState::Skipped => "skipped",
            RowState::Failed => "failed",
            RowState::Missing => "missing",
        }
    }

    fn parse(s: &str) -> Option<RowState> {
        [
            RowState::Running,
            RowState::Done,
            RowState::Skipped,
            RowState::Failed,
            RowState::Missing,
        ]
        .into_iter()
        .find(|r| r.name() == s)
    }

    /// Finished (well or not) in its last run.
    pub fn is_final(self) -> bool {
        matches!(self, RowState::Done | RowState::Skipped | RowState::Failed)
    }

    /// Has its outputs.
    pub fn is_ok(self) -> bool {
        matches!(self, RowState::Done | RowState::Skipped)
    }
}

/// A row's status file ([`STATUS_FILE`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RowStatus {
    /// Row index.
    pub row: usize,
    /// The video as written in the manifest.
    pub video: String,
    /// What happened.
    pub state: RowState,
    /// Frames read.
    pub frames: Option<u64>,
    /// Frames with a face.
    pub faces: Option<u64>,
    /// Wall seconds of the capture (of the earlier run for a skipped row).
    pub seconds: Option<f64>,
    /// The error of a failed row.
    pub error: Option<String>,
    /// Peak resident memory of the process after this row, MiB (Linux `VmHWM`).
    pub peak_rss_mb: Option<f64>,
    /// Host, process and shard that wrote it, and when (Unix seconds).
    pub host: String,
    /// Process id.
    pub pid: u32,
    /// The shard.
    pub shard: String,
    /// The Slurm job array it ran in (`SLURM_ARRAY_JOB_ID`), if any.
    pub job: Option<String>,
    /// Unix time of writing.
    pub written_unix: f64,
}

impl RowStatus {
    /// A status of `row` written now by this process.
    pub fn new(row: &Row, state: RowState, shard: Shard) -> Self {
        RowStatus {
            row: row.index,
            video: row.video_text.clone(),
            state,
            frames: None,
            faces: None,
            seconds: None,
            error: None,
            peak_rss_mb: peak_rss_mb(),
            host: host_name(),
            pid: std::process::id(),
            shard: shard.to_string(),
            job: array_job_id(),
            written_unix: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
        }
    }

    /// As JSON.
    pub fn to_json(&self) -> Value {
        json!({
            "row": self.row, "video": self.video, "status": self.state.name(),
            "frames": self.frames, "faces": self.faces, "seconds": self.seconds,
            "error": self.error, "peak_rss_mb": self.peak_rss_mb, "host": self.host,
            "pid": self.pid, "shard": self.shard, "job": self.job, "written_unix": self.written_unix,
        })
    }

    /// From JSON; `None` when it is not a status.
    pub fn from_json(v: &Value) -> Option<RowStatus> {
        Some(RowStatus {
            row: v["row"].as_u64()? as usize,
            video: v["video"].as_str()?.to_string(),
            state: RowState::parse(v["status"].as_str()?)?,
            frames: v["frames"].as_u64(),
            faces: v["faces"].as_u64(),
            seconds: v["seconds"].as_f64(),
            error: v["error"].as_str().map(str::to_string),
            peak_rss_mb: v["peak_rss_mb"].as_f64(),
            host: v["host"].as_str().unwrap_or("").to_string(),
            pid: v["pid"].as_u64().unwrap_or(0) as u32,
            shard: v["shard"].as_str().unwrap_or("").to_string(),
            job: v["job"].as_str().map(str::to_string),
            written_unix: v["written_unix"].as_f64().unwrap_or(0.0),
        })
    }

    /// Writes it atomically into `OUT/<row folder>/`.
    ///
    /// # Errors
    /// [`Error::Core`] (I/O) when the folder cannot be written.
    pub fn write(&self, row_dir: &Path) -> Result<()> {
        std::fs::create_dir_all(row_dir).map_err(|e| facecap_core::Error::io(row_dir, e))?;
        let text = serde_json::to_string_pretty(&self.to_json()).unwrap_or_default();
        facecap_core::atomic::write_atomic(row_dir.join(STATUS_FILE), |w| w.write_all(text.as_bytes()))?;
        Ok(())
    }

    /// The status of `row` in `out_dir`, or a [`RowState::Missing`] one.
    pub fn read(out_dir: &Path, row: &Row) -> RowStatus {
        let path = out_dir.join(&row.folder).join(STATUS_FILE);
        let parsed = std::fs::read(&path)
            .ok()
            .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
            .and_then(|v| RowStatus::from_json(&v))
            .filter(|s| s.row == row.index && s.video == row.video_text);
        parsed.unwrap_or_else(|| RowStatus {
            state: RowState::Missing,
            error: Some("not run yet".into()),
            peak_rss_mb: None,
            host: String::new(),
            pid: 0,
            shard: String::new(),
            job: None,
            written_unix: 0.0,
            ..RowStatus::new(row, RowState::Missing, Shard::ALL)
        })
    }
}

/// Counts of a merged summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Rows captured by their last run.
    pub done: usize,
    /// Rows kept from an earlier run.
    pub skipped: usize,
    /// Rows that failed.
    pub failed: usize,
    /// Rows running or not run yet.
    pub pending: usize,
}

impl Counts {
    /// Every row has its outputs.
    pub fn all_ok(&self) -> bool {
        self.failed == 0 && self.pending == 0
    }
}

/// The statuses of every row of `manifest` in `out_dir`.
pub fn statuses(manifest: &Manifest, out_dir: &Path) -> Vec<RowStatus> {
    manifest.rows.iter().map(|r| RowStatus::read(out_dir, r)).collect()
}

/// Whether every row's last run finished (done, skipped or failed) and, inside a Slurm
/// job array, finished in this array job (so a task never takes the rows of a task still
/// queued, whose statuses are an earlier run's, for finished).
pub fn complete(statuses: &[RowStatus]) -> bool {
    let job = array_job_id();
    statuses
        .iter()
        .all(|s| s.state.is_final() && (job.is_none() || s.job == job))
}

/// `SLURM_ARRAY_JOB_ID`, when this process is a task of a Slurm job array.
pub fn array_job_id() -> Option<String> {
    std::env::var("SLURM_ARRAY_JOB_ID")
        .ok()
        .map(|v| v.trim().to_string())
        .filter(|v| !v.is_empty())
}

/// Writes [`SUMMARY_FILE`] (one line per manifest row, [`SUMMARY_COLUMNS`]) atomically
/// from the rows' status files.
///
/// # Errors
/// [`Error::Core`] (I/O) when it cannot be written.
pub fn write_summary(out_dir: &Path, statuses: &[RowStatus]) -> Result<Counts> {
    let mut counts = Counts::default();
    let mut w = csv::Writer::from_writer(Vec::new());
    let csv_err = |e: csv::Error| facecap_core::Error::io(out_dir.join(SUMMARY_FILE), std::io::Error::other(e));
    w.write_record(SUMMARY_COLUMNS).map_err(csv_err)?;
    for s in statuses {
        match s.state {
            RowState::Done => counts.done += 1,
            RowState::Skipped => counts.skipped += 1,
            RowState::Failed => counts.failed += 1,
            RowState::Running | RowState::Missing => counts.pending += 1,
        }
        let opt = |v: Option<u64>| v.map(|x| x.to_string()).unwrap_or_default();
        w.write_record([
            s.row.to_string(),
            s.video.clone(),
            s.state.name().to_string(),
            opt(s.frames),
            opt(s.faces),
            s.seconds.map(|x| format!("{x:.3}")).unwrap_or_default(),
            s.error.clone().unwrap_or_default().replace(['\n', '\r'], " "),
        ])
        .map_err(csv_err)?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| facecap_core::Error::io(out_dir.join(SUMMARY_FILE), std::io::Error::other(e.to_string())))?;
    facecap_core::atomic::write_atomic(out_dir.join(SUMMARY_FILE), |f| f.write_all(&bytes))?;
    Ok(counts)
}

/// Claims the merge of a complete set of statuses: creates
/// `OUT/.batch/merge-<digest>` exclusively, the digest over every row's status. Of
/// several shards that find the same complete set, exactly one gets `true`.
///
/// # Errors
/// [`Error::Core`] (I/O) when the claim cannot be created for another reason than that
/// it exists.
pub fn claim_merge(out_dir: &Path, statuses: &[RowStatus]) -> Result<bool> {
    let mut h = Sha256::new();
    for s in statuses {
        h.update(s.to_json().to_string().as_bytes());
        h.update([0]);
    }
    let dir = out_dir.join(STATE_DIR);
    std::fs::create_dir_all(&dir).map_err(|e| facecap_core::Error::io(&dir, e))?;
    let claim = dir.join(format!("merge-{}", crate::resume::hex(&h.finalize()[..8])));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&claim) {
        Ok(_) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e) => Err(facecap_core::Error::io(&claim, e).into()),
    }
}

/// Peak resident memory of this process in MiB (`VmHWM` of `/proc/self/status`), or
/// `None` where the platform does not say.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .or_else(|_| std::env::var("HOSTNAME"))
        .unwrap_or_default()
}

/// What a Slurm job array needs per task.
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmPlan {
    /// Array tasks (`--array=0-(tasks-1)`), one shard each.
    pub tasks: usize,
    /// `--cpus-per-task`.
    pub cpus_per_task: usize,
    /// `--mem` in MiB.
    pub mem_mb: u64,
    /// `--time` in minutes.
    pub time_minutes: u64,
    /// `--partition`, when given.
    pub partition: Option<String>,
    /// `--job-name`.
    pub job_name: String,
    /// Where Slurm writes each task's output.
    pub log_dir: PathBuf,
    /// The command each task runs; `--shard $SLURM_ARRAY_TASK_ID/<tasks>` follows it.
    pub command: Vec<String>,
    /// Arguments after the shard (e.g. `--` and capture's options).
    pub trailing: Vec<String>,
    /// Comment lines saying where the figures come from.
    pub notes: Vec<String>,
}

/// Memory headroom over the measured peak (`mem = peak * factor + margin`).
pub const MEM_FACTOR: f64 = 1.5;
/// Fixed memory margin, MiB.
pub const MEM_MARGIN_MB: f64 = 256.0;
/// Time limit = measured seconds per row x rows per task x this factor (+ margin).
pub const TIME_FACTOR: f64 = 3.0;
/// Shortest time limit, minutes.
pub const MIN_TIME_MINUTES: u64 = 10;

impl SlurmPlan {
    /// `--mem` (MiB, a multiple of 64) for a measured per-video peak.
    pub fn mem_for_peak(peak_mb: f64) -> u64 {
        let mb = peak_mb.max(0.0) * MEM_FACTOR + MEM_MARGIN_MB;
        ((mb / 64.0).ceil() as u64) * 64
    }

    /// `--time` (minutes) for `rows` rows of `rows_per_task` per task taking
    /// `seconds_per_row` each.
    pub fn time_for(rows_per_task: usize, seconds_per_row: f64) -> u64 {
        let minutes = (rows_per_task as f64 * seconds_per_row.max(0.0) * TIME_FACTOR / 60.0).ceil() as u64 + 5;
        minutes.max(MIN_TIME_MINUTES)
    }

    /// The `sbatch` script.
    pub fn script(&self) -> String {
        let mut s = String::from("#!/bin/bash\n");
        s.push_str(&format!("#SBATCH --job-name={}\n", self.job_name));
        s.push_str(&format!("#SBATCH --array=0-{}\n", self.tasks.saturating_sub(1)));
        s.push_str("#SBATCH --ntasks=1\n");
        s.push_str(&format!("#SBATCH --cpus-per-task={}\n", self.cpus_per_task));
        s.push_str(&format!("#SBATCH --mem={}M\n", self.mem_mb));
        s.push_str(&format!(
            "#SBATCH --time={}:{:02}:00\n",
            self.time_minutes / 60,
            self.time_minutes % 60
        ));
        if let Some(p) = &self.partition {
            s.push_str(&format!("#SBATCH --partition={p}\n"));
        }
        s.push_str(&format!(
            "#SBATCH --output={}\n",
            self.log_dir.join("slurm-%A_%a.out").display()
        ));
        for n in &self.notes {
            s.push_str(&format!("# {n}\n"));
        }
        s.push_str("set -u\n");
        let words = |v: &[String]| v.iter().map(|a| sh_quote(a)).collect::<Vec<_>>().join(" ");
        let trailing = if self.trailing.is_empty() {
            String::new()
        } else {
            format!(" {}", words(&self.trailing))
        };
        s.push_str(&format!(
            "exec {} --shard \"${{SLURM_ARRAY_TASK_ID}}/{}\"{trailing}\n",
            words(&self.command),
            self.tasks
        ));
        s
    }
}

/// One shell word: unchanged when it is plain, else in single quotes.
pub fn sh_quote(s: &str) -> String {
    let plain = !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "/._-+=:,@%".contains(c));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Manifest> {
        Manifest::parse(text, Path::new("/data/m.csv"), Path::new("/data"))
    }

    #[test]
    fn a_list_of_paths_is_a_manifest() {
        let m = parse("# my clips\na.mp4\n\n /abs/b.mp4 \nsub/a.mp4\nname, with comma.mp4\n").unwrap();
        assert_eq!(m.rows.len(), 4);
        assert_eq!(m.rows[0].video, PathBuf::from("/data/a.mp4"));
        assert_eq!(m.rows[1].video, PathBuf::from("/abs/b.mp4"));
        assert_eq!(m.rows[1].line, 4);
        assert_eq!(m.rows[3].video_text, "name, with comma.mp4");
        // Two clips with one stem get two folders.
        assert!(m.rows[0].folder.starts_with("a-") && m.rows[2].folder.starts_with("a-"));
        assert_ne!(m.rows[0].folder, m.rows[2].folder);
        assert!(
            m.rows[3].folder.starts_with("name__with_comma-"),
            "{}",
            m.rows[3].folder
        );
    }

    #[test]
    fn folders_are_stable_when_rows_move() {
        let a = parse("a.mp4\nb.mp4\nc.mp4\n").unwrap();
        let b = parse("new.mp4\nc.mp4\na.mp4\n").unwrap();
        assert_eq!(a.rows[0].folder, b.rows[2].folder);
        assert_eq!(a.rows[2].folder, b.rows[1].folder);
        for r in &a.rows {
            assert_eq!(r.folder.len(), 1 + 1 + 8, "{}", r.folder);
        }
    }

    #[test]
    fn csv_manifests_carry_per_row_settings() {
        let m = parse(
            "video,rig,landmark_map,camera,neutral\n\
             a.mp4,,,,\n\
             a.mp4,ict.glb,ict68.json,\"900,900,320,240\",12\n\
             b.mp4,,,800 800 320 240,none\n",
        )
        .unwrap();
        assert_eq!(m.rows.len(), 3);
        assert_eq!(m.rows[0].rig, None);
        assert_eq!(m.rows[1].rig, Some(PathBuf::from("/data/ict.glb")));
        assert_eq!(m.rows[1].camera.as_deref(), Some("900,900,320,240"));
        assert_eq!(m.rows[2].camera.as_deref(), Some("800,800,320,240"));
        assert_eq!(m.rows[1].neutral.as_deref(), Some("12"));
        assert_eq!(m.rows[2].line, 4);
        // The same clip with other settings is another row with another folder.
        assert_ne!(m.rows[0].folder, m.rows[1].folder);
        let ids = parse("id,video\nfirst,a.mp4\nsecond,b.mp4\n").unwrap();
        assert_eq!(ids.rows[1].folder, "second");
    }

    #[test]
    fn bad_manifests_name_the_line() {
        let cases = [
            ("video,colour\na.mp4,red\n", "unknown column"),
            ("video,camera\na.mp4,1 2 3\n", ":2: camera"),
            ("video,neutral\na.mp4,sometimes\n", ":2: neutral"),
            ("a.mp4\nb.mp4\na.mp4\n", ":3: the same video"),
            ("video,id\na.mp4,x\nb.mp4,x\n", ":3: output folder"),
            ("video,id\na.mp4,../up\n", ":2: id"),
            ("video,rig\na.mp4\n", "2"),
            ("# nothing\n\n", "no videos"),
        ];
        for (text, want) in cases {
            let e = parse(text)
                .err()
                .unwrap_or_else(|| panic!("{text:?} must fail"))
                .to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn shards_split_rows_without_overlap() {
        let s: Shard = "1/3".parse().unwrap();
        let rows: Vec<usize> = (0..10).filter(|r| s.owns(*r)).collect();
        assert_eq!(rows, vec![1, 4, 7]);
        for n in 1..6 {
            for r in 0..20 {
                let owners = (0..n).filter(|i| Shard { index: *i, count: n }.owns(r)).count();
                assert_eq!(owners, 1);
            }
        }
        for bad in ["3/3", "1", "a/2", "0/0", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn summary_and_claims() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        let m = parse("a.mp4\nb.mp4\nc.mp4\n").unwrap();
        let st = statuses(&m, out);
        assert!(st.iter().all(|s| s.state == RowState::Missing));
        assert!(!complete(&st));
        let mut a = RowStatus::new(&m.rows[0], RowState::Done, Shard::ALL);
        a.frames = Some(216);
        a.faces = Some(216);
        a.seconds = Some(12.5);
        a.write(&out.join(&m.rows[0].folder)).unwrap();
        let mut b = RowStatus::new(&m.rows[1], RowState::Failed, Shard::ALL);
        b.error = Some("broken.mp4: no frames decoded,\nreally".into());
        b.write(&out.join(&m.rows[1].folder)).unwrap();
        RowStatus::new(&m.rows[2], RowState::Skipped, Shard::ALL)
            .write(&out.join(&m.rows[2].folder))
            .unwrap();
        let st = statuses(&m, out);
        assert!(complete(&st));
        let counts = write_summary(out, &st).unwrap();
        assert_eq!(
            counts,
            Counts {
                done: 1,
                skipped: 1,
                failed: 1,
                pending: 0
            }
        );
        let text = std::fs::read_to_string(out.join(SUMMARY_FILE)).unwrap();
        let mut r = csv::Reader::from_reader(text.as_bytes());
        assert_eq!(r.headers().unwrap().iter().collect::<Vec<_>>(), SUMMARY_COLUMNS);
        let recs: Vec<csv::StringRecord> = r.records().map(|x| x.unwrap()).collect();
        assert_eq!(recs.len(), 3);
        assert_eq!(&recs[0][2], "done");
        assert_eq!(&recs[0][3], "216");
        assert_eq!(&recs[1][2], "failed");
        assert_eq!(&recs[1][6], "broken.mp4: no frames decoded, really");
        // One claim per complete set.
        assert!(claim_merge(out, &st).unwrap());
        assert!(!claim_merge(out, &st).unwrap());
        // A status of another manifest's row in that folder does not count.
        let other = parse("z.mp4\n").unwrap();
        let mut moved = other.rows[0].clone();
        moved.folder = m.rows[0].folder.clone();
        assert_eq!(RowStatus::read(out, &moved).state, RowState::Missing);
    }

    #[test]
    fn slurm_script_and_resources() {
        assert_eq!(SlurmPlan::mem_for_peak(400.0), 896);
        assert_eq!(SlurmPlan::time_for(1, 20.0), MIN_TIME_MINUTES);
        assert_eq!(SlurmPlan::time_for(10, 60.0), 35);
        let plan = SlurmPlan {
            tasks: 4,
            cpus_per_task: 2,
            mem_mb: 896,
            time_minutes: 95,
            partition: Some("short".into()),
            job_name: "facecap-batch".into(),
            log_dir: PathBuf::from("/out/.batch/logs"),
            command: vec![
                "/bin/facecap".into(),
                "batch".into(),
                "/m y/list.csv".into(),
                "--out".into(),
                "/out".into(),
            ],
            trailing: vec!["--".into(), "--solver".into(), "exact".into()],
            notes: vec!["memory: measured".into()],
        };
        let s = plan.script();
        for want in [
            "#!/bin/bash\n",
            "#SBATCH --array=0-3\n",
            "#SBATCH --cpus-per-task=2\n",
            "#SBATCH --mem=896M\n",
            "#SBATCH --time=1:35:00\n",
            "#SBATCH --partition=short\n",
            "#SBATCH --output=/out/.batch/logs/slurm-%A_%a.out\n",
            "exec /bin/facecap batch '/m y/list.csv' --out /out --shard \"${SLURM_ARRAY_TASK_ID}/4\" -- --solver exact\n",
        ] {
            assert!(s.contains(want), "missing {want:?} in\n{s}");
        }
        assert_eq!(sh_quote("it's"), r"'it'\''s'");
    }
}
