//! Closing eyes for `facecap synth`: the eyeball stays put and the lids slide over it.
//!
//! A piecewise-affine warp alone squashes the eye when the lid points come together,
//! so the iris becomes a thin dark band in full contrast instead of being covered. Here
//! each eye is composed in three layers:
//!
//! 1. the warp of a *lidded* photo ([`cover_eyes`]): inside each eye opening of the
//!    photo the eyeball is replaced by lid skin (the skin band above the lashes,
//!    stretched down), so whatever the warp stretches over the swept area is skin;
//! 2. over it, from the photo moved only by the head motion (an affine map fitted to the
//!    eye points posed with all weights zero), the eyeball inside the current lid
//!    opening and the upper lid slid down over it: its margin with the lashes moves
//!    unstretched, the skin above it stretches ([`close_eye`]);
//! 3. a darker lash line along the upper lid edge, as strong as the eye is closed.
//!
//! An opening is bounded by two smooth lid curves through the 6 eye points (corners,
//! two upper and two lower lid points, dlib order): in the frame of the corner axis
//! each lid is the cubic `v(u) = u (1 - u) (a + b u)` through its two points, zero at
//! both corners. Where the upper curve meets or crosses the lower one, the eye is shut
//! and shows no eyeball at all.

use image::{Rgb, RgbImage};

use crate::warp::sample_bilinear;

pub use facecap_core::landmarks::EYES;

/// How far above the upper lid edge the skin for the lid starts, in eye widths
/// (past the lashes).
const SKIN_MARGIN: f64 = 0.10;
/// How much of the skin band one pixel of the covered opening takes (a stretch of 1/x).
const SKIN_STRETCH: f64 = 0.5;
/// Darkening of the lash line of a shut eye (fraction of the colour removed at its centre).
const LASH_DARKNESS: f64 = 0.45;
/// Half width of the lash line, pixels (a Gaussian's sigma).
const LASH_SIGMA_PX: f64 = 0.8;
/// Height of the lid margin that slides down unstretched (lashes and skin), eye widths.
const LID_BAND: f64 = 0.12;
/// Height of the skin above the margin that stretches as the lid comes down, eye widths.
const LID_STRETCH: f64 = 0.25;
/// Width of the soft edge of the eyeball, pixels.
const FEATHER_PX: f64 = 1.5;

/// The two lid curves of one eye.
#[derive(Debug, Clone, Copy)]
pub struct Lids {
    /// First corner (`u = 0`).
    c0: (f64, f64),
    /// Unit vector along the corner axis.
    e: (f64, f64),
    /// Unit normal, pointing down the image for an upright eye (lower lid side).
    n: (f64, f64),
    /// Corner distance, pixels.
    len: f64,
    /// `(a, b)` of the upper and lower lid cubics (`v` in pixels).
    up: (f64, f64),
    lo: (f64, f64),
}

/// `(a, b)` of `v(u) = u (1 - u) (a + b u)` through `(u1, v1)` and `(u2, v2)`.
fn cubic_through(p1: (f64, f64), p2: (f64, f64)) -> Option<(f64, f64)> {
    let ok = |u: f64| u > 0.02 && u < 0.98;
    if !ok(p1.0) || !ok(p2.0) || (p2.0 - p1.0).abs() < 0.02 {
        return None;
    }
    let q1 = p1.1 / (p1.0 * (1.0 - p1.0));
    let q2 = p2.1 / (p2.0 * (1.0 - p2.0));
    let b = (q2 - q1) / (p2.0 - p1.0);
    let a = q1 - b * p1.0;
    (a.is_finite() && b.is_finite()).then_some((a, b))
}

impl Lids {
    /// Lid curves through the 6 eye points (dlib order: corner, upper, upper, corner,
    /// lower, lower), or `None` when the points do not make an eye (corners together,
    /// lid points outside the corner span).
    pub fn new(p: &[(f64, f64); 6]) -> Option<Self> {
        let c0 = p[0];
        let (dx, dy) = (p[3].0 - c0.0, p[3].1 - c0.1);
        let len = dx.hypot(dy);
        if len.is_nan() || len <= 1.0 {
            return None;
        }
        let e = (dx / len, dy / len);
        let n = (-e.1, e.0);
        let mut l = Lids {
            c0,
            e,
            n,
            len,
            up: (0.0, 0.0),
            lo: (0.0, 0.0),
        };
        let q: Vec<(f64, f64)> = p.iter().map(|&(x, y)| l.local(x, y)).collect();
        l.up = cubic_through(q[1], q[2])?;
        l.lo = cubic_through(q[5], q[4])?;
        Some(l)
    }

