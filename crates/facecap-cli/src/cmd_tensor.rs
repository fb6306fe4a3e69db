//! `facecap tensor ...` and `facecap transfer`.

use std::path::PathBuf;

/// Tensor subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Build a tensor model from a corresponded mesh database.
    Build {
        /// Output model file.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Arguments of `facecap transfer`.
#[derive(Debug, clap::Args)]
pub struct TransferArgs {
    /// Source video.
    pub source: PathBuf,
    /// Target video.
    pub target: PathBuf,
}

/// Runs a tensor subcommand.
pub fn run(cmd: Command) -> anyhow::Result<std::process::ExitCode> {
    match cmd {
        Command::Build { out } => anyhow::bail!("facecap tensor build is not implemented yet ({})", out.display()),
    }
}

/// Runs `facecap transfer`.
pub fn run_transfer(args: TransferArgs) -> anyhow::Result<std::process::ExitCode> {
    anyhow::bail!(
        "facecap transfer is not implemented yet ({} -> {})",
        args.source.display(),
        args.target.display()
    )
}
