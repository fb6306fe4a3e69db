//! The thesis' default set of 11 muscles, placed from 3D landmark positions so that it
//! applies to any mesh with an iBUG-68 landmark map.
//!
//! A face frame is built from the landmarks: `s` = distance between the eye centres
//! (mean of 36-41 and 42-47), `x` from the subject's right eye to the left eye, `y` up
//! (towards the eyes from the mouth, orthogonalised), `z = x × y` out of the face. Control
//! points are landmark positions plus offsets in this frame, in units of `s`, so the set
//! scales with the face and the mesh units. Anatomy (after Waters 1987 and the thesis):
//!
//! | muscle | type | origin | insertion / control | effect |
//! |---|---|---|---|---|
//! | `cheek_L/R` (zygomaticus major) | linear | cheekbone below the outer eye corner (45/36) | mouth corner (54/48) | corner up and out (smile) |
//! | `lips1_L/R` (levator labii superioris) | linear | below the eye centre | upper lip (52/50) | upper lip up |
//! | `lips3_L/R` (depressor anguli oris) | linear | mandible below the corner | mouth corner (54/48) | corner down |
//! | `nose_forehead_L/R` (corrugator / procerus) | linear | nasal bridge beside 27 | mid brow (24/19) | brow down and in (frown) |
//! | `eyebrow_forehead_L/R` (frontalis) | parallel | forehead above mid brow | mid brow, control past the outer brow (26/17) | brow up |
//! | `lips` (orbicularis oris) | sphincter | centre of 48/51/54/57 | upper 51, corner 54 | pucker, pout |
//!
//! The jaw group holds the vertices below the lip line (between the inner lips 62/66),
//! blended over a band of `0.06 s`, fading out laterally beyond `1.0 s` and under the chin;
//! the pivot sits `0.55 s` below the eye line and `1.3 s` behind it, on the mid-plane
//! (near the temporomandibular joints). `max_angle` = 0.35 rad.
//! Left (`_L`) is the subject's left (landmarks 42-47, 22-26, 54).

use nalgebra::{Point3, Vector3};

use crate::deform::{LinearMuscle, MuscleShape, ParallelMuscle, SphincterMuscle};
use crate::error::{Error, Result};
use crate::set::{Jaw, Muscle, MuscleSet, VertexGroup, FORMAT_TAG, FORMAT_VERSION};

/// Number of muscles in the default set.
pub const NUM_DEFAULT_MUSCLES: usize = 11;
/// Default jaw range (rad).
pub const DEFAULT_MAX_JAW: f64 = 0.35;
/// Name of the jaw vertex group in the default set.
pub const JAW_GROUP: &str = "jaw";

/// 3D landmark positions from a map and mesh positions (`None` where unmapped or out of range).
pub fn landmark_positions(
    map: &facecap_core::landmark_map::LandmarkMap,
    positions: &[Point3<f64>],
) -> [Option<Point3<f64>>; 68] {
    let mut out = [None; 68];
    for (i, v) in map.mapped() {
        out[i] = positions.get(v as usize).copied();
    }
    out
}

/// The face frame of the module docs.
#[derive(Debug, Clone, Copy)]
pub struct FaceFrame {
    /// Midpoint of the eye centres.
    pub origin: Point3<f64>,
    /// Unit x (subject's right eye -> left eye).
    pub x: Vector3<f64>,
    /// Unit y (up).
    pub y: Vector3<f64>,
    /// Unit z (out of the face).
    pub z: Vector3<f64>,
    /// Eye-centre distance (mesh units).
    pub s: f64,
}

impl FaceFrame {
    /// Point at face coordinates `(a, b, c)` in units of `s`.
    pub fn at(&self, a: f64, b: f64, c: f64) -> Point3<f64> {
        self.origin + (self.x * a + self.y * b + self.z * c) * self.s
    }
    /// `p + (a, b, c) s` in the frame.
    pub fn offset(&self, p: &Point3<f64>, a: f64, b: f64, c: f64) -> Point3<f64> {
        p + (self.x * a + self.y * b + self.z * c) * self.s
    }
    /// Face coordinates of `p` in units of `s`.
    pub fn coords(&self, p: &Point3<f64>) -> Vector3<f64> {
        let d = (p - self.origin) / self.s;
        Vector3::new(d.dot(&self.x), d.dot(&self.y), d.dot(&self.z))
    }