    /// Lid curves through `p` (the 6 eye points) in the corner frame of `frame`: the
    /// curves are zero at `frame`'s corners and pass through `p`'s lid points.
    pub fn in_frame_of(p: &[(f64, f64); 6], frame: &Lids) -> Option<Self> {
        let mut l = *frame;
        let q: Vec<(f64, f64)> = p.iter().map(|&(x, y)| l.local(x, y)).collect();
        l.up = cubic_through(q[1], q[2])?;
        l.lo = cubic_through(q[5], q[4])?;
        Some(l)
    }

    /// `(u, v)` of an image point: `u` along the corner axis (0 and 1 at the corners),
    /// `v` in pixels along the normal.
    fn local(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.c0.0, y - self.c0.1);
        (
            (dx * self.e.0 + dy * self.e.1) / self.len,
            dx * self.n.0 + dy * self.n.1,
        )
    }

    /// The image point of `(u, v)`.
    fn world(&self, u: f64, v: f64) -> (f64, f64) {
        let s = u * self.len;
        (
            self.c0.0 + s * self.e.0 + v * self.n.0,
            self.c0.1 + s * self.e.1 + v * self.n.1,
        )
    }

    fn upper(&self, u: f64) -> f64 {
        u * (1.0 - u) * (self.up.0 + self.up.1 * u)
    }

    fn lower(&self, u: f64) -> f64 {
        u * (1.0 - u) * (self.lo.0 + self.lo.1 * u)
    }

    /// Height of the opening at `u`, pixels (<= 0 where the lids meet).
    fn opening(&self, u: f64) -> f64 {
        self.lower(u) - self.upper(u)
    }

    /// The widest opening along the eye, pixels.
    fn max_opening(&self) -> f64 {
        (1..20).map(|i| self.opening(i as f64 / 20.0)).fold(0.0, f64::max)
    }

    /// Pixel box `(x0, y0, x1, y1)` around both curves, grown by `grow` pixels and
    /// clipped to a `w` x `h` image; `None` when empty.
    fn pixel_box(&self, grow: f64, w: u32, h: u32) -> Option<(u32, u32, u32, u32)> {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for i in 0..=40 {
            let u = i as f64 / 40.0;
            for v in [self.upper(u), self.lower(u)] {
                let (x, y) = self.world(u, v);
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
        let (x0, y0) = ((x0 - grow).floor().max(0.0), (y0 - grow).floor().max(0.0));
        let (x1, y1) = (
            (x1 + grow).ceil().min(w as f64 - 1.0),
            (y1 + grow).ceil().min(h as f64 - 1.0),
        );
        (x0.is_finite() && y1.is_finite() && x0 <= x1 && y0 <= y1)
            .then_some((x0 as u32, y0 as u32, x1 as u32, y1 as u32))
    }
}

/// A 2D affine map `(x, y) -> (m[0] x + m[1] y + m[2], m[3] x + m[4] y + m[5])`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine(pub [f64; 6]);

impl Affine {
    /// Least-squares affine map taking `from[i]` to `to[i]` (at least 3 points not on a
    /// line), or `None`.
    pub fn fit(from: &[(f64, f64)], to: &[(f64, f64)]) -> Option<Self> {
        if from.len() != to.len() || from.len() < 3 {
            return None;
        }
        let mut ata = nalgebra::Matrix3::<f64>::zeros();
        let (mut atx, mut aty) = (nalgebra::Vector3::<f64>::zeros(), nalgebra::Vector3::<f64>::zeros());
        for (f, t) in from.iter().zip(to) {
            let r = nalgebra::Vector3::new(f.0, f.1, 1.0);
            ata += r * r.transpose();
            atx += r * t.0;
            aty += r * t.1;
        }
        let inv = ata.try_inverse()?;
        let (mx, my) = (inv * atx, inv * aty);
        let m = [mx[0], mx[1], mx[2], my[0], my[1], my[2]];
        m.iter().all(|v| v.is_finite()).then_some(Affine(m))
    }

    fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let m = &self.0;
        (m[0] * x + m[1] * y + m[2], m[3] * x + m[4] * y + m[5])
    }
}

