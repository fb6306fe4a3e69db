//! The lips' visible red and the chin's rise, read straight from the 68 landmarks and added
//! to the solved `mouthRollLower`, `mouthRollUpper` and `mouthShrugLower`.
//!
//! A lip rolled in hides its red: the band between the outer and the inner lip contour
//! narrows. The rig's roll shapes move the same points, but so do the press, the smile and
//! the shrug, and the solve's priors share the motion among them; the band's area says it
//! directly. Likewise the chin raiser (FACS AU17) pushes the lower lip up, away from the
//! chin, a motion the 68 points see as a longer chin-to-lip distance that the solve gives to
//! other shapes. Measured on the five shared clips against MediaPipe's scores
//! (docs/expressions.md, "The lips' red and the chin"): `mouthRollLower`,
//! `mouthRollUpper` and `mouthShrugLower` rise on every clip where MediaPipe's score moves,
//! including the clips where it moves too little to be counted.
//!
//! Measures ([`lip_measures`]) are taken in the eye-line frame (origin between the outer eye
//! corners, points 36 and 45, rotated so that they are level, in units of their distance), so
//! they do not change with the head's roll or distance. Each is compared with the subject's
//! rest: the clip's median (capture, `solve`) or the running median of the frames so far
//! (live input), as the resting gaze is.

use facecap_core::landmarks::Landmarks68;

use crate::expression::{running_rest_due, unit, RUNNING_REST_SEEN_MAX};

/// Share of a lip's resting red area that, lost, adds 1 to its roll weight's drive, halved:
/// `mouthRoll* += LIP_ROLL_GAIN * (1 - area / rest_area)`. A lip that shows half its
/// resting red adds 0.25. Measured flat between 0.3 and 0.7 (docs/expressions.md).
pub const LIP_ROLL_GAIN: f64 = 0.5;

/// `mouthShrugLower += CHIN_RAISE_GAIN * (d - rest_d)`, `d` the chin-to-lower-lip
/// distance (points 8 and 57, vertical in the eye-line frame) in inter-ocular distances: a
/// lower lip pushed 0.1 inter-ocular distances up from the chin adds 0.1.
pub const CHIN_RAISE_GAIN: f64 = 1.0;

/// Outer lower lip from the left mouth corner to the right (48, 59..55, 54), then the inner
/// lower lip back (64..67, 60): the lower lip's red band as a polygon.
const LOWER_RED: [usize; 12] = [48, 59, 58, 57, 56, 55, 54, 64, 65, 66, 67, 60];
/// Outer upper lip (48..54), then the inner upper lip back (64, 63..61, 60).
const UPPER_RED: [usize; 12] = [48, 49, 50, 51, 52, 53, 54, 64, 63, 62, 61, 60];

/// The lip and chin measures of one frame ([`lip_measures`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LipMeasures {
    /// Area of the lower lip's red band, in squared inter-ocular distances.
    pub lower_red: f64,
    /// Area of the upper lip's red band, in squared inter-ocular distances.
    pub upper_red: f64,
    /// Chin (8) below the lower lip's outer midpoint (57), in inter-ocular distances.
    pub chin: f64,
}

/// The measures of one frame's landmarks; `None` when the eye corners coincide or a
/// value is not finite.
pub fn lip_measures(l: &Landmarks68) -> Option<LipMeasures> {
    let (a, b) = (l.points[36], l.points[45]);
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    let iod = dx.hypot(dy);
    if !(iod.is_finite() && iod > 1e-9) {
        return None;
    }
    let (c, s) = (dx / iod, dy / iod);
    let (mx, my) = ((a.x + b.x) / 2.0, (a.y + b.y) / 2.0);
    // the point in the eye-line frame: x along the eye line, y down, in IODs
    let at = |i: usize| {
        let (x, y) = (l.points[i].x - mx, l.points[i].y - my);
        ((c * x + s * y) / iod, (-s * x + c * y) / iod)
    };
    let area = |poly: &[usize]| {
        let mut twice = 0.0;
        for (k, &i) in poly.iter().enumerate() {
            let (p, q) = (at(i), at(poly[(k + 1) % poly.len()]));
            twice += p.0 * q.1 - q.0 * p.1;
        }
        (twice / 2.0).abs()
    };
    let m = LipMeasures {
        lower_red: area(&LOWER_RED),
        upper_red: area(&UPPER_RED),
        chin: at(8).1 - at(57).1,
    };
    [m.lower_red, m.upper_red, m.chin]
        .iter()
        .all(|v| v.is_finite())
        .then_some(m)
}

