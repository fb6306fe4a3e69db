//! The iBUG 68-point layout (dlib's) from the 478-point face mesh: one mesh vertex per
//! iBUG point, so that everything built on 68 points (rigs' landmark maps, the solvers,
//! the CSV layouts) runs on the mesh front end unchanged.
//!
//! Chosen per iBUG point as the mesh vertex nearest to it on average (distance over the
//! inter-ocular distance) over 1,811 frames of three shared clips where both front ends
//! tracked the face; brows follow MediaPipe's brow contour (70, 63, 105, 66, 107 and
//! mirrored). Mean distance to dlib's points on two other clips: 0.051 IOD (eyes 0.020,
//! jaw 0.093: the mesh's jaw vertices lie on the face, dlib's on the silhouette).

/// Mesh vertex of each iBUG point (0-based iBUG order).
pub const IBUG68_FROM_MESH: [usize; 68] = [
    // jaw 0-16
    127, 234, 177, 215, 138, 136, 149, 176, 152, 377, 378, 365, 367, 435, 401, 454, 356, // brows 17-26
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300, // nose 27-35
    168, 197, 195, 4, 240, 97, 2, 326, 460, // eyes 36-47
    33, 160, 158, 155, 153, 144, 382, 385, 387, 263, 373, 380, // mouth 48-67
    61, 74, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181, 78, 82, 13, 312, 308, 317, 14, 87,
];

/// The 68 iBUG points `(x, y)` of a mesh's 478 points (`None` when it has fewer).
pub fn ibug68(points: &[[f32; 3]]) -> Option<[(f64, f64); 68]> {
    if points.len() < crate::tracker::NUM_LANDMARKS {
        return None;
    }
    Some(IBUG68_FROM_MESH.map(|v| (f64::from(points[v][0]), f64::from(points[v][1]))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertices_are_mesh_vertices_and_distinct() {
        let mut seen = std::collections::HashSet::new();
        for v in IBUG68_FROM_MESH {
            assert!(v < 468, "{v} is not a face-mesh vertex");
            assert!(seen.insert(v), "{v} twice");
        }
        assert!(ibug68(&[[0.0; 3]; 10]).is_none());
        let pts: Vec<[f32; 3]> = (0..478).map(|i| [i as f32, 2.0 * i as f32, 0.0]).collect();
        let l = ibug68(&pts).unwrap();
        assert_eq!(l[8], (152.0, 304.0));
    }
}
