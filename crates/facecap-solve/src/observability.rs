//! What the 68 landmarks can see of a rig's shapes, and the default priors that follow.
//!
//! For every shape the landmark displacement field `d_i` (68 x 3, model units) is measured in
//! the frontal image plane (x, y; depth is seen only through head rotation):
//!
//! * `motion`: `||d_i||` over the 68 points, in inter-ocular distances (IOD, the rig's own
//!   outer eye corner distance 36-45), so rigs in cm and mm compare;
//! * `independence`: `min_x ||d_i - D x|| / ||d_i||` over non-negative weights `x` of the other
//!   shapes' fields `D` (weights are never negative): 0 means another combination of shapes moves the landmarks the same way
//!   (the landmarks cannot tell them apart), 1 means no other shape does anything like it;
//! * `closest`: the other shape with the largest `|cos|` between the fields.
//!
//! [`default_priors`] turns this into the solver's [`ShapePriors`]: shapes the landmarks
//! cannot see are held at 0 (gaze `eyeLook*`: the eyelid points move with the eyeball in
//! rigs, but the 68 points carry no iris, so eyelid motion is blink or squint, never gaze;
//! `cheekPuff`, `jawForward` and `tongueOut` move mostly along the viewing direction or
//! inside the mouth), every free shape gets a ridge that grows as its independence falls,
//! and ARKit's antagonist pairs (`eyeWide` vs `eyeBlink`/`eyeSquint`, `browDown` vs
//! `browInnerUp`/`browOuterUp`, `mouthSmile` vs `mouthFrown`, `mouthPucker` vs
//! `mouthStretch`/`mouthSmile`, `mouthFunnel` vs `mouthStretch`, `mouthLeft` vs
//! `mouthRight`, `jawLeft` vs `jawRight`, `mouthPress` vs `mouthFunnel`, `mouthRollUpper` vs
//! `mouthSmile`/`mouthUpperUp`) are exclusive; blinks, the fastest action, get a tenth of
//! the temporal weight. `docs/expressions.md` has the table
//! for the built-in rig and the ICT rig.

use facecap_core::landmarks::NUM_LANDMARKS;
use nalgebra::{DMatrix, DVector};

use crate::exact3d::ShapePriors;
use crate::rig::BlendshapeRig;

/// How well the 68 landmarks see one shape (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeVisibility {
    /// Shape name.
    pub name: String,
    /// Frontal landmark motion `||d_i||` in IODs of the rig.
    pub motion: f64,
    /// Largest single-landmark frontal motion in IODs.
    pub max_point: f64,
    /// Fraction of the motion no other shape can produce, `[0, 1]`.
    pub independence: f64,
    /// The most collinear other shape and the cosine with it.
    pub closest: Option<(String, f64)>,
    /// Why the default priors hold this shape at 0 (`None`: it is solved).
    pub fixed_because: Option<&'static str>,
}

/// Shape-name prefixes held at 0 with 68 landmarks, and why.
const UNSEEN: [(&str, &str); 4] = [
    (
        "eyeLook",
        "gaze: 68 points carry no iris; set from a gaze signal instead",
    ),
    (
        "cheekPuff",
        "moves along the viewing direction; the jaw contour is a silhouette",
    ),
    ("jawForward", "moves along the viewing direction"),
    ("tongue", "inside the mouth; no landmark"),
];

/// Ridge (px^2 at IOD 100 px) of a shape with independence 1; see [`default_priors`].
pub const BASE_RIDGE: f64 = 15.0;