impl LipMeasures {
    /// Per measure the median of `frames` (`None` for none). Reorders `frames`.
    pub fn median(frames: &mut [LipMeasures]) -> Option<LipMeasures> {
        if frames.is_empty() {
            return None;
        }
        let mut med = |f: fn(&LipMeasures) -> f64| {
            let k = frames.len() / 2;
            frames.select_nth_unstable_by(k, |a, b| f(a).total_cmp(&f(b)));
            f(&frames[k])
        };
        Some(LipMeasures {
            lower_red: med(|m| m.lower_red),
            upper_red: med(|m| m.upper_red),
            chin: med(|m| m.chin),
        })
    }

    /// What this frame adds to `(mouthRollLower, mouthRollUpper, mouthShrugLower)` against
    /// the subject's `rest` (see [`LIP_ROLL_GAIN`], [`CHIN_RAISE_GAIN`]). Negative when a
    /// lip shows more red than at rest; 0 for a lip without red at rest.
    pub fn drives(&self, rest: &LipMeasures) -> [f64; 3] {
        let lost = |now: f64, rest: f64| if rest > 1e-6 { 1.0 - now / rest } else { 0.0 };
        [
            LIP_ROLL_GAIN * lost(self.lower_red, rest.lower_red),
            LIP_ROLL_GAIN * lost(self.upper_red, rest.upper_red),
            CHIN_RAISE_GAIN * (self.chin - rest.chin),
        ]
    }
}

/// The rig's `mouthRollLower`, `mouthRollUpper` and `mouthShrugLower` and the subject's
/// rest; applied per solved frame by the expression sink.
#[derive(Debug, Clone, Default)]
pub(crate) struct Lips {
    /// The three shapes' indices in the rig (`None` where the rig lacks one).
    idx: [Option<usize>; 3],
    /// The subject's rest (the clip's median, or the running median of live input).
    pub(crate) rest: Option<LipMeasures>,
    /// Whether `rest` is the whole clip's (otherwise it is updated from `seen`).
    pub(crate) rest_from_clip: bool,
    seen: Vec<LipMeasures>,
    scratch: Vec<LipMeasures>,
}

impl Lips {
    pub(crate) fn new(idx: [Option<usize>; 3]) -> Self {
        Lips { idx, ..Lips::default() }
    }

