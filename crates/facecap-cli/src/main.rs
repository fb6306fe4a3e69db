//! `facecap` command-line tool.

use clap::{Parser, Subcommand};

/// Markerless facial performance capture from monocular video.
#[derive(Debug, Parser)]
#[command(name = "facecap", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Decode a whole video and print frames decoded, resolution, fps, duration and codec.
    Info {
        /// Video file, Y4M file or folder of images.
        video: std::path::PathBuf,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Info { video } => {
            anyhow::bail!("info not implemented yet for {}", video.display())
        }
    }
}