/// Measured multipliers of the observability ridge, by ARKit shape (either side).
///
/// The ridge `BASE_RIDGE / independence^2` sets how readily a shape takes landmark motion
/// that its neighbours could also explain. On real video (face mesh front end, the five
/// shared clips against MediaPipe's blendshape scores) it let the lip shapes that share
/// their motion take each other's: `mouthRollUpper` and `mouthLowerDown` swung over 2.9x and
/// 2.5x MediaPipe's range, `mouthFunnel` 1.7x, `mouthFrown` fired (up to 1.0) where
/// MediaPipe's stayed under 0.02, while `mouthStretch` reached 0.6x. These multipliers bring
/// each one's range to 1.0-1.2x the reference's (std over the clip); mean r 0.792 -> 0.798
/// (built-in rig), 0.801 -> 0.806 (ICT), synthetic truth RMSE 0.081 -> 0.078
/// (docs/expressions.md, "Prior strength per lip shape"). `mouthPucker` x0.3 undoes the
/// rise of its ridge (31 -> 114) when the built-in `mouthLeft` / `mouthRight` came to narrow
/// the mouth as real ones do (docs/expressions.md, "The mouth's sideways slide"): its spread
/// 0.77x -> 0.93x of the reference's, mean r unchanged (0.8019 -> 0.8015, 0.8091 -> 0.8093).
pub const ARKIT_RIDGE_SCALE: [(&str, f64); 7] = [
    ("mouthPucker", 0.3),
    ("mouthRollUpper", 6.0),
    ("mouthLowerDown", 4.0),
    ("mouthFunnel", 3.0),
    ("mouthFrown", 3.0),
    ("mouthPress", 1.5),
    ("mouthStretch", 0.33),
];

/// Multiplier of the temporal weight on `eyeBlink*`: a blink closes and opens within
/// 3-6 frames at 30 fps, so the full temporal term (tuned against landmark jitter on the
/// slower mouth and brow shapes) would delay it and cut its peak.
pub const BLINK_TEMPORAL: f64 = 0.1;

/// Exclusive pairs by ARKit base name (sided names are paired side by side).
const EXCLUSIVE: [(&str, &str); 13] = [
    ("eyeWide", "eyeBlink"),
    ("eyeWide", "eyeSquint"),
    ("browDown", "browInnerUp"),
    ("browDown", "browOuterUp"),
    ("mouthSmile", "mouthFrown"),
    ("mouthPucker", "mouthStretch"),
    ("mouthPucker", "mouthSmile"),
    ("mouthFunnel", "mouthStretch"),
    ("mouthLeft", "mouthRight"),
    ("jawLeft", "jawRight"),
    ("mouthPress", "mouthFunnel"),
    // rolling the upper lip in hides its red; a smile and mouthUpperUp bare it. Solved
    // freely, ICT's mouthRollUpper took part of every smile (r -0.43 against MediaPipe on
    // liveportrait_d18); docs/expressions.md, "Rolling the upper lip".
    ("mouthRollUpper", "mouthSmile"),
    ("mouthRollUpper", "mouthUpperUp"),
];

/// Coupled shapes by ARKit base name, `(child, parent)`: the child acts only with its
/// parent ([`ShapePriors::coupled`]). ARKit's `mouthClose` is the lips closing over an open
/// jaw (its weight never exceeds `jawOpen`'s); solved alone it lifts the lower lip of a
/// closed mouth and takes the motion of `mouthRollLower`, `mouthPress` and
/// `mouthShrugLower`. `cheekSquint` is the cheek raiser's (FACS AU6) lift of the cheek,
/// which narrows the eye from below: it comes with `eyeSquint`. Solved alone on ICT's rig,
/// whose `eyeSquint` moves the 68 points by only 0.034 IOD, it took the squint's motion
/// (docs/expressions.md, "The cheek with the squint").
const COUPLED: [(&str, &str); 2] = [("mouthClose", "jawOpen"), ("cheekSquint", "eyeSquint")];

/// `(base, side)` of an ARKit-style name: `eyeBlinkLeft` / `eyeBlink_L` -> (`eyeBlink`, 'L');
/// `mouthLeft`, `jawRight` are directions, not sides.
pub fn split_side(name: &str) -> (&str, Option<char>) {
    for (suffix, side) in [("Left", 'L'), ("Right", 'R'), ("_L", 'L'), ("_R", 'R')] {
        if let Some(base) = name.strip_suffix(suffix) {
            if !base.is_empty() && base != "mouth" && base != "jaw" {
                return (base, Some(side));
            }
        }
    }
    (name, None)
}

