//! menpo `.ljson` landmark files: read versions 1, 2 and 3, write version 3.
//!
//! * v3: `{"version": 3, "groups": {"<group>": {"landmarks": {"points": [...],
//!   "connectivity": [[a, b], ...]}, "labels": [{"label": "chin", "mask": [0, ...]}]}}}`
//! * v2: one such group at top level: `{"version": 2, "landmarks": {...}, "labels": [...]}`
//!   (read as a group named `"LJSON"`, menpo's default name).
//! * v1: `{"groups": [{"label": "chin", "landmarks": [{"point": [...]}], "connectivity": [...]}]}`
//!   (one group `"LJSON"`; each v1 group becomes a label, connectivity offset accordingly).
//!
//! **Axis order.** menpo stores image landmarks as `(y, x)` (row, column), 0-based;
//! mesh landmarks as `(x, y, z)`. 2D points are therefore swapped to `(x, y)` on read
//! so they follow the crate's pixel convention; 3D points are kept as they are (model
//! units). `null` coordinates (missing points) become NaN.

use std::path::Path;

use serde_json::json;

use nalgebra::{Point2, Point3};
use serde_json::Value;

use facecap_core::atomic::write_atomic;
use facecap_core::error::{Error, Result};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};

const FORMAT: &str = "menpo LJSON";
/// Group name menpo uses for v1/v2 files.
pub const DEFAULT_GROUP: &str = "LJSON";

/// Points of one group, converted to the crate's conventions.
#[derive(Debug, Clone, PartialEq)]
pub enum LjsonPoints {
    /// Image landmarks, `(x, y)` 0-based pixels (swapped from the file's `(y, x)`).
    D2(Vec<Point2<f64>>),
    /// Mesh landmarks `(x, y, z)` in model units.
    D3(Vec<Point3<f64>>),
}

