//! Maps from the 68 iBUG landmarks to mesh vertices.
//!
//! Accepted JSON forms:
//! * an object with `vertex_by_ibug_0based`: an array of 68 vertex ids (`null` for unmapped);
//! * an object with `vertex_by_ibug_1based`: an object `{ "1": v, ... }` (missing = unmapped),
//!   as in `sfm_landmarks68.json`;
//! * a plain array of 68 vertex ids (0-based landmark order, `null` or `-1` for unmapped).

use std::path::Path;

use crate::error::{Error, Result};
use crate::landmarks::NUM_LANDMARKS;

const FORMAT: &str = "landmark map JSON";

/// iBUG-68 landmark index -> vertex index (or unmapped).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LandmarkMap {
    /// `vertices[i]` is the vertex of 0-based iBUG landmark `i`, if mapped.
    pub vertices: [Option<u32>; NUM_LANDMARKS],
}

impl LandmarkMap {
    /// Builds a map from exactly 68 entries.
    pub fn from_slice(v: &[Option<u32>]) -> Result<Self> {
        if v.len() != NUM_LANDMARKS {
            return Err(Error::DimensionMismatch {
                what: "landmark map length".into(),
                expected: NUM_LANDMARKS,
                got: v.len(),
            });
        }
        let mut vertices = [None; NUM_LANDMARKS];
        vertices.copy_from_slice(v);
        Ok(LandmarkMap { vertices })
    }