fn rig_iod(rig: &BlendshapeRig) -> f64 {
    let d: f64 = (0..3)
        .map(|c| (rig.neutral[[36, c]] - rig.neutral[[45, c]]).powi(2))
        .sum::<f64>()
        .sqrt();
    if d.is_finite() && d > 0.0 && rig.mapped[36] && rig.mapped[45] {
        d
    } else {
        // no eye corners: the neutral's x extent stands in
        let xs = (0..NUM_LANDMARKS)
            .filter(|&l| rig.mapped[l])
            .map(|l| rig.neutral[[l, 0]]);
        let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
        ((hi - lo) * 0.5).max(1e-9)
    }
}

/// Why `name` is held at 0 with 68 landmarks (`None`: it is solved).
fn unseen_reason(name: &str, motion: f64) -> Option<&'static str> {
    UNSEEN
        .iter()
        .find(|(p, _)| name.starts_with(p))
        .map(|(_, why)| *why)
        .or(if motion < 1e-3 {
            Some("does not move the landmarks")
        } else {
            None
        })
}

/// ARKit's coupled shapes present in `rig` (see [`COUPLED`]), as `(child, parent)` index
/// pairs, matched by side as [`exclusive_pairs`]; a child keeps its first parent.
pub fn coupled_pairs(rig: &BlendshapeRig) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    for (c, p) in arkit_pairs(rig, &COUPLED) {
        if !out.iter().any(|&(c2, _)| c2 == c) {
            out.push((c, p));
        }
    }
    out
}

/// `rig` with each coupled child's deltas moved by its parent's too: the shapes the
/// solver's variables stand for ([`ShapePriors::coupled`]).
pub fn coupled_rig(rig: &BlendshapeRig, coupled: &[(usize, usize)]) -> BlendshapeRig {
    // the landmark fields only: the morph mesh is not needed (and large)
    let mut out = BlendshapeRig {
        names: rig.names.clone(),
        neutral: rig.neutral.clone(),
        deltas: rig.deltas.clone(),
        mapped: rig.mapped,
        mesh: None,
        contour: None,
    };
    for &(c, p) in coupled {
        let d = rig.deltas.index_axis(ndarray::Axis(0), p).to_owned();
        let mut child = out.deltas.index_axis_mut(ndarray::Axis(0), c);
        child += &d;
    }
    out
}

/// ARKit antagonist pairs present in `rig` (module docs), as index pairs.
pub fn exclusive_pairs(rig: &BlendshapeRig) -> Vec<(usize, usize)> {
    arkit_pairs(rig, &EXCLUSIVE)
}

/// The index pairs of `rig` for a table of ARKit base-name pairs: sided names pair side by
/// side, an unsided name pairs with either side.
fn arkit_pairs(rig: &BlendshapeRig, table: &[(&str, &str)]) -> Vec<(usize, usize)> {
    let index = |base: &str, side: Option<char>| {
        rig.names.iter().position(|n| {
            let (b, s) = split_side(n);
            b == base && (s == side || s.is_none() || side.is_none())
        })
    };
    let mut out = Vec::new();
    for &(a, b) in table {
        for side in [Some('L'), Some('R'), None] {
            if let (Some(i), Some(j)) = (index(a, side), index(b, side)) {
                if i != j && !out.contains(&(i, j)) {
                    out.push((i, j));
                }
            }
        }
    }
    out
}

