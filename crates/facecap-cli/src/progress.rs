//! Progress output: bars on a terminal, plain log lines otherwise, nothing with `--quiet`.

use std::io::IsTerminal;
use std::path::Path;

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Shared progress reporter.
#[derive(Debug)]
pub struct Progress {
    quiet: bool,
    multi: Option<MultiProgress>,
}

/// One video's progress.
#[derive(Debug)]
pub struct Bar {
    bar: Option<ProgressBar>,
    name: String,
    log: bool,
    count: u64,
}

impl Progress {
    /// Bars when stderr is a terminal and not `quiet`.
    pub fn new(quiet: bool) -> Self {
        let multi = (!quiet && std::io::stderr().is_terminal())
            .then(|| MultiProgress::with_draw_target(ProgressDrawTarget::stderr()));
        Progress { quiet, multi }
    }

    /// A log line (above the bars on a terminal).
    pub fn line(&self, msg: &str) {
        if self.quiet {
            return;
        }
        match &self.multi {
            Some(m) => {
                let _ = m.println(msg);
            }
            None => eprintln!("{msg}"),
        }
    }

    /// A bar for one video (`len` frames when known).
    pub fn bar(&self, video: &Path, len: Option<u64>) -> Bar {
        let name = video
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bar = self.multi.as_ref().map(|m| {
            let b = m.add(len.map_or_else(ProgressBar::no_length, ProgressBar::new));
            let style = ProgressStyle::with_template("{prefix:>20} [{bar:30}] {pos}/{len} frames {per_sec} eta {eta}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
            b.set_style(style);
            b.set_prefix(name.clone());
            b
        });
        if !self.quiet && bar.is_none() {
            eprintln!("start {name}");
        }
        Bar {
            bar,
            name,
            log: !self.quiet && self.multi.is_none(),
            count: 0,
        }
    }
}

/// Plain-log interval in frames.
const LOG_EVERY: u64 = 500;

impl Bar {
    /// One more frame.
    pub fn inc(&mut self) {
        self.count += 1;
        if let Some(b) = &self.bar {
            b.inc(1);
        } else if self.log && self.count % LOG_EVERY == 0 {
            eprintln!("{}: {} frames", self.name, self.count);
        }
    }

    /// Done.
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        } else if self.log {
            eprintln!("done {}: {} frames", self.name, self.count);
        }
    }
}
