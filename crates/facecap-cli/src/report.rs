//! The capture report: a contact sheet (frames with landmarks drawn beside the posed
//! mesh rendered by a small software rasteriser) and SVG plots over time.

use std::fmt::Write as _;
use std::path::Path;

use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector3};

/// Colours used for plot series (cycled).
const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
];

/// Renders a triangle mesh seen from the front (+Z towards the viewer, +Y up) into a
/// `size` x `size` image with a z-buffer and Lambert shading. `positions` are in model
/// units; the mesh is scaled to fit with a margin. `rotation` (model-to-view) lets the
/// caller show the tracked head pose.
pub fn render_mesh(
    positions: &[Point3<f32>],
    triangles: &[[u32; 3]],
    rotation: &nalgebra::Rotation3<f64>,
    size: u32,
) -> RgbImage {
    let mut img = RgbImage::from_pixel(size, size, Rgb([245, 245, 245]));
    if positions.is_empty() {
        return img;
    }
    let centroid = positions
        .iter()
        .fold(Vector3::<f64>::zeros(), |a, p| a + p.coords.cast::<f64>())
        / positions.len() as f64;
    let view: Vec<Vector3<f64>> = positions
        .iter()
        .map(|p| rotation * (p.coords.cast::<f64>() - centroid))
        .collect();
    let extent = view
        .iter()
        .fold(0.0f64, |m, v| m.max(v.x.abs()).max(v.y.abs()))
        .max(1e-9);
    let scale = 0.45 * size as f64 / extent;
    let half = size as f64 / 2.0;
    // Screen: x right, y down.
    let screen: Vec<(f64, f64, f64)> = view
        .iter()
        .map(|v| (half + scale * v.x, half - scale * v.y, v.z))
        .collect();
    let mut zbuf = vec![f64::NEG_INFINITY; (size * size) as usize];
    let light = Vector3::new(0.3, 0.4, 1.0).normalize();
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= screen.len() || b >= screen.len() || c >= screen.len() {
            continue;
        }
        let n = (view[b] - view[a]).cross(&(view[c] - view[a]));
        let nn = n.norm();
        if nn <= 0.0 || n.z <= 0.0 {
            continue; // back-facing or degenerate
        }
        let shade = (0.25 + 0.75 * (n / nn).dot(&light).max(0.0)).min(1.0);
        let colour = Rgb([(225.0 * shade) as u8, (190.0 * shade) as u8, (170.0 * shade) as u8]);
        let (p0, p1, p2) = (screen[a], screen[b], screen[c]);
        let minx = p0.0.min(p1.0).min(p2.0).floor().max(0.0) as i64;
        let maxx = p0.0.max(p1.0).max(p2.0).ceil().min(size as f64 - 1.0) as i64;
        let miny = p0.1.min(p1.1).min(p2.1).floor().max(0.0) as i64;
        let maxy = p0.1.max(p1.1).max(p2.1).ceil().min(size as f64 - 1.0) as i64;
        let area = (p1.0 - p0.0) * (p2.1 - p0.1) - (p1.1 - p0.1) * (p2.0 - p0.0);
        if area.abs() < 1e-12 {
            continue;
        }
        for y in miny..=maxy {
            for x in minx..=maxx {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((p1.0 - px) * (p2.1 - py) - (p1.1 - py) * (p2.0 - px)) / area;
                let w1 = ((p2.0 - px) * (p0.1 - py) - (p2.1 - py) * (p0.0 - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p0.2 + w1 * p1.2 + w2 * p2.2;
                let idx = (y as u32 * size + x as u32) as usize;
                if z > zbuf[idx] {
                    zbuf[idx] = z;
                    img.put_pixel(x as u32, y as u32, colour);
                }
            }
        }
    }
    img
}

/// Encodes `img` as PNG with fast compression (report images are written once and
/// looked at by eye; the default compression costs several times more CPU).
pub fn png_bytes_fast(img: &RgbImage) -> std::io::Result<Vec<u8>> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let mut buf = Vec::new();
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .map_err(std::io::Error::other)?;
    Ok(buf)
}

/// The [`render_mesh`] rotation that shows a model posed by the model-to-camera rotation
/// `r` as the camera sees it: camera axes are x right, y down, z forward; the renderer looks
/// along -z with y up, so y and z are flipped after `r`.
pub fn camera_view(r: &nalgebra::Rotation3<f64>) -> nalgebra::Rotation3<f64> {
    let flip =
        nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)));
    flip * r
}

