//! `facecap info`.

use std::path::PathBuf;

/// Arguments of `facecap info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input files.
    pub inputs: Vec<PathBuf>,
}

/// Runs `facecap info`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!("facecap info is not implemented yet ({} inputs)", args.inputs.len())
}
