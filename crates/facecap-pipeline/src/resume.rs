//! Resuming work: whether a finished output folder still belongs to its input and
//! settings, and clearing a folder's old outputs before it is redone.
//!
//! A finished capture records a [`Stamp`] in its completion marker (`summary.json`,
//! under the key [`STAMP_KEY`]): the input's [`identity`] and the settings that change
//! the outputs. A rerun keeps the folder only when both are unchanged
//! ([`check`] gives [`Resume::Finished`]); otherwise the folder is redone, and
//! [`clear_outputs`] first removes everything the previous run wrote, so that no file of
//! the old run (a frame PNG of a longer contact sheet, the OBJs of an `--obj` run)
//! survives beside the new ones. `capture` and `batch` share this rule.
//!
//! **Input identity.** A file: its size, its modification time (nanoseconds since the
//! Unix epoch) and the SHA-256 of its first and last MiB ([`HEAD_TAIL_BYTES`]), so a
//! replaced file is noticed even when a copy kept its size and time, without reading a
//! long video whole. A folder of images: the number of entries and the SHA-256 of every
//! entry's name, size and modification time (in name order).
//!
//! ```
//! use facecap_pipeline::resume::{check, Resume, Stamp};
//! let dir = tempfile::tempdir().unwrap();
//! let video = dir.path().join("clip.y4m");
//! std::fs::write(&video, b"YUV4MPEG2 ...").unwrap();
//! let stamp = Stamp::new(&video, serde_json::json!({"solver": "exact3d"})).unwrap();
//! let out = dir.path().join("out");
//! std::fs::create_dir_all(&out).unwrap();
//! assert!(matches!(check(&out, &stamp), Resume::New));
//! let summary = serde_json::json!({"frames": 1, "resume": stamp.to_json()});
//! std::fs::write(out.join("summary.json"), summary.to_string()).unwrap();
//! assert!(matches!(check(&out, &stamp), Resume::Finished));
//! let other = Stamp::new(&video, serde_json::json!({"solver": "exact"})).unwrap();
//! assert!(matches!(check(&out, &other), Resume::Redo(_)));
//! ```

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::time::UNIX_EPOCH;

use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use crate::error::Result;

/// Bytes hashed at each end of an input file.
pub const HEAD_TAIL_BYTES: u64 = 1 << 20;

/// The key of the [`Stamp`] in a completion marker.
pub const STAMP_KEY: &str = "resume";

/// The completion marker of an output folder: written last, read by [`check`].
pub const MARKER: &str = "summary.json";

/// Top-level files of an output folder that a run writes and [`clear_outputs`] removes.
pub const OUTPUT_FILES: &[&str] = &[
    MARKER,
    "landmarks.csv",
    "pose.csv",
    "weights.csv",
    "openface.csv",
    "livelink.csv",
    "contractions.csv",
    "tensor.csv",
    "animation.glb",
    "report.html",
    "preview.mp4",
];

/// Sub-folders an output folder's run owns: every file directly inside them is removed
/// by [`clear_outputs`] (per-frame OBJs, contact-sheet images and plots), and the folder
/// itself when nothing else is left in it.
pub const OUTPUT_FOLDERS: &[&str] = &["obj", "report"];

/// What a run should do with an output folder.
#[derive(Debug, Clone, PartialEq)]
pub enum Resume {
    /// No finished output there: run.
    New,
    /// Finished with the same input and settings: keep it.
    Finished,
    /// Finished, but not for this input or these settings (the reason): redo it.
    Redo(String),
}

/// The input's identity and the output-changing settings of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamp {
    /// [`identity`] of the input.
    pub input: Value,
    /// The settings that change the outputs (any JSON; compared as a whole).
    pub settings: Value,
}

impl Stamp {
    /// The stamp of `input` (a file or a folder) under `settings`.
    ///
    /// # Errors
    /// [`crate::Error::Core`] (I/O, naming the path) when the input cannot be read.
    pub fn new(input: &Path, settings: Value) -> Result<Self> {
        Ok(Stamp {
            input: identity(input)?,
            settings,
        })
    }