/// Places `a` and `b` side by side (heights matched by padding).
pub fn side_by_side(a: &RgbImage, b: &RgbImage) -> RgbImage {
    let h = a.height().max(b.height());
    let mut out = RgbImage::from_pixel(a.width() + b.width(), h, Rgb([255, 255, 255]));
    image::imageops::overlay(&mut out, a, 0, 0);
    image::imageops::overlay(&mut out, b, a.width() as i64, 0);
    out
}

/// A line plot of several series over time as a standalone SVG document.
/// Non-finite values break the line.
pub fn svg_line_plot(title: &str, times: &[f64], series: &[(String, Vec<f64>)], width: u32, height: u32) -> String {
    let (ml, mr, mt, mb) = (55.0, 150.0, 28.0, 35.0);
    let (w, h) = (width as f64, height as f64);
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(1.0).max(t0 + 1e-9);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, v) in series {
        for &x in v.iter().filter(|x| x.is_finite()) {
            lo = lo.min(x);
            hi = hi.max(x);
        }
    }
    if !lo.is_finite() {
        lo = 0.0;
        hi = 1.0;
    }
    if hi - lo < 1e-9 {
        hi = lo + 1.0;
    }
    let sx = |t: f64| ml + (t - t0) / (t1 - t0) * (w - ml - mr);
    let sy = |v: f64| mt + (hi - v) / (hi - lo) * (h - mt - mb);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = write!(
        s,
        r#"<text x="{ml}" y="16" font-size="13" font-weight="bold">{}</text>"#,
        escape(title)
    );
    let _ = write!(
        s,
        r##"<rect x="{ml}" y="{mt}" width="{}" height="{}" fill="none" stroke="#999"/>"##,
        w - ml - mr,
        h - mt - mb
    );
    for k in 0..=4 {
        let v = lo + (hi - lo) * k as f64 / 4.0;
        let _ = write!(
            s,
            r#"<text x="{}" y="{}" text-anchor="end">{:.3}</text>"#,
            ml - 4.0,
            sy(v) + 4.0,
            v
        );
        let t = t0 + (t1 - t0) * k as f64 / 4.0;
        let _ = write!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">{:.2}s</text>"#,
            sx(t),
            h - mb + 15.0,
            t
        );
    }
    for (i, (name, v)) in series.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let mut d = String::new();
        let mut pen_down = false;
        for (t, x) in times.iter().zip(v) {
            if x.is_finite() {
                let _ = write!(d, "{}{:.1},{:.1} ", if pen_down { "L" } else { "M" }, sx(*t), sy(*x));
                pen_down = true;
            } else {
                pen_down = false;
            }
        }
        let _ = write!(s, r#"<path d="{d}" fill="none" stroke="{colour}" stroke-width="1.2"/>"#);
        let ly = mt + 12.0 + 13.0 * i as f64;
        if ly < h - mb {
            let _ = write!(
                s,
                r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{colour}" stroke-width="2"/><text x="{}" y="{}">{}</text>"#,
                w - mr + 8.0,
                ly - 4.0,
                w - mr + 24.0,
                ly - 4.0,
                w - mr + 28.0,
                ly,
                escape(name)
            );
        }
    }
    s.push_str("</svg>");
    s
}

