//! The default rig used when `facecap capture` gets no `--rig`: built here at start-up
//! from the mean face below and the canonical face mesh in the model cache (no rig file).
//!
//! * **Neutral landmarks**: a 68-point 3D mean face (iBUG order, centimetres, +Y up,
//!   +Z out of the face). The numbers are the 68 landmark vertices of the ICT-FaceKit
//!   generic neutral mesh (USC ICT, MIT licence), rounded to 0.1 mm.
//! * **Mesh**: MediaPipe's canonical face mesh (468 vertices, its triangles and texture
//!   coordinates; Apache-2.0, read from the model cache, where `scripts/setup.sh` puts it),
//!   aligned to the mean face by a similarity and warped by a 3D thin-plate spline so
//!   that its 68 landmark vertices (`facecap_mesh::ibug68::IBUG68_FROM_MESH`) land exactly
//!   on the mean face's points. The triangles across the inner lips are left out (the
//!   mouth opening). Vertex `i` is face-mesh landmark `i`, so the mesh front end's points
//!   are the rig's vertices.
//! * **Blendshapes**: ARKit-named expression shapes (`jawOpen`, `mouthSmileLeft`, ...)
//!   defined as 3D displacements of the 68 landmarks (FACS-style: which points move,
//!   which way, by how many cm) and, for shapes the landmarks do not carry (cheeks, nose
//!   wings), of a few more mesh vertices; spread over the rest of the mesh harmonically
//!   (`facecap_geom::harmonic`: every other vertex the weighted mean of its neighbours,
//!   no overshoot) along the skin, without the triangles across the eye openings, so
//!   one lid moves without the other, and the lips part along the mouth opening; the
//!   forehead's edge stays. "Left" is the subject's left (image right, +X).

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_geom::align::umeyama3;
use facecap_geom::harmonic::Harmonic;
use facecap_geom::tps::Tps3;
use facecap_mesh::canonical::CanonicalMesh;
use facecap_mesh::ibug68::IBUG68_FROM_MESH;
use facecap_muscle::synthetic::mirror_landmark;
use nalgebra::{Point3, Vector3};

/// 3D mean face, iBUG-68 order, cm (see module docs).
pub const MEAN_FACE_68_CM: [[f64; 3]; 68] = [
    [-7.3630, 3.6763, 3.6567],
    [-7.2762, 1.4911, 3.9250],
    [-6.9376, -0.4614, 4.5329],
    [-6.5567, -2.3563, 5.1738],
    [-5.7241, -4.4868, 6.1275],
    [-4.3023, -6.2072, 7.3472],
    [-3.0511, -6.9123, 8.7710],
    [-1.5369, -7.2580, 10.2709],
    [0.0000, -7.5671, 10.4320],
    [1.5369, -7.2580, 10.2709],
    [3.0511, -6.9123, 8.7710],
    [4.3023, -6.2072, 7.3472],
    [5.7241, -4.4868, 6.1275],
    [6.5567, -2.3563, 5.1738],
    [6.9376, -0.4614, 4.5329],
    [7.2762, 1.4911, 3.9250],
    [7.3630, 3.6763, 3.6567],
    [-5.8154, 5.1987, 7.9104],
    [-4.9326, 5.9768, 8.9889],
    [-3.7933, 6.2551, 9.8275],
    [-2.4145, 6.1917, 10.4817],
    [-1.1719, 5.9083, 10.7279],
    [1.1719, 5.9083, 10.7279],
    [2.4145, 6.1917, 10.4817],
    [3.7933, 6.2551, 9.8275],
    [4.9326, 5.9768, 8.9889],
    [5.8154, 5.1987, 7.9104],
    [0.0000, 3.7410, 10.7344],
    [0.0000, 2.6343, 11.5179],
    [0.0000, 1.6116, 12.3060],
    [0.0000, 0.4059, 13.0691],
    [-1.2531, -1.1447, 10.8712],
    [-0.6024, -1.1377, 11.4192],
    [0.0000, -1.2033, 11.5657],
    [0.6024, -1.1377, 11.4192],
    [1.2531, -1.1447, 10.8712],
    [-4.4590, 3.4321, 8.6029],
    [-3.8691, 3.8747, 9.3627],
    [-2.7813, 3.9361, 9.5314],
    [-1.8438, 3.2519, 9.1957],
    [-2.7292, 3.0847, 9.4139],
    [-3.8560, 3.0716, 9.2287],
    [1.8441, 3.2524, 9.1955],
    [2.7813, 3.9361, 9.5314],
    [3.8691, 3.8747, 9.3627],
    [4.4590, 3.4321, 8.6029],
    [3.8560, 3.0716, 9.2287],
    [2.7292, 3.0847, 9.4139],
    [-2.5349, -3.5196, 10.1875],
    [-1.7021, -2.7768, 11.2210],
    [-0.7282, -2.4223, 11.7294],
    [0.0000, -2.4825, 11.8387],
    [0.7282, -2.4223, 11.7294],
    [1.7021, -2.7768, 11.2210],
    [2.5349, -3.5196, 10.1875],
    [1.8008, -4.0565, 10.8984],
    [1.0343, -4.3023, 11.3885],
    [0.0000, -4.3769, 11.5492],
    [-1.0343, -4.3023, 11.3885],
    [-1.8008, -4.0565, 10.8984],
    [-2.2092, -3.4901, 10.1277],
    [-0.9963, -3.2969, 11.0867],
    [0.0000, -3.3235, 11.2810],
    [0.9963, -3.2969, 11.0867],
    [2.2092, -3.4901, 10.1277],
    [1.0692, -3.3797, 11.0401],
    [0.0000, -3.3998, 11.2526],
    [-1.0692, -3.3797, 11.0401],
];

/// The face mesh's inner lip ring (both lips' inner edges, corner to corner): the
/// triangles spanning it close the mouth in the canonical mesh and are left out.
const MESH_INNER_LIP: [usize; 20] = [
    78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 324, 318, 402, 317, 14, 87, 178, 88, 95,
];

