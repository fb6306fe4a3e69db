//! The three muscle deformers of Mramornov (2015), after Waters (1987) and Bui et al. (2004).
//!
//! Every deformer maps a rest vertex `P` (with unit normal `n`) to its displacement
//! `P'_i - P` at **full contraction** `c_i = 1`. Contractions combine linearly
//! (thesis eq. for the combination, see [`crate::rig`]):
//!
//! ```text
//! P_new = P + sum_i c_i (P'_i - P),   c_i in [0, 1]
//! ```
//!
//! so a deformer is evaluated once per vertex when a rig is built and posing is a sparse
//! `axpy` per muscle.
//!
//! All lengths are in the mesh's units (ICT: cm, SFM: mm); angles in radians.
//!
//! ## Linear muscle (Waters 1987) with wrinkles (Bui, Heylen & Nijholt 2004)
//! Origin (bony attachment) `V1`, insertion (skin attachment) `V2`. For a vertex `P`
//! at distance `D = |P - V1|` and angle `mu = angle(P - V1, V2 - V1)`:
//!
//! ```text
//! A = cos(mu / Omega * pi/2)                       for mu < Omega, else 0   (angular falloff)
//! R = cos((1 - D / Rs) * pi/2)                     for D < Rs               (radial falloff,
//! R = cos((D - Rs) / (Rf - Rs) * pi/2)             for Rs <= D <= Rf         start Rs, finish Rf)
//! R = 0                                            for D > Rf
//! P' - P = K * A * R * (V1 - P) / D                                           (pull towards V1)
//!        + H * u(l) * n                                                       (wrinkles, H > 0)
//! u(l) = A * R * (1 - cos(2 pi N_w l)) / 2,  l = D / Rf                      (N_w crests)
//! ```
//!
//! With the angular zone `Omega = pi` (the default) `A = cos(mu / pi * pi/2)`, the thesis' form.
//! `K` is the elasticity: the largest displacement, in mesh units, at full contraction.
//! The wrinkle profile `u(l)` is our reading of Bui et al.: `N_w` raised crests along the
//! muscle, scaled by the same falloffs so that they vanish where the muscle has no effect.
//!
//! ## Parallel (sheet) muscle
//! Origin `V1`, insertion `V2` and a control point `C` that spans the muscle plane with the
//! axis; `C`'s distance `W` from the axis is the sheet's half width. With the unit axis
//! `a = (V2 - V1)/|V2 - V1|`, the in-plane lateral unit vector `w` (towards `C`) and the plane
//! normal `m = a x w`, a vertex has coordinates `s = (P-V1).a`, `t = (P-V1).w`, `h = (P-V1).m`:
//!
//! ```text
//! R(s) as the linear muscle's R with D := s (0 <= s <= Rf)
//! A = cos(|t| / W * pi/2)          for |t| < W          (lateral falloff)
//! V = cos(|h| / H * pi/2)          for |h| < H          (height: distance from the plane)
//! P' - P = -K * A * R * V * a                            (every vertex moves parallel to the axis)
//! ```
//!
//! ## Sphincter muscle (orbicularis oris)
//! Centre `C`, upper-lip point `U` and corner point `Q` define the ellipse: semi-axes
//! `a = |Q - C|` along `e_x = (Q-C)/a` and `b` = distance of `U` from that axis along `e_y`;
//! `e_z` is the plane normal, oriented out of the face (along the mesh normals near `C`).
//! With `(x, y, z)` the coordinates of `P - C` in that frame, the elliptic radius
//! `rho = sqrt((x/a)^2 + (y/b)^2)` and the radius of influence `R` (in ellipse units):
//!
//! ```text
//! g = cos(rho / R * pi/2)               for rho < R, else 0
//! q = cos(min(|z| / (R a), 1) * pi/2)   (depth falloff)
//! D1 = -K g q (x e_x + y e_y)           in-plane contraction towards the centre (pucker)
//! D2 = -K g q z e_z                     pull towards the lip plane (lips press together)
//! D3 =  H g q e_z                       protrusion by the height H (pout)
//! P' - P = D1 + D2 + D3
//! ```
//!
//! Here `K` is dimensionless (fraction of the distance to the centre, in `[0, 1]`).
//!
//! | muscle | parameter | meaning | range |
//! |---|---|---|---|
//! | linear | `rs`, `rf` | radial falloff start / finish (mesh units) | `0 < rs < rf` |
//! | linear | `k` | elasticity: peak displacement (mesh units) | `>= 0` |
//! | linear | `zone` | angular zone `Omega` (rad), default `pi` | `(0, pi]` |
//! | linear | `wrinkle.height`, `wrinkle.count` | `H` (mesh units), `N_w` | `>= 0`, `>= 1` |
//! | parallel | `rs`, `rf`, `k` | as linear, along the axis | `0 < rs < rf`, `k >= 0` |
//! | parallel | `height` | half thickness around the plane (mesh units) | `> 0` |
//! | sphincter | `radius` | `R`, influence radius in ellipse units | `> 0` |
//! | sphincter | `height` | `H`, protrusion (mesh units) | `>= 0` |
//! | sphincter | `k` | contraction fraction | `[0, 1]` |

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{finite, non_negative, positive, Error, Result};