fn smoothstep01(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn mix(a: [u8; 3], b: [u8; 3], t: f64) -> [u8; 3] {
    let mut o = [0u8; 3];
    for k in 0..3 {
        o[k] = (a[k] as f64 * (1.0 - t) + b[k] as f64 * t).round().clamp(0.0, 255.0) as u8;
    }
    o
}

/// The photo with each eye's opening (`lids`, photo geometry) covered by lid skin: a
/// pixel at depth `t` below the upper lid samples the photo `SKIN_MARGIN` eye widths
/// above the lid plus `SKIN_STRETCH * t`, with a 1 px soft edge outside the opening.
pub fn cover_eyes(photo: &RgbImage, lids: &[Lids]) -> RgbImage {
    let mut out = photo.clone();
    for l in lids {
        let Some((x0, y0, x1, y1)) = l.pixel_box(2.0, photo.width(), photo.height()) else {
            continue;
        };
        let margin = SKIN_MARGIN * l.len;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (u, v) = l.local(x as f64, y as f64);
                if !(0.0..=1.0).contains(&u) || l.opening(u) <= 0.0 {
                    continue;
                }
                let up = l.upper(u);
                let d = (v - up).min(l.lower(u) - v);
                let a = (d + 1.0).clamp(0.0, 1.0);
                if a <= 0.0 {
                    continue;
                }
                let depth = (v - up).max(0.0);
                let (sx, sy) = l.world(u, up - margin - SKIN_STRETCH * depth);
                let skin = sample_bilinear(photo, sx, sy);
                let here = out.get_pixel(x, y).0;
                out.put_pixel(x, y, Rgb(mix(here, skin, a)));
            }
        }
    }
    out
}

/// Closes one eye of `frame` over the photo's eyeball. `to_photo` maps frame pixels to
/// photo pixels by the head motion alone; `photo_lids` are the photo's lids and `cur` the
/// frame's 6 eye points. Working in the photo's eye frame, with the upper lid lowered by
/// `D(u)` (never below the lower lid):
///
/// - inside the opening, the eyeball of the photo where it is (soft 1.5 px edges);
/// - the lid margin (lashes and `LID_BAND` eye widths of skin above them) slides down
///   by `D` unstretched;
/// - the skin above it (`LID_STRETCH` eye widths) stretches to take up the move and
///   fades into the warp at its top;
/// - a darker lash line along the lid edge, as strong as the eye is shut.
///
/// Below the lower lid the frame keeps the warp. Where the lids meet, no eyeball shows.
pub fn close_eye(frame: &mut RgbImage, photo: &RgbImage, photo_lids: &Lids, cur: &[(f64, f64); 6], to_photo: &Affine) {
    let cur_photo = cur.map(|(x, y)| to_photo.apply(x, y));
    let Some(lc) = Lids::in_frame_of(&cur_photo, photo_lids) else {
        return;
    };
    let l0 = photo_lids;
    let rest_open = l0.max_opening();
    let closure = if rest_open > 0.0 {
        (1.0 - lc.max_opening().max(0.0) / rest_open).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let band = LID_BAND * l0.len;
    let stretch = LID_STRETCH * l0.len;
    let Some(cur_lids) = Lids::new(cur) else {
        return;
    };
    let Some((x0, y0, x1, y1)) = cur_lids.pixel_box(band + stretch + 3.0, frame.width(), frame.height()) else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (px, py) = to_photo.apply(x as f64, y as f64);
            let (u, v) = l0.local(px, py);
            if !(0.0..=1.0).contains(&u) {
                continue;
            }
            let lo = lc.lower(u);
            let up = lc.upper(u).min(lo);
            let up0 = l0.upper(u);
            let shift = (up - up0).max(0.0);
            let top = up0 - band - stretch;
            // Blend weight of the drawn eye against the warp: 0 above the stretched skin,
            // 0 below the lower lid.
            let a_top = smoothstep01((v - (top - 2.0)) / 4.0);
            let a_low = smoothstep01((lo - v + 0.5 * FEATHER_PX) / FEATHER_PX);
            let a = a_top * a_low;
            if a <= 0.0 {
                continue;
            }
            // The lid at this pixel: where it samples the photo.
            let v_lid = if v >= up - band {
                v - shift
            } else if v >= top {
                top + (v - top) * stretch / (stretch + shift)
            } else {
                v
            };
            let lid = {
                let (sx, sy) = l0.world(u, v_lid);
                sample_bilinear(photo, sx, sy)
            };
            // The eyeball shows below the lid edge, not where the lids meet.
            let open = (lo - up).clamp(0.0, 1.0);
            let e = smoothstep01((v - up + 0.5 * FEATHER_PX) / FEATHER_PX) * open;
            let mut c = if e > 0.0 {
                let (sx, sy) = l0.world(u, v);
                mix(lid, sample_bilinear(photo, sx, sy), e)
            } else {
                lid
            };
            if closure > 0.0 {
                let t = v - up + 0.3;
                let taper = (4.0 * u * (1.0 - u)).sqrt().min(1.0);
                let dark = LASH_DARKNESS * closure * taper * (-(t * t) / (2.0 * LASH_SIGMA_PX * LASH_SIGMA_PX)).exp();
                for ch in c.iter_mut() {
                    *ch = (*ch as f64 * (1.0 - dark)).round().clamp(0.0, 255.0) as u8;
                }
            }
            let here = frame.get_pixel(x, y).0;
            frame.put_pixel(x, y, Rgb(mix(here, c, a)));
        }
    }
}

