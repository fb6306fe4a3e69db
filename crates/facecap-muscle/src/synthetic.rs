//! A small synthetic face for tests, benches and examples: a subdivided grid draped over
//! an ellipsoid with a nose bump, and a 68-landmark map onto its vertices.
//!
//! Units: the eye-centre distance is about 6 (cm-like). +X is the subject's left, +Y up,
//! +Z out of the face. The grid is symmetric about `x = 0` ([`SyntheticFace::mirror_vertex`]).

use nalgebra::Point3;

use facecap_core::landmark_map::LandmarkMap;

/// The synthetic face.
#[derive(Debug, Clone)]
pub struct SyntheticFace {
    /// Vertex positions.
    pub positions: Vec<Point3<f64>>,
    /// CCW triangles (seen from +Z).
    pub triangles: Vec<[u32; 3]>,
    /// Grid columns (odd, so that x = 0 is a column).
    pub cols: usize,
    /// Grid rows.
    pub rows: usize,
    /// iBUG-68 landmark map (every landmark mapped).
    pub map: LandmarkMap,
}

/// 2D landmark template (x right = subject's left, y up), eye-centre distance 1.
pub const TEMPLATE_68: [[f64; 2]; 68] = [
    [-0.95, -0.10],
    [-0.93, -0.33],
    [-0.88, -0.55],
    [-0.80, -0.76],
    [-0.68, -0.95],
    [-0.52, -1.10],
    [-0.36, -1.20],
    [-0.18, -1.26],
    [0.00, -1.28],
    [0.18, -1.26],
    [0.36, -1.20],
    [0.52, -1.10],
    [0.68, -0.95],
    [0.80, -0.76],
    [0.88, -0.55],
    [0.93, -0.33],
    [0.95, -0.10],
    [-0.80, 0.26],
    [-0.65, 0.34],
    [-0.48, 0.37],
    [-0.32, 0.35],
    [-0.16, 0.30],
    [0.16, 0.30],
    [0.32, 0.35],
    [0.48, 0.37],
    [0.65, 0.34],
    [0.80, 0.26],
    [0.00, 0.02],
    [0.00, -0.14],
    [0.00, -0.29],
    [0.00, -0.44],
    [-0.18, -0.54],
    [-0.09, -0.57],
    [0.00, -0.59],
    [0.09, -0.57],
    [0.18, -0.54],
    [-0.68, 0.00],
    [-0.57, 0.06],
    [-0.43, 0.06],
    [-0.32, 0.00],
    [-0.43, -0.05],
    [-0.57, -0.05],
    [0.32, 0.00],
    [0.43, 0.06],
    [0.57, 0.06],
    [0.68, 0.00],
    [0.57, -0.05],
    [0.43, -0.05],
    [-0.40, -0.85],
    [-0.27, -0.77],
    [-0.10, -0.73],
    [0.00, -0.75],
    [0.10, -0.73],
    [0.27, -0.77],
    [0.40, -0.85],
    [0.27, -0.95],
    [0.10, -1.00],
    [0.00, -1.01],
    [-0.10, -1.00],
    [-0.27, -0.95],
    [-0.32, -0.85],
    [-0.10, -0.81],
    [0.00, -0.81],
    [0.10, -0.81],
    [0.32, -0.85],
    [0.10, -0.89],
    [0.00, -0.89],
    [-0.10, -0.89],
];

/// The iBUG-68 left/right mirror permutation (0-based).
pub fn mirror_landmark(i: usize) -> usize {
    const M: [usize; 68] = [
        16, 15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0, 26, 25, 24, 23, 22, 21, 20, 19, 18, 17, 27, 28, 29,
        30, 35, 34, 33, 32, 31, 45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40, 54, 53, 52, 51, 50, 49, 48, 59, 58, 57,
        56, 55, 64, 63, 62, 61, 60, 67, 66, 65,
    ];
    M[i]
}

/// Scale: eye-centre distance.
const IOD: f64 = 6.0;

