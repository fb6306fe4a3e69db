//! `facecap landmarks`.

use std::path::PathBuf;

/// Arguments of `facecap landmarks`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input files.
    pub inputs: Vec<PathBuf>,
}

/// Runs `facecap landmarks`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!(
        "facecap landmarks is not implemented yet ({} inputs)",
        args.inputs.len()
    )
}
