//! Muscle sets: the JSON format, parsing and validation.
//!
//! ```json
//! {
//!   "format": "facecap-muscle-set",
//!   "version": 1,
//!   "units": "cm",
//!   "muscles": [
//!     { "name": "cheek_L", "type": "linear",
//!       "origin": [6.1, 1.0, 2.0], "insertion": [2.4, -3.2, 4.9],
//!       "rs": 5.0, "rf": 7.5, "k": 1.2, "zone": 3.14159,
//!       "wrinkle": { "height": 0.05, "count": 3 },
//!       "vertex_group": "left_face" },
//!     { "name": "eyebrow_forehead_L", "type": "parallel",
//!       "origin": [...], "insertion": [...], "control": [...],
//!       "height": 2.0, "rs": 2.0, "rf": 4.0, "k": 0.6 },
//!     { "name": "lips", "type": "sphincter",
//!       "centre": [...], "upper": [...], "corner": [...],
//!       "radius": 1.6, "height": 0.4, "k": 0.3 }
//!   ],
//!   "vertex_groups": { "jaw": { "indices": [10, 11, 12], "weights": [1.0, 0.5, 0.2] } },
//!   "jaw": { "pivot": [0.0, -1.0, -6.0], "max_angle": 0.35, "vertex_group": "jaw" }
//! }
//! ```
//!
//! * `type` is `linear`, `parallel` or `sphincter`; the parameters are those of
//!   [`crate::deform`] (lengths in the mesh's units).
//! * `vertex_group` (optional) names an entry of `vertex_groups`: the muscle then moves only
//!   those vertices, each scaled by its weight in `[0, 1]` (`weights` default to 1).
//! * `jaw` (optional): opening is a rotation by the jaw angle `theta` in `[0, max_angle]`
//!   about the model X axis (or `axis`) through `pivot`, applied to the jaw vertex group with
//!   its weights (linear blend).
//!
//! Unknown keys are rejected, so a typo (`"rF"`) is an error, not a silently ignored value.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::deform::MuscleShape;
use crate::error::{finite, Error, Result};

/// The value of the `format` key.
pub const FORMAT_TAG: &str = "facecap-muscle-set";
/// The supported `version`.
pub const FORMAT_VERSION: u32 = 1;

fn format_tag() -> String {
    FORMAT_TAG.into()
}
fn format_version() -> u32 {
    FORMAT_VERSION
}

/// One named muscle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Muscle {
    /// Unique name; the CSV column and the baked morph target are named after it.
    pub name: String,
    /// Optional vertex group restricting (and weighting) the muscle's effect.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vertex_group: Option<String>,
    /// Type and parameters.
    #[serde(flatten)]
    pub shape: MuscleShape,
}

/// Per-vertex weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VertexGroup {
    /// Vertex indices (0-based, unique).
    pub indices: Vec<u32>,
    /// Weights in `[0, 1]`, one per index; absent = all 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<Vec<f64>>,
}

impl VertexGroup {
    /// Weight of the `i`-th entry.
    pub fn weight(&self, i: usize) -> f64 {
        self.weights.as_ref().map_or(1.0, |w| w[i])
    }
}

/// Jaw opening.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Jaw {
    /// Rotation centre (mesh units).
    pub pivot: [f64; 3],
    /// Largest opening angle in radians, `(0, pi/2]`.
    pub max_angle: f64,
    /// Vertex group that rotates (with its weights).
    pub vertex_group: String,
    /// Rotation axis (default model X `[1, 0, 0]`); opening is a positive rotation.
    #[serde(default = "x_axis")]
    pub axis: [f64; 3],
}

fn x_axis() -> [f64; 3] {
    [1.0, 0.0, 0.0]
}

/// A muscle set (see module docs for the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuscleSet {
    /// Always [`FORMAT_TAG`].
    #[serde(default = "format_tag")]
    pub format: String,
    /// Always [`FORMAT_VERSION`].
    #[serde(default = "format_version")]
    pub version: u32,
    /// Free-form units note (e.g. "cm"), informational.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<String>,
    /// The muscles, in column order.
    pub muscles: Vec<Muscle>,
    /// Named vertex groups.
    #[serde(default)]
    pub vertex_groups: BTreeMap<String, VertexGroup>,
    /// Optional jaw.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jaw: Option<Jaw>,
}