/// The 6 points of eye `k` ([`EYES`]) out of a landmark list.
pub fn eye_points(pts: &[(f64, f64)], k: usize) -> [(f64, f64); 6] {
    EYES[k].map(|i| pts[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eye(open: f64) -> [(f64, f64); 6] {
        [
            (10.0, 20.0),
            (17.0, 20.0 - open),
            (23.0, 20.0 - open),
            (30.0, 20.0),
            (23.0, 20.0 + 0.5 * open),
            (17.0, 20.0 + 0.5 * open),
        ]
    }

    #[test]
    fn lids_pass_through_the_points() {
        let p = eye(4.0);
        let l = Lids::new(&p).unwrap();
        for i in [1, 2] {
            let (u, v) = l.local(p[i].0, p[i].1);
            assert!((l.upper(u) - v).abs() < 1e-9);
        }
        for i in [4, 5] {
            let (u, v) = l.local(p[i].0, p[i].1);
            assert!((l.lower(u) - v).abs() < 1e-9);
        }
        assert!(l.opening(0.5) > 5.0);
        assert!(Lids::new(&[(0.0, 0.0); 6]).is_none());
    }

    #[test]
    fn a_shut_eye_shows_no_eyeball() {
        // Eyeball: pure blue; skin elsewhere: grey.
        let photo = RgbImage::from_fn(40, 40, |x, y| {
            if (16..25).contains(&x) && (18..22).contains(&y) {
                Rgb([0, 0, 255])
            } else {
                Rgb([128, 128, 128])
            }
        });
        let rest = Lids::new(&eye(4.0)).unwrap();
        let id = Affine::fit(&eye(4.0), &eye(4.0)).unwrap();
        let covered = cover_eyes(&photo, &[rest]);
        let mut frame = covered.clone();
        close_eye(&mut frame, &photo, &rest, &eye(-0.5), &id);
        assert!(frame.pixels().all(|p| p.0[2] <= p.0[0] + 1), "blue left in a shut eye");
        // Open: the eyeball is there.
        let mut frame = covered;
        close_eye(&mut frame, &photo, &rest, &eye(4.0), &id);
        assert_eq!(frame.get_pixel(20, 20).0, [0, 0, 255]);
    }

    #[test]
    fn affine_fit_recovers_a_map() {
        let m = Affine([1.1, 0.2, 3.0, -0.1, 0.9, -2.0]);
        let from: Vec<(f64, f64)> = eye(3.0).to_vec();
        let to: Vec<(f64, f64)> = from.iter().map(|p| m.apply(p.0, p.1)).collect();
        let fit = Affine::fit(&from, &to).unwrap();
        for (a, b) in fit.0.iter().zip(m.0) {
            assert!((a - b).abs() < 1e-9);
        }
    }
}
