//! `--upsample`, shared by every command that runs the face detector on video or images.

use facecap_landmarks::detect::Upsample;

/// The flag, flattened into each command's arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::Args)]
pub struct UpsampleFlag {
    /// Face detector up-sampling: `auto` (default; finds what dlib's `detector(img, 1)`
    /// finds, scanning the finest levels only when needed) or N = 0..4 doublings of the
    /// image before detection, exactly dlib's `detector(img, N)` (docs/detection.md).
    #[arg(long, value_name = "auto|N", default_value = "auto")]
    pub upsample: Upsample,
}
