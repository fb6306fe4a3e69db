//! `facecap landmarks IMAGE... [--landmarks dlib68|mesh] [--model FILE] [--out DIR] [--draw]`.
//!
//! For every input image, with `--landmarks dlib68` (the default): detect faces
//! (dlib-compatible HOG detector, largest first), predict landmarks with a dlib
//! `shape_predictor` model (68 points by default), and write
//!
//! * `<out>/<stem>_<face>.pts` per face (`face` = 0-based index, largest face
//!   first; iBUG `.pts`, 1-based coordinates); `<stem>` is the input's file stem,
//!   sanitised and made unique among the inputs (`a/img.png`, `b/img.png` give `img` and
//!   `img-2`; [`facecap_core::paths::unique_output_names`]),
//! * `<out>/summary.csv` with one row per face:
//!   `image,face,left,top,right,bottom,score,num_points,pts_file,error`
//!   (dlib inclusive box in 0-based pixels; `score` is the detector's, empty for
//!   `--box`; images without a face get one row with `face` = -1 and empty fields; an
//!   image that cannot be read or processed gets `face` = -1 and its `error`),
//! * with `--draw`, `<out>/<stem>_landmarks.png`: the image with the boxes (green)
//!   and points (red).
//!
//! With `--landmarks mesh` (MediaPipe's face detector and 478-point face mesh, run afresh
//! on every image as FaceLandmarker's IMAGE mode, every face, with facecap's small-face
//! search; docs/mesh.md):
//!
//! * `<out>/landmarks.csv`: one row per input image in input order (`frame` = its 0-based
//!   position, `timestamp` 0) with the largest face,
//!   `frame,timestamp,success,confidence,x_0,y_0,z_0,...,z_477` (the 478-point layout of
//!   docs/formats.md; `confidence` = the mesh's face presence);
//! * `<out>/<stem>_<face>.pts` per face (largest first) with the 478 points (x, y), and
//!   `summary.csv` as above (the box is the points' bounding box, `score` the detector's);
//! * with `--draw`, the image with every face's 478 points.
//!
//! `--model`, `--box`, `--upsample`, `--ert-precision` and `--grey` are dlib's and are
//! refused or unused with `mesh`.
//!
//! A damaged image fails alone (its error also on stderr); the exit code is non-zero
//! when no image could be processed, or with `--strict` when any could not. A `--box`
//! that does not overlap an image is that image's error.
//!
//! A single video input (mp4, avi, mov, mkv, webm, y4m) or folder of images is handed to
//! the video mode ([`crate::cmd_landmarks_video`]), which tracks it as one sequence.

use facecap_landmarks::detect::Upsample;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use facecap_core::landmarks::Rect;
use facecap_landmarks::ert::ShapePredictor;
use image::{GrayImage, Rgb, RgbImage};
use nalgebra::Point2;

/// File extensions treated as video.
pub const VIDEO_EXTENSIONS: [&str; 6] = ["mp4", "avi", "mov", "mkv", "webm", "y4m"];

/// How colour images are turned into the grey image the models see.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GreyMode {
    /// BT.601 luma (OpenCV's `COLOR_RGB2GRAY` weights), facecap's default.
    Bt601,
    /// `(r + g + b) / 3` (integer), what dlib uses when given an RGB image.
    Mean,
}