/// Minimal XML/HTML escaping.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Writes `report.html` into `dir` referencing contact-sheet PNGs and SVG plots that
/// the caller wrote into the same folder (relative file names).
pub fn write_report_html(
    dir: &Path,
    title: &str,
    summary_rows: &[(String, String)],
    sheet_intro: &str,
    sheets: &[(String, String)],
    plots: &[String],
) -> anyhow::Result<()> {
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>body{{font-family:sans-serif;margin:20px}}\
         table{{border-collapse:collapse}}td{{border:1px solid #ccc;padding:3px 8px}}.sheet{{display:flex;flex-wrap:wrap;gap:8px}}\
         figure{{margin:0}}figcaption{{font-size:12px}}img{{max-width:100%}}</style></head><body><h1>{t}</h1><table>",
        t = escape(title)
    );
    for (k, v) in summary_rows {
        let _ = write!(html, "<tr><td>{}</td><td>{}</td></tr>", escape(k), escape(v));
    }
    let _ = write!(
        html,
        "</table><h2>Contact sheet</h2><p>{}</p><div class=\"sheet\">",
        escape(sheet_intro)
    );
    for (file, caption) in sheets {
        let _ = write!(
            html,
            "<figure><img src=\"{}\" width=\"400\"><figcaption>{}</figcaption></figure>",
            escape(file),
            escape(caption)
        );
    }
    html.push_str("</div><h2>Over time</h2>");
    for p in plots {
        let _ = write!(html, "<div><img src=\"{}\"></div>", escape(p));
    }
    html.push_str("</body></html>\n");
    facecap_core::atomic::write_atomic(dir.join("report.html"), |w| w.write_all(html.as_bytes()))?;
    Ok(())
}

// ------------------------------------------------------------------------------------
// The capture report: plots drawn with `plotters` (SVG backend), page assembled here.

/// Grey of the shading that marks frames without a tracked face, in every plot.
const LOST_SHADE: plotters::style::RGBColor = plotters::style::RGBColor(205, 205, 205);
/// Line colour of facecap's curves.
const OURS: plotters::style::RGBColor = plotters::style::RGBColor(31, 105, 180);
/// Line colour of the reference curves.
const REFERENCE: plotters::style::RGBColor = plotters::style::RGBColor(230, 120, 20);
/// A shape counts as active when its weight exceeds this on some solved frame.
pub const ACTIVE_WEIGHT: f64 = 0.05;

fn plot_err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("drawing a plot: {e}")
}

/// A tick label without float noise: at most 2 decimals, trailing zeros dropped.
pub fn tick(v: f64) -> String {
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// Time spans `[start, end]` (seconds) of consecutive frames where `ok` is false,
/// each frame covering half a frame interval either side.
pub fn lost_spans(times: &[f64], ok: &[bool]) -> Vec<(f64, f64)> {
    let dt = if times.len() > 1 {
        (times[times.len() - 1] - times[0]) / (times.len() - 1) as f64
    } else {
        0.04
    };
    let mut spans: Vec<(f64, f64)> = Vec::new();
    for (t, &good) in times.iter().zip(ok) {
        if good {
            continue;
        }
        let (a, b) = (t - dt / 2.0, t + dt / 2.0);
        match spans.last_mut() {
            Some(last) if a <= last.1 + 1e-9 => last.1 = b,
            _ => spans.push((a, b)),
        }
    }
    spans
}

/// Splits a series at non-finite values into drawable runs of (t, v).
fn runs(times: &[f64], v: &[f64]) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
    for (&t, &x) in times.iter().zip(v) {
        if x.is_finite() {
            if let Some(last) = out.last_mut() {
                last.push((t, x));
            }
        } else if out.last().is_some_and(|l| !l.is_empty()) {
            out.push(Vec::new());
        }
    }
    out.retain(|r| !r.is_empty());
    out
}

/// One curve of a small-multiples plot, with its reference when there is one.
#[derive(Debug, Clone)]
pub struct ShapeCurve {
    /// Shape name (plot title).
    pub name: String,
    /// facecap's values per frame (NaN where not solved).
    pub values: Vec<f64>,
    /// The reference's values per frame (NaN where it has none).
    pub reference: Option<Vec<f64>>,
}