/// The visibility table of `rig` (module docs), in rig order. A shape's independence is
/// measured against the shapes that can be active together with it: not those held at 0,
/// not its exclusive antagonists.
pub fn analyse(rig: &BlendshapeRig) -> Vec<ShapeVisibility> {
    let n = rig.num_shapes();
    let iod = rig_iod(rig);
    let rows = 2 * NUM_LANDMARKS;
    let mut fields = DMatrix::<f64>::zeros(rows, n);
    for k in 0..n {
        for l in 0..NUM_LANDMARKS {
            if rig.mapped[l] {
                fields[(2 * l, k)] = rig.deltas[[k, l, 0]] / iod;
                fields[(2 * l + 1, k)] = rig.deltas[[k, l, 1]] / iod;
            }
        }
    }
    let norms: Vec<f64> = (0..n).map(|k| fields.column(k).norm()).collect();
    let fixed: Vec<Option<&'static str>> = (0..n).map(|k| unseen_reason(&rig.names[k], norms[k])).collect();
    let exclusive = exclusive_pairs(rig);
    (0..n)
        .map(|k| {
            let name = rig.names[k].clone();
            let motion = norms[k];
            let max_point = (0..NUM_LANDMARKS)
                .map(|l| fields[(2 * l, k)].hypot(fields[(2 * l + 1, k)]))
                .fold(0.0, f64::max);
            let together: Vec<usize> = (0..n)
                .filter(|&j| {
                    j != k
                        && norms[j] > 0.0
                        && fixed[j].is_none()
                        && !exclusive.contains(&(j, k))
                        && !exclusive.contains(&(k, j))
                })
                .collect();
            let independence = if motion <= 0.0 {
                0.0
            } else if together.is_empty() {
                1.0
            } else {
                let a = DMatrix::from_fn(rows, together.len(), |r, c| fields[(r, together[c])]);
                let b = DVector::from_column_slice(fields.column(k).as_slice());
                // min ||A x - b|| over x >= 0: weights are never negative, so a shape
                // is explained only by what the others do with positive weights (a
                // lower lid rising in a squint does not explain an upper lid falling in
                // a blink by a negative amount of something else)
                let m = together.len();
                let h = a.transpose() * &a; // symmetric: either storage order
                let g = a.transpose() * &b;
                let mut x = vec![0.0; m];
                // exact (active set), a few dozen working-set changes; the coordinate descent
                // used before stopped at its pass cap on a fifth of these problems
                facecap_geom::qp::solve_box_qp(
                    h.as_slice(),
                    g.as_slice(),
                    &vec![0.0; m],
                    &vec![f64::INFINITY; m],
                    &mut x,
                    &facecap_geom::qp::QpOptions::default(),
                    &mut facecap_geom::qp::QpWorkspace::new(m),
                );
                let x = DVector::from_vec(x);
                ((&a * x - &b).norm() / motion).clamp(0.0, 1.0)
            };
            let closest = (0..n)
                .filter(|&j| j != k && norms[j] > 0.0 && motion > 0.0)
                .map(|j| (j, fields.column(k).dot(&fields.column(j)) / (motion * norms[j])))
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map(|(j, c)| (rig.names[j].clone(), c));
            ShapeVisibility {
                name,
                motion,
                max_point,
                independence,
                closest,
                fixed_because: fixed[k],
            }
        })
        .collect()
}

/// The default priors of `rig` for 68-landmark input (module docs): unseen shapes fixed,
/// ridge `BASE_RIDGE / max(independence, 0.1)^2` on the others (times [`ridge_scale`]
/// for the lip shapes [`ARKIT_RIDGE_SCALE`] lists), ARKit antagonists
/// exclusive, ARKit's coupled shapes coupled ([`with_arkit_coupling`]), the temporal weight
/// cut to [`BLINK_TEMPORAL`] on blinks, every landmark weighted 1.
pub fn default_priors(rig: &BlendshapeRig) -> ShapePriors {
    with_arkit_coupling(rig, uncoupled_priors(rig))
}

