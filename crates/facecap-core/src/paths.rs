//! Where facecap finds its model cache and the shared test data.
//!
//! | variable | meaning | default |
//! |---|---|---|
//! | `FACECAP_MODELS` | folder with model files fetched by `scripts/setup.sh` | `$FACECAP_CACHE/models` |
//! | `FACECAP_CACHE` | facecap's cache root | `$XDG_CACHE_HOME/facecap`, else `$HOME/.cache/facecap` |
//! | `FACECAP_DATA` | shared research data (videos, annotations, 3D models) | `<workspace>/../shared/data` |

use std::path::PathBuf;

/// The cache root (see module docs). `None` only when no home directory is known.
pub fn cache_dir() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_CACHE") {
        return Some(PathBuf::from(p));
    }
    if let Some(p) = std::env::var_os("XDG_CACHE_HOME") {
        return Some(PathBuf::from(p).join("facecap"));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache").join("facecap"))
}

/// The model folder (see module docs).
pub fn model_dir() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_MODELS") {
        return Some(PathBuf::from(p));
    }
    cache_dir().map(|c| c.join("models"))
}

/// Path of a named model file in the model folder, if it exists.
pub fn model_file(name: &str) -> Option<PathBuf> {
    model_dir().map(|d| d.join(name)).filter(|p| p.is_file())
}

/// File name of dlib's 68-point shape predictor in the model folder.
pub const DLIB_68_MODEL: &str = "shape_predictor_68_face_landmarks.dat";
/// File name of dlib's 5-point shape predictor in the model folder.
pub const DLIB_5_MODEL: &str = "shape_predictor_5_face_landmarks.dat";

/// The shared data folder: `$FACECAP_DATA`, else `../shared/data` next to the
/// workspace root. `None` when it does not exist (tests then print a skip line).
pub fn shared_data_dir() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_DATA") {
        let p = PathBuf::from(p);
        return p.is_dir().then_some(p);
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    root.is_dir().then_some(root)
}

/// Environment variable naming a file every [`skip`] line is appended to
/// (`scripts/test.sh` sets it and counts the lines: the test harness hides what passing
/// tests print, so `SKIP:` lines on stderr alone are never seen).
pub const SKIP_LOG_ENV: &str = "FACECAP_SKIP_LOG";

/// Reports that a test (or part of one) did not run: prints `SKIP: <what>` on stderr
/// and appends it to the file named by [`SKIP_LOG_ENV`]. For an optional tool (e.g.
/// Blender); missing data and models go through [`skip_missing_data`].
pub fn skip(what: &str) {
    let line = format!("SKIP: {what}");
    eprintln!("{line}");
    if let Some(log) = std::env::var_os(SKIP_LOG_ENV) {
        use std::io::Write as _;
        if let Ok(mut f) = std::fs::OpenOptions::new().create(true).append(true).open(log) {
            let _ = writeln!(f, "{line}");
        }
    }
}

/// [`skip`] for missing test data, models or tools `scripts/setup.sh` installs. With
/// `CI=true` and the shared data present the environment is meant to be complete, so
/// this fails the test instead of skipping it.
///
/// # Panics
/// Under `CI=true` when [`shared_data_dir`] exists (see above).
#[allow(clippy::panic)]
pub fn skip_missing_data(what: &str) {
    skip(what);
    if std::env::var("CI").is_ok_and(|v| v == "true") && shared_data_dir().is_some() {
        panic!("SKIP: {what}: with CI=true and the shared data present, missing data fails the test");
    }
}

/// A file below the shared data folder, or `None` (with a `SKIP:` line on stderr
/// naming `test`) when the data is absent. For tests and examples.
pub fn shared_data_file(test: &str, relative: &str) -> Option<PathBuf> {
    match shared_data_dir().map(|d| d.join(relative)).filter(|p| p.exists()) {
        Some(p) => Some(p),
        None => {
            skip_missing_data(&format!(
                "{test}: shared data file {relative} not found (set FACECAP_DATA or place ../shared/data)"
            ));
            None
        }
    }
}

/// A model file from the cache, or `None` (with a `SKIP:` line naming `test`).
pub fn model_file_or_skip(test: &str, name: &str) -> Option<PathBuf> {
    match model_file(name) {
        Some(p) => Some(p),
        None => {
            skip_missing_data(&format!(
                "{test}: model {name} not in the model cache (run scripts/setup.sh)"
            ));
            None
        }
    }
}

/// Largest length of an output name made by [`unique_output_names`], bytes.
pub const MAX_OUTPUT_NAME: usize = 100;

/// A file or folder name inside an output folder made from an input's file stem: the
/// characters `A-Z a-z 0-9 . _ -` kept, every other character (path separators,
/// spaces, control and non-ASCII characters) replaced by `_`, leading dots replaced by
/// `_` (so `..`, `.` and hidden names never appear), cut to [`MAX_OUTPUT_NAME`] bytes;
/// `fallback` when nothing is left.
pub fn sanitise_output_name(stem: &str, fallback: &str) -> String {
    let mut s: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect();
    let dots = s.len() - s.trim_start_matches('.').len();
    s.replace_range(..dots, &"_".repeat(dots));
    s.truncate(MAX_OUTPUT_NAME);
    if s.is_empty() {
        fallback.to_string()
    } else {
        s
    }
}

/// One output name per input, unique inside one output folder and stable for the same
/// list of inputs: the sanitised file stem ([`sanitise_output_name`]); when several
/// inputs give the same name (compared case-insensitively, for case-insensitive file
/// systems), the second gets `-2`, the third `-3`, ... in input order (camera cards
/// name every clip `C0001.MP4`).
pub fn unique_output_names(inputs: &[impl AsRef<std::path::Path>], fallback: &str) -> Vec<String> {
    let mut taken = std::collections::HashSet::new();
    inputs
        .iter()
        .map(|p| {
            let stem = p
                .as_ref()
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let base = sanitise_output_name(&stem, fallback);
            let mut name = base.clone();
            let mut k = 2u64;
            while !taken.insert(name.to_ascii_lowercase()) {
                name = format!("{base}-{k}");
                k += 1;
            }
            name
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use std::path::{Component, Path, PathBuf};

    #[test]
    fn output_names_are_unique_sanitised_and_stay_inside() {
        let inputs: Vec<PathBuf> = [
            "a/C0001.MP4",
            "b/C0001.MP4",
            "c/c0001.mp4",
            "...mp4",
            "..",
            "/",
            "x/.hidden.mp4",
            "we ird/na;me$.mov",
            "C0001-2.mp4",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        let names = unique_output_names(&inputs, "video");
        assert_eq!(
            names,
            [
                "C0001",
                "C0001-2",
                "c0001-3",
                "__",
                "video",
                "video-2",
                "_hidden",
                "na_me_",
                "C0001-2-2"
            ]
        );
        let mut lower: Vec<String> = names.iter().map(|n| n.to_ascii_lowercase()).collect();
        lower.sort();
        lower.dedup();
        assert_eq!(lower.len(), names.len());
        for n in &names {
            let joined = Path::new("out").join(n);
            let c: Vec<Component> = joined.components().collect();
            assert_eq!(c.len(), 2, "{n}");
            assert!(matches!(c[1], Component::Normal(_)), "{n}");
        }
        // Stable: the same inputs give the same names.
        assert_eq!(unique_output_names(&inputs, "video"), names);
        assert_eq!(sanitise_output_name(&"x".repeat(300), "v").len(), MAX_OUTPUT_NAME);
    }
}