impl MuscleSet {
    /// Parses and validates JSON text.
    ///
    /// # Errors
    /// [`Error::MuscleSet`] for malformed JSON (with line/column), otherwise as [`Self::validate`].
    pub fn from_json_str(text: &str) -> Result<Self> {
        let set: MuscleSet = serde_json::from_str(text).map_err(|e| Error::MuscleSet {
            path: Default::default(),
            reason: e.to_string(),
        })?;
        set.validate()?;
        Ok(set)
    }

    /// Reads, parses and validates a JSON file.
    ///
    /// # Errors
    /// I/O errors, then as [`Self::from_json_str`] with the path filled in.
    pub fn from_json_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| facecap_core::Error::io(path, e))?;
        Self::from_json_str(&text).map_err(|e| match e {
            Error::MuscleSet { reason, .. } => Error::MuscleSet {
                path: path.to_path_buf(),
                reason,
            },
            other => other,
        })
    }

    /// Pretty JSON.
    ///
    /// # Errors
    /// Only if serialisation fails (non-finite numbers cannot occur in a validated set).
    pub fn to_json_string(&self) -> Result<String> {
        serde_json::to_string_pretty(self).map_err(|e| Error::MuscleSet {
            path: Default::default(),
            reason: e.to_string(),
        })
    }

    /// Muscle names in order.
    pub fn names(&self) -> Vec<&str> {
        self.muscles.iter().map(|m| m.name.as_str()).collect()
    }

    /// Checks the format tag, unique non-empty names, every muscle's parameters, vertex
    /// groups (weights in `[0, 1]`, unique indices, matching lengths) and references.
    ///
    /// # Errors
    /// The first problem found, naming the muscle / group / key.
    pub fn validate(&self) -> Result<()> {
        if self.format != FORMAT_TAG {
            return Err(Error::invalid("format", &self.format, format!("{FORMAT_TAG:?}")));
        }
        if self.version != FORMAT_VERSION {
            return Err(Error::invalid("version", self.version, format!("{FORMAT_VERSION}")));
        }
        if self.muscles.is_empty() {
            return Err(Error::invalid("muscles", "[]", "at least one muscle"));
        }
        let mut seen = BTreeSet::new();
        for m in &self.muscles {
            if m.name.is_empty() || m.name.contains([',', '"', '\n']) {
                return Err(Error::invalid(
                    "muscle name",
                    format!("{:?}", m.name),
                    "non-empty, without commas, quotes or newlines",
                ));
            }
            if m.name == "jaw" {
                return Err(Error::invalid(
                    "muscle name",
                    "\"jaw\"",
                    "a name other than the reserved \"jaw\"",
                ));
            }
            if !seen.insert(m.name.as_str()) {
                return Err(Error::invalid("muscle name", format!("{:?}", m.name), "unique names"));
            }
            m.shape.validate(&m.name)?;
            if let Some(g) = &m.vertex_group {
                if !self.vertex_groups.contains_key(g) {
                    return Err(Error::invalid(
                        format!("muscle {:?}: vertex_group", m.name),
                        format!("{g:?}"),
                        "the name of an entry in vertex_groups",
                    ));
                }
            }
        }
        for (name, g) in &self.vertex_groups {
            let mut uniq = BTreeSet::new();
            if let Some(i) = g.indices.iter().find(|i| !uniq.insert(**i)) {
                return Err(Error::invalid(
                    format!("vertex group {name:?}: indices"),
                    i,
                    "unique vertex indices",
                ));
            }
            if let Some(w) = &g.weights {
                if w.len() != g.indices.len() {
                    return Err(Error::DimensionMismatch {
                        what: format!("weights of vertex group {name:?}"),
                        expected: g.indices.len(),
                        got: w.len(),
                    });
                }
                if let Some(x) = w.iter().find(|x| !(x.is_finite() && (0.0..=1.0).contains(*x))) {
                    return Err(Error::invalid(format!("vertex group {name:?}: weight"), x, "in [0, 1]"));
                }
            }
        }
        if let Some(j) = &self.jaw {
            for v in j.pivot.iter() {
                finite("jaw.pivot", *v)?;
            }
            finite("jaw.max_angle", j.max_angle)?;
            if !(j.max_angle > 0.0 && j.max_angle <= std::f64::consts::FRAC_PI_2) {
                return Err(Error::invalid("jaw.max_angle", j.max_angle, "in (0, pi/2]"));
            }
            let n = (j.axis[0].powi(2) + j.axis[1].powi(2) + j.axis[2].powi(2)).sqrt();
            if !(n.is_finite() && n > 1e-12) {
                return Err(Error::invalid(
                    "jaw.axis",
                    format!("{:?}", j.axis),
                    "a finite non-zero vector",
                ));
            }
            if !self.vertex_groups.contains_key(&j.vertex_group) {
                return Err(Error::invalid(
                    "jaw.vertex_group",
                    format!("{:?}", j.vertex_group),
                    "the name of an entry in vertex_groups",
                ));
            }
        }
        Ok(())
    }

    /// Checks that every vertex group index is `< num_vertices`.
    ///
    /// # Errors
    /// The first out-of-range index, naming the group.
    pub fn validate_for_mesh(&self, num_vertices: usize) -> Result<()> {
        for (name, g) in &self.vertex_groups {
            if let Some(i) = g.indices.iter().find(|i| **i as usize >= num_vertices) {
                return Err(Error::invalid(
                    format!("vertex group {name:?}: index"),
                    i,
                    format!("< {num_vertices} (the mesh's vertex count)"),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"{
      "muscles": [
        {"name": "a", "type": "linear", "origin": [0,0,0], "insertion": [1,0,0], "rs": 1, "rf": 2, "k": 0.1,
         "vertex_group": "g"},
        {"name": "s", "type": "sphincter", "centre": [0,0,0], "upper": [0,1,0], "corner": [2,0,0],
         "radius": 1.5, "height": 0.1, "k": 0.3}
      ],
      "vertex_groups": {"g": {"indices": [0, 1], "weights": [1.0, 0.5]}},
      "jaw": {"pivot": [0, 0, -3], "max_angle": 0.3, "vertex_group": "g"}
    }"#;

    #[test]
    fn parses_round_trips_and_rejects() {
        let s = MuscleSet::from_json_str(GOOD).unwrap();
        assert_eq!(s.names(), ["a", "s"]);
        let again = MuscleSet::from_json_str(&s.to_json_string().unwrap()).unwrap();
        assert_eq!(s, again);
        // Every truncation of a valid file is rejected.
        for cut in 0..GOOD.len() - 1 {
            if GOOD.is_char_boundary(cut) && !GOOD[cut..].trim().is_empty() {
                assert!(MuscleSet::from_json_str(&GOOD[..cut]).is_err(), "cut {cut}");
            }
        }
        for (bad, needle) in [
            (GOOD.replace("\"rf\": 2", "\"rF\": 2"), "rF"),
            (GOOD.replace("\"rf\": 2", "\"rf\": 0.5"), "rf"),
            (GOOD.replace("\"type\": \"linear\"", "\"type\": \"ring\""), "ring"),
            (GOOD.replace("[1.0, 0.5]", "[1.0, 1.5]"), "weight"),
            (
                GOOD.replace("\"vertex_group\": \"g\"}", "\"vertex_group\": \"h\"}"),
                "vertex_group",
            ),
            (GOOD.replace("\"max_angle\": 0.3", "\"max_angle\": 3"), "max_angle"),
            (GOOD.replace("\"name\": \"s\"", "\"name\": \"a\""), "unique"),
        ] {
            let e = MuscleSet::from_json_str(&bad).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
        }
        assert!(s.validate_for_mesh(2).is_ok());
        assert!(s.validate_for_mesh(1).is_err());
    }
}