/// The [`ARKIT_RIDGE_SCALE`] multiplier of shape `name` (1 for a shape not listed).
pub fn ridge_scale(name: &str) -> f64 {
    let base = split_side(name).0;
    ARKIT_RIDGE_SCALE
        .iter()
        .find(|(n, _)| *n == base)
        .map_or(1.0, |&(_, m)| m)
}

/// [`default_priors`] without ARKit's coupled shapes.
pub fn uncoupled_priors(rig: &BlendshapeRig) -> ShapePriors {
    let table = analyse(rig);
    let n = rig.num_shapes();
    let mut p = ShapePriors::neutral(n);
    for (k, v) in table.iter().enumerate() {
        p.fixed[k] = v.fixed_because.is_some();
        p.ridge[k] = BASE_RIDGE / v.independence.max(0.1).powi(2) * ridge_scale(&v.name);
        if split_side(&v.name).0 == "eyeBlink" {
            p.temporal[k] = BLINK_TEMPORAL;
        }
    }
    p.exclusive = exclusive_pairs(rig);
    p
}

/// `priors` with ARKit's coupled shapes of `rig` ([`COUPLED`], [`ShapePriors::coupled`]):
/// each coupled child's ridge re-measured on what the landmarks see of its variable (the
/// child with its parent's motion); the parent keeps its own. Part of [`default_priors`]
/// since the subject's neutral mouth is fitted with the lips together: on the shared clips
/// mean r 0.627 -> 0.631 (built-in rig), 0.588 -> 0.591 (ICT) with dlib's 68 points, 0.707
/// -> 0.714 and 0.681 -> 0.685 with the face mesh, `mouthClose` 0.89 -> 0.94 / 0.98 -> 0.99
/// (mesh); before that change it lowered `jawOpen` and pinned `mouthShrugLower` on resting
/// pressed lips (docs/expressions.md, "Coupling mouthClose to jawOpen").
pub fn with_arkit_coupling(rig: &BlendshapeRig, mut priors: ShapePriors) -> ShapePriors {
    let coupled = coupled_pairs(rig);
    if !coupled.is_empty() {
        let with = analyse(&coupled_rig(rig, &coupled));
        for &(c, _) in &coupled {
            if c >= priors.ridge.len() || priors.fixed.get(c).copied().unwrap_or(true) {
                continue;
            }
            // a variable that moves no landmark is held at 0, like any unseen shape
            priors.fixed[c] = with[c].fixed_because.is_some();
            priors.ridge[c] = BASE_RIDGE / with[c].independence.max(0.1).powi(2);
        }
    }
    priors.coupled = coupled;
    priors
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_lip_ridge_scales_apply_to_either_side_and_either_naming() {
        assert_eq!(ridge_scale("mouthRollUpper"), 6.0);
        assert_eq!(ridge_scale("mouthStretchLeft"), 0.33);
        assert_eq!(ridge_scale("mouthStretch_R"), 0.33);
        assert_eq!(ridge_scale("mouthFrown_L"), 3.0);
        // directions, unlisted shapes and near-misses keep the observability ridge
        assert_eq!(ridge_scale("mouthLeft"), 1.0);
        assert_eq!(ridge_scale("jawOpen"), 1.0);
        assert_eq!(ridge_scale("mouthRollUpperX"), 1.0);
        for (name, m) in ARKIT_RIDGE_SCALE {
            assert!(m > 0.0 && m.is_finite(), "{name}");
        }
    }

    #[test]
    fn sides_are_split_but_directions_are_not() {
        assert_eq!(split_side("eyeBlinkLeft"), ("eyeBlink", Some('L')));
        assert_eq!(split_side("eyeBlink_R"), ("eyeBlink", Some('R')));
        assert_eq!(split_side("mouthLeft"), ("mouthLeft", None));
        assert_eq!(split_side("jawRight"), ("jawRight", None));
        assert_eq!(split_side("jawOpen"), ("jawOpen", None));
    }

    #[test]
    fn a_duplicated_shape_has_no_independence_and_a_unique_one_has_full() {
        let mut rig = BlendshapeRig::synthetic(3, 1);
        // shape 1 := shape 0 (indistinguishable); shape 2 moves one landmark no one else moves
        for l in 0..NUM_LANDMARKS {
            for c in 0..3 {
                rig.deltas[[1, l, c]] = rig.deltas[[0, l, c]];
                rig.deltas[[2, l, c]] = 0.0;
            }
        }
        for k in 0..2 {
            rig.deltas[[k, 5, 0]] = 0.0;
            rig.deltas[[k, 5, 1]] = 0.0;
        }
        rig.deltas[[2, 5, 0]] = 0.5;
        let t = analyse(&rig);
        assert!(t[0].independence < 1e-6, "{:?}", t[0]);
        assert!(t[1].independence < 1e-6, "{:?}", t[1]);
        assert!((t[2].independence - 1.0).abs() < 1e-9, "{:?}", t[2]);
        assert!((t[0].closest.as_ref().unwrap().1 - 1.0).abs() < 1e-9);
    }

    #[test]
    fn mouth_close_is_coupled_to_the_jaw_and_its_ridge_measured_with_it() {
        let mut rig = BlendshapeRig::synthetic(4, 5);
        rig.names = ["jawOpen", "mouthSmile_L", "mouthClose", "mouthPucker"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(coupled_pairs(&rig), vec![(2, 0)]);
        // mouthClose := -jawOpen: alone it undoes the jaw, so only with it is it seen as
        // nothing at all (the coupled variable moves no landmark)
        for l in 0..NUM_LANDMARKS {
            for c in 0..3 {
                rig.deltas[[2, l, c]] = -rig.deltas[[0, l, c]];
            }
        }
        let coupled = coupled_rig(&rig, &coupled_pairs(&rig));
        assert!(coupled
            .deltas
            .index_axis(ndarray::Axis(0), 2)
            .iter()
            .all(|v| v.abs() < 1e-12));
        let plain = uncoupled_priors(&rig);
        assert!(plain.coupled.is_empty());
        let p = with_arkit_coupling(&rig, plain.clone());
        assert_eq!(p.coupled, vec![(2, 0)]);
        assert_eq!(default_priors(&rig), p);
        // a variable the landmarks cannot see: held at 0, independence floored at 0.1
        assert!(!plain.fixed[2] && p.fixed[2]);
        assert!((p.ridge[2] - BASE_RIDGE / 0.01).abs() < 1e-9, "{}", p.ridge[2]);
        // the parent keeps the ridge of its own motion
        assert_eq!(p.ridge[0], plain.ridge[0]);
        p.validate(4).unwrap();
        let mut none = rig.clone();
        none.names[0] = "jawDrop".into();
        assert!(coupled_pairs(&none).is_empty());
    }

    #[test]
    fn arkit_priors_fix_gaze_and_pair_antagonists_per_side() {
        let mut rig = BlendshapeRig::synthetic(6, 2);
        rig.names = [
            "eyeBlink_L",
            "eyeWide_L",
            "eyeBlink_R",
            "eyeWide_R",
            "eyeLookDown_L",
            "jawOpen",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let p = default_priors(&rig);
        assert_eq!(p.fixed, vec![false, false, false, false, true, false]);
        assert!(p.exclusive.contains(&(1, 0)) && p.exclusive.contains(&(3, 2)));
        assert!(!p.exclusive.contains(&(1, 2)) && !p.exclusive.contains(&(3, 0)));
        assert_eq!(p.temporal, vec![BLINK_TEMPORAL, 1.0, BLINK_TEMPORAL, 1.0, 1.0, 1.0]);
        p.validate(6).unwrap();
        let mut short = p.clone();
        short.temporal.pop();
        assert!(short.validate(6).is_err());
        let mut negative = p;
        negative.temporal[0] = -1.0;
        assert!(negative.validate(6).is_err());
    }
}
