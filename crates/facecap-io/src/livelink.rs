//! `livelink.csv`: weights and head rotation in the Live Link Face CSV layout (Epic
//! Games' iPhone capture app), so existing importers read them.
//!
//! Header: `Timecode,BlendShapeCount,` then the 52 ARKit blendshapes in Live Link
//! order (PascalCase), then `HeadYaw,HeadPitch,HeadRoll` and the six eye rotations:
//! 61 values per row (`BlendShapeCount` = 61). **Timecode** is `HH:MM:SS:FF.mmm`
//! computed from the frame index at the video's nominal frame rate (frame `i` is
//! `FF = i mod fps` of second `i div fps`; `.mmm` is 0), so rows advance by exactly one
//! frame. **Head rotation** in radians, from the head rotation relative to facing the
//! camera ([`facecap_core::camera::head_rotation`]): `HeadYaw` = rotation about the
//! vertical axis (`pose.csv`'s `pose_Ry`), `HeadPitch` = about the horizontal axis
//! (`pose_Rx`), `HeadRoll` = about the viewing axis (`pose_Rz`); 0 on frames without a
//! pose. **Eye rotations** in radians, relative to the head, with the head's signs (yaw > 0:
//! towards the subject's right; pitch > 0: down), from the writer's `eyes` (the pipeline turns
//! the `eyeLook*` weights of the gaze estimate into rotations,
//! `facecap_landmarks::gaze::eye_rotations`); the eyes' roll is 0. Only solved frames get a row:
//! a frame without a face has no timecode in the file rather than a row of zeros that
//! would read as a neutral face.
//!
//! Rig names map onto ARKit names case-insensitively, with `_L`/`_R` suffixes read as
//! `Left`/`Right` (ICT style); where a rig splits an unsided ARKit shape into `_L`/`_R`
//! halves (e.g. `browInnerUp_L`), the halves are averaged. ARKit shapes the rig lacks
//! are written as 0. Written only when every rig shape maps.

use std::path::Path;

use facecap_core::camera::{pose_row, ModelToCamera};

use facecap_core::error::Result;

/// The 52 ARKit blendshapes in Live Link Face order.
pub const LIVE_LINK_SHAPES: [&str; 52] = [
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawRight",
    "JawLeft",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthRight",
    "MouthLeft",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
];

/// Trailing pose columns of the layout.
pub const LIVE_LINK_POSE: [&str; 9] = [
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
];

fn normalise(name: &str) -> String {
    let n = if let Some(b) = name.strip_suffix("_L") {
        format!("{b}Left")
    } else if let Some(b) = name.strip_suffix("_R") {
        format!("{b}Right")
    } else {
        name.to_string()
    };
    n.to_ascii_lowercase()
}

/// For each rig shape, the Live Link column it feeds and its share (1, or 0.5 for a
/// split half). `None` when some shape has no ARKit counterpart.
pub fn mapping(names: &[String]) -> Option<Vec<(usize, f64)>> {
    let lower: Vec<String> = LIVE_LINK_SHAPES.iter().map(|s| s.to_ascii_lowercase()).collect();
    names
        .iter()
        .map(|n| {
            let key = normalise(n);
            if let Some(i) = lower.iter().position(|l| *l == key) {
                return Some((i, 1.0));
            }
            // Split halves of an unsided ARKit shape.
            let base = n
                .strip_suffix("_L")
                .or_else(|| n.strip_suffix("_R"))?
                .to_ascii_lowercase();
            lower.iter().position(|l| *l == base).map(|i| (i, 0.5))
        })
        .collect()
}

/// Frames per second used when the video's rate is unknown or not positive.
pub const FALLBACK_FPS: f64 = 30.0;

/// `fps` when it is a usable frame rate (finite, positive), [`FALLBACK_FPS`] otherwise.
pub fn rate_or_fallback(fps: f64) -> f64 {
    if fps.is_finite() && fps > 0.0 {
        fps
    } else {
        FALLBACK_FPS
    }
}

/// `HH:MM:SS:FF.mmm` of frame `index` at `fps` frames per second (rounded to whole
/// frames per second for the `FF` field, as SMPTE timecode is).
pub fn timecode(index: u64, fps: f64) -> String {
    let rate = if fps.is_finite() && fps > 0.0 {
        fps.round().max(1.0) as u64
    } else {
        FALLBACK_FPS as u64
    };
    let ff = index % rate;
    let total = index / rate;
    format!(
        "{:02}:{:02}:{:02}:{:02}.000",
        total / 3600,
        (total / 60) % 60,
        total % 60,
        ff
    )
}

