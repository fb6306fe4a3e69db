//! The iBUG / Multi-PIE 68-point landmark scheme.
//!
//! Points are stored in **0-based pixel coordinates**: the centre of the top-left
//! pixel is `(0, 0)`, x right, y down (dlib and OpenCV convention). iBUG `.pts`
//! files are 1-based and are shifted by one on read and write.
//!
//! | region | 0-based indices |
//! |---|---|
//! | jaw | 0-16 |
//! | right brow (subject's) | 17-21 |
//! | left brow | 22-26 |
//! | nose | 27-35 |
//! | right eye | 36-41 |
//! | left eye | 42-47 |
//! | mouth (outer 48-59, inner 60-67) | 48-67 |

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Number of points in the iBUG scheme.
pub const NUM_LANDMARKS: usize = 68;
/// Index of the right eye's outer corner (image left for a frontal face).
pub const OUTER_EYE_RIGHT: usize = 36;
/// Index of the left eye's outer corner (image right for a frontal face).
pub const OUTER_EYE_LEFT: usize = 45;
/// The six points of each eye, right eye (image left) first, in iBUG order: corner, upper
/// lid (two points), corner, lower lid (two points, walking back), so point 1 faces 5 and
/// 2 faces 4.
pub const EYES: [[usize; 6]; 2] = [[36, 37, 38, 39, 40, 41], [42, 43, 44, 45, 46, 47]];

/// Eye aspect ratio of six eye points in the order of [`EYES`] (or any walk around the
/// eye where point 1 faces 5 and 2 faces 4): the mean of the two lid distances over the
/// corner distance `|p3 - p0|`. NaN when the corners coincide or a point is not finite.
pub fn eye_aspect_ratio(pts: &[Point2<f64>; 6]) -> f64 {
    let l = (pts[3] - pts[0]).norm();
    if l > 0.0 {
        ((pts[1] - pts[5]).norm() + (pts[2] - pts[4]).norm()) / (2.0 * l)
    } else {
        f64::NAN
    }
}

/// Named regions of the 68-point scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Region {
    /// Jaw line, 0-16.
    Jaw,
    /// Both eyebrows, 17-26.
    Brows,
    /// Nose bridge and base, 27-35.
    Nose,
    /// Both eyes, 36-47.
    Eyes,
    /// Outer and inner lips, 48-67.
    Mouth,
}

impl Region {
    /// All regions in index order.
    pub const ALL: [Region; 5] = [Region::Jaw, Region::Brows, Region::Nose, Region::Eyes, Region::Mouth];

    /// The 0-based index range of the region.
    pub fn indices(self) -> std::ops::Range<usize> {
        match self {
            Region::Jaw => 0..17,
            Region::Brows => 17..27,
            Region::Nose => 27..36,
            Region::Eyes => 36..48,
            Region::Mouth => 48..68,
        }
    }

    /// The region a landmark index belongs to, or `None` when out of range.
    pub fn of(index: usize) -> Option<Region> {
        Region::ALL.into_iter().find(|r| r.indices().contains(&index))
    }

    /// Lower-case name used in files and docs.
    pub fn name(self) -> &'static str {
        match self {
            Region::Jaw => "jaw",
            Region::Brows => "brows",
            Region::Nose => "nose",
            Region::Eyes => "eyes",
            Region::Mouth => "mouth",
        }
    }
}

/// An axis-aligned face box in pixel coordinates (0-based, see module docs).
///
/// `left`/`top` is the top-left corner, `width`/`height` the extent. dlib's
/// inclusive integer rectangles `(l, t, r, b)` map to `Rect { left: l, top: t,
/// width: r - l + 1, height: b - t + 1 }` (see [`Rect::from_dlib`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rect {
    /// x of the left edge.
    pub left: f64,
    /// y of the top edge.
    pub top: f64,
    /// Width in pixels (> 0 for a valid box).
    pub width: f64,
    /// Height in pixels (> 0 for a valid box).
    pub height: f64,
}

impl Rect {
    /// Creates a box, rejecting non-finite values and non-positive sizes.
    pub fn new(left: f64, top: f64, width: f64, height: f64) -> Result<Self> {
        for (name, v) in [
            ("rect.left", left),
            ("rect.top", top),
            ("rect.width", width),
            ("rect.height", height),
        ] {
            crate::error::ensure_finite(name, v)?;
        }
        if width <= 0.0 {
            return Err(Error::invalid("rect.width", width, "> 0"));
        }
        if height <= 0.0 {
            return Err(Error::invalid("rect.height", height, "> 0"));
        }
        Ok(Rect {
            left,
            top,
            width,
            height,
        })
    }

