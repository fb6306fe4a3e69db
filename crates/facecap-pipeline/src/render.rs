//! A small software renderer for rigs: the rig posed with blendshape weights and a head
//! pose, as an RGB image (the report, the preview video, a live window), and the same
//! mesh drawn over a video frame through the camera.
//!
//! * **Shading**: smooth (Phong): area-weighted vertex normals of the posed mesh,
//!   interpolated per pixel, one directional light from the upper front plus a little
//!   specular; triangles facing away from the eye are culled, a z-buffer resolves the
//!   rest. Shading is deferred (a depth + triangle-id pass, then one shading pass per
//!   covered pixel), so a semi-transparent overlay blends only the front surface.
//! * **Colours**: per vertex, from the rig's landmark map in the neutral's frontal plane:
//!   lips (between the outer 48-59 and inner 60-67 lip contours), eye openings (36-41,
//!   42-47) and brows (near 17-21, 22-26) get their own tones; the rest is skin. Triangles
//!   whose centre lies inside an eye opening are drawn dark (the eye between the lids), so
//!   an open eye reads as open on meshes with no vertex inside the opening.
//! * **Mouth interior**: the polygon of the inner lip contour (60-67) is filled with a
//!   dark mouth colour *behind* every surface, so an open mouth shows a dark cavity
//!   wherever the mesh has a hole there (the built-in rig has one) instead of stretched
//!   or folded skin. The polygons of the eyes (36-41, 42-47) get a dark eye colour the
//!   same way, for meshes with holes for the eyes.
//!
//! Conventions: rigs are +Y up, +Z out of the face (glTF); poses are
//! [`ModelToCamera`] (camera x right, y down, z forward); image pixels have their
//! top-left centre at (0, 0).

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::MorphMesh;
use image::{Rgb, RgbImage};
use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};

use crate::error::{Error, Result};

/// Background of [`RigRenderer::render`].
pub const BACKGROUND: [u8; 3] = [236, 238, 242];
/// Skin albedo (linear 0..1).
const SKIN: [f32; 3] = [0.86, 0.70, 0.60];
/// Lip albedo.
const LIPS: [f32; 3] = [0.72, 0.36, 0.38];
/// Eye-opening albedo.
const EYES: [f32; 3] = [0.58, 0.46, 0.44];
/// Albedo of the triangles spanning an eye opening (the eye seen between the lids).
const EYE_OPENING: [f32; 3] = [0.30, 0.25, 0.25];
/// Tint of the mesh drawn over a video frame ([`View::Camera`]), mixed into the albedo
/// by [`OVERLAY_TINT_MIX`] so the overlay stands out from the skin under it.
const OVERLAY_TINT: [f32; 3] = [0.35, 0.65, 1.0];
/// Fraction of [`OVERLAY_TINT`] in the overlay's albedo.
const OVERLAY_TINT_MIX: f32 = 0.6;
/// Brow albedo.
const BROWS: [f32; 3] = [0.42, 0.30, 0.24];
/// Mouth cavity colour.
const MOUTH: [u8; 3] = [58, 18, 24];
/// Colour behind an eye opening (a mesh with holes for the eyes shows it there).
const EYE_CAVITY: [u8; 3] = [66, 54, 54];
/// Growth of an eye's landmark polygon for its cavity (about its centre).
const EYE_CAVITY_GROW: f64 = 1.4;
/// Ambient light fraction.
const AMBIENT: f32 = 0.28;
/// Specular strength (Blinn-Phong, exponent 16: four squarings).
const SPECULAR: f32 = 0.10;
/// Brow band half-width, as a fraction of the inter-ocular distance.
const BROW_BAND: f64 = 0.09;
/// Portrait fill: the neutral's radius covers this fraction of half the image.
const PORTRAIT_FILL: f64 = 0.92;

/// iBUG indices of the outer lip contour.
const OUTER_LIP: [usize; 12] = [48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59];
/// iBUG indices of the inner lip contour.
pub const INNER_LIP: [usize; 8] = [60, 61, 62, 63, 64, 65, 66, 67];

/// How a render looks at the mesh.
#[derive(Debug, Clone, Copy)]
pub enum View<'a> {
    /// The head alone, centred in a `size` x `size` image, rotated as the camera sees
    /// it (the pose's rotation; no pose: frontal), orthographic.
    Portrait {
        /// Image side in pixels.
        size: u32,
    },
    /// Through the video camera: the mesh posed by `pose`, projected with `camera`
    /// into the frame it is drawn on.
    Camera {
        /// The video camera.
        camera: &'a Intrinsics,
        /// Model to camera.
        pose: &'a ModelToCamera,
    },
}