impl LjsonPoints {
    /// Number of points.
    pub fn len(&self) -> usize {
        match self {
            LjsonPoints::D2(p) => p.len(),
            LjsonPoints::D3(p) => p.len(),
        }
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A labelled landmark group.
#[derive(Debug, Clone, PartialEq)]
pub struct LjsonGroup {
    /// Group name.
    pub name: String,
    /// The points.
    pub points: LjsonPoints,
    /// Undirected edges between point indices.
    pub connectivity: Vec<[usize; 2]>,
    /// `(label, point indices)` in file order.
    pub labels: Vec<(String, Vec<usize>)>,
}

impl LjsonGroup {
    /// The group as 68 image landmarks.
    ///
    /// # Errors
    /// [`Error::Parse`] for 3D points, another count or missing (NaN) points.
    pub fn landmarks68(&self) -> Result<Landmarks68> {
        match &self.points {
            LjsonPoints::D2(p) if p.len() == NUM_LANDMARKS => {
                let xy: Vec<(f64, f64)> = p.iter().map(|q| (q.x, q.y)).collect();
                Landmarks68::from_slice(&xy).map_err(|e| Error::parse(FORMAT, "", e.to_string()))
            }
            LjsonPoints::D2(p) => Err(Error::parse(
                FORMAT,
                "",
                format!("group {:?} has {} points, not 68", self.name, p.len()),
            )),
            LjsonPoints::D3(_) => Err(Error::parse(
                FORMAT,
                "",
                format!("group {:?} holds 3D (mesh) landmarks", self.name),
            )),
        }
    }
}

/// iBUG ranges of menpo's 68-point labels (`face_ibug_68` and the older 3D names).
const IBUG68_LABELS: [(&[&str], std::ops::Range<usize>); 7] = [
    (&["jaw", "chin"], 0..17),
    (&["left_eyebrow", "leyebrow"], 17..22),
    (&["right_eyebrow", "reyebrow"], 22..27),
    (&["nose"], 27..36),
    (&["left_eye", "leye"], 36..42),
    (&["right_eye", "reye"], 42..48),
    (&["mouth"], 48..68),
];

impl LjsonGroup {
    /// The file index of each iBUG landmark, from the group's labels (menpo's
    /// `face_ibug_68` names `jaw`, `left_eyebrow`, ... or the older `chin`, `leyebrow`,
    /// `leye`, ...; menpo's left is the image's left, iBUG 17-21 and 36-41), whatever order
    /// the labels come in.
    ///
    /// # Errors
    /// [`Error::Parse`] when a label is missing, its mask has the wrong length or points
    /// outside the group.
    pub fn ibug68_order(&self) -> Result<[usize; NUM_LANDMARKS]> {
        let mut order = [0usize; NUM_LANDMARKS];
        for (names, range) in IBUG68_LABELS {
            let Some((label, mask)) = self.labels.iter().find(|(l, _)| names.contains(&l.as_str())) else {
                return Err(Error::parse(
                    FORMAT,
                    "",
                    format!("group {:?} has no label {:?} (68-point labels)", self.name, names[0]),
                ));
            };
            if mask.len() != range.len() || mask.iter().any(|&i| i >= self.points.len()) {
                return Err(Error::parse(
                    FORMAT,
                    "",
                    format!(
                        "label {label:?} of group {:?}: {} points (want {}), or an index past its {} points",
                        self.name,
                        mask.len(),
                        range.len(),
                        self.points.len()
                    ),
                ));
            }
            for (slot, &i) in order[range].iter_mut().zip(mask) {
                *slot = i;
            }
        }
        Ok(order)
    }

    /// The group as 68 mesh (3D) landmarks in iBUG order ([`Self::ibug68_order`]).
    ///
    /// # Errors
    /// [`Error::Parse`] for 2D points or labels that do not give the 68 points.
    pub fn mesh_landmarks68(&self) -> Result<Vec<Point3<f64>>> {
        let LjsonPoints::D3(p) = &self.points else {
            return Err(Error::parse(
                FORMAT,
                "",
                format!("group {:?} holds 2D (image) landmarks", self.name),
            ));
        };
        Ok(self.ibug68_order()?.iter().map(|&i| p[i]).collect())
    }
}

/// A parsed `.ljson` file.
#[derive(Debug, Clone, PartialEq)]
pub struct Ljson {
    /// Format version (1, 2 or 3).
    pub version: u32,
    /// Groups; for v3 files sorted by name (JSON objects are read as sorted maps).
    pub groups: Vec<LjsonGroup>,
}

impl Ljson {
    /// A group by name.
    pub fn group(&self, name: &str) -> Option<&LjsonGroup> {
        self.groups.iter().find(|g| g.name == name)
    }
}

/// Reads a `.ljson` file (see module docs).
///
/// # Errors
/// [`Error::Io`]; [`Error::Parse`] (with line/column for JSON syntax errors) for
/// malformed JSON, an unknown version, mixed point dimensions, points that are not
/// 2D/3D, non-numeric coordinates, or masks/edges out of range.
pub fn read_ljson(path: impl AsRef<Path>) -> Result<Ljson> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_ljson(&bytes).map_err(|e| e.at_path(path))
}

fn perr(r: impl Into<String>) -> Error {
    Error::parse(FORMAT, "", r)
}

/// Parses `.ljson` bytes (errors carry an empty path).
///
/// # Errors
/// As [`read_ljson`].
pub fn parse_ljson(bytes: &[u8]) -> Result<Ljson> {
    let v: Value =
        serde_json::from_slice(bytes).map_err(|e| perr(format!("line {} column {}: {e}", e.line(), e.column())))?;
    let version = match v.get("version") {
        None | Some(Value::Null) => 1,
        Some(x) => x
            .as_u64()
            .filter(|&n| (1..=3).contains(&n))
            .ok_or_else(|| perr(format!("unsupported version {x}")))? as u32,
    };
    let groups = match version {
        3 => {
            let obj = v
                .get("groups")
                .and_then(Value::as_object)
                .ok_or_else(|| perr("v3 file without a \"groups\" object"))?;
            obj.iter()
                .map(|(name, g)| parse_group_v2(name, g))
                .collect::<Result<Vec<_>>>()?
        }
        2 => vec![parse_group_v2(DEFAULT_GROUP, &v)?],
        _ => vec![parse_v1(&v)?],
    };
    Ok(Ljson { version, groups })
}

fn coord(x: &Value, what: &str) -> Result<f64> {
    match x {
        Value::Null => Ok(f64::NAN),
        Value::Number(n) => n.as_f64().ok_or_else(|| perr(format!("{what}: {n} is not a float"))),
        other => Err(perr(format!("{what}: {other} is not a number"))),
    }
}

fn parse_points(list: &[&Value], group: &str) -> Result<LjsonPoints> {
    let mut dim = None;
    let mut flat: Vec<f64> = Vec::with_capacity(list.len() * 3);
    for (i, p) in list.iter().enumerate() {
        let arr = p
            .as_array()
            .ok_or_else(|| perr(format!("group {group:?} point {i} is not an array")))?;
        if arr.len() != 2 && arr.len() != 3 {
            return Err(perr(format!("group {group:?} point {i} has {} coordinates", arr.len())));
        }
        if *dim.get_or_insert(arr.len()) != arr.len() {
            return Err(perr(format!("group {group:?} mixes 2D and 3D points (point {i})")));
        }
        for c in arr {
            flat.push(coord(c, &format!("group {group:?} point {i}"))?);
        }
    }
    Ok(match dim {
        Some(3) => LjsonPoints::D3(flat.chunks_exact(3).map(|c| Point3::new(c[0], c[1], c[2])).collect()),
        // menpo image landmarks are (y, x): swap.
        _ => LjsonPoints::D2(flat.chunks_exact(2).map(|c| Point2::new(c[1], c[0])).collect()),
    })
}

fn index_list(v: &Value, n: usize, what: &str) -> Result<Vec<usize>> {
    let arr = v.as_array().ok_or_else(|| perr(format!("{what} is not an array")))?;
    arr.iter()
        .map(|x| {
            x.as_u64()
                .map(|i| i as usize)
                .filter(|&i| i < n)
                .ok_or_else(|| perr(format!("{what}: {x} is not a point index < {n}")))
        })
        .collect()
}

fn edges(v: Option<&Value>, n: usize, offset: usize, group: &str) -> Result<Vec<[usize; 2]>> {
    let Some(v) = v.filter(|v| !v.is_null()) else {
        return Ok(Vec::new());
    };
    let arr = v
        .as_array()
        .ok_or_else(|| perr(format!("group {group:?} connectivity is not an array")))?;
    arr.iter()
        .map(|e| {
            let ij = index_list(e, n.saturating_sub(offset), &format!("group {group:?} connectivity"))?;
            match ij.as_slice() {
                [a, b] => Ok([a + offset, b + offset]),
                _ => Err(perr(format!("group {group:?} connectivity entry {e} is not a pair"))),
            }
        })
        .collect()
}

fn parse_group_v2(name: &str, g: &Value) -> Result<LjsonGroup> {
    let lms = g
        .get("landmarks")
        .ok_or_else(|| perr(format!("group {name:?} without \"landmarks\"")))?;
    let pts = lms
        .get("points")
        .and_then(Value::as_array)
        .ok_or_else(|| perr(format!("group {name:?} without \"landmarks.points\" array")))?;
    let refs: Vec<&Value> = pts.iter().collect();
    let points = parse_points(&refs, name)?;
    let n = points.len();
    let connectivity = edges(lms.get("connectivity"), n, 0, name)?;
    let mut labels = Vec::new();
    if let Some(ls) = g.get("labels").filter(|v| !v.is_null()) {
        let ls = ls
            .as_array()
            .ok_or_else(|| perr(format!("group {name:?} labels is not an array")))?;
        for l in ls {
            let label = l
                .get("label")
                .and_then(Value::as_str)
                .ok_or_else(|| perr(format!("group {name:?}: label without a \"label\" string")))?;
            let mask = l
                .get("mask")
                .ok_or_else(|| perr(format!("group {name:?} label {label:?} without \"mask\"")))?;
            labels.push((
                label.to_owned(),
                index_list(mask, n, &format!("group {name:?} label {label:?} mask"))?,
            ));
        }
    }
    Ok(LjsonGroup {
        name: name.to_owned(),
        points,
        connectivity,
        labels,
    })
}

fn parse_v1(v: &Value) -> Result<LjsonGroup> {
    let groups = v
        .get("groups")
        .and_then(Value::as_array)
        .ok_or_else(|| perr("v1 file without a \"groups\" array"))?;
    // First pass: all points, to know the total count.
    let mut refs: Vec<&Value> = Vec::new();
    let mut spans = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        let label = g
            .get("label")
            .and_then(Value::as_str)
            .ok_or_else(|| perr(format!("v1 group {gi} without a \"label\" string")))?;
        let lms = g
            .get("landmarks")
            .and_then(Value::as_array)
            .ok_or_else(|| perr(format!("v1 group {label:?} without a \"landmarks\" array")))?;
        let start = refs.len();
        for (i, l) in lms.iter().enumerate() {
            refs.push(
                l.get("point")
                    .ok_or_else(|| perr(format!("v1 group {label:?} landmark {i} without \"point\"")))?,
            );
        }
        spans.push((label.to_owned(), start, refs.len(), g.get("connectivity")));
    }
    let points = parse_points(&refs, DEFAULT_GROUP)?;
    let mut connectivity = Vec::new();
    let mut labels = Vec::new();
    for (label, start, end, conn) in spans {
        connectivity.extend(edges(conn, end, start, &label)?);
        labels.push((label, (start..end).collect()));
    }
    Ok(LjsonGroup {
        name: DEFAULT_GROUP.to_owned(),
        points,
        connectivity,
        labels,
    })
}