    /// The rest from every frame of a clip.
    pub(crate) fn rest_from<'f>(&mut self, frames: impl Iterator<Item = &'f Landmarks68>) {
        let mut m: Vec<LipMeasures> = frames.filter_map(lip_measures).collect();
        self.rest = LipMeasures::median(&mut m);
        self.rest_from_clip = self.rest.is_some();
    }

    /// Adds the lips' drives to the roll shapes of `weights` (clamped to [0, 1]) and
    /// returns the chin's, to be added to `mouthShrugLower` after the rolled lip's share
    /// ([`crate::expression::rolled_lip_shrug`]) by [`Lips::add_chin`].
    pub(crate) fn add_rolls(&mut self, l: Option<&Landmarks68>, weights: &mut [f64]) -> f64 {
        if self.idx.iter().all(Option::is_none) {
            return 0.0;
        }
        let Some(m) = l.and_then(lip_measures) else { return 0.0 };
        if !self.rest_from_clip && self.seen.len() < RUNNING_REST_SEEN_MAX {
            self.seen.push(m);
            if running_rest_due(self.seen.len(), self.rest.is_some()) {
                self.scratch.clone_from(&self.seen);
                self.rest = LipMeasures::median(&mut self.scratch);
            }
        }
        let Some(rest) = self.rest else { return 0.0 };
        let d = m.drives(&rest);
        for (slot, add) in self.idx[..2].iter().zip(d) {
            if let Some(w) = slot.and_then(|k| weights.get_mut(k)) {
                *w = unit(*w + add);
            }
        }
        d[2]
    }

    /// Adds the chin's drive (from [`Lips::add_rolls`]) to `mouthShrugLower`.
    pub(crate) fn add_chin(&self, chin: f64, weights: &mut [f64]) {
        if let Some(w) = self.idx[2].and_then(|k| weights.get_mut(k)) {
            *w = unit(*w + chin);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frontal face: eyes level 100 px apart, lips with red bands `lower` and `upper` px
    /// thick at the middle, chin `chin` px below the lower lip.
    fn face(lower: f64, upper: f64, chin: f64) -> Landmarks68 {
        let mut l = Landmarks68::from_fn(|_| (200.0, 250.0));
        l.points[36] = nalgebra::Point2::new(150.0, 200.0);
        l.points[45] = nalgebra::Point2::new(250.0, 200.0);
        // mouth corners, inner lip along y = 300
        let xs = [170.0, 180.0, 190.0, 200.0, 210.0, 220.0, 230.0];
        let bump = |x: f64| 1.0 - ((x - 200.0) / 30.0).powi(2);
        for (k, &x) in xs.iter().enumerate() {
            l.points[48 + k] = nalgebra::Point2::new(x, 300.0 - upper * bump(x));
        }
        for (k, &x) in xs.iter().rev().enumerate().skip(1).take(5) {
            l.points[55 + k - 1] = nalgebra::Point2::new(x, 300.0 + lower * bump(x));
        }
        for (k, i) in (60..=64).enumerate() {
            l.points[i] = nalgebra::Point2::new(170.0 + 15.0 * k as f64, 300.0);
        }
        for (k, i) in (65..=67).enumerate() {
            l.points[i] = nalgebra::Point2::new(215.0 - 15.0 * k as f64, 300.0);
        }
        l.points[8] = nalgebra::Point2::new(200.0, 300.0 + lower + chin);
        l
    }

    #[test]
    fn a_rolled_lip_shows_less_red_and_drives_its_roll() {
        let rest = lip_measures(&face(10.0, 8.0, 40.0)).unwrap();
        assert!(rest.lower_red > 0.0 && rest.upper_red > 0.0);
        assert!((rest.chin - 0.4).abs() < 1e-9, "{rest:?}");
        // the same face turned 30 degrees in the image and twice as far: the same measures
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let mut turned = face(10.0, 8.0, 40.0);
        for p in &mut turned.points {
            let (x, y) = (p.x - 200.0, p.y - 250.0);
            *p = nalgebra::Point2::new(100.0 + 0.5 * (c * x - s * y), 80.0 + 0.5 * (s * x + c * y));
        }
        let t = lip_measures(&turned).unwrap();
        assert!((t.lower_red - rest.lower_red).abs() < 1e-9 && (t.chin - rest.chin).abs() < 1e-9);
        // the lower lip half rolled in, the upper as at rest: +0.25 on mouthRollLower
        let d = lip_measures(&face(5.0, 8.0, 40.0)).unwrap().drives(&rest);
        assert!((d[0] - 0.5 * LIP_ROLL_GAIN).abs() < 0.05, "{d:?}");
        assert!(d[1].abs() < 1e-9);
        // the lower lip pushed 10 px (0.1 IOD) up from the chin
        let d = lip_measures(&face(10.0, 8.0, 50.0)).unwrap().drives(&rest);
        assert!((d[2] - 0.1 * CHIN_RAISE_GAIN).abs() < 1e-9, "{d:?}");
        // eyes on one point: no measure
        let mut bad = face(10.0, 8.0, 40.0);
        bad.points[45] = bad.points[36];
        assert!(lip_measures(&bad).is_none());
    }

    #[test]
    fn the_drives_land_on_the_rigs_shapes_against_the_running_rest() {
        let mut lips = Lips::new([Some(0), Some(1), Some(2)]);
        let mut w = [0.1, 0.1, 0.1];
        // live input: nothing added until the running rest exists
        for _ in 0..crate::expression::RUNNING_REST_EVERY - 1 {
            assert_eq!(lips.add_rolls(Some(&face(10.0, 8.0, 40.0)), &mut w), 0.0);
        }
        assert_eq!(w, [0.1, 0.1, 0.1]);
        lips.add_rolls(Some(&face(10.0, 8.0, 40.0)), &mut w);
        assert!(lips.rest.is_some());
        let chin = lips.add_rolls(Some(&face(2.0, 2.0, 50.0)), &mut w);
        assert!(w[0] > 0.4 && w[1] > 0.4, "{w:?}");
        lips.add_chin(chin, &mut w);
        assert!((w[2] - 0.2).abs() < 0.05, "{w:?}");
        // a clip's rest is fixed; a frame without landmarks changes nothing
        let frames = [face(10.0, 8.0, 40.0), face(12.0, 8.0, 40.0), face(8.0, 8.0, 40.0)];
        lips.rest_from(frames.iter());
        assert!(lips.rest_from_clip);
        let before = w;
        assert_eq!(lips.add_rolls(None, &mut w), 0.0);
        assert_eq!(w, before);
        // a rig without the shapes: nothing
        let mut none = Lips::new([None; 3]);
        assert_eq!(none.add_rolls(Some(&face(2.0, 2.0, 50.0)), &mut w), 0.0);
    }
}