/// Arguments of `facecap landmarks`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap landmarks photo.jpg --out pts/ --draw\n  facecap landmarks clip.mp4 --out tracked/\n  facecap landmarks clip.mp4 --landmarks mesh --out mesh/   # 478 points x_i,y_i,z_i"
)]
pub struct Args {
    /// Input images (or one video file, or one folder of images tracked as a video).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Landmark front end: `dlib68` (dlib's detector and 68-point model; `.pts` per face,
    /// `landmarks.csv` with `x_0..x_67,y_0..y_67` for videos) or `mesh` (MediaPipe's face
    /// detector and 478-point face mesh with irises; `landmarks.csv` with `x_i,y_i,z_i`
    /// for the 478 points, docs/mesh.md and docs/formats.md).
    #[arg(long, value_name = "dlib68|mesh", default_value = "dlib68")]
    pub landmarks: facecap_pipeline::FrontEnd,
    /// dlib shape_predictor model (default: shape_predictor_68_face_landmarks.dat in
    /// the model cache).
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR", default_value = ".")]
    pub out: PathBuf,
    /// Also write `<stem>_landmarks.png` with the boxes and points drawn.
    #[arg(long)]
    pub draw: bool,
    /// Video mode: smooth landmarks with the One Euro filter (as `capture --smooth`); with
    /// `--landmarks mesh`, MediaPipe's video-mode smoothing (FaceLandmarker's VIDEO mode).
    #[arg(long)]
    pub smooth: bool,
    /// Use this face box (dlib inclusive `left,top,right,bottom`, 0-based pixels)
    /// for every image instead of running the face detector.
    #[arg(long = "box", value_name = "L,T,R,B", value_parser = parse_box)]
    pub face_box: Option<Rect>,
    /// Grey conversion of colour images.
    #[arg(long, value_enum, default_value_t = GreyMode::Bt601)]
    pub grey: GreyMode,
    /// `--upsample`.
    #[command(flatten)]
    pub detect: crate::upsample_flag::UpsampleFlag,
    /// `--ert-precision`.
    #[command(flatten)]
    pub ert: crate::ert_flag::ErtFlag,
    /// Exit non-zero when any image cannot be read or processed (by default such images
    /// get a row with their error in `summary.csv`, the others are processed, and the
    /// exit code is non-zero only when no image could be processed).
    #[arg(long)]
    pub strict: bool,
}

/// What the video mode receives from `facecap landmarks VIDEO ...`.
#[derive(Debug, Clone)]
pub struct VideoJob {
    /// The video file.
    pub input: PathBuf,
    /// Output folder.
    pub out_dir: PathBuf,
    /// `--draw` was given.
    pub draw: bool,
    /// `--model`, when given (else the cache's 68-point model).
    pub model: Option<PathBuf>,
    /// `--upsample`.
    pub upsample: Upsample,
    /// `--ert-precision`.
    pub ert_precision: facecap_landmarks::ert::ErtPrecision,
    /// `--smooth` was given.
    pub smooth: bool,
    /// `--strict` was given (stop at the first undecodable frame).
    pub strict: bool,
    /// `--landmarks`.
    pub front_end: facecap_pipeline::FrontEnd,
}

