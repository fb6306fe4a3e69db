//! `facecap capture`.

use std::path::PathBuf;

/// Arguments of `facecap capture`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input files.
    pub inputs: Vec<PathBuf>,
}

/// Runs `facecap capture`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!("facecap capture is not implemented yet ({} inputs)", args.inputs.len())
}