/// Scratch buffers of one rendering thread (reused between frames).
#[derive(Debug, Default)]
pub struct RenderWorkspace {
    posed: Vec<Point3<f32>>,
    view: Vec<Vector3<f32>>,
    screen: Vec<[f32; 3]>,
    normals: Vec<Vector3<f32>>,
    depth: Vec<f32>,
    id: Vec<u32>,
    setup: Vec<TriSetup>,
    lit: Vec<[f32; 3]>,
    /// Per vertex: the light factor on the albedo and the specular term.
    shade: Vec<[f32; 2]>,
}

/// Screen-space set-up of one triangle (see [`RigRenderer::draw`]).
#[derive(Debug, Clone, Copy, Default)]
struct TriSetup {
    ox: f32,
    oy: f32,
    a0: f32,
    b0: f32,
    a1: f32,
    b1: f32,
    /// The Gouraud colour as a plane over the image: per channel (0..255) the value at
    /// pixel (0, 0) and its slopes along x and y.
    col: [[f32; 3]; 3],
}

/// A rig ready to render (module docs). `Send + Sync`: share one between threads, one
/// [`RenderWorkspace`] per thread.
#[derive(Debug, Clone)]
pub struct RigRenderer {
    mesh: MorphMesh,
    colours: Vec<[f32; 3]>,
    /// `colours` mixed with the overlay tint ([`View::Camera`]).
    tinted: Vec<[f32; 3]>,
    /// Triangles across an eye opening (centroid inside the eye's six landmarks in the
    /// neutral's frontal plane): drawn with [`EYE_OPENING`], whatever their corners'
    /// colours (a mesh with a hole for the eye has no vertex inside the opening to carry it).
    eye_triangles: Vec<bool>,
    mouth: Option<[u32; 8]>,
    /// The six landmark vertices of each eye, for the eye cavity.
    eyes: Vec<[u32; 6]>,
    centre: Vector3<f64>,
    radius: f64,
}

/// The flip from camera axes (y down, z forward) to view axes (y up, z toward the eye).
fn flip() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

fn inside(poly: &[(f64, f64)], x: f64, y: f64) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a.1 > y) != (b.1 > y) && x < (b.0 - a.0) * (y - a.1) / (b.1 - a.1) + a.0 {
            c = !c;
        }
    }
    c
}

fn segment_distance(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((p.0 - a.0 - t * dx).powi(2) + (p.1 - a.1 - t * dy).powi(2)).sqrt()
}

