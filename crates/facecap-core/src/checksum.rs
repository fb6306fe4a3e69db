//! Model files checked against the checksums `scripts/setup.sh` recorded.
//!
//! `scripts/setup.sh` verifies every model it installs against a pinned sha256 and then
//! writes `SHA256SUMS` into the model folder (`<sha256>  <absolute path>` per line, the
//! `sha256sum` format). [`verify_model_file`] looks a model file up there by its file
//! name: when the file is the one setup installed, or a copy of it (same name, same
//! size), its sha256 must match, so a damaged or bit-flipped model is an error instead
//! of silently wrong landmarks. A file setup does not know (another name, or a model of
//! the same name but another size) is [`Checksum::Unknown`]: callers still run their
//! structural and plausibility checks on it.

use std::io::Read as _;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::error::{Error, Result};

/// Name of the checksum list in the model folder.
pub const SUMS_FILE: &str = "SHA256SUMS";

/// What [`verify_model_file`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Checksum {
    /// The file's sha256 equals the one setup recorded for it.
    Verified,
    /// Setup recorded nothing for this file (another model, or no `SHA256SUMS`).
    Unknown,
}

/// The lowercase hex sha256 of a file.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read.
pub fn sha256_file(path: &Path) -> Result<String> {
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Entries of a `SHA256SUMS` file: (sha256, path). Malformed lines are ignored.
fn read_sums(sums: &Path) -> Vec<(String, PathBuf)> {
    let Ok(text) = std::fs::read_to_string(sums) else {
        return Vec::new();
    };
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let (hash, path) = l.split_once("  ")?;
            (hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit()))
                .then(|| (hash.to_ascii_lowercase(), PathBuf::from(path)))
        })
        .collect()
}

/// Checks `path` against the `SHA256SUMS` of `models` (default: [`crate::paths::model_dir`]);
/// see the module docs for which files are checked.
///
/// # Errors
/// [`Error::Parse`] naming both checksums when they differ; [`Error::Io`] when the file
/// cannot be read.
pub fn verify_model_file(path: &Path, models: Option<&Path>) -> Result<Checksum> {
    let dir = match models {
        Some(d) => d.to_path_buf(),
        None => match crate::paths::model_dir() {
            Some(d) => d,
            None => return Ok(Checksum::Unknown),
        },
    };
    let sums = dir.join(SUMS_FILE);
    let Some(name) = path.file_name() else {
        return Ok(Checksum::Unknown);
    };
    let size = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
    let canonical = std::fs::canonicalize(path).ok();
    for (expected, listed) in read_sums(&sums) {
        if listed.file_name() != Some(name) {
            continue;
        }
        let same_file = canonical.is_some() && std::fs::canonicalize(&listed).ok() == canonical;
        let listed_size = std::fs::metadata(&listed).map(|m| m.len()).ok();
        // The installed file itself, or a copy of it (same name and size); a model of the
        // same name but another size is another model.
        if !(same_file || listed_size == Some(size)) {
            continue;
        }
        let got = sha256_file(path)?;
        if got != expected {
            return Err(Error::parse(
                "model",
                path,
                format!(
                    "sha256 {got} differs from {expected} recorded by scripts/setup.sh in {} \
                     (the file is damaged: run scripts/setup.sh again to reinstall it)",
                    sums.display()
                ),
            ));
        }
        return Ok(Checksum::Verified);
    }
    Ok(Checksum::Unknown)
}