fn surface(x: f64, y: f64) -> f64 {
    // Ellipsoid (semi-axes 1.25, 1.7, 1.0 in IOD units, centred 0.4 below the eyes) plus a nose.
    let e = 1.0 - (x / 1.25).powi(2) - ((y + 0.4) / 1.7).powi(2);
    let base = e.max(0.0).sqrt();
    let nose = 0.3 * (-(x * x) / 0.012 - (y + 0.3).powi(2) / 0.06).exp();
    base + nose
}

impl SyntheticFace {
    /// A `cols x rows` grid (cols made odd) over `x in [-1.15, 1.15]`, `y in [-1.5, 0.9]`
    /// (IOD units), scaled to IOD 6.
    pub fn new(cols: usize, rows: usize) -> Self {
        let cols = cols.max(3) | 1;
        let rows = rows.max(3);
        let (x0, x1, y0, y1) = (-1.15, 1.15, -1.5, 0.9);
        let mut positions = Vec::with_capacity(cols * rows);
        for r in 0..rows {
            let y = y0 + (y1 - y0) * r as f64 / (rows - 1) as f64;
            for c in 0..cols {
                let x = x0 + (x1 - x0) * c as f64 / (cols - 1) as f64;
                positions.push(Point3::new(x * IOD, y * IOD, surface(x, y) * IOD));
            }
        }
        let mut triangles = Vec::new();
        let id = |r: usize, c: usize| (r * cols + c) as u32;
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                // Split symmetric about x = 0 so that the mirrored mesh has the same triangles.
                if (c < cols / 2) == (r % 2 == 0) {
                    triangles.push([id(r, c), id(r, c + 1), id(r + 1, c + 1)]);
                    triangles.push([id(r, c), id(r + 1, c + 1), id(r + 1, c)]);
                } else {
                    triangles.push([id(r, c), id(r, c + 1), id(r + 1, c)]);
                    triangles.push([id(r, c + 1), id(r + 1, c + 1), id(r + 1, c)]);
                }
            }
        }
        let mut v = [None; 68];
        for (i, t) in TEMPLATE_68.iter().enumerate() {
            let c = (((t[0] - x0) / (x1 - x0)) * (cols - 1) as f64).round() as usize;
            let r = (((t[1] - y0) / (y1 - y0)) * (rows - 1) as f64).round() as usize;
            v[i] = Some(id(r.min(rows - 1), c.min(cols - 1)));
        }
        // Keep the map mirror-consistent (rounding of +-x can differ at .5 ties).
        for i in 0..68 {
            let j = mirror_landmark(i);
            if let (Some(a), true) = (v[i], i < j) {
                let (r, c) = (a as usize / cols, a as usize % cols);
                v[j] = Some(id(r, cols - 1 - c));
            }
        }
        let map = LandmarkMap { vertices: v };
        SyntheticFace {
            positions,
            triangles,
            cols,
            rows,
            map,
        }
    }

    /// The vertex at the mirrored grid position (x -> -x).
    pub fn mirror_vertex(&self, v: usize) -> usize {
        let (r, c) = (v / self.cols, v % self.cols);
        r * self.cols + (self.cols - 1 - c)
    }

    /// As a core mesh (f32).
    pub fn mesh(&self) -> facecap_core::mesh::Mesh {
        facecap_core::mesh::Mesh {
            positions: self.positions.iter().map(|p| p.cast()).collect(),
            triangles: self.triangles.clone(),
            normals: Vec::new(),
            uvs: Vec::new(),
        }
    }
}

/// A synthetic ground-truth sequence: known contractions, jaw and head pose per frame and
/// the noisy projections of the tracked points (see [`make_sequence`]).
#[derive(Debug, Clone)]
pub struct SyntheticSequence {
    /// Camera.
    pub intrinsics: facecap_core::camera::Intrinsics,
    /// True contractions per frame.
    pub contractions: Vec<Vec<f64>>,
    /// True jaw angle per frame.
    pub jaw: Vec<f64>,
    /// True head pose per frame.
    pub poses: Vec<facecap_core::camera::ModelToCamera>,
    /// Observed (noisy) 2D points per frame, in the tracked-point order of the model.
    pub observations: Vec<Vec<nalgebra::Point2<f64>>>,
}

