//! The capture report: a contact sheet (frames with landmarks drawn beside the posed
//! mesh rendered by a small software rasteriser) and SVG plots over time.

use std::fmt::Write as _;
use std::path::Path;

use image::{Rgb, RgbImage};
use nalgebra::{Point2, Point3, Vector3};

/// Colours used for plot series (cycled).
const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
];

/// Draws filled discs of `radius` px at `points` (0-based pixel coordinates).
pub fn draw_points(img: &mut RgbImage, points: &[Point2<f64>], radius: i64, colour: [u8; 3]) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    for p in points {
        if !(p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        let (cx, cy) = (p.x.round() as i64, p.y.round() as i64);
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (x, y) = (cx + dx, cy + dy);
                if dx * dx + dy * dy <= radius * radius && x >= 0 && y >= 0 && x < w && y < h {
                    img.put_pixel(x as u32, y as u32, Rgb(colour));
                }
            }
        }
    }
}

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
}
