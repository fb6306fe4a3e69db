//! Synthetic eyes for the gaze tests and bench: two almond-shaped eyes (parabolic lids
//! through the corners) with a dark iris disc at a known position, rendered with 4x4
//! supersampling, and the 68 landmarks with the 12 eye points placed on the drawn lids.
#![allow(dead_code)]

use facecap_core::landmarks::Landmarks68;
use image::GrayImage;
use nalgebra::{Point2, Vector2};

/// Skin, sclera and iris grey levels.
pub const SKIN: f64 = 150.0;
pub const SCLERA: f64 = 210.0;
pub const IRIS: f64 = 40.0;

/// One drawn eye.
#[derive(Clone, Copy, Debug)]
pub struct EyeSpec {
    /// Outer corner (pixels).
    pub outer: Point2<f64>,
    /// Inner corner (pixels).
    pub inner: Point2<f64>,
    /// Lid height at the middle (each lid), in corner distances.
    pub lid: f64,
    /// Iris centre in (u, v) eye coordinates.
    pub iris_uv: (f64, f64),
    /// Iris radius in corner distances.
    pub iris_r: f64,
    /// Right eye (normal points (-a_y, a_x)) or left (normal (a_y, -a_x)).
    pub right: bool,
}

impl EyeSpec {
    fn frame(&self) -> (Vector2<f64>, Vector2<f64>, f64) {
        let d = self.inner - self.outer;
        let l = d.norm();
        let a = d / l;
        let n = if self.right {
            Vector2::new(-a.y, a.x)
        } else {
            Vector2::new(a.y, -a.x)
        };
        (a, n, l)
    }

    /// Point at eye coordinates (u, v).
    pub fn at(&self, u: f64, v: f64) -> Point2<f64> {
        let (a, n, l) = self.frame();
        self.outer + (a * u + n * v) * l
    }

    /// Iris centre in pixels.
    pub fn iris_px(&self) -> Point2<f64> {
        self.at(self.iris_uv.0, self.iris_uv.1)
    }

    /// Grey level at a pixel sub-sample, `None` outside the eye.
    fn shade(&self, p: Point2<f64>) -> Option<f64> {
        let (a, n, l) = self.frame();
        let d = p - self.outer;
        let (u, v) = (d.dot(&a) / l, d.dot(&n) / l);
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let lid = 4.0 * self.lid * u * (1.0 - u);
        if v.abs() > lid {
            return None;
        }
        let (du, dv) = (u - self.iris_uv.0, v - self.iris_uv.1);
        Some(if (du * du + dv * dv).sqrt() <= self.iris_r {
            IRIS
        } else {
            SCLERA
        })
    }

    /// The 6 landmarks in iBUG order for this eye: for the right eye 36 outer, 37, 38
    /// upper, 39 inner, 40, 41 lower; for the left eye 42 inner, 43, 44 upper, 45 outer,
    /// 46, 47 lower.
    pub fn landmarks(&self, lm: &mut Landmarks68) {
        let h = 4.0 * self.lid * (1.0 / 3.0) * (2.0 / 3.0);
        if self.right {
            lm.points[36] = self.at(0.0, 0.0);
            lm.points[37] = self.at(1.0 / 3.0, -h);
            lm.points[38] = self.at(2.0 / 3.0, -h);
            lm.points[39] = self.at(1.0, 0.0);
            lm.points[40] = self.at(2.0 / 3.0, h);
            lm.points[41] = self.at(1.0 / 3.0, h);
        } else {
            lm.points[42] = self.at(1.0, 0.0);
            lm.points[43] = self.at(2.0 / 3.0, -h);
            lm.points[44] = self.at(1.0 / 3.0, -h);
            lm.points[45] = self.at(0.0, 0.0);
            lm.points[46] = self.at(1.0 / 3.0, h);
            lm.points[47] = self.at(2.0 / 3.0, h);
        }
    }
}

/// A face: the two eyes, upright or rolled by `roll` radians about `centre`, eye width
/// `width` px, iris positions per eye.
pub fn face(
    centre: Point2<f64>,
    width: f64,
    roll: f64,
    lid: f64,
    right_iris: (f64, f64),
    left_iris: (f64, f64),
    iris_r: f64,
) -> [EyeSpec; 2] {
    let (c, s) = (roll.cos(), roll.sin());
    let rot = |x: f64, y: f64| Point2::new(centre.x + c * x - s * y, centre.y + s * x + c * y);
    let gap = 0.5 * width; // half the distance between the inner corners
    [
        EyeSpec {
            outer: rot(-gap - width, 0.0),
            inner: rot(-gap, 0.0),
            lid,
            iris_uv: right_iris,
            iris_r,
            right: true,
        },
        EyeSpec {
            outer: rot(gap + width, 0.0),
            inner: rot(gap, 0.0),
            lid,
            iris_uv: left_iris,
            iris_r,
            right: false,
        },
    ]
}

/// Renders the eyes on skin (4x4 supersampling, rounded to 8 bit) and returns the image
/// and the landmarks (non-eye points at the image centre).
pub fn render(w: u32, h: u32, eyes: &[EyeSpec; 2]) -> (GrayImage, Landmarks68) {
    const SS: usize = 4;
    let img = GrayImage::from_fn(w, h, |x, y| {
        let mut acc = 0.0;
        for sy in 0..SS {
            for sx in 0..SS {
                let p = Point2::new(
                    x as f64 + (sx as f64 + 0.5) / SS as f64 - 0.5,
                    y as f64 + (sy as f64 + 0.5) / SS as f64 - 0.5,
                );
                acc += eyes.iter().find_map(|e| e.shade(p)).unwrap_or(SKIN);
            }
        }
        image::Luma([(acc / (SS * SS) as f64).round() as u8])
    });
    let mut lm = Landmarks68::default();
    for p in lm.points.iter_mut() {
        *p = Point2::new(w as f64 / 2.0, h as f64 / 2.0);
    }
    for e in eyes {
        e.landmarks(&mut lm);
    }
    (img, lm)
}