/// Deforms the full rig with smooth random activations (two bumps per muscle, several
/// muscles active at once), a jaw that opens up to `0.8 * max_jaw`, and a moving head
/// (yaw +-0.25 rad, pitch +-0.12, roll +-0.05, at ~40 units = ~120 px eye distance with a
/// 640x480 camera, f = 800), then projects the tracked vertices and adds Gaussian noise of
/// `noise_px`. Frame 0 is neutral. `uniform` returns samples in `[0, 1)` (seeded by the caller).
///
/// # Errors
/// Rig posing errors (none for a valid rig).
pub fn make_sequence(
    rig: &crate::rig::MuscleRig,
    tracked_vertices: &[u32],
    frames: usize,
    noise_px: f64,
    uniform: &mut dyn FnMut() -> f64,
) -> crate::Result<SyntheticSequence> {
    use facecap_core::camera::{Intrinsics, ModelToCamera};
    use nalgebra::{Point2, UnitQuaternion, Vector3};
    use std::f64::consts::PI;
    let intr = Intrinsics::new(800.0, 800.0, 319.5, 239.5)?;
    let m = rig.num_muscles();
    let n = frames.max(2) as f64;
    let mut bumps = Vec::new(); // (muscle or m for jaw, start, length, amplitude)
    for i in 0..=m {
        for _ in 0..2 {
            let len = 0.15 + 0.25 * uniform();
            let start = 0.02 + (0.98 - len) * uniform();
            let amp = if i == m {
                0.8 * rig.max_jaw()
            } else {
                0.3 + 0.7 * uniform()
            };
            bumps.push((i, start, len, amp));
        }
    }
    let phase = [uniform() * 2.0 * PI, uniform() * 2.0 * PI, uniform() * 2.0 * PI];
    let mut posed = rig.base().to_vec();
    let mut seq = SyntheticSequence {
        intrinsics: intr,
        contractions: Vec::new(),
        jaw: Vec::new(),
        poses: Vec::new(),
        observations: Vec::new(),
    };
    let mut normal = || {
        let (u1, u2) = (uniform().max(1e-12), uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    };
    for f in 0..frames {
        let t = f as f64 / n;
        let mut c = vec![0.0; m];
        let mut jaw = 0.0;
        for &(i, s, l, a) in &bumps {
            if f > 0 && t >= s && t <= s + l {
                let v = a * (PI * (t - s) / l).sin().powi(2);
                if i == m {
                    jaw = f64::max(jaw, v);
                } else {
                    c[i] = f64::max(c[i], v);
                }
            }
        }
        let w = 2.0 * PI * t;
        let (yaw, pitch, roll) = (
            0.25 * (w + phase[0]).sin(),
            0.12 * (w * 1.3 + phase[1]).sin(),
            0.05 * (w * 0.7 + phase[2]).sin(),
        );
        // Model (+Y up, +Z to the camera) to camera (+Y down, +Z forward): flip, then turn.
        let flip = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI);
        let turn = UnitQuaternion::from_euler_angles(pitch, yaw, roll);
        let pose = ModelToCamera(nalgebra::Isometry3::from_parts(
            Vector3::new(1.5 * (w * 0.5).sin(), 1.0 * (w * 0.8).cos(), 40.0 + 3.0 * w.sin()).into(),
            flip * turn,
        ));
        rig.pose_into(&c, jaw, &mut posed)?;
        let obs: Vec<Point2<f64>> = tracked_vertices
            .iter()
            .map(|&v| {
                let p = pose.project(&intr, &posed[v as usize]).unwrap_or(Point2::origin());
                p + nalgebra::Vector2::new(normal(), normal()) * noise_px
            })
            .collect();
        seq.contractions.push(c);
        seq.jaw.push(jaw);
        seq.poses.push(pose);
        seq.observations.push(obs);
    }
    Ok(seq)
}