/// Below this length two control points are considered coincident.
const MIN_LENGTH: f64 = 1e-9;

fn p3(a: &[f64; 3]) -> Point3<f64> {
    Point3::new(a[0], a[1], a[2])
}

fn mirror(a: &[f64; 3]) -> [f64; 3] {
    [-a[0], a[1], a[2]]
}

/// Optional wrinkles on a linear muscle (Bui et al. 2004).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wrinkle {
    /// `H`: crest height along the normal at full contraction (mesh units, >= 0).
    pub height: f64,
    /// `N_w`: number of crests over `[0, Rf]` (>= 1).
    pub count: u32,
}

/// Waters' linear muscle (see module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinearMuscle {
    /// `V1`: origin (bone attachment).
    pub origin: [f64; 3],
    /// `V2`: insertion (skin attachment).
    pub insertion: [f64; 3],
    /// `Rs`: radial falloff start (mesh units).
    pub rs: f64,
    /// `Rf`: radial falloff finish (mesh units).
    pub rf: f64,
    /// `K`: elasticity, peak displacement at full contraction (mesh units).
    pub k: f64,
    /// `Omega`: angular zone in radians (default `pi`, the thesis' `cos(mu/pi * pi/2)`).
    #[serde(default = "default_zone")]
    pub zone: f64,
    /// Optional wrinkles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrinkle: Option<Wrinkle>,
}

fn default_zone() -> f64 {
    PI
}

/// Parallel (sheet) muscle (see module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParallelMuscle {
    /// `V1`: origin.
    pub origin: [f64; 3],
    /// `V2`: insertion.
    pub insertion: [f64; 3],
    /// `C`: control point in the muscle plane; its distance from the axis is the half width.
    pub control: [f64; 3],
    /// `H`: half thickness of the influence around the plane (mesh units).
    pub height: f64,
    /// `Rs`: falloff start along the axis (mesh units).
    pub rs: f64,
    /// `Rf`: falloff finish along the axis (mesh units).
    pub rf: f64,
    /// `K`: peak displacement (mesh units).
    pub k: f64,
}

/// Sphincter muscle, orbicularis oris (see module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphincterMuscle {
    /// `C`: ellipse centre.
    pub centre: [f64; 3],
    /// `U`: upper-lip point (gives the vertical semi-axis).
    pub upper: [f64; 3],
    /// `Q`: mouth-corner point (gives the horizontal semi-axis).
    pub corner: [f64; 3],
    /// `R`: radius of influence in ellipse units (1 = the ellipse through `U` and `Q`).
    pub radius: f64,
    /// `H`: protrusion at full contraction (mesh units).
    pub height: f64,
    /// `K`: contraction towards the centre, fraction in `[0, 1]`.
    pub k: f64,
}

/// One muscle's geometry and parameters, tagged by `"type"` in JSON.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum MuscleShape {
    /// Waters' linear muscle.
    Linear(LinearMuscle),
    /// Sheet muscle.
    Parallel(ParallelMuscle),
    /// Sphincter muscle.
    Sphincter(SphincterMuscle),
}

/// Waters' radial falloff `R(D)` for start `rs` and finish `rf`.
fn radial(d: f64, rs: f64, rf: f64) -> f64 {
    if !(0.0..=rf).contains(&d) {
        0.0
    } else if d < rs {
        ((1.0 - d / rs) * FRAC_PI_2).cos()
    } else {
        ((d - rs) / (rf - rs) * FRAC_PI_2).cos()
    }
}

/// `cos(x * pi/2)` for `x` in `[0, 1)`, else 0.
fn cos_falloff(x: f64) -> f64 {
    if (0.0..1.0).contains(&x) {
        (x * FRAC_PI_2).cos()
    } else {
        0.0
    }
}

