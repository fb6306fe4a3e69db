//! `facecap solve`.

use std::path::PathBuf;

/// Arguments of `facecap solve`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input files.
    pub inputs: Vec<PathBuf>,
}

/// Runs `facecap solve`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!("facecap solve is not implemented yet ({} inputs)", args.inputs.len())
}