impl Ljson {
    /// A version-3 file with one 2D group of 68 landmarks labelled by iBUG region
    /// (`jaw`, `brows`, `nose`, `eyes`, `mouth`).
    pub fn from_landmarks68(group: &str, landmarks: &Landmarks68) -> Self {
        let labels = facecap_core::landmarks::Region::ALL
            .iter()
            .map(|r| (r.name().to_owned(), r.indices().collect()))
            .collect();
        Ljson {
            version: 3,
            groups: vec![LjsonGroup {
                name: group.to_owned(),
                points: LjsonPoints::D2(landmarks.points.to_vec()),
                connectivity: Vec::new(),
                labels,
            }],
        }
    }
}

fn num_or_null(v: f64) -> Value {
    if v.is_nan() {
        Value::Null
    } else {
        json!(v)
    }
}

/// The version-3 JSON text of `ljson` (the `version` field is ignored: always 3).
///
/// # Errors
/// [`Error::InvalidParameter`] for infinite coordinates, duplicate group names,
/// masks or edges out of range.
pub fn ljson_to_string(ljson: &Ljson) -> Result<String> {
    let mut groups = serde_json::Map::new();
    for g in &ljson.groups {
        let n = g.points.len();
        let points: Vec<Value> = match &g.points {
            LjsonPoints::D2(p) => p.iter().map(|q| json!([num_or_null(q.y), num_or_null(q.x)])).collect(),
            LjsonPoints::D3(p) => p
                .iter()
                .map(|q| json!([num_or_null(q.x), num_or_null(q.y), num_or_null(q.z)]))
                .collect(),
        };
        let infinite = match &g.points {
            LjsonPoints::D2(p) => p.iter().any(|q| q.x.is_infinite() || q.y.is_infinite()),
            LjsonPoints::D3(p) => p
                .iter()
                .any(|q| q.x.is_infinite() || q.y.is_infinite() || q.z.is_infinite()),
        };
        if infinite {
            return Err(Error::invalid("LJSON point", &g.name, "finite coordinates or NaN"));
        }
        if g.connectivity.iter().flatten().any(|&i| i >= n) || g.labels.iter().any(|(_, m)| m.iter().any(|&i| i >= n)) {
            return Err(Error::invalid(
                "LJSON group",
                &g.name,
                format!("connectivity and masks indexing its {n} points"),
            ));
        }
        let labels: Vec<Value> = g.labels.iter().map(|(l, m)| json!({ "label": l, "mask": m })).collect();
        let group = json!({
            "landmarks": { "points": points, "connectivity": g.connectivity },
            "labels": labels,
        });
        if groups.insert(g.name.clone(), group).is_some() {
            return Err(Error::invalid("LJSON group name", &g.name, "unique group names"));
        }
    }
    let root = json!({ "version": 3, "groups": groups });
    serde_json::to_string_pretty(&root).map_err(|e| Error::invalid("LJSON document", e, "serialisable JSON"))
}

/// Writes `ljson` as a version-3 `.ljson` file (atomically).
///
/// # Errors
/// As [`ljson_to_string`], or [`Error::Io`].
pub fn write_ljson(path: impl AsRef<Path>, ljson: &Ljson) -> Result<()> {
    let text = ljson_to_string(ljson)?;
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}