impl MuscleShape {
    /// Short type name as in JSON.
    pub fn type_name(&self) -> &'static str {
        match self {
            MuscleShape::Linear(_) => "linear",
            MuscleShape::Parallel(_) => "parallel",
            MuscleShape::Sphincter(_) => "sphincter",
        }
    }

    /// Validates every parameter; errors name the muscle and the parameter.
    ///
    /// # Errors
    /// Non-finite values, out-of-range parameters (see the module table), coincident
    /// control points.
    pub fn validate(&self, muscle: &str) -> Result<()> {
        let n = |p: &str| format!("muscle {muscle:?}: {p}");
        let pts = |names: &[(&str, &[f64; 3])]| -> Result<()> {
            for (pn, p) in names {
                for v in p.iter() {
                    finite(n(pn), *v)?;
                }
            }
            Ok(())
        };
        let distinct = |a: &[f64; 3], b: &[f64; 3], what: &str| -> Result<()> {
            if (p3(a) - p3(b)).norm() <= MIN_LENGTH {
                return Err(Error::Degenerate {
                    what: format!("muscle {muscle:?}"),
                    reason: format!("{what} coincide"),
                });
            }
            Ok(())
        };
        let falloff = |rs: f64, rf: f64| -> Result<()> {
            positive(n("rs"), rs)?;
            finite(n("rf"), rf)?;
            if rf <= rs {
                return Err(Error::invalid(n("rf"), rf, format!("> rs = {rs}")));
            }
            Ok(())
        };
        match self {
            MuscleShape::Linear(m) => {
                pts(&[("origin", &m.origin), ("insertion", &m.insertion)])?;
                distinct(&m.origin, &m.insertion, "origin and insertion")?;
                falloff(m.rs, m.rf)?;
                non_negative(n("k"), m.k)?;
                finite(n("zone"), m.zone)?;
                if !(m.zone > 0.0 && m.zone <= PI) {
                    return Err(Error::invalid(n("zone"), m.zone, "in (0, pi]"));
                }
                if let Some(w) = m.wrinkle {
                    non_negative(n("wrinkle.height"), w.height)?;
                    if w.count == 0 {
                        return Err(Error::invalid(n("wrinkle.count"), 0, ">= 1"));
                    }
                }
            }
            MuscleShape::Parallel(m) => {
                pts(&[
                    ("origin", &m.origin),
                    ("insertion", &m.insertion),
                    ("control", &m.control),
                ])?;
                distinct(&m.origin, &m.insertion, "origin and insertion")?;
                falloff(m.rs, m.rf)?;
                non_negative(n("k"), m.k)?;
                positive(n("height"), m.height)?;
                let a = (p3(&m.insertion) - p3(&m.origin)).normalize();
                let c = p3(&m.control) - p3(&m.origin);
                if (c - a * c.dot(&a)).norm() <= MIN_LENGTH {
                    return Err(Error::Degenerate {
                        what: format!("muscle {muscle:?}"),
                        reason: "control point lies on the muscle axis (no plane, zero width)".into(),
                    });
                }
            }
            MuscleShape::Sphincter(m) => {
                pts(&[("centre", &m.centre), ("upper", &m.upper), ("corner", &m.corner)])?;
                distinct(&m.centre, &m.corner, "centre and corner")?;
                positive(n("radius"), m.radius)?;
                non_negative(n("height"), m.height)?;
                finite(n("k"), m.k)?;
                if !(0.0..=1.0).contains(&m.k) {
                    return Err(Error::invalid(n("k"), m.k, "in [0, 1]"));
                }
                let ex = (p3(&m.corner) - p3(&m.centre)).normalize();
                let u = p3(&m.upper) - p3(&m.centre);
                if (u - ex * u.dot(&ex)).norm() <= MIN_LENGTH {
                    return Err(Error::Degenerate {
                        what: format!("muscle {muscle:?}"),
                        reason: "upper-lip point lies on the centre-corner line (flat ellipse)".into(),
                    });
                }
            }
        }
        Ok(())
    }

    /// The control points, for retargeting.
    pub fn control_points(&self) -> Vec<[f64; 3]> {
        match self {
            MuscleShape::Linear(m) => vec![m.origin, m.insertion],
            MuscleShape::Parallel(m) => vec![m.origin, m.insertion, m.control],
            MuscleShape::Sphincter(m) => vec![m.centre, m.upper, m.corner],
        }
    }

    /// Replaces the control points (same order as [`Self::control_points`]).
    ///
    /// # Errors
    /// Wrong number of points.
    pub fn set_control_points(&mut self, p: &[[f64; 3]]) -> Result<()> {
        let want = self.control_points().len();
        if p.len() != want {
            return Err(Error::DimensionMismatch {
                what: "muscle control point count".into(),
                expected: want,
                got: p.len(),
            });
        }
        match self {
            MuscleShape::Linear(m) => {
                m.origin = p[0];
                m.insertion = p[1];
            }
            MuscleShape::Parallel(m) => {
                m.origin = p[0];
                m.insertion = p[1];
                m.control = p[2];
            }
            MuscleShape::Sphincter(m) => {
                m.centre = p[0];
                m.upper = p[1];
                m.corner = p[2];
            }
        }
        Ok(())
    }

    /// Multiplies every length parameter (not the control points) by `s`: used when a set
    /// is retargeted to a mesh of another size or unit.
    pub fn scale_lengths(&mut self, s: f64) {
        match self {
            MuscleShape::Linear(m) => {
                m.rs *= s;
                m.rf *= s;
                m.k *= s;
                if let Some(w) = &mut m.wrinkle {
                    w.height *= s;
                }
            }
            MuscleShape::Parallel(m) => {
                m.rs *= s;
                m.rf *= s;
                m.k *= s;
                m.height *= s;
            }
            MuscleShape::Sphincter(m) => m.height *= s,
        }
    }

    /// The muscle mirrored through the plane `x = 0`.
    pub fn mirrored_x(&self) -> Self {
        match *self {
            MuscleShape::Linear(m) => MuscleShape::Linear(LinearMuscle {
                origin: mirror(&m.origin),
                insertion: mirror(&m.insertion),
                ..m
            }),
            MuscleShape::Parallel(m) => MuscleShape::Parallel(ParallelMuscle {
                origin: mirror(&m.origin),
                insertion: mirror(&m.insertion),
                control: mirror(&m.control),
                ..m
            }),
            MuscleShape::Sphincter(m) => MuscleShape::Sphincter(SphincterMuscle {
                centre: mirror(&m.centre),
                upper: mirror(&m.upper),
                corner: mirror(&m.corner),
                ..m
            }),
        }
    }
}