/// `[HeadYaw, HeadPitch, HeadRoll]` of a pose (module docs); zeros without one.
pub fn head_angles(pose: Option<&ModelToCamera>) -> [f64; 3] {
    match pose {
        Some(p) => {
            let r = pose_row(Some(p));
            [r[4], r[3], r[5]]
        }
        None => [0.0; 3],
    }
}

/// One row of the file: frame index, weights in rig order, head pose.
#[derive(Debug, Clone, Copy)]
pub struct LiveLinkRow<'a> {
    /// Frame index.
    pub index: u64,
    /// Weights in rig order.
    pub weights: &'a [f64],
    /// Head pose.
    pub pose: Option<&'a ModelToCamera>,
}

/// The 52 ARKit values ([`LIVE_LINK_SHAPES`] order) of rig `weights` through a [`mapping`]
/// (a split half adds its share; a missing weight counts as 0).
pub fn arkit_values(map: &[(usize, f64)], weights: &[f64]) -> [f64; 52] {
    let mut values = [0.0f64; 52];
    for (k, &(col, share)) in map.iter().enumerate() {
        values[col] += share * weights.get(k).copied().unwrap_or(0.0);
    }
    values
}

/// Writes `path` when every rig name maps onto ARKit; returns the file name written,
/// or `None` (nothing written) when the names do not map. `eyes` gives a row's
/// `LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, RightEyePitch, RightEyeRoll`
/// (radians, module docs) from its 52 ARKit values; non-finite ones are written as 0.
///
/// # Errors
/// When the file cannot be written.
pub fn write_if_arkit<'a>(
    path: &Path,
    names: &[String],
    fps: f64,
    rows: impl IntoIterator<Item = LiveLinkRow<'a>>,
    eyes: impl Fn(&[f64; 52]) -> [f64; 6],
) -> Result<Option<String>> {
    let Some(map) = mapping(names) else { return Ok(None) };
    let mut text = String::from("Timecode,BlendShapeCount");
    for s in LIVE_LINK_SHAPES.iter().chain(LIVE_LINK_POSE.iter()) {
        text.push(',');
        text.push_str(s);
    }
    text.push('\n');
    let count = LIVE_LINK_SHAPES.len() + LIVE_LINK_POSE.len();
    for row in rows {
        let values = arkit_values(&map, row.weights);
        let head = head_angles(row.pose);
        text.push_str(&timecode(row.index, fps));
        text.push_str(&format!(",{count}"));
        let eyes = eyes(&values).map(|v| if v.is_finite() { v } else { 0.0 });
        for v in values.iter().chain(head.iter()).chain(eyes.iter()) {
            text.push_str(&format!(",{v}"));
        }
        text.push('\n');
    }
    facecap_core::atomic::write_atomic(path, |f| f.write_all(text.as_bytes()))?;
    Ok(path.file_name().map(|s| s.to_string_lossy().into_owned()))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn maps_ict_names() {
        let ict: Vec<String> = [
            "eyeBlink_L",
            "jawOpen",
            "browInnerUp_L",
            "browInnerUp_R",
            "mouthSmile_R",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let m = mapping(&ict).unwrap();
        assert_eq!(m[0], (0, 1.0));
        assert_eq!(m[1], (17, 1.0));
        assert_eq!(m[2], (43, 0.5));
        assert_eq!(m[4], (24, 1.0));
        assert!(mapping(&["smileish".to_string()]).is_none());
    }

    #[test]
    fn timecodes_advance_one_frame_per_index() {
        assert_eq!(timecode(0, 30.0), "00:00:00:00.000");
        assert_eq!(timecode(1845, 30.0), "00:01:01:15.000");
        // 29.97 fps counts 30 frames per timecode second
        assert_eq!(timecode(30, 29.97), "00:00:01:00.000");
        assert_eq!(timecode(3, f64::NAN), "00:00:00:03.000");
        // consecutive indices: strictly one frame apart, never repeated
        let codes: Vec<String> = (0..1000).map(|i| timecode(i, 25.0)).collect();
        for w in codes.windows(2) {
            assert!(w[0] < w[1], "{} {}", w[0], w[1]);
        }
    }
}