    /// As stored in a completion marker under [`STAMP_KEY`].
    pub fn to_json(&self) -> Value {
        json!({"input": self.input, "settings": self.settings})
    }

    /// Why `stored` (a [`Stamp::to_json`]) is not this stamp, or `None` when it is.
    pub fn difference(&self, stored: &Value) -> Option<String> {
        let input = &stored["input"];
        if *input != self.input {
            let what = [
                "kind",
                "size",
                "mtime_ns",
                "sha256_head_tail",
                "entries",
                "sha256_entries",
            ]
            .iter()
            .filter(|k| input.get(**k) != self.input.get(**k))
            .copied()
            .collect::<Vec<_>>();
            return Some(if input.is_null() {
                "the finished output records no input identity".to_string()
            } else {
                format!("the input changed ({})", what.join(", "))
            });
        }
        let settings = &stored["settings"];
        if *settings != self.settings {
            return Some(match (settings.as_object(), self.settings.as_object()) {
                (Some(old), Some(new)) => {
                    let mut keys: Vec<&String> = old.keys().chain(new.keys()).collect();
                    keys.sort();
                    keys.dedup();
                    let changed: Vec<String> = keys
                        .into_iter()
                        .filter(|k| old.get(*k) != new.get(*k))
                        .map(|k| {
                            let show = |v: Option<&Value>| v.map_or("unset".to_string(), short);
                            format!("{k}: {} -> {}", show(old.get(k)), show(new.get(k)))
                        })
                        .collect();
                    format!("the settings changed ({})", changed.join("; "))
                }
                _ => "the settings changed".to_string(),
            });
        }
        None
    }
}

/// A setting's value for a message, cut to a readable length.
fn short(v: &Value) -> String {
    const MAX: usize = 60;
    let s = v.to_string();
    if s.chars().count() > MAX {
        format!("{}...", s.chars().take(MAX).collect::<String>())
    } else {
        s
    }
}

/// Whether the finished output in `out_dir` (its [`MARKER`]) was made from the same
/// input and settings as `stamp`.
///
/// A marker that cannot be read or parsed, or that has no stamp (an older version's),
/// means [`Resume::Redo`]: a rerun never keeps what it cannot vouch for.
pub fn check(out_dir: &Path, stamp: &Stamp) -> Resume {
    let marker = out_dir.join(MARKER);
    if !marker.is_file() {
        return Resume::New;
    }
    let stored = match std::fs::read(&marker)
        .map_err(|e| e.to_string())
        .and_then(|b| serde_json::from_slice::<Value>(&b).map_err(|e| e.to_string()))
    {
        Ok(v) => v,
        Err(e) => return Resume::Redo(format!("{} cannot be read ({e})", marker.display())),
    };
    match stamp.difference(&stored[STAMP_KEY]) {
        None => Resume::Finished,
        Some(why) => Resume::Redo(why),
    }
}

/// Removes what a previous run wrote into `out_dir`: the [`MARKER`] first (so an
/// interrupted clear never leaves a folder that looks finished), then the other
/// [`OUTPUT_FILES`] and every file directly inside the [`OUTPUT_FOLDERS`]. Other files
/// (the user's own, temporary files of running writers) are left alone.
///
/// # Errors
/// [`crate::Error::Core`] (I/O, naming the path) when a file exists but cannot be removed.
pub fn clear_outputs(out_dir: &Path) -> Result<()> {
    for name in OUTPUT_FILES {
        remove_if_present(&out_dir.join(name))?;
    }
    for folder in OUTPUT_FOLDERS {
        let dir = out_dir.join(folder);
        let entries = match std::fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(facecap_core::Error::io(&dir, e).into()),
        };
        for entry in entries {
            let entry = entry.map_err(|e| facecap_core::Error::io(&dir, e))?;
            let name = entry.file_name();
            // Temporary files of a writer still running belong to that writer.
            if name.to_string_lossy().starts_with('.') {
                continue;
            }
            let is_file = entry.file_type().map(|t| t.is_file()).unwrap_or(false);
            if is_file {
                remove_if_present(&entry.path())?;
            }
        }
        // An emptied folder goes too (it fails, harmlessly, while anything is left).
        let _ = std::fs::remove_dir(&dir);
    }
    Ok(())
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(facecap_core::Error::io(path, e).into()),
    }
}

