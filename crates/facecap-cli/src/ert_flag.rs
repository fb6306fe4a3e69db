//! `--ert-precision`, shared by every command that runs the ERT shape predictor.

use facecap_landmarks::ert::ErtPrecision;

/// The flag, flattened into each command's arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::Args)]
pub struct ErtFlag {
    /// ERT landmark precision: `exact` (default: f32 leaves, the same landmarks as
    /// dlib) or `fast` (16-bit leaves: less memory traffic, points differ from exact by
    /// a few hundredths of a pixel on average; see docs/landmarks.md, "Fast precision").
    #[arg(long = "ert-precision", value_name = "exact|fast", default_value = "exact", value_parser = parse_precision)]
    pub ert_precision: ErtPrecision,
}

fn parse_precision(s: &str) -> Result<ErtPrecision, String> {
    s.parse()
}