    /// From dlib's inclusive integer rectangle `(left, top, right, bottom)`.
    pub fn from_dlib(left: i64, top: i64, right: i64, bottom: i64) -> Self {
        Rect {
            left: left as f64,
            top: top as f64,
            width: (right - left + 1) as f64,
            height: (bottom - top + 1) as f64,
        }
    }

    /// Back to dlib's inclusive integer rectangle `(left, top, right, bottom)`
    /// (rounded to nearest).
    pub fn to_dlib(&self) -> (i64, i64, i64, i64) {
        let l = self.left.round() as i64;
        let t = self.top.round() as i64;
        let r = (self.left + self.width).round() as i64 - 1;
        let b = (self.top + self.height).round() as i64 - 1;
        (l, t, r, b)
    }

    /// x of the right edge (exclusive).
    pub fn right(&self) -> f64 {
        self.left + self.width
    }

    /// y of the bottom edge (exclusive).
    pub fn bottom(&self) -> f64 {
        self.top + self.height
    }

    /// Area in square pixels.
    pub fn area(&self) -> f64 {
        self.width.max(0.0) * self.height.max(0.0)
    }

    /// Intersection over union with another box (0 when disjoint).
    pub fn iou(&self, other: &Rect) -> f64 {
        let iw = (self.right().min(other.right()) - self.left.max(other.left)).max(0.0);
        let ih = (self.bottom().min(other.bottom()) - self.top.max(other.top)).max(0.0);
        let inter = iw * ih;
        let union = self.area() + other.area() - inter;
        if union > 0.0 {
            inter / union
        } else {
            0.0
        }
    }
}

/// 68 landmarks in the iBUG order, 0-based pixel coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Landmarks68 {
    /// The points, index `i` is iBUG point `i` (0-based).
    pub points: [Point2<f64>; NUM_LANDMARKS],
}

impl Default for Landmarks68 {
    fn default() -> Self {
        Landmarks68 {
            points: [Point2::origin(); NUM_LANDMARKS],
        }
    }
}

impl Landmarks68 {
    /// Builds landmarks from a function of the index returning `(x, y)`.
    pub fn from_fn(mut f: impl FnMut(usize) -> (f64, f64)) -> Self {
        let mut out = Landmarks68::default();
        for (i, p) in out.points.iter_mut().enumerate() {
            let (x, y) = f(i);
            *p = Point2::new(x, y);
        }
        out
    }

    /// Builds landmarks from a slice of exactly 68 `(x, y)` pairs, rejecting
    /// other lengths and non-finite values.
    pub fn from_slice(xy: &[(f64, f64)]) -> Result<Self> {
        if xy.len() != NUM_LANDMARKS {
            return Err(Error::DimensionMismatch {
                what: "landmark count".into(),
                expected: NUM_LANDMARKS,
                got: xy.len(),
            });
        }
        let mut out = Landmarks68::default();
        for (i, &(x, y)) in xy.iter().enumerate() {
            if !x.is_finite() || !y.is_finite() {
                return Err(Error::invalid(
                    "landmark coordinate",
                    format!("point {i} = ({x}, {y})"),
                    "finite numbers",
                ));
            }
            out.points[i] = Point2::new(x, y);
        }
        Ok(out)
    }

    /// Distance between the outer eye corners (points 36 and 45), the normaliser
    /// of the "inter-ocular normalised mean error" of 300-W.
    pub fn interocular_distance(&self) -> f64 {
        (self.points[OUTER_EYE_LEFT] - self.points[OUTER_EYE_RIGHT]).norm()
    }

    /// Mean point-to-point distance to `other` divided by `other`'s inter-ocular
    /// distance (`other` is the ground truth).
    pub fn normalised_mean_error(&self, truth: &Landmarks68) -> f64 {
        let mean = self
            .points
            .iter()
            .zip(truth.points.iter())
            .map(|(a, b)| (a - b).norm())
            .sum::<f64>()
            / NUM_LANDMARKS as f64;
        mean / truth.interocular_distance()
    }

    /// Tight bounding box of the points (zero-size boxes are widened to 1 px).
    pub fn bounding_box(&self) -> Rect {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in &self.points {
            x0 = x0.min(p.x);
            y0 = y0.min(p.y);
            x1 = x1.max(p.x);
            y1 = y1.max(p.y);
        }
        Rect {
            left: x0,
            top: y0,
            width: (x1 - x0).max(1.0),
            height: (y1 - y0).max(1.0),
        }
    }

    /// True when every coordinate is finite.
    pub fn is_finite(&self) -> bool {
        self.points.iter().all(|p| p.x.is_finite() && p.y.is_finite())
    }
}