impl RigRenderer {
    /// Prepares `mesh` (colours from `map` when given; without a map the rig is all
    /// skin and has no mouth cavity).
    ///
    /// # Errors
    /// An invalid mesh, a map naming vertices it does not have, or a mesh without
    /// vertices or triangles.
    pub fn new(mesh: &MorphMesh, map: Option<&LandmarkMap>) -> Result<Self> {
        mesh.validate()?;
        let n = mesh.base.num_vertices();
        if n == 0 || mesh.base.triangles.is_empty() {
            return Err(Error::invalid("rig mesh", "no triangles", "a triangle mesh"));
        }
        if let Some(m) = map {
            m.validate(n)?;
        }
        let pos: Vec<Vector3<f64>> = mesh.base.positions.iter().map(|p| p.coords.cast::<f64>()).collect();
        let centre = pos.iter().fold(Vector3::zeros(), |a, p| a + p) / n as f64;
        let radius = pos
            .iter()
            .map(|p| (p - centre).xy().norm())
            .fold(0.0f64, f64::max)
            .max(1e-9);
        let mut colours = vec![SKIN; n];
        let mut eye_triangles = vec![false; mesh.base.triangles.len()];
        let mut mouth = None;
        let mut eyes = Vec::new();
        if let Some(m) = map {
            let lm = |ids: &[usize]| -> Option<Vec<Vector3<f64>>> {
                ids.iter().map(|&i| m.vertices[i].map(|v| pos[v as usize])).collect()
            };
            let xy = |v: &[Vector3<f64>]| v.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>();
            let io = match (m.vertices[36], m.vertices[45]) {
                (Some(a), Some(b)) => (pos[a as usize] - pos[b as usize]).norm(),
                _ => radius / 2.0,
            };
            let front_of = |v: &[Vector3<f64>]| v.iter().map(|p| p.z).fold(f64::INFINITY, f64::min) - 0.3 * io;
            let mut paint = |poly: &[Vector3<f64>], exclude: Option<&[Vector3<f64>]>, colour: [f32; 3]| {
                let (p2, zmin) = (xy(poly), front_of(poly));
                let ex = exclude.map(xy);
                for (c, p) in colours.iter_mut().zip(&pos) {
                    if p.z >= zmin && inside(&p2, p.x, p.y) && !ex.as_ref().is_some_and(|e| inside(e, p.x, p.y)) {
                        *c = colour;
                    }
                }
            };
            if let (Some(outer), inner) = (lm(&OUTER_LIP), lm(&INNER_LIP)) {
                paint(&outer, inner.as_deref(), LIPS);
            }
            for eye in facecap_core::landmarks::EYES {
                if let Some(e) = lm(&eye) {
                    paint(&e, None, EYES);
                    let (p2, zmin) = (xy(&e), front_of(&e));
                    for (flag, t) in eye_triangles.iter_mut().zip(&mesh.base.triangles) {
                        let c = t.iter().fold(Vector3::zeros(), |a, &i| a + pos[i as usize]) / 3.0;
                        if c.z >= zmin && inside(&p2, c.x, c.y) {
                            *flag = true;
                        }
                    }
                }
            }
            for brow in [17..22usize, 22..27] {
                let ids: Vec<usize> = brow.collect();
                if let Some(b) = lm(&ids) {
                    let line = xy(&b);
                    let zmin = front_of(&b);
                    for (c, p) in colours.iter_mut().zip(&pos) {
                        let d = line
                            .windows(2)
                            .map(|s| segment_distance((p.x, p.y), s[0], s[1]))
                            .fold(f64::INFINITY, f64::min);
                        if p.z >= zmin && d < BROW_BAND * io {
                            *c = BROWS;
                        }
                    }
                }
            }
            let ids: Option<Vec<u32>> = INNER_LIP.iter().map(|&i| m.vertices[i]).collect();
            mouth = ids.and_then(|v| <[u32; 8]>::try_from(v).ok());
            for eye in facecap_core::landmarks::EYES {
                let ids: Option<Vec<u32>> = eye.iter().map(|&i| m.vertices[i]).collect();
                if let Some(e) = ids.and_then(|v| <[u32; 6]>::try_from(v).ok()) {
                    eyes.push(e);
                }
            }
        }
        let tinted = colours
            .iter()
            .map(|c| [0, 1, 2].map(|ch| c[ch] + OVERLAY_TINT_MIX * (OVERLAY_TINT[ch] - c[ch])))
            .collect();
        Ok(RigRenderer {
            mesh: mesh.clone(),
            colours,
            tinted,
            eye_triangles,
            mouth,
            eyes,
            centre,
            radius,
        })
    }

    /// The rig.
    pub fn mesh(&self) -> &MorphMesh {
        &self.mesh
    }

    /// Number of blendshapes (the length of the weights).
    pub fn num_shapes(&self) -> usize {
        self.mesh.targets.len()
    }

    /// Renders the rig posed with `weights`, rotated by `pose` as the camera sees the
    /// head (frontal when `None`), into a new `size` x `size` image.
    ///
    /// # Errors
    /// A weight count that is not the rig's, or a size of 0 or above 8192.
    pub fn render(&self, weights: &[f64], pose: Option<&ModelToCamera>, size: u32) -> Result<RgbImage> {
        if size == 0 || size > 8192 {
            return Err(Error::invalid("render size", size, "1..=8192 pixels"));
        }
        let mut img = RgbImage::from_pixel(size, size, Rgb(BACKGROUND));
        let mut ws = RenderWorkspace::default();
        self.draw(&mut img, weights, pose, View::Portrait { size }, 1.0, &mut ws)?;
        Ok(img)
    }