/// A validated muscle with its local frame precomputed: evaluates `P' - P` at `c = 1`.
#[derive(Debug, Clone, Copy)]
pub struct Deformer {
    kind: Prepared,
}

#[derive(Debug, Clone, Copy)]
enum Prepared {
    Linear {
        v1: Point3<f64>,
        axis: Vector3<f64>,
        rs: f64,
        rf: f64,
        k: f64,
        zone: f64,
        wrinkle: Option<Wrinkle>,
    },
    Parallel {
        v1: Point3<f64>,
        a: Vector3<f64>,
        w: Vector3<f64>,
        m: Vector3<f64>,
        half_width: f64,
        height: f64,
        rs: f64,
        rf: f64,
        k: f64,
    },
    Sphincter {
        c: Point3<f64>,
        ex: Vector3<f64>,
        ey: Vector3<f64>,
        ez: Vector3<f64>,
        a: f64,
        b: f64,
        radius: f64,
        height: f64,
        k: f64,
    },
}

impl Deformer {
    /// Validates `shape` and precomputes its frame. `outward` orients the sphincter's
    /// normal `e_z` (out of the face); pass the mean mesh normal near the mouth, or `None`
    /// to use `e_x x e_y` as is.
    ///
    /// # Errors
    /// As [`MuscleShape::validate`].
    pub fn new(shape: &MuscleShape, name: &str, outward: Option<Vector3<f64>>) -> Result<Self> {
        shape.validate(name)?;
        let kind = match *shape {
            MuscleShape::Linear(m) => Prepared::Linear {
                v1: p3(&m.origin),
                axis: (p3(&m.insertion) - p3(&m.origin)).normalize(),
                rs: m.rs,
                rf: m.rf,
                k: m.k,
                zone: m.zone,
                wrinkle: m.wrinkle,
            },
            MuscleShape::Parallel(m) => {
                let v1 = p3(&m.origin);
                let a = (p3(&m.insertion) - v1).normalize();
                let c = p3(&m.control) - v1;
                let wv = c - a * c.dot(&a);
                let half_width = wv.norm();
                let w = wv / half_width;
                Prepared::Parallel {
                    v1,
                    a,
                    w,
                    m: a.cross(&w),
                    half_width,
                    height: m.height,
                    rs: m.rs,
                    rf: m.rf,
                    k: m.k,
                }
            }
            MuscleShape::Sphincter(m) => {
                let c = p3(&m.centre);
                let qa = p3(&m.corner) - c;
                let a = qa.norm();
                let ex = qa / a;
                let u = p3(&m.upper) - c;
                let up = u - ex * u.dot(&ex);
                let b = up.norm();
                let ey = up / b;
                let mut ez = ex.cross(&ey);
                if let Some(o) = outward {
                    if ez.dot(&o) < 0.0 {
                        ez = -ez;
                    }
                }
                Prepared::Sphincter {
                    c,
                    ex,
                    ey,
                    ez,
                    a,
                    b,
                    radius: m.radius,
                    height: m.height,
                    k: m.k,
                }
            }
        };
        Ok(Deformer { kind })
    }