/// Modification time in nanoseconds since the Unix epoch (0 when the platform has none).
fn mtime_ns(meta: &std::fs::Metadata) -> u128 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos())
}

/// The identity of an input file or folder (see the module docs), as JSON.
///
/// # Errors
/// [`crate::Error::Core`] (I/O, naming the path) when it cannot be read.
pub fn identity(path: &Path) -> Result<Value> {
    let io = |e| facecap_core::Error::io(path, e);
    let meta = std::fs::metadata(path).map_err(io)?;
    if meta.is_dir() {
        let mut entries: Vec<(String, u64, u128)> = Vec::new();
        for entry in std::fs::read_dir(path).map_err(io)? {
            let entry = entry.map_err(io)?;
            let m = entry.metadata().map_err(|e| facecap_core::Error::io(entry.path(), e))?;
            entries.push((entry.file_name().to_string_lossy().into_owned(), m.len(), mtime_ns(&m)));
        }
        entries.sort();
        let mut h = Sha256::new();
        for (name, size, t) in &entries {
            h.update(name.as_bytes());
            h.update([0]);
            h.update(size.to_le_bytes());
            h.update(t.to_le_bytes());
        }
        return Ok(json!({
            "kind": "folder",
            "entries": entries.len(),
            "sha256_entries": hex(&h.finalize()),
        }));
    }
    let size = meta.len();
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut h = Sha256::new();
    h.update(size.to_le_bytes());
    let mut buf = vec![0u8; HEAD_TAIL_BYTES.min(size) as usize];
    file.read_exact(&mut buf).map_err(io)?;
    h.update(&buf);
    if size > HEAD_TAIL_BYTES {
        // The last MiB (overlapping the first when the file is shorter than 2 MiB).
        let tail = HEAD_TAIL_BYTES.min(size);
        file.seek(SeekFrom::Start(size - tail)).map_err(io)?;
        buf.resize(tail as usize, 0);
        file.read_exact(&mut buf).map_err(io)?;
        h.update(&buf);
    }
    Ok(json!({
        "kind": "file",
        "size": size,
        // A string: nanoseconds overflow JSON's exact integers in some readers.
        "mtime_ns": mtime_ns(&meta).to_string(),
        "sha256_head_tail": hex(&h.finalize()),
    }))
}

