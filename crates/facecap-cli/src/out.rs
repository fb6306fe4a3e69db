//! Terminal output conventions of every command.
//!
//! * Results go to stdout through [`println`], which never panics: when stdout is closed
//!   (`facecap ... | head`), further output is dropped and the command finishes its work
//!   (its files are written as usual).
//! * Progress and notes go to stderr through [`info`] (silenced by `--quiet`) and
//!   [`verbose`] (shown with `--verbose` only).
//! * Errors go to stderr exactly once, from `main` (or per failed video in `capture`),
//!   also with `--quiet`.

use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering};

static QUIET: AtomicBool = AtomicBool::new(false);
static VERBOSE: AtomicBool = AtomicBool::new(false);
static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);

/// Sets the global verbosity (from `--quiet` / `--verbose`).
pub fn set(quiet: bool, verbose: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
    VERBOSE.store(verbose && !quiet, Ordering::Relaxed);
}

/// Whether `--quiet` was given.
pub fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// One line on stdout; dropped once stdout is closed.
pub fn println(line: &str) {
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    if writeln!(out, "{line}").and_then(|()| out.flush()).is_err() {
        STDOUT_CLOSED.store(true, Ordering::Relaxed);
    }
}

/// A progress or summary line on stderr, unless `--quiet`.
pub fn info(line: &str) {
    if !quiet() {
        let _ = writeln!(std::io::stderr(), "{line}");
    }
}

/// A detail line on stderr, with `--verbose` only.
pub fn verbose(line: &str) {
    if VERBOSE.load(Ordering::Relaxed) {
        let _ = writeln!(std::io::stderr(), "{line}");
    }
}