    /// The map of 68 landmark positions given as points in the mesh's frame (a scan
    /// annotated with 3D points, not vertex ids): each landmark takes the vertex of
    /// `positions` nearest to it; a non-finite point stays unmapped.
    ///
    /// ```
    /// use facecap_core::landmark_map::LandmarkMap;
    /// use nalgebra::Point3;
    /// let mesh = [Point3::new(0.0f32, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)];
    /// let mut points = vec![Point3::new(0.9, 0.1, 0.0); 68];
    /// points[3] = Point3::new(f64::NAN, 0.0, 0.0);
    /// let map = LandmarkMap::nearest_vertices(&mesh, &points).unwrap();
    /// assert_eq!((map.vertices[0], map.vertices[3]), (Some(1), None));
    /// ```
    ///
    /// # Errors
    /// Not 68 points, or a mesh without vertices (or with more than `u32::MAX`).
    pub fn nearest_vertices(positions: &[nalgebra::Point3<f32>], points: &[nalgebra::Point3<f64>]) -> Result<Self> {
        if points.len() != NUM_LANDMARKS {
            return Err(Error::DimensionMismatch {
                what: "landmark points".into(),
                expected: NUM_LANDMARKS,
                got: points.len(),
            });
        }
        if positions.is_empty() || u32::try_from(positions.len()).is_err() {
            return Err(Error::DimensionMismatch {
                what: "mesh vertices (1 to u32::MAX)".into(),
                expected: 1,
                got: positions.len(),
            });
        }
        let mut vertices = [None; NUM_LANDMARKS];
        for (slot, q) in vertices.iter_mut().zip(points) {
            if !(q.x.is_finite() && q.y.is_finite() && q.z.is_finite()) {
                continue;
            }
            *slot = positions
                .iter()
                .map(|p| {
                    (f64::from(p.x) - q.x).powi(2) + (f64::from(p.y) - q.y).powi(2) + (f64::from(p.z) - q.z).powi(2)
                })
                .enumerate()
                .filter(|(_, d2)| d2.is_finite())
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, _)| i as u32);
        }
        Ok(LandmarkMap { vertices })
    }

    /// Reads one of the JSON forms in the module docs.
    pub fn from_json_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_json_str(&text).map_err(|e| e.at_path(path))
    }

    /// Parses one of the JSON forms in the module docs.
    pub fn from_json_str(text: &str) -> Result<Self> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| Error::parse(FORMAT, "", format!("invalid JSON: {e}")))?;
        let entry = |i: usize, v: &serde_json::Value| -> Result<Option<u32>> {
            if v.is_null() {
                return Ok(None);
            }
            match v.as_i64() {
                Some(-1) => Ok(None),
                Some(x) if (0..=u32::MAX as i64).contains(&x) => Ok(Some(x as u32)),
                _ => Err(Error::parse(
                    FORMAT,
                    "",
                    format!("entry for landmark {i} is {v}, expected a vertex id >= 0"),
                )),
            }
        };
        let from_array = |arr: &Vec<serde_json::Value>| -> Result<Self> {
            if arr.len() != NUM_LANDMARKS {
                return Err(Error::parse(
                    FORMAT,
                    "",
                    format!("expected 68 entries, found {}", arr.len()),
                ));
            }
            let v = arr
                .iter()
                .enumerate()
                .map(|(i, x)| entry(i, x))
                .collect::<Result<Vec<_>>>()?;
            Self::from_slice(&v)
        };
        match &value {
            serde_json::Value::Array(arr) => from_array(arr),
            serde_json::Value::Object(obj) => {
                if let Some(serde_json::Value::Array(arr)) = obj.get("vertex_by_ibug_0based") {
                    return from_array(arr);
                }
                if let Some(serde_json::Value::Object(m)) = obj.get("vertex_by_ibug_1based") {
                    let mut v = vec![None; NUM_LANDMARKS];
                    for (k, x) in m {
                        let id: usize = k
                            .parse()
                            .ok()
                            .filter(|id| (1..=NUM_LANDMARKS).contains(id))
                            .ok_or_else(|| Error::parse(FORMAT, "", format!("landmark id {k:?} is not in 1..=68")))?;
                        v[id - 1] = entry(id - 1, x)?;
                    }
                    return Self::from_slice(&v);
                }
                Err(Error::parse(
                    FORMAT,
                    "",
                    "object has neither vertex_by_ibug_0based nor vertex_by_ibug_1based",
                ))
            }
            _ => Err(Error::parse(FORMAT, "", "expected a JSON array or object")),
        }
    }

    /// Checks every mapped vertex is `< num_vertices`.
    pub fn validate(&self, num_vertices: usize) -> Result<()> {
        for (i, v) in self.vertices.iter().enumerate() {
            if let Some(v) = v {
                if *v as usize >= num_vertices {
                    return Err(Error::invalid(
                        "landmark map vertex",
                        format!("landmark {i} -> vertex {v}"),
                        format!("< {num_vertices}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// `(landmark index, vertex)` pairs of the mapped landmarks.
    pub fn mapped(&self) -> impl Iterator<Item = (usize, u32)> + '_ {
        self.vertices.iter().enumerate().filter_map(|(i, v)| v.map(|v| (i, v)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_array_and_rejections() {
        let arr: Vec<String> = (0..68).map(|i| i.to_string()).collect();
        let m = LandmarkMap::from_json_str(&format!("[{}]", arr.join(","))).unwrap();
        assert_eq!(m.vertices[5], Some(5));
        assert!(m.validate(68).is_ok());
        assert!(m.validate(10).is_err());
        assert!(LandmarkMap::from_json_str("[1,2,3]").is_err());
        assert!(LandmarkMap::from_json_str("{\"x\":1}").is_err());
        assert!(LandmarkMap::from_json_str("[").is_err());
    }

    #[test]
    fn shared_maps() {
        for (rel, mapped) in [
            ("models3d/ict_facekit/ict_landmarks68.json", 68),
            ("models3d/eos_sfm/sfm_landmarks68.json", 50),
        ] {
            let Some(p) = crate::paths::shared_data_file("landmark_map::shared_maps", rel) else {
                continue;
            };
            let m = LandmarkMap::from_json_file(&p).unwrap();
            assert_eq!(m.mapped().count(), mapped, "{rel}");
        }
    }
}
