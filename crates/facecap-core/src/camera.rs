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

/// Model-to-camera rotation of a rig face looking straight into the camera.
///
/// Rigs are +X to the subject's left as seen by the camera (image right), +Y up and
/// +Z out of the face; the camera is +Y down and +Z forward, so a frontal face has
/// `F = diag(1, -1, -1)`.
pub const FACING_CAMERA: [f64; 3] = [1.0, -1.0, -1.0];

/// The head rotation *relative to facing the camera*: `R F` where `R` is the
/// model-to-camera rotation of `pose` and `F` = [`FACING_CAMERA`]. A frontal face gives
/// the identity; this is the rotation every facecap output reports (`pose.csv`,
/// `openface.csv`, `livelink.csv`, the glTF head node).
pub fn head_rotation(pose: &ModelToCamera) -> Rotation3<f64> {
    let flip = nalgebra::Matrix3::from_diagonal(&Vector3::from(FACING_CAMERA));
    Rotation3::from_matrix_unchecked(pose.0.rotation.to_rotation_matrix().matrix() * flip)
}

/// The one `pose.csv` row: `[Tx, Ty, Tz, Rx, Ry, Rz]`. Translation in model units in
/// camera axes (x right, y down, z forward); rotation [`head_rotation`] as Euler angles
/// in radians with `R = Rz(Rz) Ry(Ry) Rx(Rx)`: `Rx` pitch (positive: chin down in the
/// image), `Ry` yaw, `Rz` roll. `None` gives NaN.
pub fn pose_row(pose: Option<&ModelToCamera>) -> [f64; 6] {
    match pose {
        Some(p) => {
            let t = p.tvec();
            let (rx, ry, rz) = head_rotation(p).euler_angles();
            [t.x, t.y, t.z, rx, ry, rz]
        }
        None => [f64::NAN; 6],
    }
}

/// Euler angles `(a, b, c)` with `R = Rx(a) Ry(b) Rz(c)`, the order OpenFace 2.x writes
/// `pose_Rx, pose_Ry, pose_Rz` in (`RotationMatrix2Euler`).
pub fn euler_rx_ry_rz(r: &Rotation3<f64>) -> (f64, f64, f64) {
    let m = r.matrix();
    let b = m[(0, 2)].clamp(-1.0, 1.0).asin();
    let a = (-m[(1, 2)]).atan2(m[(2, 2)]);
    let c = (-m[(0, 1)]).atan2(m[(0, 0)]);
    (a, b, c)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod head_pose_tests {
    use super::*;

    #[test]
    fn frontal_face_reports_zero_rotation() {
        let frontal = ModelToCamera(Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 50.0),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_diagonal(
                &Vector3::from(FACING_CAMERA),
            ))),
        ));
        let row = pose_row(Some(&frontal));
        assert_eq!(&row[..3], &[1.0, 2.0, 50.0]);
        for v in &row[3..] {
            assert!(v.abs() < 1e-12, "{row:?}");
        }
        assert!(pose_row(None).iter().all(|v| v.is_nan()));
    }

    #[test]
    fn both_euler_orders_rebuild_the_rotation() {
        for (a, b, c) in [(0.1, -0.3, 0.2), (-0.5, 0.4, -0.7), (0.0, 0.0, 0.0), (1.2, -1.0, 2.5)] {
            let r = Rotation3::from_axis_angle(&Vector3::x_axis(), a)
                * Rotation3::from_axis_angle(&Vector3::y_axis(), b)
                * Rotation3::from_axis_angle(&Vector3::z_axis(), c);
            let (x, y, z) = euler_rx_ry_rz(&r);
            assert!((x - a).abs() < 1e-12 && (y - b).abs() < 1e-12 && (z - c).abs() < 1e-12);
            // pose_row's order: R = Rz Ry Rx
            let pose = ModelToCamera(Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_rotation_matrix(
                    &(r * Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_diagonal(&Vector3::from(
                        FACING_CAMERA,
                    )))),
                ),
            ));
            let row = pose_row(Some(&pose));
            let back = Rotation3::from_euler_angles(row[3], row[4], row[5]);
            assert!((back.matrix() - r.matrix()).abs().max() < 1e-9);
        }
    }
}