/// The [`identity`] of an optional file the settings name (a rig, a model), or `null`.
/// A path that cannot be read is recorded as such (the run itself reports the error).
pub fn file_identity_or_null(path: Option<&Path>) -> Value {
    match path {
        None => Value::Null,
        Some(p) => identity(p).unwrap_or_else(|e| json!({"unreadable": e.to_string()})),
    }
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use std::time::{Duration, SystemTime};

    fn set_mtime(path: &Path, t: SystemTime) {
        std::fs::File::options()
            .write(true)
            .open(path)
            .unwrap()
            .set_modified(t)
            .unwrap();
    }

    #[test]
    fn a_replaced_file_of_the_same_size_and_time_is_noticed() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.mp4");
        // 3 MiB: the change sits in the last MiB, which is hashed.
        let mut bytes = vec![7u8; 3 << 20];
        std::fs::write(&p, &bytes).unwrap();
        let t = SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        set_mtime(&p, t);
        let a = identity(&p).unwrap();
        assert_eq!(a, identity(&p).unwrap(), "identity is deterministic");
        let n = bytes.len();
        bytes[n - 10] = 8;
        std::fs::write(&p, &bytes).unwrap();
        set_mtime(&p, t);
        let b = identity(&p).unwrap();
        assert_eq!(a["size"], b["size"]);
        assert_eq!(a["mtime_ns"], b["mtime_ns"]);
        assert_ne!(a["sha256_head_tail"], b["sha256_head_tail"]);
        // Only the time changes (a copy, a touch): also a different input.
        set_mtime(&p, t + Duration::from_secs(1));
        assert_ne!(b, identity(&p).unwrap());
    }

    #[test]
    fn short_files_and_folders_have_identities() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("small.y4m");
        std::fs::write(&p, b"abc").unwrap();
        let a = identity(&p).unwrap();
        assert_eq!(a["size"], 3);
        let folder = dir.path().join("frames");
        std::fs::create_dir(&folder).unwrap();
        std::fs::write(folder.join("frame_1.png"), b"x").unwrap();
        let f1 = identity(&folder).unwrap();
        assert_eq!(f1["kind"], "folder");
        assert_eq!(f1["entries"], 1);
        std::fs::write(folder.join("frame_2.png"), b"y").unwrap();
        assert_ne!(f1, identity(&folder).unwrap());
        assert!(identity(&dir.path().join("missing.mp4")).is_err());
    }

    #[test]
    fn check_says_why_a_folder_is_redone() {
        let dir = tempfile::tempdir().unwrap();
        let video = dir.path().join("clip.y4m");
        std::fs::write(&video, b"one").unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir(&out).unwrap();
        let settings = json!({"solver": "exact3d", "obj": null, "sheet_frames": 12});
        let stamp = Stamp::new(&video, settings).unwrap();
        assert_eq!(check(&out, &stamp), Resume::New);
        std::fs::write(out.join(MARKER), json!({STAMP_KEY: stamp.to_json()}).to_string()).unwrap();
        assert_eq!(check(&out, &stamp), Resume::Finished);
        let other = Stamp::new(&video, json!({"solver": "exact", "obj": "model", "sheet_frames": 12})).unwrap();
        let Resume::Redo(why) = check(&out, &other) else {
            panic!("other settings must redo")
        };
        assert!(
            why.contains("obj: null -> \"model\"") && why.contains("solver"),
            "{why}"
        );
        assert!(!why.contains("sheet_frames"), "{why}");
        std::fs::write(&video, b"two!").unwrap();
        let Resume::Redo(why) = check(&out, &Stamp::new(&video, stamp.settings.clone()).unwrap()) else {
            panic!("a replaced input must redo")
        };
        assert!(why.contains("input changed") && why.contains("size"), "{why}");
        // A marker of an older version (no stamp) or a damaged one: redo.
        std::fs::write(out.join(MARKER), b"{\"frames\": 3}").unwrap();
        assert!(matches!(check(&out, &stamp), Resume::Redo(_)));
        std::fs::write(out.join(MARKER), b"{\"fra").unwrap();
        assert!(matches!(check(&out, &stamp), Resume::Redo(_)));
    }

    #[test]
    fn clear_outputs_removes_the_previous_run_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        for f in OUTPUT_FILES {
            std::fs::write(out.join(f), b"old").unwrap();
        }
        std::fs::create_dir_all(out.join("report")).unwrap();
        std::fs::create_dir_all(out.join("obj")).unwrap();
        for k in 0..9 {
            std::fs::write(out.join("report").join(format!("frame_{k:06}.png")), b"png").unwrap();
            std::fs::write(out.join("obj").join(format!("frame_{k:06}.obj")), b"obj").unwrap();
        }
        std::fs::write(out.join("report").join(".frame_000001.png.tmp-1"), b"busy").unwrap();
        std::fs::write(out.join("notes.txt"), b"mine").unwrap();
        clear_outputs(out).unwrap();
        for f in OUTPUT_FILES {
            assert!(!out.join(f).exists(), "{f} left");
        }
        assert!(!out.join("obj").exists(), "an emptied folder is removed");
        let left: Vec<_> = std::fs::read_dir(out.join("report"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, vec![std::ffi::OsString::from(".frame_000001.png.tmp-1")]);
        assert!(out.join("notes.txt").is_file());
        clear_outputs(out).unwrap();
    }
}