/// The face mesh's eye openings (lid edges of each eye): their triangles are kept for
/// drawing but carry no displacement from one lid to the other.
const MESH_EYE_OPENINGS: [[usize; 16]; 2] = [
    [
        33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246,
    ],
    [
        263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466,
    ],
];

/// Names of the default rig's blendshapes: ARKit's 52, the first 16 in the order of the
/// earlier 16-shape rig (synthetic clips and their truth use these).
pub const DEFAULT_SHAPES: [&str; 52] = [
    "jawOpen",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthPucker",
    "mouthStretchLeft",
    "mouthStretchRight",
    "browInnerUp",
    "browDownLeft",
    "browDownRight",
    "browOuterUpLeft",
    "browOuterUpRight",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "mouthRollLower",
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
    "eyeSquintLeft",
    "eyeSquintRight",
    "eyeWideLeft",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "mouthClose",
    "mouthFunnel",
    "mouthLeft",
    "mouthRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// `mouthLeft` at the 68 landmarks (cm), from ICT-FaceKit's shape (MIT); `mouthRight` is its
/// mirror image ([`sided`]).
const MOUTH_LEFT_CM: [(usize, [f64; 3]); 29] = [
    (4, [0.36, 0.0, 0.43]),
    (5, [0.39, -0.04, 0.52]),
    (6, [0.35, 0.02, 0.43]),
    (7, [0.34, 0.05, 0.25]),
    (8, [0.24, 0.02, 0.09]),
    (9, [0.25, 0.07, -0.06]),
    (10, [0.17, 0.12, -0.14]),
    (11, [0.08, 0.16, -0.04]),
    (12, [0.12, 0.14, 0.08]),
    (48, [1.55, 0.04, 0.93]),
    (49, [1.67, -0.07, 0.43]),
    (50, [1.68, 0.03, -0.07]),
    (51, [1.61, 0.08, -0.33]),
    (52, [1.36, 0.13, -0.48]),
    (53, [0.96, 0.26, -0.57]),
    (54, [0.61, 0.57, -0.41]),
    (55, [1.0, 0.32, -0.49]),
    (56, [1.27, 0.18, -0.52]),
    (57, [1.58, 0.07, -0.34]),
    (58, [1.72, 0.01, 0.03]),
    (59, [1.77, -0.01, 0.47]),
    (60, [1.51, 0.08, 0.8]),
    (61, [1.53, 0.02, 0.11]),
    (62, [1.41, 0.03, -0.28]),
    (63, [1.09, 0.16, -0.45]),
    (64, [0.64, 0.5, -0.31]),
    (65, [1.11, 0.21, -0.36]),
    (66, [1.36, 0.1, -0.2]),
    (67, [1.56, 0.05, 0.2]),
];

/// `mouthUpperUpLeft` at the 68 landmarks (cm), from ICT-FaceKit's `mouthUpperUp_L` (MIT);
/// the right is its mirror image ([`sided`]).
const MOUTH_UPPER_UP_LEFT_CM: [(usize, [f64; 3]); 15] = [
    (11, [-0.01, 0.07, 0.09]),
    (12, [-0.03, 0.07, 0.09]),
    (32, [-0.04, 0.12, -0.05]),
    (33, [0.0, 0.13, -0.06]),
    (34, [0.08, 0.23, -0.1]),
    (35, [0.17, 0.51, -0.14]),
    (49, [-0.01, 0.05, 0.0]),
    (50, [-0.04, 0.26, -0.04]),
    (51, [0.0, 0.4, -0.06]),
    (52, [0.1, 0.57, -0.08]),
    (53, [0.21, 0.81, -0.04]),
    (55, [0.01, 0.09, 0.02]),
    (61, [-0.04, 0.18, -0.01]),
    (62, [0.0, 0.38, -0.03]),
    (63, [0.14, 0.59, -0.02]),
];

/// `mouthPucker` at the lips' 20 landmarks (cm), from ICT-FaceKit's shape (MIT).
const MOUTH_PUCKER_CM: [(usize, [f64; 3]); 20] = [
    (48, [0.46, 0.22, 0.98]),
    (49, [0.21, 0.25, 0.91]),
    (50, [0.07, 0.36, 0.79]),
    (51, [0.0, 0.37, 0.8]),
    (52, [-0.07, 0.36, 0.79]),
    (53, [-0.21, 0.25, 0.91]),
    (54, [-0.46, 0.22, 0.98]),
    (55, [-0.31, 0.07, 0.91]),
    (56, [-0.18, -0.1, 0.73]),
    (57, [0.0, -0.19, 0.63]),
    (58, [0.18, -0.1, 0.73]),
    (59, [0.31, 0.07, 0.91]),
    (60, [0.52, 0.21, 1.09]),
    (61, [0.25, -0.09, 0.85]),
    (62, [0.0, -0.03, 0.69]),
    (63, [-0.25, -0.09, 0.85]),
    (64, [-0.52, 0.21, 1.09]),
    (65, [-0.25, 0.08, 1.05]),
    (66, [0.0, 0.02, 0.9]),
    (67, [0.25, 0.08, 1.05]),
];

/// `mouthPressLeft` at the 68 landmarks (cm), from ICT-FaceKit's `mouthPress_L` (MIT): the lower
/// lip and chin rise and come forward on that side; the right is its mirror image ([`sided`]).
const MOUTH_PRESS_LEFT_CM: [(usize, [f64; 3]); 27] = [
    (7, [0.0, 0.04, 0.02]),
    (8, [0.0, 0.22, 0.13]),
    (9, [-0.02, 0.38, 0.17]),
    (10, [-0.02, 0.21, 0.2]),
    (11, [-0.08, 0.13, 0.12]),
    (12, [-0.07, 0.04, 0.04]),
    (28, [0.0, -0.03, 0.01]),
    (29, [0.0, -0.04, -0.01]),
    (30, [0.0, -0.04, -0.04]),
    (33, [0.0, -0.02, 0.03]),
    (34, [0.01, -0.02, 0.03]),
    (35, [0.02, -0.01, 0.09]),
    (50, [0.02, -0.04, -0.02]),
    (51, [0.0, -0.07, -0.04]),
    (52, [-0.05, -0.09, -0.04]),
    (53, [-0.09, -0.01, -0.01]),
    (54, [-0.01, 0.13, 0.05]),
    (55, [0.0, 0.28, 0.13]),
    (56, [-0.01, 0.24, 0.11]),
    (57, [0.0, 0.15, 0.09]),
    (58, [0.0, 0.08, 0.04]),
    (62, [0.0, -0.03, -0.04]),
    (63, [-0.03, 0.02, -0.04]),
    (64, [-0.03, 0.16, 0.06]),
    (65, [0.0, 0.17, 0.07]),
    (66, [0.0, 0.09, 0.07]),
    (67, [0.0, 0.05, 0.02]),
];
/// `mouthFrownLeft` at the 68 landmarks (cm), from ICT-FaceKit's `mouthFrown_L` (MIT): the corner
/// down, out and back, the chin forward; the right is its mirror image ([`sided`]).
const MOUTH_FROWN_LEFT_CM: [(usize, [f64; 3]); 24] = [
    (8, [0.0, 0.05, 0.07]),
    (9, [-0.02, 0.05, 0.13]),
    (10, [0.0, -0.06, 0.14]),
    (11, [-0.01, -0.06, 0.08]),
    (12, [-0.02, -0.05, 0.05]),
    (13, [-0.04, -0.04, 0.03]),
    (14, [-0.02, -0.05, 0.01]),
    (15, [-0.01, -0.03, 0.0]),
    (32, [0.0, -0.03, -0.01]),
    (33, [0.0, -0.03, -0.02]),
    (34, [0.0, -0.06, -0.02]),
    (35, [0.01, -0.11, -0.03]),
    (50, [-0.01, -0.04, -0.02]),
    (51, [0.0, -0.05, -0.03]),
    (52, [0.02, -0.09, -0.05]),
    (53, [0.08, -0.2, -0.11]),
    (54, [0.19, -0.46, -0.18]),
    (55, [0.1, -0.14, 0.02]),
    (56, [0.03, -0.03, 0.03]),
    (61, [-0.01, -0.03, -0.02]),
    (62, [0.0, -0.04, -0.04]),
    (63, [0.04, -0.09, -0.06]),
    (64, [0.18, -0.39, -0.13]),
    (65, [0.06, -0.08, 0.01]),
];
/// `mouthShrugUpper` at the 68 landmarks (cm), from ICT-FaceKit's shape (MIT).
const MOUTH_SHRUG_UPPER_CM: [(usize, [f64; 3]); 14] = [
    (31, [0.0, 0.12, 0.0]),
    (32, [0.0, 0.23, 0.0]),
    (33, [0.0, 0.26, 0.01]),
    (34, [0.0, 0.23, 0.0]),
    (35, [0.0, 0.13, 0.0]),
    (49, [-0.02, 0.31, 0.02]),
    (50, [-0.01, 0.52, 0.02]),
    (51, [0.0, 0.57, 0.03]),
    (52, [0.01, 0.52, 0.02]),
    (53, [0.02, 0.32, 0.02]),
    (60, [-0.01, 0.05, 0.0]),
    (61, [-0.01, 0.42, 0.09]),
    (62, [0.0, 0.53, 0.1]),
    (63, [0.01, 0.43, 0.09]),
];
/// `browOuterUpLeft` at the 68 landmarks (cm), from ICT-FaceKit's `browOuterUp_L` (MIT); the
/// right is its mirror image ([`sided`]).
const BROW_OUTER_UP_LEFT_CM: [(usize, [f64; 3]); 13] = [
    (14, [0.0, 0.05, 0.0]),
    (15, [0.0, 0.07, 0.02]),
    (16, [0.0, 0.08, 0.03]),
    (21, [-0.01, 0.05, 0.0]),
    (22, [0.05, 0.21, -0.02]),
    (23, [0.15, 0.55, -0.09]),
    (24, [0.23, 0.75, -0.2]),
    (25, [0.19, 0.75, -0.3]),
    (26, [0.11, 0.58, -0.24]),
    (27, [0.0, 0.03, 0.0]),
    (43, [0.0, 0.03, -0.01]),
    (44, [0.0, 0.07, -0.02]),
    (45, [0.0, 0.05, 0.0]),
];
/// `jawLeft` at the 68 landmarks (cm), from ICT-FaceKit's shape (MIT): the chin and the lower
/// lip ~0.85 cm to the subject's left, the jaw's contour less towards the ears; `jawRight` is
/// its mirror image ([`sided`]).
const JAW_LEFT_CM: [(usize, [f64; 3]); 41] = [
    (2, [0.06, -0.03, 0.01]),
    (3, [0.19, -0.03, 0.01]),
    (4, [0.35, -0.01, 0.01]),
    (5, [0.52, 0.03, 0.03]),
    (6, [0.69, 0.0, 0.04]),
    (7, [0.85, 0.01, 0.03]),
    (8, [0.86, 0.01, 0.01]),
    (9, [0.86, 0.02, -0.01]),
    (10, [0.73, 0.02, -0.03]),
    (11, [0.56, 0.05, -0.04]),
    (12, [0.38, 0.04, -0.07]),
    (13, [0.32, 0.01, -0.04]),
    (14, [0.24, 0.01, 0.0]),
    (15, [0.04, 0.0, 0.0]),
    (16, [0.03, 0.0, 0.01]),
    (30, [0.04, 0.0, 0.0]),
    (31, [0.09, 0.0, 0.0]),
    (32, [0.08, 0.0, 0.0]),
    (33, [0.09, 0.0, 0.0]),
    (34, [0.09, 0.0, 0.0]),
    (35, [0.09, -0.01, 0.0]),
    (48, [0.45, 0.0, 0.08]),
    (49, [0.2, 0.0, 0.02]),
    (50, [0.17, 0.0, 0.01]),
    (51, [0.17, 0.0, 0.0]),
    (52, [0.18, 0.0, 0.0]),
    (53, [0.24, 0.01, 0.02]),
    (54, [0.5, 0.04, 0.0]),
    (55, [0.83, 0.04, -0.01]),
    (56, [0.84, 0.04, 0.01]),
    (57, [0.79, 0.03, 0.09]),
    (58, [0.73, 0.04, 0.17]),
    (59, [0.7, 0.03, 0.18]),
    (60, [0.48, 0.01, 0.09]),
    (61, [0.18, 0.0, 0.01]),
    (62, [0.16, 0.0, 0.0]),
    (63, [0.2, 0.01, 0.0]),
    (64, [0.55, 0.04, -0.01]),
    (65, [0.81, 0.03, 0.01]),
    (66, [0.79, 0.03, 0.08]),
    (67, [0.72, 0.03, 0.17]),
];

/// The displacements of `table` (listed for the left side, or for both sides of a symmetric
/// shape) for the shape `name`: as listed, or their mirror image (iBUG points mirrored, x
/// negated) when `name` ends in `Right`.
fn sided<'a>(table: &'a [(usize, [f64; 3])], name: &str) -> impl Iterator<Item = (usize, Vector3<f64>)> + 'a {
    let s = if name.ends_with("Right") { -1.0 } else { 1.0 };
    table.iter().map(move |&(i, [x, y, z])| {
        let i = if s > 0.0 { i } else { mirror_landmark(i) };
        (i, Vector3::new(x * s, y, z))
    })
}

