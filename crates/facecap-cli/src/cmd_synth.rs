//! `facecap synth`.

use std::path::PathBuf;

/// Arguments of `facecap synth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input files.
    pub inputs: Vec<PathBuf>,
}

/// Runs `facecap synth`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!("facecap synth is not implemented yet ({} inputs)", args.inputs.len())
}
