//! The eyes of the 478-point mesh: per eye an outline of six vertices and the iris
//! centre, for gaze measured from the mesh itself (the iris position between the eye
//! corners and lids).
//!
//! MediaPipe's topology: the subject's right eye (image left) runs from the outer corner
//! 33 to the inner corner 133, upper lid `33 246 161 160 159 158 157 173 133`, lower lid
//! `33 7 163 144 145 153 154 155 133`; the left eye from 263 to 362, upper lid
//! `263 466 388 387 386 385 384 398 362`, lower lid `263 249 390 373 374 380 381 382 362`.
//! The outlines below take the corners and the lid vertices a third and two thirds of the
//! way along, in the iBUG walk order (outer corner, upper lid outer then inner, inner
//! corner, lower lid inner then outer), as `facecap_landmarks::gaze` expects. The corners
//! are the mesh's own canthi (133 / 362), not the vertices nearest dlib's inner corners
//! that [`crate::ibug68`] uses (155 / 382).

/// Subject's right eye (image left), iBUG walk order.
pub const RIGHT_EYE_OUTLINE: [usize; 6] = [33, 160, 158, 133, 153, 144];
/// Subject's left eye (image right), iBUG walk order.
pub const LEFT_EYE_OUTLINE: [usize; 6] = [263, 387, 385, 362, 380, 373];
/// Iris centre of the subject's right eye.
pub const RIGHT_IRIS_CENTER: usize = crate::tracker::IRIS_CENTERS[0];
/// Iris centre of the subject's left eye.
pub const LEFT_IRIS_CENTER: usize = crate::tracker::IRIS_CENTERS[1];

/// One eye in image pixels: its six outline points `(x, y)` and its iris centre.
pub type EyePoints = ([(f64, f64); 6], (f64, f64));

/// One eye's outline `(x, y)` and iris centre from a mesh's points (`None` when it has
/// fewer than the 478 points).
pub fn eye(points: &[[f32; 3]], outline: &[usize; 6], iris: usize) -> Option<EyePoints> {
    if points.len() < crate::tracker::NUM_LANDMARKS {
        return None;
    }
    let xy = |i: usize| (f64::from(points[i][0]), f64::from(points[i][1]));
    Some((outline.map(xy), xy(iris)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outlines_are_face_vertices_and_irises_are_iris_vertices() {
        for v in RIGHT_EYE_OUTLINE.iter().chain(&LEFT_EYE_OUTLINE) {
            assert!(*v < 468);
        }
        assert_eq!((RIGHT_IRIS_CENTER, LEFT_IRIS_CENTER), (468, 473));
        // the rotation landmarks of the tracker are the outer corners
        assert_eq!(
            [RIGHT_EYE_OUTLINE[0], LEFT_EYE_OUTLINE[0]],
            crate::tracker::ROTATION_LANDMARKS
        );
        assert!(eye(&[[0.0; 3]; 100], &RIGHT_EYE_OUTLINE, RIGHT_IRIS_CENTER).is_none());
        let pts: Vec<[f32; 3]> = (0..478).map(|i| [i as f32, 1.0, 0.0]).collect();
        let (o, c) = eye(&pts, &LEFT_EYE_OUTLINE, LEFT_IRIS_CENTER).unwrap();
        assert_eq!(o[3], (362.0, 1.0));
        assert_eq!(c, (473.0, 1.0));
    }
}