/// Displacement (cm) of each of the 68 landmarks for the named shape.
fn landmark_displacements(name: &str) -> [Vector3<f64>; 68] {
    let mut d = [Vector3::zeros(); 68];
    let p = |i: usize| Vector3::new(MEAN_FACE_68_CM[i][0], MEAN_FACE_68_CM[i][1], MEAN_FACE_68_CM[i][2]);
    let mut set = |ids: &[usize], v: Vector3<f64>| {
        for &i in ids {
            d[i] += v;
        }
    };
    match name {
        "jawOpen" => {
            // Jaw rotates down: chin moves most, jaw angle points little. Chin 2.4 cm at 1 (a
            // wide open mouth; at 1.6 cm a yawn pinned the weight, docs/expressions.md "The
            // neutral mouth"). The lower lip stretches over the teeth and moves further than
            // the chin, as in ICT-FaceKit's jawOpen (lip middle 1.25x the chin, the points
            // beside it 0.94x, the corners 0.46x): middle 2.7, beside 2.0, corners 1.0 cm.
            // With the lip at 2.25 / 1.5 / 0.75 cm the rest of a yawn went to mouthLowerDown,
            // pinned at 1 on 26 % of liveportrait_d18 (docs/expressions.md "The jaw's lower lip").
            for i in 2..=14usize {
                let w = (1.0 - (i as f64 - 8.0).abs() / 6.5).max(0.0);
                set(&[i], Vector3::new(0.0, -2.4 * w, -0.6 * w));
            }
            set(&[56, 57, 58, 65, 66, 67], Vector3::new(0.0, -2.7, -0.54));
            set(&[55, 59], Vector3::new(0.0, -2.0, -0.4));
            set(&[48, 54, 60, 64], Vector3::new(0.0, -1.0, -0.2));
        }
        "mouthSmileLeft" | "mouthSmileRight" => {
            let (s, corner, inner, near) = if name.ends_with("Left") {
                (1.0, 54, 64, [53, 55])
            } else {
                (-1.0, 48, 60, [49, 59])
            };
            set(&[corner, inner], Vector3::new(0.5 * s, 0.55, -0.15));
            set(&near, Vector3::new(0.25 * s, 0.3, -0.05));
            let cheek = if s > 0.0 { [12, 13] } else { [4, 3] };
            set(&cheek, Vector3::new(0.1 * s, 0.15, 0.05));
            // the lips' middle and the chin rise with each side's smile (as in ICT-FaceKit's
            // mouthSmile: 0.2 and 0.16 cm); without it a broad smile read as mouthShrugLower
            // and mouthPress as well (docs/expressions.md, "The smile's lips and chin")
            set(&[51, 62, 57, 66], Vector3::new(0.0, 0.2, -0.1));
            set(&[7, 8, 9], Vector3::new(0.0, 0.16, 0.0));
        }
        "mouthFrownLeft" | "mouthFrownRight" => {
            for (i, v) in sided(&MOUTH_FROWN_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "mouthPucker" => {
            for (i, v) in sided(&MOUTH_PUCKER_CM, name) {
                set(&[i], v);
            }
        }
        "mouthStretchLeft" | "mouthStretchRight" => {
            let (s, corner, inner, near) = if name.ends_with("Left") {
                (1.0, 54, 64, [53, 55])
            } else {
                (-1.0, 48, 60, [49, 59])
            };
            set(&[corner, inner], Vector3::new(0.6 * s, -0.2, -0.1));
            set(&near, Vector3::new(0.3 * s, -0.1, 0.0));
        }
        "browInnerUp" => {
            set(&[21, 22], Vector3::new(0.0, 0.7, 0.0));
            set(&[20, 23], Vector3::new(0.0, 0.4, 0.0));
            set(&[19, 24], Vector3::new(0.0, 0.15, 0.0));
        }
        "browDownLeft" | "browDownRight" => {
            let (ids, s) = if name.ends_with("Left") {
                ([22, 23, 24, 25, 26], 1.0)
            } else {
                ([21, 20, 19, 18, 17], -1.0)
            };
            for (k, &i) in ids.iter().enumerate() {
                let w = 1.0 - 0.15 * k as f64;
                set(&[i], Vector3::new(-0.15 * s * w, -0.45 * w, 0.0));
            }
        }
        "browOuterUpLeft" | "browOuterUpRight" => {
            for (i, v) in sided(&BROW_OUTER_UP_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "eyeBlinkLeft" | "eyeBlinkRight" => {
            // Upper lid meets the lower lid.
            let pairs: [(usize, usize); 2] = if name.ends_with("Left") {
                [(43, 47), (44, 46)]
            } else {
                [(37, 41), (38, 40)]
            };
            for (up, low) in pairs {
                let dy = p(low).y - p(up).y;
                set(&[up], Vector3::new(0.0, 0.85 * dy, 0.0));
                set(&[low], Vector3::new(0.0, -0.15 * dy, 0.0));
            }
        }
        "mouthRollLower" => {
            set(&[56, 57, 58], Vector3::new(0.0, 0.35, -0.3));
            set(&[65, 66, 67], Vector3::new(0.0, 0.2, -0.3));
        }
        "eyeLookDownLeft" | "eyeLookDownRight" | "eyeLookUpLeft" | "eyeLookUpRight" => {
            // No eyeballs: the lids follow the gaze a little (the upper lid most).
            let pairs: [(usize, usize); 2] = if name.ends_with("Left") {
                [(43, 47), (44, 46)]
            } else {
                [(37, 41), (38, 40)]
            };
            let down = name.starts_with("eyeLookDown");
            for (up, low) in pairs {
                let dy = p(low).y - p(up).y;
                if down {
                    set(&[up], Vector3::new(0.0, 0.3 * dy, 0.0));
                    set(&[low], Vector3::new(0.0, 0.08 * dy, 0.0));
                } else {
                    set(&[up], Vector3::new(0.0, -0.25 * dy, 0.0));
                    set(&[low], Vector3::new(0.0, -0.1 * dy, 0.0));
                }
            }
        }
        "eyeSquintLeft" | "eyeSquintRight" => {
            // The lower lid rises and straightens, the upper lid comes down a little.
            let pairs: [(usize, usize); 2] = if name.ends_with("Left") {
                [(43, 47), (44, 46)]
            } else {
                [(37, 41), (38, 40)]
            };
            for (up, low) in pairs {
                let dy = p(low).y - p(up).y;
                set(&[low], Vector3::new(0.0, -0.35 * dy, 0.05));
                set(&[up], Vector3::new(0.0, 0.1 * dy, 0.0));
            }
            // FACS AU6 (the orbital part of orbicularis oculi, what ARKit's eyeSquint
            // follows in a smile) also draws the brow's outer half down a little. Without
            // it, smiles read as browDown (0.3-0.45 on three shared clips, docs/expressions.md
            // "eyeSquint and the brow").
            let brow = if name.ends_with("Left") {
                [26, 25, 24]
            } else {
                [17, 18, 19]
            };
            for (i, down) in brow.into_iter().zip([0.25, 0.175, 0.0875]) {
                set(&[i], Vector3::new(0.0, -down, 0.0));
            }
        }
        "eyeWideLeft" | "eyeWideRight" => {
            let pairs: [(usize, usize); 2] = if name.ends_with("Left") {
                [(43, 47), (44, 46)]
            } else {
                [(37, 41), (38, 40)]
            };
            for (up, low) in pairs {
                let dy = p(low).y - p(up).y;
                set(&[up], Vector3::new(0.0, -0.35 * dy, 0.05));
                set(&[low], Vector3::new(0.0, 0.08 * dy, 0.0));
            }
        }
        "jawForward" => {
            for i in 3..=13usize {
                let w = (1.0 - (i as f64 - 8.0).abs() / 6.0).max(0.0);
                set(&[i], Vector3::new(0.0, 0.0, 0.6 * w));
            }
            set(&[55, 56, 57, 58, 59, 65, 66, 67], Vector3::new(0.0, 0.05, 0.5));
        }
        "jawLeft" | "jawRight" => {
            for (i, v) in sided(&JAW_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "mouthClose" => {
            // Lips closed over an open jaw: the lower lip and corners go back up by the
            // lip part of jawOpen (its other half, the jaw, stays).
            set(&[56, 57, 58, 65, 66, 67], Vector3::new(0.0, 1.4, 0.3));
            set(&[55, 59], Vector3::new(0.0, 0.9, 0.2));
            set(&[48, 54, 60, 64], Vector3::new(0.0, 0.4, 0.1));
            set(&[61, 62, 63], Vector3::new(0.0, -0.1, 0.0));
        }
        "mouthFunnel" => {
            set(&[48, 60], Vector3::new(0.35, 0.0, 0.2));
            set(&[54, 64], Vector3::new(-0.35, 0.0, 0.2));
            set(&[49, 50, 51, 52, 53], Vector3::new(0.0, 0.15, 0.45));
            set(&[55, 56, 57, 58, 59], Vector3::new(0.0, -0.2, 0.45));
            set(&[61, 62, 63], Vector3::new(0.0, 0.3, 0.35));
            set(&[65, 66, 67], Vector3::new(0.0, -0.35, 0.35));
        }
        "mouthLeft" | "mouthRight" => {
            // The mouth slides sideways round the face, as in ICT-FaceKit's mouthLeft (cm):
            // the middle ~1.5 cm, the trailing corner as far and forward, the leading corner
            // only 0.6 cm and up into the cheek, so the mouth narrows by ~1 cm. The uniform
            // 0.6 cm slide this replaces saturated at 1 on a sideways mouth and left the
            // narrowing to mouthPucker (liveportrait_d9 frames 144-188: pucker 0.7-0.99
            // where MediaPipe gives 0.02-0.1; docs/expressions.md, "The mouth's sideways slide").
            for (i, v) in sided(&MOUTH_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "mouthDimpleLeft" | "mouthDimpleRight" => {
            let (s, corner, inner) = if name.ends_with("Left") {
                (1.0, 54, 64)
            } else {
                (-1.0, 48, 60)
            };
            // Back into the cheek (a stretch pulls outward and down).
            set(&[corner, inner], Vector3::new(0.08 * s, 0.0, -0.4));
        }
        "mouthRollUpper" => {
            set(&[50, 51, 52], Vector3::new(0.0, -0.35, -0.3));
            set(&[61, 62, 63], Vector3::new(0.0, -0.2, -0.3));
        }
        "mouthShrugLower" => {
            set(&[56, 57, 58], Vector3::new(0.0, 0.3, 0.25));
            set(&[65, 66, 67], Vector3::new(0.0, 0.15, 0.15));
            set(&[7, 8, 9], Vector3::new(0.0, 0.25, 0.1));
        }
        "mouthShrugUpper" => {
            for (i, v) in sided(&MOUTH_SHRUG_UPPER_CM, name) {
                set(&[i], v);
            }
        }
        "mouthPressLeft" | "mouthPressRight" => {
            for (i, v) in sided(&MOUTH_PRESS_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "mouthLowerDownLeft" | "mouthLowerDownRight" => {
            let (side, inner) = if name.ends_with("Left") {
                ([55, 56], 65)
            } else {
                ([59, 58], 67)
            };
            set(&side, Vector3::new(0.0, -0.5, 0.05));
            set(&[inner], Vector3::new(0.0, -0.45, 0.0));
            set(&[57, 66], Vector3::new(0.0, -0.25, 0.0));
        }
        "mouthUpperUpLeft" | "mouthUpperUpRight" => {
            // ICT-FaceKit's mouthUpperUp_L (cm): the upper lip rises most beside the middle
            // and the nostril's wing with it; ICT's mouth corner (0.44 cm up) is left out,
            // it took part of every smile (docs/expressions.md, "The upper lip's raise")
            for (i, v) in sided(&MOUTH_UPPER_UP_LEFT_CM, name) {
                set(&[i], v);
            }
        }
        "cheekPuff" => {
            set(&[48, 60], Vector3::new(-0.1, 0.0, 0.1));
            set(&[54, 64], Vector3::new(0.1, 0.0, 0.1));
            set(&[4, 5], Vector3::new(-0.2, 0.0, 0.1));
            set(&[11, 12], Vector3::new(0.2, 0.0, 0.1));
        }
        // cheekSquint raises the cheek below the lower lid, not the lid's landmarks (that is
        // eyeSquint; with both on the lid the 68 points could not tell them apart): its
        // motion is in `mesh_handles` only
        "noseSneerLeft" | "noseSneerRight" => {
            let (wing, brow) = if name.ends_with("Left") {
                ([34, 35], 22)
            } else {
                ([32, 31], 21)
            };
            set(&wing, Vector3::new(0.0, 0.3, 0.0));
            set(&[brow], Vector3::new(0.0, -0.15, 0.0));
            let upper: [usize; 2] = if name.ends_with("Left") { [52, 53] } else { [50, 49] };
            set(&upper, Vector3::new(0.0, 0.1, 0.0));
        }
        "tongueOut" => {
            set(&[56, 57, 58], Vector3::new(0.0, -0.3, 0.2));
            set(&[65, 66, 67], Vector3::new(0.0, -0.5, 0.3));
        }
        _ => {}
    }
    d
}

/// Displacement (cm) of mesh vertices that are not landmarks, for the shapes whose
/// motion lies between the landmarks (cheeks, nose wings): `(vertex, displacement)`.
fn mesh_handles(name: &str) -> Vec<(usize, Vector3<f64>)> {
    let side = |left: bool, r: usize, l: usize| if left { l } else { r };
    let left = name.ends_with("Left");
    let s = if left { 1.0 } else { -1.0 };
    match name {
        "cheekPuff" => {
            let mut h = Vec::new();
            for (r, l, out) in [
                (50, 280, 0.7),
                (205, 425, 0.6),
                (187, 411, 0.5),
                (207, 427, 0.6),
                (216, 436, 0.4),
            ] {
                h.push((r, Vector3::new(-out, 0.0, 0.35 * out)));
                h.push((l, Vector3::new(out, 0.0, 0.35 * out)));
            }
            h
        }
        "cheekSquintLeft" | "cheekSquintRight" => [
            (118, 347, 0.35),
            (117, 346, 0.3),
            (119, 348, 0.3),
            (50, 280, 0.25),
            (101, 330, 0.2),
        ]
        .iter()
        .map(|&(r, l, up)| (side(left, r, l), Vector3::new(0.0, up, 0.1)))
        .collect(),
        "noseSneerLeft" | "noseSneerRight" => [(129, 358, 0.3), (48, 278, 0.3), (64, 294, 0.25), (49, 279, 0.25)]
            .iter()
            .map(|&(r, l, up)| (side(left, r, l), Vector3::new(0.05 * s, up, 0.0)))
            .collect(),
        "mouthSmileLeft" | "mouthSmileRight" => [(205, 425, 0.3), (50, 280, 0.2)]
            .iter()
            .map(|&(r, l, up)| (side(left, r, l), Vector3::new(0.1 * s, up, 0.1)))
            .collect(),
        _ => Vec::new(),
    }
}

/// The default rig: the face mesh topology with ARKit's 52 morph targets, and its landmark map.
///
/// # Errors
/// The canonical face mesh missing from the model cache (`scripts/setup.sh` puts it
/// there) or damaged.
pub fn default_rig() -> anyhow::Result<(MorphMesh, LandmarkMap)> {
    let canon = facecap_mesh::canonical::canonical_mesh_from_cache()
        .map_err(|e| anyhow::anyhow!("the built-in rig is made from the canonical face mesh: {e}"))?;
    build_default_rig(&canon)
}

/// Builds the default rig from the canonical face mesh (module docs).
///
/// # Errors
/// A degenerate mesh (the alignment or a fit fails).
pub fn build_default_rig(canon: &CanonicalMesh) -> anyhow::Result<(MorphMesh, LandmarkMap)> {
    let n = canon.positions.len();
    if n != facecap_mesh::canonical::CANONICAL_VERTICES {
        anyhow::bail!("canonical face mesh with {n} vertices, expected 468");
    }
    let lm_vertices = IBUG68_FROM_MESH;
    // Neutral: the canonical face aligned (similarity) and warped (3D thin-plate spline)
    // so that its 68 landmark vertices land exactly on the mean face.
    let src: Vec<Point3<f64>> = lm_vertices.iter().map(|&v| Point3::from(canon.positions[v])).collect();
    let dst: Vec<Point3<f64>> = MEAN_FACE_68_CM.iter().map(|&p| Point3::from(p)).collect();
    let sim = umeyama3(&src, &dst, None, true)?;
    let aligned: Vec<[f64; 3]> = canon
        .positions
        .iter()
        .map(|&p| {
            let q = sim.apply(&Point3::from(p));
            [q.x, q.y, q.z]
        })
        .collect();
    let centres: Vec<[f64; 3]> = lm_vertices.iter().map(|&v| aligned[v]).collect();
    let warp = Tps3::fit(&centres, &MEAN_FACE_68_CM)
        .ok_or_else(|| anyhow::anyhow!("default rig: degenerate landmark layout"))?;
    let mut pos: Vec<[f64; 3]> = aligned.iter().map(|p| warp.apply(p)).collect();
    for (i, &v) in lm_vertices.iter().enumerate() {
        pos[v] = MEAN_FACE_68_CM[i];
    }
    // Triangles: the mouth opening is left out; facing +Z (counter-clockwise seen from the
    // front), flipped if the file winds the other way.
    let in_mouth = |t: &[u32; 3]| t.iter().all(|&v| MESH_INNER_LIP.contains(&(v as usize)));
    let mut tris: Vec<[u32; 3]> = canon.triangles.iter().copied().filter(|t| !in_mouth(t)).collect();
    let facing: f64 = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| pos[i as usize]);
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        })
        .sum();
    if facing < 0.0 {
        for t in &mut tris {
            t.swap(1, 2);
        }
    }
    // Displacements spread harmonically over the mesh from the landmarks, without the
    // triangles across the eye openings (a lid moves alone); the forehead's edge stays.
    let in_eye = |t: &[u32; 3]| {
        MESH_EYE_OPENINGS
            .iter()
            .any(|eye| t.iter().all(|&v| eye.contains(&(v as usize))))
    };
    let spread_tris: Vec<[u32; 3]> = tris.iter().copied().filter(|t| !in_eye(t)).collect();
    let brow_top = (17..27).map(|i| MEAN_FACE_68_CM[i][1]).fold(f64::MIN, f64::max);
    let mut fixed: Vec<usize> = lm_vertices.to_vec();
    fixed.extend(
        boundary_vertices(&tris)
            .into_iter()
            .filter(|&v| pos[v][1] > brow_top && !lm_vertices.contains(&v)),
    );
    let base_fixed = fixed.len();
    let mut spreads: std::collections::HashMap<Vec<usize>, Harmonic> = std::collections::HashMap::new();
    let positions: Vec<Point3<f32>> = pos
        .iter()
        .map(|p| Point3::new(p[0] as f32, p[1] as f32, p[2] as f32))
        .collect();
    let uvs = canon.uvs.iter().map(|t| [t[0] as f32, t[1] as f32]).collect();
    let mut base = Mesh {
        positions,
        triangles: tris,
        normals: Vec::new(),
        uvs,
    };
    base.compute_normals();
    let mut targets = Vec::with_capacity(DEFAULT_SHAPES.len());
    for name in DEFAULT_SHAPES {
        let d = landmark_displacements(name);
        let mut values: Vec<[f64; 3]> = d.iter().map(|v| [v.x, v.y, v.z]).collect();
        values.resize(base_fixed, [0.0; 3]);
        let handles: Vec<(usize, Vector3<f64>)> = mesh_handles(name)
            .into_iter()
            .filter(|(v, _)| !fixed.contains(v))
            .collect();
        let key: Vec<usize> = handles.iter().map(|h| h.0).collect();
        values.extend(handles.iter().map(|(_, v)| [v.x, v.y, v.z]));
        let harmonic = match spreads.entry(key) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let mut f = fixed.clone();
                f.extend_from_slice(e.key());
                e.insert(Harmonic::new(&pos, &spread_tris, &f)?)
            }
        };
        let field = harmonic.interpolate(&values)?;
        targets.push(MorphTarget {
            name: name.to_string(),
            deltas: field
                .iter()
                .map(|v| Vector3::new(v[0] as f32, v[1] as f32, v[2] as f32))
                .collect(),
        });
    }
    let rig = MorphMesh { base, targets };
    rig.validate()?;
    let ids: Vec<Option<u32>> = lm_vertices.iter().map(|&v| Some(v as u32)).collect();
    let map = LandmarkMap::from_slice(&ids)?;
    Ok((rig, map))
}

/// Vertices on the mesh's open edges (edges of one triangle only).
fn boundary_vertices(tris: &[[u32; 3]]) -> Vec<usize> {
    let mut count = std::collections::HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_insert(0u32) += 1;
        }
    }
    let mut v: Vec<usize> = count
        .into_iter()
        .filter(|&(_, c)| c == 1)
        .flat_map(|((a, b), _)| [a as usize, b as usize])
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Option<(MorphMesh, LandmarkMap)> {
        facecap_core::paths::model_file_or_skip("default_rig", facecap_mesh::canonical::GEOMETRY_METADATA)?;
        Some(default_rig().unwrap())
    }

    #[test]
    fn default_rig_is_valid_and_exact_at_landmarks() {
        let Some((rig, map)) = rig() else { return };
        assert_eq!(rig.base.num_vertices(), 468);
        assert_eq!(rig.targets.len(), 52);
        let names: Vec<&str> = rig.targets.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(names, DEFAULT_SHAPES);
        let unique: std::collections::HashSet<&str> = names.iter().copied().collect();
        assert_eq!(unique.len(), 52);
        map.validate(rig.base.num_vertices()).unwrap();
        let lm = |i: usize| map.vertices[i].unwrap() as usize;
        for (i, p) in MEAN_FACE_68_CM.iter().enumerate() {
            let v = rig.base.positions[lm(i)];
            assert!((v.x as f64 - p[0]).abs() < 1e-5 && (v.z as f64 - p[2]).abs() < 1e-5);
        }
        // jawOpen moves the chin down by 2.4 cm and leaves the brows and the upper lip alone.
        let jaw = &rig.targets[0];
        assert!((jaw.deltas[lm(8)].y + 2.4).abs() < 1e-5);
        assert!(jaw.deltas[lm(19)].norm() < 1e-6);
        // the lower lip's middle moves further than the chin, its corners about half as far
        // (ICT-FaceKit's proportions; smaller lip motion pinned mouthLowerDown in a yawn)
        assert!(jaw.deltas[lm(57)].y < jaw.deltas[lm(8)].y - 0.2);
        assert!((jaw.deltas[lm(54)].y / jaw.deltas[lm(8)].y - 0.42).abs() < 0.05);
        for v in [0usize, 37, 267, 13, 82, 312] {
            assert!(
                jaw.deltas[v].norm() < 0.2,
                "upper lip vertex {v} moves {}",
                jaw.deltas[v].norm()
            );
        }
        // the lower lip's inner edge opens with the jaw
        for v in [14usize, 87, 317] {
            assert!(jaw.deltas[v].y < -1.0, "lower lip vertex {v}: {:?}", jaw.deltas[v]);
        }
        // a blink closes the upper lid's middle, the lower lid hardly moves
        let blink = &rig.targets[13];
        assert_eq!(blink.name, "eyeBlinkLeft");
        assert!(blink.deltas[386].y < -0.5, "{:?}", blink.deltas[386]);
        assert!(blink.deltas[374].y.abs() < 0.2, "{:?}", blink.deltas[374]);
        // no triangle closes the mouth; nearly all face the front
        assert!(rig.base.triangles.len() < 898);
        let front = rig
            .base
            .triangles
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|i| rig.base.positions[i as usize]);
                (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x) > 0.0
            })
            .count();
        assert!(
            front * 10 > rig.base.triangles.len() * 9,
            "{front} of {}",
            rig.base.triangles.len()
        );
        // displacements stay inside the range of the given ones (no overshoot)
        for t in &rig.targets {
            let handles = mesh_handles(&t.name).into_iter().map(|(v, _)| v);
            let max_lm = (0..68)
                .map(lm)
                .chain(handles)
                .map(|v| t.deltas[v].norm())
                .fold(0.0f32, f32::max);
            let max_all = t.deltas.iter().map(|d| d.norm()).fold(0.0f32, f32::max);
            assert!(max_all <= max_lm * 1.0001 + 1e-6, "{}: {max_all} > {max_lm}", t.name);
        }
    }

    /// The rendered rig shows open eyes as dark openings between the lids (the mesh has
    /// no vertex inside an eye opening to carry the tone) and closes them on a blink.
    #[test]
    fn rendered_eyes_are_open_at_rest_and_closed_in_a_blink() {
        let Some((rig, map)) = rig() else { return };
        let r = facecap_pipeline::render::RigRenderer::new(&rig, Some(&map)).unwrap();
        let dark = |names: &[&str]| {
            let w: Vec<f64> = rig
                .targets
                .iter()
                .map(|t| if names.contains(&t.name.as_str()) { 1.0 } else { 0.0 })
                .collect();
            let img = r.render(&w, None, 256).unwrap();
            img.enumerate_pixels()
                .filter(|(_, y, p)| *y < 128 && p.0[0] < 90)
                .count()
        };
        let (open, closed) = (dark(&[]), dark(&["eyeBlinkLeft", "eyeBlinkRight"]));
        eprintln!("dark pixels in the upper half: at rest {open}, blink {closed}");
        assert!(open >= closed + 100, "at rest {open}, blink {closed}");
    }

    /// With `FACECAP_DEBUG_DIR` set, draws the rig at rest and at full weight of a few
    /// shapes (`default_rig_shapes.png`) to look at.
    #[test]
    fn draws_shapes_to_look_at() {
        let Some(dir) = std::env::var_os("FACECAP_DEBUG_DIR") else {
            return;
        };
        let Some((rig, map)) = rig() else { return };
        let r = facecap_pipeline::render::RigRenderer::new(&rig, Some(&map)).unwrap();
        let sets: [&[&str]; 12] = [
            &[],
            &["jawOpen"],
            &[
                "mouthSmileLeft",
                "mouthSmileRight",
                "cheekSquintLeft",
                "cheekSquintRight",
            ],
            &["eyeBlinkLeft", "eyeBlinkRight"],
            &[
                "browInnerUp",
                "browOuterUpLeft",
                "browOuterUpRight",
                "eyeWideLeft",
                "eyeWideRight",
            ],
            &["mouthPucker"],
            &["cheekPuff"],
            &["mouthFunnel", "jawOpen"],
            &["jawLeft"],
            &[
                "mouthUpperUpLeft",
                "mouthUpperUpRight",
                "noseSneerLeft",
                "noseSneerRight",
            ],
            &["browDownLeft", "browDownRight", "eyeSquintLeft", "eyeSquintRight"],
            &["mouthFrownLeft", "mouthFrownRight", "mouthShrugLower"],
        ];
        let size = 256;
        let mut sheet = image::RgbImage::new(size * 6, size * 2);
        for (k, set) in sets.iter().enumerate() {
            let w: Vec<f64> = rig
                .targets
                .iter()
                .map(|t| if set.contains(&t.name.as_str()) { 1.0 } else { 0.0 })
                .collect();
            let img = r.render(&w, None, size).unwrap();
            image::imageops::replace(
                &mut sheet,
                &img,
                (k as u32 % 6 * size) as i64,
                (k as u32 / 6 * size) as i64,
            );
        }
        sheet
            .save(std::path::Path::new(&dir).join("default_rig_shapes.png"))
            .unwrap();
    }
}
