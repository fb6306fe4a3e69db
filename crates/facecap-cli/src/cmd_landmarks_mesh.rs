//! Images mode of `facecap landmarks --landmarks mesh`: MediaPipe's face detector and
//! 478-point face mesh run afresh on every image (FaceLandmarker's IMAGE mode, every face,
//! with facecap's small-face search), writing `landmarks.csv` in the 478-point layout
//! (the largest face), a `.pts` of the 478 points per face and `summary.csv` (module
//! docs of [`crate::cmd_landmarks`]).

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use facecap_io::csv::{mesh_columns, mesh_values, FrameCsvWriter, FrameRow, MESH_POINTS};
use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshTracker, MeshWorkspace, RgbView};
use image::{Rgb, RgbImage};
use nalgebra::Point2;

use crate::cmd_landmarks::{csv_field, Args};

/// What one image gave.
struct ImageMesh {
    /// Whether a face was found.
    found: bool,
    /// How many faces were found.
    faces: usize,
    /// Face presence of the found face (0 without one).
    presence: f64,
}

/// Runs the images mode with the mesh front end.
pub fn run_images(args: &Args) -> anyhow::Result<ExitCode> {
    let tracker = MeshTracker::new(
        MeshModels::from_cache().context("loading the face mesh models")?,
        MeshParams::default(),
    )?;
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let csv_path = args.out.join("landmarks.csv");
    let mut csv = FrameCsvWriter::create(&csv_path, &mesh_columns())?;
    let mut values = vec![0.0; 3 * MESH_POINTS];
    let mut summary = String::from("image,face,left,top,right,bottom,score,num_points,pts_file,error\n");
    let (mut faces, mut failed) = (0usize, 0usize);
    let stems = facecap_core::paths::unique_output_names(&args.inputs, "image");
    for (k, (input, stem)) in args.inputs.iter().zip(&stems).enumerate() {
        let name = csv_field(&input.display().to_string());
        let result = mesh_image(args, input, stem, &tracker, &mut ws, &mut mesh, &mut summary);
        let got = match result {
            Ok(g) => g,
            Err(e) => {
                let msg = crate::error_text(&e);
                eprintln!("error: {}: {msg}", input.display());
                let _ = writeln!(summary, "{name},-1,,,,,,0,,{}", csv_field(&msg));
                failed += 1;
                ImageMesh {
                    found: false,
                    faces: 0,
                    presence: 0.0,
                }
            }
        };
        faces += got.faces;
        mesh_values(got.found.then_some(mesh.points.as_slice()), &mut values)?;
        csv.write_row(&FrameRow {
            frame: k as u64,
            timestamp: 0.0,
            success: got.found,
            confidence: got.presence,
            values: &values,
        })?;
    }
    csv.finish()?;
    let summary_path = args.out.join("summary.csv");
    facecap_core::atomic::write_atomic(&summary_path, |w| std::io::Write::write_all(w, summary.as_bytes()))
        .with_context(|| format!("writing {}", summary_path.display()))?;
    eprintln!(
        "{} image(s), {faces} face(s), {failed} failed; wrote {} and {}",
        args.inputs.len(),
        csv_path.display(),
        summary_path.display()
    );
    Ok(if failed == args.inputs.len() || (args.strict && failed > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

/// One image: every face's `.pts`, `summary.csv` row and drawing; the largest face's
/// mesh into `mesh` (its `landmarks.csv` row).
fn mesh_image(
    args: &Args,
    input: &Path,
    stem: &str,
    tracker: &MeshTracker,
    ws: &mut MeshWorkspace,
    mesh: &mut FaceMesh,
    summary: &mut String,
) -> anyhow::Result<ImageMesh> {
    let mut rgb = facecap_io::image_io::load_rgb(input)?;
    // detection afresh, then landmarks in every detected region
    let faces = tracker
        .faces_in_image(&RgbView::from_image(&rgb)?, ws)
        .with_context(|| format!("running the face mesh on {}", input.display()))?;
    let name = csv_field(&input.display().to_string());
    let Some(first) = faces.first() else {
        let _ = writeln!(summary, "{name},-1,,,,,,0,,");
        eprintln!("{}: no face found", input.display());
        return Ok(ImageMesh {
            found: false,
            faces: 0,
            presence: 0.0,
        });
    };
    *mesh = first.mesh.clone();
    let mut drawn = Vec::with_capacity(faces.len());
    for (k, face) in faces.iter().enumerate() {
        let points: Vec<Point2<f64>> = face
            .mesh
            .points
            .iter()
            .map(|p| Point2::new(f64::from(p[0]), f64::from(p[1])))
            .collect();
        let pts_name = format!("{stem}_{k}.pts");
        facecap_io::formats::pts::write_pts_points(args.out.join(&pts_name), &points)
            .with_context(|| format!("writing {pts_name}"))?;
        let (l, t, r, b) = bounding_box(&points);
        let _ = writeln!(
            summary,
            "{name},{k},{l},{t},{r},{b},{:.6},{},{},",
            face.detection_score,
            points.len(),
            csv_field(&pts_name)
        );
        drawn.push(((l, t, r, b), points));
    }
    if args.draw {
        for (bx, points) in &drawn {
            draw_mesh(&mut rgb, *bx, points);
        }
        let png = args.out.join(format!("{stem}_landmarks.png"));
        crate::save_png_atomic(&rgb, &png)?;
    }
    Ok(ImageMesh {
        found: true,
        faces: faces.len(),
        presence: f64::from(first.mesh.presence).clamp(0.0, 1.0),
    })
}

/// dlib-style inclusive integer box `(left, top, right, bottom)` around finite points.
fn bounding_box(points: &[Point2<f64>]) -> (i64, i64, i64, i64) {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in points {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    (x0.floor() as i64, y0.floor() as i64, x1.ceil() as i64, y1.ceil() as i64)
}

/// The box (green) and each of the 478 points as a one-pixel cross (red; the irises
/// yellow).
fn draw_mesh(img: &mut RgbImage, (l, t, r, b): (i64, i64, i64, i64), points: &[Point2<f64>]) {
    const BOX: Rgb<u8> = Rgb([0, 230, 0]);
    const POINT: Rgb<u8> = Rgb([255, 40, 40]);
    const IRIS: Rgb<u8> = Rgb([255, 230, 0]);
    let (w, h) = (i64::from(img.width()), i64::from(img.height()));
    let mut put = |x: i64, y: i64, c: Rgb<u8>| {
        if x >= 0 && y >= 0 && x < w && y < h {
            img.put_pixel(x as u32, y as u32, c);
        }
    };
    // only the part of the box inside the image is walked
    for x in l.max(0)..=r.min(w - 1) {
        put(x, t, BOX);
        put(x, b, BOX);
    }
    for y in t.max(0)..=b.min(h - 1) {
        put(l, y, BOX);
        put(r, y, BOX);
    }
    for (i, p) in points.iter().enumerate() {
        let c = if i >= 468 { IRIS } else { POINT };
        let (x, y) = (p.x.round() as i64, p.y.round() as i64);
        for (dx, dy) in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)] {
            put(x + dx, y + dy, c);
        }
    }
}