/// Small multiples: one small plot per curve on a grid of `cols` columns, all with
/// the y range `y` and the same time axis, frames in `lost` shaded.
pub fn small_multiples_svg(
    times: &[f64],
    curves: &[ShapeCurve],
    lost: &[(f64, f64)],
    y: (f64, f64),
    cols: usize,
) -> anyhow::Result<String> {
    use plotters::prelude::*;
    let cols = cols.max(1).min(curves.len().max(1));
    let rows = curves.len().div_ceil(cols).max(1);
    let (cell_w, cell_h) = (300u32, 150u32);
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(1.0).max(t0 + 1e-6);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (cell_w * cols as u32, cell_h * rows as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let cells = root.split_evenly((rows, cols));
        for (cell, c) in cells.iter().zip(curves) {
            let mut chart = ChartBuilder::on(cell)
                .caption(&c.name, ("sans-serif", 14))
                .margin(6)
                .x_label_area_size(20)
                .y_label_area_size(30)
                .build_cartesian_2d(t0..t1, y.0..y.1)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_labels(5)
                .y_labels(3)
                .x_label_formatter(&|v| format!("{} s", tick(*v)))
                .y_label_formatter(&|v| tick(*v))
                .label_style(("sans-serif", 11))
                .light_line_style(WHITE)
                .bold_line_style(RGBColor(232, 232, 232))
                .draw()
                .map_err(plot_err)?;
            chart
                .draw_series(
                    lost.iter()
                        .map(|&(a, b)| Rectangle::new([(a.max(t0), y.0), (b.min(t1), y.1)], LOST_SHADE.filled())),
                )
                .map_err(plot_err)?;
            if let Some(r) = &c.reference {
                for run in runs(times, r) {
                    chart
                        .draw_series(LineSeries::new(run, REFERENCE.stroke_width(1)))
                        .map_err(plot_err)?;
                }
            }
            let ours = runs(times, &c.values);
            if ours.is_empty() {
                cell.draw(&Text::new(
                    "no solved frame",
                    ((cell_w / 3) as i32, (cell_h / 2) as i32),
                    ("sans-serif", 12),
                ))
                .map_err(plot_err)?;
            }
            for run in ours {
                chart
                    .draw_series(LineSeries::new(run, OURS.stroke_width(2)))
                    .map_err(plot_err)?;
            }
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

/// A plot of a few named series on one axis (head rotation, confidence, ...), frames in
/// `lost` shaded. With no finite value at all, the plot says `empty_reason` instead.
pub fn lines_svg(
    times: &[f64],
    series: &[(String, Vec<f64>)],
    lost: &[(f64, f64)],
    y_label: &str,
    empty_reason: &str,
) -> anyhow::Result<String> {
    use plotters::prelude::*;
    const COLOURS: [RGBColor; 4] = [
        RGBColor(31, 105, 180),
        RGBColor(230, 120, 20),
        RGBColor(44, 160, 44),
        RGBColor(200, 40, 40),
    ];
    let (w, h) = (900u32, 240u32);
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(1.0).max(t0 + 1e-6);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in series.iter().flat_map(|(_, v)| v.iter()).filter(|v| v.is_finite()) {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    let empty = !lo.is_finite();
    if empty {
        (lo, hi) = (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(1e-3);
    let (lo, hi) = (lo - pad, hi + pad);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(52)
            .build_cartesian_2d(t0..t1, lo..hi)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_labels(10)
            .y_labels(5)
            .x_desc("time (s)")
            .y_desc(y_label)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .label_style(("sans-serif", 12))
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(232, 232, 232))
            .draw()
            .map_err(plot_err)?;
        chart
            .draw_series(
                lost.iter()
                    .map(|&(a, b)| Rectangle::new([(a.max(t0), lo), (b.min(t1), hi)], LOST_SHADE.filled())),
            )
            .map_err(plot_err)?;
        if empty {
            root.draw(&Text::new(
                empty_reason.to_string(),
                (80, (h / 2) as i32),
                ("sans-serif", 15),
            ))
            .map_err(plot_err)?;
        }
        for (k, (name, v)) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let mut first = true;
            for run in runs(times, v) {
                let s = chart
                    .draw_series(LineSeries::new(run, colour.stroke_width(2)))
                    .map_err(plot_err)?;
                if first {
                    s.label(name.clone())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
                    first = false;
                }
            }
        }
        if !empty {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(200, 200, 200))
                .label_font(("sans-serif", 12))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

/// The ARKit name of a rig shape (ICT's `_L`/`_R` suffixes become `Left`/`Right`).
pub fn arkit_name(name: &str) -> String {
    for (suf, arkit) in [("_L", "Left"), ("_R", "Right")] {
        if let Some(base) = name.strip_suffix(suf) {
            return format!("{base}{arkit}");
        }
    }
    name.to_string()
}

/// Reads a MediaPipe blendshape CSV in the layout of `scripts/eval_expressions.py`
/// (`frame,success,_neutral,<52 ARKit names>`) and returns, per rig shape in `names`,
/// its reference curve over `frames` (frame indices; NaN where the reference has no
/// face), or `None` when the file has no column for that shape.
///
/// # Errors
/// An unreadable file, or one without the `frame` and `success` columns.
pub fn read_reference(path: &Path, names: &[String], frames: &[u64]) -> anyhow::Result<Vec<Option<Vec<f64>>>> {
    let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').map(str::trim).collect();
    let col = |n: &str| header.iter().position(|h| *h == n);
    let (Some(fi), Some(si)) = (col("frame"), col("success")) else {
        anyhow::bail!(
            "{}: not a reference CSV (needs the columns frame, success and ARKit shape names)",
            path.display()
        );
    };
    let cols: Vec<Option<usize>> = names.iter().map(|n| col(&arkit_name(n))).collect();
    let mut by_frame: std::collections::HashMap<u64, Vec<f64>> = std::collections::HashMap::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let (Some(frame), Some(ok)) = (f.get(fi).and_then(|v| v.parse::<f64>().ok()), f.get(si)) else {
            continue;
        };
        if !matches!(*ok, "1" | "true" | "True") || frame < 0.0 {
            continue;
        }
        let vals = cols
            .iter()
            .map(|c| {
                c.and_then(|c| f.get(c))
                    .and_then(|v| v.parse::<f64>().ok())
                    .unwrap_or(f64::NAN)
            })
            .collect();
        by_frame.insert(frame as u64, vals);
    }
    Ok(cols
        .iter()
        .enumerate()
        .map(|(k, c)| {
            c.map(|_| {
                frames
                    .iter()
                    .map(|fr| by_frame.get(fr).map_or(f64::NAN, |v| v[k]))
                    .collect()
            })
        })
        .collect())
}

/// One section of the capture report: a heading, a plot (file name relative to the
/// report) and a note under it.
#[derive(Debug, Clone)]
pub struct Section {
    /// Heading.
    pub title: String,
    /// The plot's file (relative), if any.
    pub plot: Option<String>,
    /// Text under the heading (HTML-escaped when written).
    pub note: String,
}

/// A face this much smaller than the frame's short side (bounding box of its landmarks,
/// long side) gets its report tile cropped to it ([`face_crop`]).
pub const CROP_FACE_BELOW: f64 = 0.25;
/// The crop's side over the face box's long side.
pub const CROP_MARGIN: f64 = 2.2;

/// The square `(left, top, side)` in pixels around a small face of a `width` x `height`
/// frame, `points` its landmarks in the frame's pixels: [`CROP_MARGIN`] times the long
/// side of their box, centred on it and moved inside the frame. `None` when the face is
/// large enough to be seen in the whole frame (long side of its box at least
/// [`CROP_FACE_BELOW`] of the frame's short side), or a point is not finite.
pub fn face_square(width: u32, height: u32, points: &[(f64, f64)]) -> Option<(u32, u32, u32)> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for &(x, y) in points {
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    let (w, h) = (f64::from(width), f64::from(height));
    let long = (x1 - x0).max(y1 - y0);
    let short_side = w.min(h);
    if !(long.is_finite() && long > 0.0 && long < CROP_FACE_BELOW * short_side) {
        return None;
    }
    let s = (CROP_MARGIN * long).min(short_side);
    let left = ((x0 + x1 - s) / 2.0).clamp(0.0, w - s);
    let top = ((y0 + y1 - s) / 2.0).clamp(0.0, h - s);
    let (l, t) = (left.round() as u32, top.round() as u32);
    let n = (s.round() as u32).max(1).min(width - l).min(height - t);
    Some((l, t, n))
}

/// The square `(left, top, n)` of `img` (from [`face_square`]) scaled to `side` x `side`.
pub fn crop_square(img: &RgbImage, (l, t, n): (u32, u32, u32), side: u32) -> RgbImage {
    let view = image::imageops::crop_imm(img, l, t, n, n).to_image();
    image::imageops::resize(&view, side.max(1), side.max(1), image::imageops::FilterType::Triangle)
}

/// Writes `report.html` of a capture: the preview video at the top (when given), the
/// summary table, the frame tiles (relative file names with captions) and the plot
/// sections.
#[allow(clippy::too_many_arguments)]
pub fn write_capture_html(
    dir: &Path,
    title: &str,
    video: Option<&str>,
    no_video_note: &str,
    summary_rows: &[(String, String)],
    tiles_intro: &str,
    tiles: &[(String, String)],
    sections: &[Section],
) -> anyhow::Result<()> {
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
         <link rel=\"icon\" href=\"data:,\"><style>\
         body{{font-family:sans-serif;margin:20px;max-width:1400px;color:#222}}\
         table{{border-collapse:collapse;margin:8px 0;max-width:100%}}td{{border:1px solid #ccc;padding:3px 8px;font-size:14px;overflow-wrap:anywhere}}\
         video{{width:100%;max-width:1400px;background:#000}}\
         .tiles{{display:grid;grid-template-columns:repeat(auto-fill,minmax(600px,1fr));gap:10px}}\
         figure{{margin:0}}figcaption{{font-size:13px;color:#444}}img{{max-width:100%}}\
         .note{{color:#555;font-size:14px;max-width:900px}}.legend span{{display:inline-block;width:22px;height:4px;vertical-align:middle;margin:0 4px 0 12px}}\
         </style></head><body><h1>{t}</h1>",
        t = escape(title)
    );
    match video {
        Some(v) => {
            let _ = write!(
                html,
                "<video id=\"preview\" src=\"{}\" controls muted loop playsinline preload=\"auto\"></video>\
                 <p class=\"note\">Left: the video with the tracked landmarks (green) and the rig drawn \
                 over the face in the solved head pose; middle: the rig with the solved weights and head \
                 rotation; right: the weights of the most active shapes.</p>",
                escape(v)
            );
        }
        None => {
            let _ = write!(html, "<p class=\"note\">{}</p>", escape(no_video_note));
        }
    }
    html.push_str("<table>");
    for (k, v) in summary_rows {
        let _ = write!(html, "<tr><td>{}</td><td>{}</td></tr>", escape(k), escape(v));
    }
    let _ = write!(
        html,
        "</table><h2>Frames</h2><p class=\"note\">{}</p><div class=\"tiles\">",
        escape(tiles_intro)
    );
    for (file, caption) in tiles {
        let _ = write!(
            html,
            "<figure><img src=\"{}\" alt=\"{c}\"><figcaption>{c}</figcaption></figure>",
            escape(file),
            c = escape(caption)
        );
    }
    html.push_str("</div>");
    for s in sections {
        let _ = write!(
            html,
            "<h2>{}</h2><p class=\"note\">{}</p>",
            escape(&s.title),
            escape(&s.note)
        );
        if let Some(p) = &s.plot {
            let _ = write!(
                html,
                "<div><img src=\"{}\" alt=\"{}\"></div>",
                escape(p),
                escape(&s.title)
            );
        }
    }
    html.push_str("</body></html>\n");
    facecap_core::atomic::write_atomic(dir.join("report.html"), |w| w.write_all(html.as_bytes()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_default_rig_and_plots() {
        let (rig, _) = crate::default_rig::default_rig().unwrap();
        let img = render_mesh(
            &rig.base.positions,
            &rig.base.triangles,
            &nalgebra::Rotation3::identity(),
            200,
        );
        // The face covers a good part of the image and is shaded.
        let covered = img.pixels().filter(|p| p.0 != [245, 245, 245]).count();
        assert!(covered > 200 * 200 / 5, "covered {covered}");
        if let Some(dir) = std::env::var_os("FACECAP_DEBUG_DIR") {
            let mut posed = Vec::new();
            let mut w = vec![0.0; rig.targets.len()];
            w[0] = 1.0;
            w[1] = 1.0;
            rig.pose_into(&w, &mut posed).unwrap();
            let b = render_mesh(
                &posed,
                &rig.base.triangles,
                &nalgebra::Rotation3::from_euler_angles(0.0, 0.4, 0.0),
                200,
            );
            side_by_side(&img, &b)
                .save(std::path::Path::new(&dir).join("default_rig.png"))
                .unwrap();
        }
        let svg = svg_line_plot(
            "t",
            &[0.0, 1.0, 2.0],
            &[("a<b".into(), vec![0.0, f64::NAN, 1.0])],
            400,
            200,
        );
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>") && svg.contains("a&lt;b"));
    }

    fn face_crop(img: &RgbImage, points: &[(f64, f64)], side: u32) -> Option<RgbImage> {
        face_square(img.width(), img.height(), points).map(|sq| crop_square(img, sq, side))
    }

    #[test]
    fn small_faces_get_a_cropped_tile() {
        // a 1920 x 1080 frame, red inside a 100 px face box at (1600..1700, 900..1000)
        let img = RgbImage::from_fn(1920, 1080, |x, y| {
            if (1600..1700).contains(&x) && (900..1000).contains(&y) {
                image::Rgb([255, 0, 0])
            } else {
                image::Rgb([0, 0, 255])
            }
        });
        let face = [(1600.0, 900.0), (1699.0, 999.0), (1650.0, 950.0)];
        let tile = face_crop(&img, &face, 480).expect("a 100 px face in 1080 p is cropped");
        assert_eq!(tile.dimensions(), (480, 480));
        // 2.2 face widths around the face, centred: the face fills about (1 / 2.2)^2 of it
        let red = tile.pixels().filter(|p| p.0[0] > 128).count() as f64 / (480.0 * 480.0);
        assert!((red - (1.0f64 / 2.2).powi(2)).abs() < 0.03, "{red}");
        assert!(tile.get_pixel(240, 240).0[0] > 128 && tile.get_pixel(0, 0).0[0] < 128);
        // near the frame's edge the square moves inside the frame: the face off centre
        let low = [(1600.0, 1000.0), (1699.0, 1079.0)];
        let tile = face_crop(&img, &low, 480).unwrap();
        assert!(
            tile.get_pixel(240, 470).0[2] > 128,
            "the frame's bottom rows lie at the tile's bottom"
        );
        assert!(tile.get_pixel(240, 100).0[0] > 128, "the red box above them");
        // a face a third of the frame's height is shown whole; no points, no crop
        assert!(face_crop(&img, &[(800.0, 300.0), (1200.0, 700.0)], 480).is_none());
        assert!(face_crop(&img, &[], 480).is_none());
        assert!(face_crop(&img, &[(f64::NAN, 1.0), (3.0, 4.0)], 480).is_none());
        // a face at the very corner: the crop stays inside the frame
        assert!(face_crop(&img, &[(0.0, 0.0), (40.0, 40.0)], 100).is_some());
    }

    #[test]
    fn ticks_spans_and_plots() {
        assert_eq!(tick(0.30000000000000004), "0.3");
        assert_eq!(tick(2.0), "2");
        assert_eq!(tick(-0.0001), "0");
        let times: Vec<f64> = (0..10).map(|k| k as f64 * 0.1).collect();
        let ok = [true, false, false, true, true, true, false, true, true, true];
        let spans = lost_spans(&times, &ok);
        assert_eq!(spans.len(), 2);
        assert!((spans[0].0 - 0.05).abs() < 1e-9 && (spans[0].1 - 0.25).abs() < 1e-9);
        let v: Vec<f64> = times
            .iter()
            .zip(&ok)
            .map(|(t, &g)| if g { *t } else { f64::NAN })
            .collect();
        let curves = vec![
            ShapeCurve {
                name: "jawOpen".into(),
                values: v.clone(),
                reference: Some(vec![0.5; 10]),
            },
            ShapeCurve {
                name: "mouthPucker".into(),
                values: vec![f64::NAN; 10],
                reference: None,
            },
        ];
        let svg = small_multiples_svg(&times, &curves, &spans, (0.0, 1.0), 4).unwrap();
        assert!(svg.contains("jawOpen") && svg.contains("no solved frame"));
        // Lost frames are shaded: the shade colour appears (once per span per plot).
        assert!(svg.matches("#CDCDCD").count() >= 4, "{}", &svg[..400.min(svg.len())]);
        let empty = lines_svg(
            &times,
            &[("yaw".into(), vec![f64::NAN; 10])],
            &[],
            "deg",
            "no head pose",
        )
        .unwrap();
        assert!(empty.contains("no head pose"));
    }

    #[test]
    fn reference_columns_by_arkit_name() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("mp.csv");
        std::fs::write(
            &p,
            "frame,success,_neutral,eyeBlinkLeft,jawOpen\n0,1,0,0.25,0.5\n1,0,0,0,0\n2,1,0,0.75,0.1\n",
        )
        .unwrap();
        let names = vec!["eyeBlink_L".to_string(), "jawOpen".into(), "cheekPuffy".into()];
        let r = read_reference(&p, &names, &[0, 1, 2]).unwrap();
        assert_eq!(r[0].as_ref().unwrap()[0], 0.25);
        assert!(r[0].as_ref().unwrap()[1].is_nan());
        assert_eq!(r[1].as_ref().unwrap()[2], 0.1);
        assert!(r[2].is_none());
        std::fs::write(&p, "a,b\n").unwrap();
        assert!(read_reference(&p, &names, &[0]).is_err());
    }
}
