//! Weights in the Live Link Face CSV layout (Epic Games' iPhone capture app), so
//! existing importers read them.
//!
//! Header: `Timecode,BlendShapeCount,` then the 52 ARKit blendshapes in Live Link
//! order (PascalCase), then `HeadYaw,HeadPitch,HeadRoll` and the six eye rotations:
//! 61 values per row (`BlendShapeCount` = 61). Timecode is `HH:MM:SS:FF.mmm` at the
//! video frame rate. Rig names map onto ARKit names case-insensitively, with `_L`/`_R`
//! suffixes read as `Left`/`Right` (ICT style); where a rig splits an unsided ARKit
//! shape into `_L`/`_R` halves (e.g. `browInnerUp_L`), the halves are averaged.
//! ARKit shapes the rig lacks are written as 0. Written only when every rig shape maps.

use std::path::Path;

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

/// `HH:MM:SS:FF.mmm` for a time in seconds at `fps`.
pub fn timecode(t: f64, fps: f64) -> String {
    let t = t.max(0.0);
    let total = t.floor() as u64;
    let frac = t - total as f64;
    let frames = frac * fps;
    let ff = frames.floor() as u64;
    let ms = ((frames - ff as f64) * 1000.0).round().min(999.0) as u64;
    format!(
        "{:02}:{:02}:{:02}:{:02}.{:03}",
        total / 3600,
        (total / 60) % 60,
        total % 60,
        ff,
        ms
    )
}

/// Writes `path` when every rig name maps onto ARKit; returns the file name written,
/// or `None` (nothing written) when the names do not map.
pub fn write_if_arkit(
    path: &Path,
    names: &[String],
    weights: &[Vec<f64>],
    times: &[f64],
) -> anyhow::Result<Option<String>> {
    let Some(map) = mapping(names) else { return Ok(None) };
    let fps = if times.len() > 1 {
        let span = times[times.len() - 1] - times[0];
        if span > 0.0 {
            (times.len() - 1) as f64 / span
        } else {
            30.0
        }
    } else {
        30.0
    };
    let mut text = String::from("Timecode,BlendShapeCount");
    for s in LIVE_LINK_SHAPES.iter().chain(LIVE_LINK_POSE.iter()) {
        text.push(',');
        text.push_str(s);
    }
    text.push('\n');
    let count = LIVE_LINK_SHAPES.len() + LIVE_LINK_POSE.len();
    for (w, &t) in weights.iter().zip(times) {
        let mut row = [0.0f64; 52];
        for (k, &(col, share)) in map.iter().enumerate() {
            row[col] += share * w.get(k).copied().unwrap_or(0.0);
        }
        text.push_str(&timecode(t, fps));
        text.push_str(&format!(",{count}"));
        for v in row.iter().chain([0.0; 9].iter()) {
            text.push_str(&format!(",{v}"));
        }
        text.push('\n');
    }
    facecap_core::atomic::write_atomic(path, |f| f.write_all(text.as_bytes()))?;
    Ok(path.file_name().map(|s| s.to_string_lossy().into_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_ict_and_default_names() {
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
        let names: Vec<String> = crate::default_rig::DEFAULT_SHAPES
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert!(mapping(&names).is_some());
        assert!(mapping(&["smileish".to_string()]).is_none());
        assert_eq!(timecode(61.5, 30.0), "00:01:01:15.000");
    }
}
