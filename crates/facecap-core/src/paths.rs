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

/// A file below the shared data folder, or `None` (with a `SKIP:` line on stderr
/// naming `test`) when the data is absent. For tests and examples.
pub fn shared_data_file(test: &str, relative: &str) -> Option<PathBuf> {
    match shared_data_dir().map(|d| d.join(relative)).filter(|p| p.exists()) {
        Some(p) => Some(p),
        None => {
            eprintln!("SKIP: {test}: shared data file {relative} not found (set FACECAP_DATA or place ../shared/data)");
            None
        }
    }
}

/// A model file from the cache, or `None` (with a `SKIP:` line naming `test`).
pub fn model_file_or_skip(test: &str, name: &str) -> Option<PathBuf> {
    match model_file(name) {
        Some(p) => Some(p),
        None => {
            eprintln!("SKIP: {test}: model {name} not in the model cache (run scripts/setup.sh)");
            None
        }
    }
}