    /// Draws the posed rig into `img` as `view` sees it, blended with weight `alpha`
    /// (1 = opaque). With [`View::Portrait`] `pose` only rotates the head.
    ///
    /// # Errors
    /// A weight count that is not the rig's; `alpha` outside `[0, 1]`.
    pub fn draw(
        &self,
        img: &mut RgbImage,
        weights: &[f64],
        pose: Option<&ModelToCamera>,
        view: View<'_>,
        alpha: f32,
        ws: &mut RenderWorkspace,
    ) -> Result<()> {
        if !(0.0..=1.0).contains(&alpha) {
            return Err(Error::invalid("alpha", alpha, "0..=1"));
        }
        self.mesh.pose_into(weights, &mut ws.posed)?;
        let (w, h) = (img.width(), img.height());
        let n = ws.posed.len();
        ws.view.clear();
        ws.screen.clear();
        // View space: x right, y up, z toward the eye; screen: pixels and a depth that
        // grows toward the eye.
        match view {
            View::Portrait { size } => {
                let r = portrait_rotation(pose).into_inner();
                let s = PORTRAIT_FILL * 0.5 * f64::from(size) / self.radius;
                let half = f64::from(size) / 2.0 - 0.5;
                for p in &ws.posed {
                    let q = r * (p.coords.cast::<f64>() - self.centre);
                    ws.view.push(q.cast());
                    ws.screen
                        .push([(half + s * q.x) as f32, (half - s * q.y) as f32, q.z as f32]);
                }
            }
            View::Camera { camera, pose } => {
                for p in &ws.posed {
                    let c = pose.transform(&p.cast::<f64>());
                    let q = Vector3::new(c.x, -c.y, -c.z);
                    ws.view.push(q.cast());
                    let s = camera.project(&c).unwrap_or(Point2::new(f64::NAN, f64::NAN));
                    ws.screen.push([s.x as f32, s.y as f32, q.z as f32]);
                }
            }
        }
        let is_ortho = matches!(view, View::Portrait { .. });
        // Smooth normals of the posed mesh, in view space.
        ws.normals.clear();
        ws.normals.resize(n, Vector3::zeros());
        for t in &self.mesh.base.triangles {
            let [a, b, c] = t.map(|i| i as usize);
            let nrm = (ws.view[b] - ws.view[a]).cross(&(ws.view[c] - ws.view[a]));
            for i in [a, b, c] {
                ws.normals[i] += nrm;
            }
        }
        for v in &mut ws.normals {
            let l = v.norm();
            if l > 0.0 {
                *v /= l;
            }
        }
        let pixels = (w as usize) * (h as usize);
        ws.depth.clear();
        ws.depth.resize(pixels, f32::NEG_INFINITY);
        ws.id.clear();
        ws.id.resize(pixels, u32::MAX);
        ws.setup.clear();
        ws.setup.resize(self.mesh.base.triangles.len(), TriSetup::default());
        // Mouth and eye cavities: behind every surface.
        // (an eye's polygon grown about its centre: a rig's eye landmarks may sit inside
        // the lid edge, and whatever the cavity overfills is drawn over by the skin)
        let cavities = self.mouth.iter().map(|ids| (&ids[..], MOUTH, 1.0));
        for (ids, colour, grow) in cavities.chain(self.eyes.iter().map(|ids| (&ids[..], EYE_CAVITY, EYE_CAVITY_GROW))) {
            let mut poly: Vec<(f64, f64)> = ids
                .iter()
                .map(|&v| {
                    let s = ws.screen[v as usize];
                    (f64::from(s[0]), f64::from(s[1]))
                })
                .collect();
            let k = poly.len() as f64;
            let (cx, cy) = poly.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 / k, a.1 + p.1 / k));
            for p in &mut poly {
                *p = (cx + grow * (p.0 - cx), cy + grow * (p.1 - cy));
            }
            if poly.iter().all(|p| p.0.is_finite() && p.1.is_finite()) {
                fill_polygon(img, &poly, colour, alpha);
            }
        }
        // Lighting per vertex (Gouraud: the smooth vertex normals lit once, the colours
        // interpolated per pixel; on the rigs' small triangles it looks like per-pixel
        // lighting at a fraction of the cost).
        let light = Vector3::new(0.35f32, 0.45, 1.0).normalize();
        let ortho_eye = Vector3::new(0.0f32, 0.0, 1.0);
        let ortho_half = (light + ortho_eye).normalize();
        let colours = if is_ortho { &self.colours } else { &self.tinted };
        ws.shade.clear();
        ws.shade.extend(ws.normals.iter().zip(&ws.view).map(|(n, v)| {
            let (eye, half) = if is_ortho {
                (ortho_eye, ortho_half)
            } else {
                let e = (-v).try_normalize(1e-12).unwrap_or(ortho_eye);
                (e, (light + e).normalize())
            };
            let nrm = if n.dot(&eye) < 0.0 { -n } else { *n };
            let diffuse = nrm.dot(&light).max(0.0);
            let mut spec = nrm.dot(&half).max(0.0);
            for _ in 0..4 {
                spec *= spec;
            }
            spec *= SPECULAR;
            [AMBIENT + (1.0 - AMBIENT) * diffuse, spec]
        }));
        let lit_with = |albedo: &[f32; 3], [shade, spec]: [f32; 2]| albedo.map(|c| (c * shade + spec).min(1.0) * 255.0);
        ws.lit.clear();
        ws.lit
            .extend(colours.iter().zip(&ws.shade).map(|(albedo, &sh)| lit_with(albedo, sh)));
        let eye_albedo = if is_ortho {
            EYE_OPENING
        } else {
            [0, 1, 2].map(|ch| EYE_OPENING[ch] + OVERLAY_TINT_MIX * (OVERLAY_TINT[ch] - EYE_OPENING[ch]))
        };
        // Pass 1: depth and triangle id. Per triangle, the barycentric coordinates are
        // planes in screen space relative to its first vertex (w0 = 1 + a0 dx + b0 dy,
        // w1 = a1 dx + b1 dy), and each row visits only the span where all three can be
        // inside (the exact test is still made per pixel).
        const EPS: f32 = -1e-4;
        // bounding box of the rows and columns pass 1 visited (pass 2 looks only there)
        let mut covered = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for (k, t) in self.mesh.base.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| i as usize);
            let fnrm = (ws.view[b] - ws.view[a]).cross(&(ws.view[c] - ws.view[a]));
            let to_eye = if is_ortho {
                Vector3::new(0.0, 0.0, 1.0)
            } else {
                -(ws.view[a] + ws.view[b] + ws.view[c]) / 3.0
            };
            if fnrm.dot(&to_eye) <= 0.0 {
                continue;
            }
            let (p0, p1, p2) = (ws.screen[a], ws.screen[b], ws.screen[c]);
            if !(p0.iter().chain(&p1).chain(&p2).all(|v| v.is_finite())) {
                continue;
            }
            let area = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0]);
            if area.abs() < 1e-9 {
                continue;
            }
            let minx = p0[0].min(p1[0]).min(p2[0]).floor().max(0.0) as i64;
            let maxx = p0[0].max(p1[0]).max(p2[0]).ceil().min(w as f32 - 1.0) as i64;
            let miny = p0[1].min(p1[1]).min(p2[1]).floor().max(0.0) as i64;
            let maxy = p0[1].max(p1[1]).max(p2[1]).ceil().min(h as f32 - 1.0) as i64;
            if minx > maxx || miny > maxy {
                continue;
            }
            let inv = 1.0 / area;
            let (a0, b0) = ((p1[1] - p2[1]) * inv, (p2[0] - p1[0]) * inv);
            let (a1, b1) = ((p2[1] - p0[1]) * inv, (p0[0] - p2[0]) * inv);
            // colour = la w0 + lb w1 + lc w2 with w2 = 1 - w0 - w1: a plane in x, y
            let (la, lb, lc) = if self.eye_triangles[k] {
                (
                    lit_with(&eye_albedo, ws.shade[a]),
                    lit_with(&eye_albedo, ws.shade[b]),
                    lit_with(&eye_albedo, ws.shade[c]),
                )
            } else {
                (ws.lit[a], ws.lit[b], ws.lit[c])
            };
            let col = [0, 1, 2].map(|ch| {
                let (da, db) = (la[ch] - lc[ch], lb[ch] - lc[ch]);
                let (gx, gy) = (da * a0 + db * a1, da * b0 + db * b1);
                [la[ch] - gx * p0[0] - gy * p0[1], gx, gy]
            });
            let su = TriSetup {
                ox: p0[0],
                oy: p0[1],
                a0,
                b0,
                a1,
                b1,
                col,
            };
            ws.setup[k] = su;
            let (z0, z1, z2) = (p0[2] - p2[2], p1[2] - p2[2], p2[2]);
            let a2 = -(su.a0 + su.a1);
            // reciprocals once per triangle (the span bounds below have a pixel of slack,
            // the exact test per pixel decides)
            let coef = [su.a0, su.a1, a2].map(|aa| (aa, if aa != 0.0 { 1.0 / aa } else { 0.0 }));
            for y in miny..=maxy {
                let dy = y as f32 - su.oy;
                let (c0, c1) = (1.0 + su.b0 * dy, su.b1 * dy);
                let c2 = 1.0 - c0 - c1;
                // the dx where each coordinate reaches EPS bounds the span
                let (mut lo, mut hi) = (minx as f32 - su.ox, maxx as f32 - su.ox);
                for (cc, (aa, inv_aa)) in [c0, c1, c2].into_iter().zip(coef) {
                    if aa > 0.0 {
                        lo = lo.max((EPS - cc) * inv_aa);
                    } else if aa < 0.0 {
                        hi = hi.min((EPS - cc) * inv_aa);
                    } else if cc < EPS {
                        hi = lo - 1.0;
                    }
                }
                if lo > hi {
                    continue;
                }
                // truncation and a pixel of slack each side (the test below decides)
                let x0 = (((lo + su.ox) as i64) - 1).max(minx);
                let x1 = (((hi + su.ox) as i64) + 2).min(maxx);
                let row = y as usize * w as usize;
                covered = (covered.0.min(x0), covered.1.max(x1), covered.2.min(y), covered.3.max(y));
                for x in x0..=x1 {
                    let dx = x as f32 - su.ox;
                    let w0 = c0 + su.a0 * dx;
                    let w1 = c1 + su.a1 * dx;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < EPS || w1 < EPS || w2 < EPS {
                        continue;
                    }
                    let z = z2 + w0 * z0 + w1 * z1;
                    let idx = row + x as usize;
                    if z > ws.depth[idx] {
                        ws.depth[idx] = z;
                        ws.id[idx] = k as u32;
                    }
                }
            }
        }
        // Pass 2: colour each covered pixel once, inside the box pass 1 visited.
        if covered.0 > covered.1 || covered.2 > covered.3 {
            return Ok(());
        }
        let stride = w as usize;
        let (cx0, cx1) = (covered.0 as usize, covered.1 as usize);
        let raw: &mut [u8] = img;
        for y in covered.2 as usize..=covered.3 as usize {
            let fy = y as f32;
            let ids = &ws.id[y * stride + cx0..=y * stride + cx1];
            let row = &mut raw[3 * (y * stride + cx0)..3 * (y * stride + cx1 + 1)];
            for (x, (&k, px)) in (cx0..).zip(ids.iter().zip(row.chunks_exact_mut(3))) {
                if k == u32::MAX {
                    continue;
                }
                let col = &ws.setup[k as usize].col;
                let fx = x as f32;
                for (p, c) in px.iter_mut().zip(col) {
                    let v = c[0] + c[1] * fx + c[2] * fy;
                    // +0.5 and the saturating cast round to nearest within 0..=255
                    *p = if alpha == 1.0 {
                        (v + 0.5) as u8
                    } else {
                        (alpha * v + (1.0 - alpha) * f32::from(*p) + 0.5) as u8
                    };
                }
            }
        }
        Ok(())
    }
}

