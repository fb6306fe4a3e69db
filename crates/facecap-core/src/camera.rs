//! Pinhole cameras and rigid poses that name the frames they map between.
//!
//! Camera space follows OpenCV: +X right, +Y down, +Z forward; a point
//! `X_c = (x, y, z)` projects to pixel `(fx * x / z + cx, fy * y / z + cy)` in the
//! 0-based pixel convention of [`crate::landmarks`].

use nalgebra::{Isometry3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{ensure_finite, Error, Result};

/// Pinhole intrinsics (no distortion).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length in pixels along x.
    pub fx: f64,
    /// Focal length in pixels along y.
    pub fy: f64,
    /// Principal point x (0-based pixels).
    pub cx: f64,
    /// Principal point y (0-based pixels).
    pub cy: f64,
}

impl Intrinsics {
    /// Validated constructor: focal lengths finite and > 0, principal point finite.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self> {
        for (n, v) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
            ensure_finite(n, v)?;
        }
        if fx <= 0.0 {
            return Err(Error::invalid("fx", fx, "> 0"));
        }
        if fy <= 0.0 {
            return Err(Error::invalid("fy", fy, "> 0"));
        }
        Ok(Intrinsics { fx, fy, cx, cy })
    }

    /// The documented default camera when the user gives none:
    /// `fx = fy = max(width, height)`, principal point at the image centre
    /// `((width - 1) / 2, (height - 1) / 2)` in 0-based pixel coordinates.
    /// (A ~53 degree horizontal field of view for landscape frames, typical of webcams
    /// and phone video.)
    pub fn default_for_frame(width: u32, height: u32) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::invalid("frame size", format!("{width}x{height}"), "both > 0"));
        }
        let f = width.max(height) as f64;
        Intrinsics::new(f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0)
    }

    /// Projects a camera-space point; `None` when it is not in front of the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        Some(Point2::new(
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
        ))
    }
}

/// A rigid transform from model space to camera space: `X_c = R * X_m + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelToCamera(pub Isometry3<f64>);

impl ModelToCamera {
    /// Identity pose.
    pub fn identity() -> Self {
        ModelToCamera(Isometry3::identity())
    }

    /// From a rotation vector (axis * angle, radians) and a translation.
    pub fn from_rvec_tvec(rvec: Vector3<f64>, tvec: Vector3<f64>) -> Self {
        ModelToCamera(Isometry3::from_parts(
            Translation3::from(tvec),
            UnitQuaternion::from_scaled_axis(rvec),
        ))
    }

    /// Rotation vector (axis * angle, radians), OpenFace/OpenCV style.
    pub fn rvec(&self) -> Vector3<f64> {
        self.0.rotation.scaled_axis()
    }

    /// Translation in model units.
    pub fn tvec(&self) -> Vector3<f64> {
        self.0.translation.vector
    }

    /// Euler angles `(rx, ry, rz)` in radians with `R = Rz * Ry * Rx` — the
    /// `pose_Rx, pose_Ry, pose_Rz` columns of the pose CSV (pitch, yaw, roll).
    pub fn euler_xyz(&self) -> (f64, f64, f64) {
        let r: Rotation3<f64> = self.0.rotation.to_rotation_matrix();
        r.euler_angles()
    }

    /// Maps a model point to camera space.
    pub fn transform(&self, p: &Point3<f64>) -> Point3<f64> {
        self.0.transform_point(p)
    }

    /// Projects a model point to pixels through `k`.
    pub fn project(&self, k: &Intrinsics, p: &Point3<f64>) -> Option<Point2<f64>> {
        k.project(&self.transform(p))
    }
}