fn parse_box(s: &str) -> Result<Rect, String> {
    let v: Vec<i64> = s
        .split(',')
        .map(|x| x.trim().parse::<i64>().map_err(|e| format!("bad box value {x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    let [l, t, r, b] = v[..] else {
        return Err(format!("expected 4 comma-separated integers L,T,R,B, got {}", v.len()));
    };
    if r < l || b < t {
        return Err(format!("box {s}: need right >= left and bottom >= top"));
    }
    Ok(Rect::from_dlib(l, t, r, b))
}

/// True when `path` is tracked as one sequence by the video mode: a video file or a
/// folder (of images).
pub fn is_sequence(path: &Path) -> bool {
    is_video(path) || path.is_dir()
}

/// True when the path's extension names a video container.
pub fn is_video(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The model to use: `--model` or the 68-point model in the cache.
pub fn resolve_model(model: Option<&Path>) -> anyhow::Result<PathBuf> {
    if let Some(m) = model {
        return Ok(m.to_path_buf());
    }
    let name = facecap_core::paths::DLIB_68_MODEL;
    facecap_core::paths::model_file(name).with_context(|| {
        format!(
            "{name} not found in the model cache ({}); run scripts/setup.sh or pass --model",
            facecap_core::paths::model_dir().map_or_else(|| "unknown".into(), |d| d.display().to_string())
        )
    })
}

/// Runs `facecap landmarks`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mesh = args.landmarks == facecap_pipeline::FrontEnd::Mesh;
    if mesh && args.model.is_some() {
        bail!("--model names a dlib shape predictor; --landmarks mesh uses the face mesh models of the cache");
    }
    if mesh && args.face_box.is_some() {
        bail!("--box is not supported with --landmarks mesh (the face mesh finds its own face region)");
    }
    if args.inputs.len() == 1 && is_sequence(&args.inputs[0]) {
        let job = VideoJob {
            input: args.inputs[0].clone(),
            out_dir: args.out.clone(),
            draw: args.draw,
            model: args.model.clone(),
            upsample: args.detect.upsample,
            ert_precision: args.ert.ert_precision,
            smooth: args.smooth,
            strict: args.strict,
            front_end: args.landmarks,
        };
        return run_video(&job);
    }
    if let Some(v) = args.inputs.iter().find(|p| is_sequence(p)) {
        bail!(
            "{}: a video or a folder of images must be the only input (video mode)",
            v.display()
        );
    }
    if mesh {
        return crate::cmd_landmarks_mesh::run_images(&args);
    }
    let model_path = resolve_model(args.model.as_deref())?;
    let sp = ShapePredictor::from_file_cached(&model_path)
        .map(|(sp, _)| {
            let params = sp.params();
            sp.with_params(facecap_landmarks::ert::ErtParams {
                precision: args.ert.ert_precision,
                ..params
            })
        })
        .with_context(|| format!("loading shape predictor {}", model_path.display()))?;
    let detector = match args.face_box {
        Some(_) => None,
        None => Some(
            facecap_landmarks::detect::FaceDetector::default_model()
                .and_then(|d| d.with_upsample(args.detect.upsample))
                .context("loading the face detector")?,
        ),
    };
    let mut det_ws = detector.as_ref().map(|d| d.new_workspace());
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut ws = sp.new_workspace();
    let mut points = vec![Point2::origin(); sp.num_parts()];
    let mut csv = String::from("image,face,left,top,right,bottom,score,num_points,pts_file,error\n");
    let mut total_faces = 0usize;
    let mut failed = 0usize;
    let mut grey = GrayImage::new(0, 0);
    // Output names unique inside --out (a/img.png and b/img.png give img_0.pts and
    // img-2_0.pts); summary.csv says which input went where.
    let stems = facecap_core::paths::unique_output_names(&args.inputs, "image");
    for (input, stem) in args.inputs.iter().zip(&stems) {
        // A damaged image fails alone: its row records the error, the others go on.
        if let Err(e) = process_image(
            &args,
            input,
            stem,
            &sp,
            detector.as_ref(),
            det_ws.as_mut(),
            &mut ws,
            &mut points,
            &mut grey,
            &mut csv,
            &mut total_faces,
        ) {
            let msg = crate::error_text(&e);
            eprintln!("error: {}: {msg}", input.display());
            let _ = writeln!(
                csv,
                "{},-1,,,,,,0,,{}",
                csv_field(&input.display().to_string()),
                csv_field(&msg)
            );
            failed += 1;
        }
    }
    let summary = args.out.join("summary.csv");
    facecap_core::atomic::write_atomic(&summary, |w| std::io::Write::write_all(w, csv.as_bytes()))
        .with_context(|| format!("writing {}", summary.display()))?;
    eprintln!(
        "{} image(s), {total_faces} face(s), {failed} failed; wrote {}",
        args.inputs.len(),
        summary.display()
    );
    Ok(if failed == args.inputs.len() || (args.strict && failed > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

/// One image of `facecap landmarks`: its `.pts` files, `summary.csv` rows and drawing.
#[allow(clippy::too_many_arguments)]
fn process_image(
    args: &Args,
    input: &Path,
    stem: &str,
    sp: &ShapePredictor,
    detector: Option<&facecap_landmarks::detect::FaceDetector>,
    det_ws: Option<&mut facecap_landmarks::detect::DetectWorkspace>,
    ws: &mut facecap_landmarks::ert::ErtWorkspace,
    points: &mut [Point2<f64>],
    grey: &mut GrayImage,
    csv: &mut String,
    total_faces: &mut usize,
) -> anyhow::Result<()> {
    {
        // the loaders name the file in their errors
        load_grey(input, args.grey, grey)?;
        if let Some(b) = &args.face_box {
            check_box_in_image(b, grey.width(), grey.height())?;
        }
        let faces: Vec<(Rect, Option<f64>)> = match (&args.face_box, detector, det_ws) {
            (Some(b), _, _) => vec![(*b, None)],
            (None, Some(d), Some(dws)) => d
                .detect(grey, dws)
                .with_context(|| format!("detecting faces in {}", input.display()))?
                .into_iter()
                .map(|det| (det.rect, Some(det.score)))
                .collect(),
            _ => Vec::new(),
        };
        let mut drawn = Vec::new();
        let mut rows = String::new();
        if faces.is_empty() {
            let _ = writeln!(rows, "{},-1,,,,,,0,,", csv_field(&input.display().to_string()));
            eprintln!("{}: no face found", input.display());
        }
        for (k, (rect, score)) in faces.iter().enumerate() {
            sp.predict_into(grey, rect, ws, points)
                .with_context(|| format!("predicting landmarks in {}", input.display()))?;
            let pts_name = format!("{stem}_{k}.pts");
            facecap_io::formats::pts::write_pts_points(args.out.join(&pts_name), points)
                .with_context(|| format!("writing {pts_name}"))?;
            let (l, t, r, b) = rect.to_dlib();
            let _ = writeln!(
                rows,
                "{},{k},{l},{t},{r},{b},{},{},{},",
                csv_field(&input.display().to_string()),
                score.map_or_else(String::new, |s| format!("{s:.6}")),
                points.len(),
                csv_field(&pts_name)
            );
            drawn.push((*rect, points.to_vec()));
        }
        if args.draw {
            let mut rgb = match facecap_io::image_io::load_rgb(input) {
                Ok(img) => img,
                Err(_) => image::DynamicImage::ImageLuma8(grey.clone()).to_rgb8(),
            };
            for (rect, pts) in &drawn {
                draw_overlay(&mut rgb, rect, pts);
            }
            let png = args.out.join(format!("{stem}_landmarks.png"));
            let bytes = crate::report::png_bytes_fast(&rgb)?;
            facecap_core::atomic::write_atomic(&png, |w| std::io::Write::write_all(w, &bytes))
                .with_context(|| format!("writing {}", png.display()))?;
        }
        csv.push_str(&rows);
        *total_faces += drawn.len();
    }
    Ok(())
}

/// A `--box` must overlap the image (a box beside it gives points predicted from
/// nothing but the mean shape).
fn check_box_in_image(b: &Rect, width: u32, height: u32) -> anyhow::Result<()> {
    let (l, t, r, bt) = b.to_dlib();
    if r < 0 || bt < 0 || l >= i64::from(width) || t >= i64::from(height) {
        bail!("--box {l},{t},{r},{bt} lies outside the {width}x{height} image");
    }
    Ok(())
}

/// Video mode: hands a single video input to the tracker's command
/// ([`crate::cmd_landmarks_video::run`]).
fn run_video(job: &VideoJob) -> anyhow::Result<ExitCode> {
    crate::cmd_landmarks_video::run(job)
}

fn load_grey(path: &Path, mode: GreyMode, out: &mut GrayImage) -> anyhow::Result<()> {
    match mode {
        GreyMode::Bt601 => *out = facecap_io::image_io::load_gray(path)?,
        GreyMode::Mean => {
            let rgb = facecap_io::image_io::load_rgb(path)?;
            *out = GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                let p = rgb.get_pixel(x, y).0;
                image::Luma([((u32::from(p[0]) + u32::from(p[1]) + u32::from(p[2])) / 3) as u8])
            });
        }
    }
    Ok(())
}

/// A field of `summary.csv`, quoted when needed.
pub(crate) fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Draws the box outline (green) and each point as a small filled disc (red).
fn draw_overlay(img: &mut RgbImage, rect: &Rect, pts: &[Point2<f64>]) {
    const BOX: Rgb<u8> = Rgb([0, 230, 0]);
    const POINT: Rgb<u8> = Rgb([255, 40, 40]);
    let (w, h) = (i64::from(img.width()), i64::from(img.height()));
    let put = |img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>| {
        if x >= 0 && y >= 0 && x < w && y < h {
            img.put_pixel(x as u32, y as u32, c);
        }
    };
    let (l, t, r, b) = rect.to_dlib();
    let thick = (1 + (r - l) / 200).max(1);
    for d in 0..thick {
        for x in l..=r {
            put(img, x, t + d, BOX);
            put(img, x, b - d, BOX);
        }
        for y in t..=b {
            put(img, l + d, y, BOX);
            put(img, r - d, y, BOX);
        }
    }
    let rad = (1 + (r - l) / 150).clamp(1, 6);
    for p in pts {
        let (cx, cy) = (p.x.round() as i64, p.y.round() as i64);
        for dy in -rad..=rad {
            for dx in -rad..=rad {
                if dx * dx + dy * dy <= rad * rad {
                    put(img, cx + dx, cy + dy, POINT);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_parsing() {
        assert_eq!(parse_box("1,2,30,40"), Ok(Rect::from_dlib(1, 2, 30, 40)));
        assert!(parse_box("1,2,3").is_err());
        assert!(parse_box("5,2,3,40").is_err());
        assert!(parse_box("a,2,3,4").is_err());
    }

    #[test]
    fn video_extensions() {
        assert!(is_video(Path::new("a/b.MP4")));
        assert!(is_video(Path::new("x.y4m")));
        assert!(!is_video(Path::new("x.png")));
        assert!(!is_video(Path::new("mp4")));
    }
}