    /// Builds the frame from landmarks (needs the eyes and the mouth corners).
    ///
    /// # Errors
    /// [`Error::MissingLandmark`]; [`Error::Degenerate`] for coincident eyes.
    pub fn from_landmarks(lm: &[Option<Point3<f64>>; 68]) -> Result<Self> {
        let mean = |r: std::ops::Range<usize>| -> Result<Point3<f64>> {
            let mut acc = Vector3::zeros();
            for i in r.clone() {
                acc += need(lm, i, "the face frame (eye centres)")?.coords;
            }
            Ok(Point3::from(acc / r.len() as f64))
        };
        let er = mean(36..42)?;
        let el = mean(42..48)?;
        let mouth = nalgebra::center(
            &need(lm, 48, "the face frame (mouth)")?,
            &need(lm, 54, "the face frame (mouth)")?,
        );
        let s = (el - er).norm();
        if s <= 1e-12 {
            return Err(Error::Degenerate {
                what: "face frame".into(),
                reason: "eye centres coincide".into(),
            });
        }
        let x = (el - er) / s;
        let origin = nalgebra::center(&er, &el);
        let up = origin - mouth;
        let yv = up - x * up.dot(&x);
        if yv.norm() <= 1e-12 {
            return Err(Error::Degenerate {
                what: "face frame".into(),
                reason: "mouth lies on the eye line".into(),
            });
        }
        let y = yv.normalize();
        Ok(FaceFrame {
            origin,
            x,
            y,
            z: x.cross(&y),
            s,
        })
    }
}

fn need(lm: &[Option<Point3<f64>>; 68], i: usize, purpose: &'static str) -> Result<Point3<f64>> {
    lm[i].ok_or(Error::MissingLandmark { landmark: i, purpose })
}

fn arr(p: Point3<f64>) -> [f64; 3] {
    [p.x, p.y, p.z]
}

fn linear(name: String, origin: Point3<f64>, insertion: Point3<f64>, s: f64, spill: f64, k: f64) -> Muscle {
    let l = (insertion - origin).norm();
    Muscle {
        name,
        vertex_group: None,
        shape: MuscleShape::Linear(LinearMuscle {
            origin: arr(origin),
            insertion: arr(insertion),
            rs: l,
            rf: l + spill * s,
            k: k * s,
            zone: std::f64::consts::PI,
            wrinkle: None,
        }),
    }
}

fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The default 11-muscle set for a mesh (`positions`) whose 3D landmarks are `lm`.
///
/// # Errors
/// [`Error::MissingLandmark`] naming the first landmark needed and unmapped (the set needs
/// the eyes 36-47, brows 17, 19, 24, 26, nose 27, mouth 48, 50-52, 54, 57; 62/66 and 8 are
/// optional), or degenerate landmarks.
pub fn default_muscle_set(lm: &[Option<Point3<f64>>; 68], positions: &[Point3<f64>]) -> Result<MuscleSet> {
    let f = FaceFrame::from_landmarks(lm)?;
    let s = f.s;
    let mut muscles = Vec::with_capacity(NUM_DEFAULT_MUSCLES);
    // (suffix, sign of x, outer eye, eye range, mouth corner, upper lip, mid brow, outer brow)
    let sides = [
        ("L", 1.0, 45, 42..48, 54, 52, 24, 26),
        ("R", -1.0, 36, 36..42, 48, 50, 19, 17),
    ];
    for (sfx, sg, eye_out, eye, corner, upper, brow, _) in sides.clone() {
        let eo = need(lm, eye_out, "cheek muscle origin")?;
        let mc = need(lm, corner, "mouth-corner insertion")?;
        let origin = f.offset(&eo, 0.15 * sg, -0.45, -0.2);
        muscles.push(linear(format!("cheek_{sfx}"), origin, mc, s, 0.35, 0.2));
        let mut ec = Vector3::zeros();
        for i in eye {
            ec += need(lm, i, "eye centre")?.coords;
        }
        let ec = Point3::from(ec / 6.0);
        let ul = need(lm, upper, "upper-lip insertion")?;
        muscles.push(linear(
            format!("lips1_{sfx}"),
            f.offset(&ec, 0.0, -0.3, -0.15),
            ul,
            s,
            0.25,
            0.15,
        ));
        muscles.push(linear(
            format!("lips3_{sfx}"),
            f.offset(&mc, 0.1 * sg, -0.55, -0.15),
            mc,
            s,
            0.3,
            0.15,
        ));
        let nb = need(lm, 27, "nose-forehead muscle origin")?;
        let mb = need(lm, brow, "brow insertion")?;
        muscles.push(linear(
            format!("nose_forehead_{sfx}"),
            f.offset(&nb, 0.08 * sg, 0.0, -0.1),
            mb,
            s,
            0.3,
            0.12,
        ));
    }
    for (sfx, sg, _, _, _, _, brow, brow_out) in sides {
        let mb = need(lm, brow, "frontalis insertion")?;
        let ob = need(lm, brow_out, "frontalis control point")?;
        let origin = f.offset(&mb, 0.0, 0.9, -0.1);
        let l = (mb - origin).norm();
        muscles.push(Muscle {
            name: format!("eyebrow_forehead_{sfx}"),
            vertex_group: None,
            shape: MuscleShape::Parallel(ParallelMuscle {
                origin: arr(origin),
                insertion: arr(mb),
                control: arr(f.offset(&ob, 0.1 * sg, 0.0, 0.0)),
                height: 0.5 * s,
                rs: l,
                rf: l + 0.35 * s,
                k: 0.15 * s,
            }),
        });
    }
    let (m48, m51, m54, m57) = (
        need(lm, 48, "sphincter")?,
        need(lm, 51, "sphincter")?,
        need(lm, 54, "sphincter")?,
        need(lm, 57, "sphincter")?,
    );
    let centre = Point3::from((m48.coords + m51.coords + m54.coords + m57.coords) / 4.0);
    muscles.push(Muscle {
        name: "lips".into(),
        vertex_group: None,
        shape: MuscleShape::Sphincter(SphincterMuscle {
            centre: arr(centre),
            upper: arr(m51),
            corner: arr(m54),
            radius: 1.6,
            height: 0.08 * s,
            k: 0.25,
        }),
    });

    // Jaw group and pivot.
    let split = match (lm[62], lm[66]) {
        (Some(a), Some(b)) => f.coords(&nalgebra::center(&a, &b)).y,
        _ => f.coords(&nalgebra::center(&m48, &m54)).y,
    };
    let chin = lm[8].map_or_else(|| f.coords(&m57).y - 0.35, |c| f.coords(&c).y);
    let pivot = f.at(0.0, -0.55, -1.3);
    let pivot_z = f.coords(&pivot).z;
    const LIP_BAND: f64 = 0.06;
    let (mut indices, mut weights) = (Vec::new(), Vec::new());
    for (i, p) in positions.iter().enumerate() {
        let q = f.coords(p);
        let w = smoothstep((split - q.y) / LIP_BAND + 0.5)
            * (1.0 - smoothstep((q.x.abs() - 1.0) / 0.3))
            * (1.0 - smoothstep((chin - 0.15 - q.y) / 0.4))
            * smoothstep((q.z - pivot_z) / 0.4);
        if w > 1e-6 {
            indices.push(i as u32);
            weights.push(w.min(1.0));
        }
    }
    let mut vertex_groups = std::collections::BTreeMap::new();
    vertex_groups.insert(
        JAW_GROUP.to_string(),
        VertexGroup {
            indices,
            weights: Some(weights),
        },
    );
    let set = MuscleSet {
        format: FORMAT_TAG.into(),
        version: FORMAT_VERSION,
        units: None,
        muscles,
        vertex_groups,
        jaw: Some(Jaw {
            pivot: arr(pivot),
            max_angle: DEFAULT_MAX_JAW,
            vertex_group: JAW_GROUP.into(),
            axis: arr(Point3::from(f.x)),
        }),
    };
    set.validate()?;
    Ok(set)
}