/// Fills a simple polygon (pixel coordinates) with `colour` blended by `alpha`.
fn fill_polygon(img: &mut RgbImage, poly: &[(f64, f64)], colour: [u8; 3], alpha: f32) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let miny = poly.iter().map(|p| p.1).fold(f64::INFINITY, f64::min).floor().max(0.0) as i64;
    let maxy = poly
        .iter()
        .map(|p| p.1)
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil()
        .min(h as f64 - 1.0) as i64;
    let minx = poly.iter().map(|p| p.0).fold(f64::INFINITY, f64::min).floor().max(0.0) as i64;
    let maxx = poly
        .iter()
        .map(|p| p.0)
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil()
        .min(w as f64 - 1.0) as i64;
    for y in miny..=maxy {
        for x in minx..=maxx {
            if inside(poly, x as f64, y as f64) {
                let px = img.get_pixel_mut(x as u32, y as u32);
                for (p, &c) in px.0.iter_mut().zip(&colour) {
                    *p = (alpha * f32::from(c) + (1.0 - alpha) * f32::from(*p) + 0.5) as u8;
                }
            }
        }
    }
}

/// Scales `src` to `w` x `h` by bilinear sampling (pixel centres aligned), a cheap
/// resampling for moderate reductions such as a preview's.
pub fn scale_bilinear(src: &RgbImage, w: u32, h: u32) -> RgbImage {
    let (sw, sh) = (src.width(), src.height());
    let mut out = RgbImage::new(w, h);
    if sw == 0 || sh == 0 {
        return out;
    }
    let (fx, fy) = (sw as f32 / w.max(1) as f32, sh as f32 / h.max(1) as f32);
    let raw = src.as_raw();
    let at = |x: u32, y: u32, c: usize| f32::from(raw[(y as usize * sw as usize + x as usize) * 3 + c]);
    for (x, y, px) in out.enumerate_pixels_mut() {
        let sx = ((x as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
        let sy = ((y as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
        let (x0, y0) = (sx as u32, sy as u32);
        let (x1, y1) = ((x0 + 1).min(sw - 1), (y0 + 1).min(sh - 1));
        let (ax, ay) = (sx - x0 as f32, sy - y0 as f32);
        for c in 0..3 {
            let top = at(x0, y0, c) * (1.0 - ax) + at(x1, y0, c) * ax;
            let bottom = at(x0, y1, c) * (1.0 - ax) + at(x1, y1, c) * ax;
            px.0[c] = (top * (1.0 - ay) + bottom * ay + 0.5) as u8;
        }
    }
    out
}

/// Draws filled discs of `radius` px with a one-pixel dark outline at `points` (0-based
/// pixel coordinates; non-finite points are skipped).
pub fn draw_landmarks(img: &mut RgbImage, points: &[Point2<f64>], radius: f64, colour: [u8; 3]) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let outer = radius + 1.0;
    for p in points {
        if !(p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        let r = outer.ceil() as i64;
        let (cx, cy) = (p.x.round() as i64, p.y.round() as i64);
        for y in (cy - r).max(0)..=(cy + r).min(h - 1) {
            for x in (cx - r).max(0)..=(cx + r).min(w - 1) {
                let d = ((x as f64 - p.x).powi(2) + (y as f64 - p.y).powi(2)).sqrt();
                if d <= radius {
                    img.put_pixel(x as u32, y as u32, Rgb(colour));
                } else if d <= outer {
                    img.put_pixel(x as u32, y as u32, Rgb([20, 20, 20]));
                }
            }
        }
    }
}

/// Draws `text` with the 8x8 public-domain bitmap font scaled by `scale`, top-left
/// corner at (`x`, `y`); characters outside the font are drawn as `?`.
pub fn draw_text(img: &mut RgbImage, text: &str, x: i64, y: i64, scale: u32, colour: [u8; 3]) {
    use font8x8::UnicodeFonts;
    let s = i64::from(scale.max(1));
    let (w, h) = (img.width() as i64, img.height() as i64);
    for (k, ch) in text.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS
            .get(ch)
            .or_else(|| font8x8::BASIC_FONTS.get('?'))
            .unwrap_or([0; 8]);
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits & (1 << col) == 0 {
                    continue;
                }
                for dy in 0..s {
                    for dx in 0..s {
                        let (px, py) = (x + (k as i64 * 8 + col) * s + dx, y + row as i64 * s + dy);
                        if px >= 0 && py >= 0 && px < w && py < h {
                            img.put_pixel(px as u32, py as u32, Rgb(colour));
                        }
                    }
                }
            }
        }
    }
}

/// Characters of a shape name shown by [`draw_weight_bars`].
const LABEL_CHARS: usize = 17;

/// Row height of [`draw_weight_bars`], pixels.
pub const BAR_ROW: u32 = 15;

/// Draws a horizontal bar chart of `weights` (clamped to `[0, 1]` for drawing; the
/// number printed is the value) for the shapes `shown` (indices into `names`), into the
/// `width` x `height` box at (`x0`, `y0`) of `img`. Rows that do not fit are left out.
pub fn draw_weight_bars(
    img: &mut RgbImage,
    (x0, y0, width, height): (u32, u32, u32, u32),
    names: &[String],
    weights: &[f64],
    shown: &[usize],
) {
    let label_w = 8 * LABEL_CHARS as u32;
    let bar_w = width.saturating_sub(label_w + 8 * 5 + 8);
    let rows = (height / BAR_ROW) as usize;
    for (r, &k) in shown.iter().take(rows).enumerate() {
        let (Some(name), Some(&v)) = (names.get(k), weights.get(k)) else {
            continue;
        };
        let y = y0 + r as u32 * BAR_ROW;
        let label: String = name.chars().take(LABEL_CHARS).collect();
        draw_text(img, &label, i64::from(x0), i64::from(y + 3), 1, [40, 40, 40]);
        let bx = x0 + label_w + 4;
        for yy in y + 2..y + BAR_ROW - 2 {
            for xx in bx..bx + bar_w {
                if xx < img.width() && yy < img.height() {
                    img.put_pixel(xx, yy, Rgb([215, 218, 224]));
                }
            }
        }
        let fill = if v.is_finite() {
            (v.clamp(0.0, 1.0) * f64::from(bar_w)).round() as u32
        } else {
            0
        };
        for yy in y + 2..y + BAR_ROW - 2 {
            for xx in bx..bx + fill {
                if xx < img.width() && yy < img.height() {
                    img.put_pixel(xx, yy, Rgb([52, 120, 200]));
                }
            }
        }
        let num = if v.is_finite() { format!("{v:.2}") } else { "-".into() };
        draw_text(img, &num, i64::from(bx + bar_w + 4), i64::from(y + 3), 1, [40, 40, 40]);
    }
}

/// The [`Rotation3`] a portrait render applies for `pose` (camera view of the head).
pub fn portrait_rotation(pose: Option<&ModelToCamera>) -> Rotation3<f64> {
    match pose {
        Some(p) => Rotation3::from_matrix_unchecked(flip() * p.0.rotation.to_rotation_matrix().into_inner()),
        None => Rotation3::identity(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use facecap_core::mesh::{Mesh, MorphTarget};

    /// A unit quad (two triangles, +Z normal) with one target lifting a corner.
    fn quad() -> MorphMesh {
        let positions = vec![
            Point3::new(-1.0f32, -1.0, 0.0),
            Point3::new(1.0, -1.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(-1.0, 1.0, 0.0),
        ];
        MorphMesh {
            base: Mesh {
                positions,
                triangles: vec![[0, 1, 2], [0, 2, 3]],
                normals: Vec::new(),
                uvs: Vec::new(),
            },
            targets: vec![MorphTarget {
                name: "lift".into(),
                deltas: vec![
                    Vector3::zeros(),
                    Vector3::zeros(),
                    Vector3::new(0.0, 0.0, 1.0),
                    Vector3::zeros(),
                ],
            }],
        }
    }

    #[test]
    fn portrait_covers_the_centre_and_culls_the_back() {
        let r = RigRenderer::new(&quad(), None).unwrap();
        let img = r.render(&[0.0], None, 64).unwrap();
        assert_ne!(img.get_pixel(32, 32).0, BACKGROUND);
        assert_eq!(img.get_pixel(1, 1).0, BACKGROUND);
        // Turned half a turn about y, the quad faces away: nothing drawn.
        let back = ModelToCamera(nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, 10.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 0.0),
        ));
        // Frontal in camera terms is F (y, z flipped); identity rotation faces away.
        let img = r.render(&[0.0], Some(&back), 64).unwrap();
        assert!(img.pixels().all(|p| p.0 == BACKGROUND));
        assert!(r.render(&[0.0, 1.0], None, 64).is_err());
        assert!(r.render(&[0.0], None, 0).is_err());
    }

    #[test]
    fn camera_view_lands_where_the_camera_projects() {
        let r = RigRenderer::new(&quad(), None).unwrap();
        let k = Intrinsics::new(100.0, 100.0, 50.0, 40.0).unwrap();
        // Frontal: model +Z toward the camera (rotation diag(1, -1, -1)), 10 units away.
        let pose = ModelToCamera(nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, 10.0),
            nalgebra::UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(flip())),
        ));
        let mut img = RgbImage::from_pixel(100, 80, Rgb([0, 0, 0]));
        let mut ws = RenderWorkspace::default();
        let view = View::Camera {
            camera: &k,
            pose: &pose,
        };
        r.draw(&mut img, &[0.0], Some(&pose), view, 1.0, &mut ws).unwrap();
        // The quad spans +-1 unit at 10 units: +-10 px around the principal point.
        assert_ne!(img.get_pixel(50, 40).0, [0, 0, 0]);
        assert_ne!(img.get_pixel(58, 33).0, [0, 0, 0]);
        assert_eq!(img.get_pixel(63, 40).0, [0, 0, 0]);
        assert_eq!(img.get_pixel(50, 53).0, [0, 0, 0]);
        // Half transparent: between the background and the opaque colour.
        let opaque = img.get_pixel(50, 40).0;
        let mut half = RgbImage::from_pixel(100, 80, Rgb([0, 0, 0]));
        r.draw(&mut half, &[0.0], Some(&pose), view, 0.5, &mut ws).unwrap();
        let p = half.get_pixel(50, 40).0;
        assert!((i32::from(p[0]) - i32::from(opaque[0]) / 2).abs() <= 1);
    }

    #[test]
    fn smooth_shading_varies_across_a_curved_surface() {
        // A lifted corner bends the quad: normals interpolate, so shades vary smoothly
        // inside each triangle instead of one flat value per triangle.
        let r = RigRenderer::new(&quad(), None).unwrap();
        let img = r.render(&[1.0], None, 64).unwrap();
        let row: Vec<[u8; 3]> = (10..54).map(|x| img.get_pixel(x, 40).0).collect();
        let distinct: std::collections::HashSet<_> = row.iter().collect();
        assert!(distinct.len() > 4, "{distinct:?}");
    }

    #[test]
    fn bilinear_scaling_keeps_flat_colours_and_size() {
        let src = RgbImage::from_pixel(512, 300, Rgb([10, 200, 77]));
        let out = scale_bilinear(&src, 360, 211);
        assert_eq!((out.width(), out.height()), (360, 211));
        assert!(out.pixels().all(|p| p.0 == [10, 200, 77]));
        // A left-to-right ramp stays a ramp.
        let ramp = RgbImage::from_fn(256, 4, |x, _| Rgb([x as u8, 0, 0]));
        let half = scale_bilinear(&ramp, 128, 2);
        assert!(half.get_pixel(0, 0).0[0] < half.get_pixel(127, 1).0[0]);
    }

    #[test]
    fn text_and_bars_draw_inside_the_image() {
        let mut img = RgbImage::from_pixel(300, 40, Rgb([255, 255, 255]));
        draw_weight_bars(
            &mut img,
            (0, 0, 300, 40),
            &["jawOpen".into(), "x".into()],
            &[0.5, 2.0],
            &[0, 1],
        );
        let blue = img.pixels().filter(|p| p.0 == [52, 120, 200]).count();
        assert!(blue > 0);
        draw_text(&mut img, "é?", -4, -4, 3, [0, 0, 0]);
        draw_landmarks(
            &mut img,
            &[Point2::new(0.0, 0.0), Point2::new(f64::NAN, 1.0)],
            3.0,
            [0, 255, 0],
        );
    }
}
