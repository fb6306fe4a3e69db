//! `facecap muscle ...`.

use std::path::PathBuf;

/// Muscle subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Track muscle contractions and jaw rotation from a video.
    Track {
        /// Video file.
        video: PathBuf,
    },
}

/// Runs a muscle subcommand.
pub fn run(cmd: Command) -> anyhow::Result<std::process::ExitCode> {
    match cmd {
        Command::Track { video } => anyhow::bail!("facecap muscle track is not implemented yet ({})", video.display()),
    }
}