    /// `P' - P` at full contraction for rest vertex `p` with unit normal `n`
    /// (the normal is used only by wrinkles).
    pub fn displacement(&self, p: &Point3<f64>, n: &Vector3<f64>) -> Vector3<f64> {
        match self.kind {
            Prepared::Linear {
                v1,
                axis,
                rs,
                rf,
                k,
                zone,
                wrinkle,
            } => {
                let d = p - v1;
                let dist = d.norm();
                if dist <= MIN_LENGTH || dist > rf {
                    return Vector3::zeros();
                }
                let mu = (d.dot(&axis) / dist).clamp(-1.0, 1.0).acos();
                let a = cos_falloff(mu / zone);
                let r = radial(dist, rs, rf);
                let mut out = -d / dist * (k * a * r);
                if let Some(w) = wrinkle {
                    let l = dist / rf;
                    let u = a * r * 0.5 * (1.0 - (2.0 * PI * f64::from(w.count) * l).cos());
                    out += n * (w.height * u);
                }
                out
            }
            Prepared::Parallel {
                v1,
                a,
                w,
                m,
                half_width,
                height,
                rs,
                rf,
                k,
            } => {
                let d = p - v1;
                let s = d.dot(&a);
                let lat = cos_falloff(d.dot(&w).abs() / half_width);
                let hgt = cos_falloff(d.dot(&m).abs() / height);
                let r = radial(s, rs, rf);
                -a * (k * lat * hgt * r)
            }
            Prepared::Sphincter {
                c,
                ex,
                ey,
                ez,
                a,
                b,
                radius,
                height,
                k,
            } => {
                let d = p - c;
                let (x, y, z) = (d.dot(&ex), d.dot(&ey), d.dot(&ez));
                let rho = ((x / a).powi(2) + (y / b).powi(2)).sqrt();
                let g = cos_falloff(rho / radius);
                if g == 0.0 {
                    return Vector3::zeros();
                }
                let q = ((z.abs() / (radius * a)).min(1.0) * FRAC_PI_2).cos();
                let d1 = -(ex * x + ey * y) * (k * g * q);
                let d2 = -ez * (k * g * q * z);
                let d3 = ez * (height * g * q);
                d1 + d2 + d3
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lin() -> MuscleShape {
        MuscleShape::Linear(LinearMuscle {
            origin: [0.0, 0.0, 0.0],
            insertion: [1.0, 0.0, 0.0],
            rs: 1.0,
            rf: 2.0,
            k: 0.3,
            zone: PI,
            wrinkle: None,
        })
    }

    #[test]
    fn linear_peaks_at_rs_on_axis_and_pulls_to_origin() {
        let d = Deformer::new(&lin(), "m", None).unwrap();
        let v = d.displacement(&Point3::new(1.0, 0.0, 0.0), &Vector3::z());
        assert!((v - Vector3::new(-0.3, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(
            d.displacement(&Point3::new(2.5, 0.0, 0.0), &Vector3::z()),
            Vector3::zeros()
        );
        // Behind the origin the angular falloff vanishes.
        assert!(d.displacement(&Point3::new(-1.0, 0.0, 0.0), &Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn validation_names_the_parameter() {
        let MuscleShape::Linear(mut m) = lin() else {
            unreachable!()
        };
        m.rf = 0.5;
        let e = MuscleShape::Linear(m).validate("cheek_L").unwrap_err().to_string();
        assert!(e.contains("cheek_L") && e.contains("rf"), "{e}");
        m.rf = 2.0;
        m.k = f64::NAN;
        let e = MuscleShape::Linear(m).validate("x").unwrap_err().to_string();
        assert!(e.contains("k"), "{e}");
        m.k = 0.1;
        m.zone = 4.0;
        assert!(MuscleShape::Linear(m).validate("x").is_err());
        m.zone = PI;
        m.insertion = m.origin;
        assert!(MuscleShape::Linear(m).validate("x").is_err());
        let s = MuscleShape::Sphincter(SphincterMuscle {
            centre: [0.0; 3],
            upper: [0.0, 1.0, 0.0],
            corner: [2.0, 0.0, 0.0],
            radius: 1.5,
            height: 0.1,
            k: 1.5,
        });
        assert!(s.validate("lips").unwrap_err().to_string().contains("k"));
    }
}
