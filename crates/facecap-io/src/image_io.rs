//! Loading still images as grey or RGB with errors that name the file.
//!
//! Formats: PNG, JPEG and PNM (PGM/PPM/PBM), the features `image` is built with in this
//! workspace. Every failure is an [`Error`] naming the path:
//!
//! | input | error |
//! |---|---|
//! | missing / unreadable file | [`Error::Io`] |
//! | empty (0-byte) file | [`Error::Decode`] "empty file (0 bytes)" |
//! | not an image, truncated, unsupported format | [`Error::Decode`] with the decoder's reason |
//! | image with zero width or height | [`Error::Decode`] "image has zero size WxH" |
//!
//! ## Grey conversion
//! Colour images become grey with the ITU-R BT.601 luma weights in the same 14-bit
//! fixed-point form OpenCV's `cvtColor(RGB2GRAY)` uses
//! (`Y = (4899 R + 9617 G + 1868 B + 2^13) >> 14`), so a grey frame here equals the grey
//! frame an OpenCV/dlib pipeline sees for the same decoded RGB pixels. (`image`'s own
//! `to_luma8` uses Rec. 709 weights instead; we do not use it.) Alpha is dropped, 16-bit
//! samples are reduced to 8 bits by `image`'s conversion.
//!
//! ```
//! # fn main() -> facecap_core::Result<()> {
//! let dir = tempfile::tempdir().map_err(|e| facecap_core::Error::io("tempdir", e))?;
//! let path = dir.path().join("a.png");
//! image::RgbImage::from_pixel(4, 3, image::Rgb([255, 0, 0])).save(&path).map_err(|e| {
//!     facecap_core::Error::Decode { path: path.clone(), frame: None, reason: e.to_string() }
//! })?;
//! let g = facecap_io::image_io::load_gray(&path)?;
//! assert_eq!(g.dimensions(), (4, 3));
//! assert_eq!(g.get_pixel(0, 0)[0], 76); // 0.299 * 255
//! # Ok(()) }
//! ```

use std::path::Path;

use image::{DynamicImage, GrayImage, RgbImage};

use facecap_core::error::{Error, Result};

/// File extensions (lower case) recognised as still images.
pub const IMAGE_EXTENSIONS: &[&str] = &["png", "jpg", "jpeg", "pgm", "ppm", "pbm", "pnm"];

/// BT.601 luma weights in OpenCV's 14-bit fixed point (R, G, B).
const BT601_FIXED: [u32; 3] = [4899, 9617, 1868];
/// Fixed-point shift of [`BT601_FIXED`].
const BT601_SHIFT: u32 = 14;

/// Whether `path` has one of the [`IMAGE_EXTENSIONS`] (case-insensitive).
pub fn has_image_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| IMAGE_EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)))
        .unwrap_or(false)
}

fn decode_error(path: &Path, frame: Option<u64>, reason: impl Into<String>) -> Error {
    Error::Decode {
        path: path.to_path_buf(),
        frame,
        reason: reason.into(),
    }
}

/// Decodes any supported image; checks the file exists, is non-empty and has non-zero size.
/// `frame` is put into errors when the image is one frame of a sequence.
pub fn load_dynamic(path: &Path, frame: Option<u64>) -> Result<DynamicImage> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(decode_error(path, frame, "is a directory, not an image file"));
    }
    if meta.len() == 0 {
        return Err(decode_error(path, frame, "empty file (0 bytes)"));
    }
    let reader = image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    if reader.format().is_none() {
        return Err(decode_error(
            path,
            frame,
            "not a supported image (expected PNG, JPEG or PNM content)",
        ));
    }
    let img = reader
        .decode()
        .map_err(|e| decode_error(path, frame, format!("cannot decode image: {e}")))?;
    if img.width() == 0 || img.height() == 0 {
        return Err(decode_error(
            path,
            frame,
            format!("image has zero size {}x{}", img.width(), img.height()),
        ));
    }
    Ok(img)
}

/// Converts RGB to grey with OpenCV's fixed-point BT.601 weights (see module docs),
/// writing into `out` (resized only when its size differs).
pub fn rgb_to_gray_into(rgb: &RgbImage, out: &mut GrayImage) {
    if out.dimensions() != rgb.dimensions() {
        *out = GrayImage::new(rgb.width(), rgb.height());
    }
    for (g, p) in out.as_mut().iter_mut().zip(rgb.as_raw().chunks_exact(3)) {
        *g = bt601_luma(p[0], p[1], p[2]);
    }
}

/// BT.601 luma of one RGB pixel, OpenCV fixed point, rounded.
#[inline]
pub fn bt601_luma(r: u8, g: u8, b: u8) -> u8 {
    let y = BT601_FIXED[0] * u32::from(r) + BT601_FIXED[1] * u32::from(g) + BT601_FIXED[2] * u32::from(b);
    // The weights sum to 2^14, so the result is at most 255.
    ((y + (1 << (BT601_SHIFT - 1))) >> BT601_SHIFT) as u8
}

/// Grey version of a decoded image: grey images are taken as they are, colour images
/// through [`rgb_to_gray_into`].
pub fn dynamic_to_gray_into(img: &DynamicImage, out: &mut GrayImage) {
    match img {
        DynamicImage::ImageLuma8(g) => {
            if out.dimensions() == g.dimensions() {
                out.as_mut().copy_from_slice(g.as_raw());
            } else {
                *out = g.clone();
            }
        }
        DynamicImage::ImageLumaA8(_) | DynamicImage::ImageLuma16(_) | DynamicImage::ImageLumaA16(_) => {
            *out = img.to_luma8();
        }
        DynamicImage::ImageRgb8(rgb) => rgb_to_gray_into(rgb, out),
        other => rgb_to_gray_into(&other.to_rgb8(), out),
    }
}

/// Loads an image as 8-bit grey (see module docs for the conversion and the errors).
pub fn load_gray(path: impl AsRef<Path>) -> Result<GrayImage> {
    let path = path.as_ref();
    let img = load_dynamic(path, None)?;
    let mut out = GrayImage::new(0, 0);
    dynamic_to_gray_into(&img, &mut out);
    Ok(out)
}

/// Loads an image as 8-bit RGB (grey images are replicated into the three channels).
pub fn load_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    let path = path.as_ref();
    Ok(load_dynamic(path, None)?.to_rgb8())
}

/// Width and height of an image file without decoding the pixels, with the same
/// errors as [`load_gray`] for missing, empty or unreadable files.
pub fn image_dimensions(path: impl AsRef<Path>) -> Result<(u32, u32)> {
    let path = path.as_ref();
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.len() == 0 {
        return Err(decode_error(path, None, "empty file (0 bytes)"));
    }
    let (w, h) = image::image_dimensions(path)
        .map_err(|e| decode_error(path, None, format!("cannot read image header: {e}")))?;
    if w == 0 || h == 0 {
        return Err(decode_error(path, None, format!("image has zero size {w}x{h}")));
    }
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;

    #[test]
    fn bt601_matches_opencv_fixed_point_extremes() {
        assert_eq!(bt601_luma(0, 0, 0), 0);
        assert_eq!(bt601_luma(255, 255, 255), 255);
        assert_eq!(bt601_luma(255, 0, 0), 76);
        assert_eq!(bt601_luma(0, 255, 0), 150);
        assert_eq!(bt601_luma(0, 0, 255), 29);
    }

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.png");
        let e = load_gray(&missing).unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
        assert!(e.to_string().contains("missing.png"));

        let empty = dir.path().join("empty.png");
        std::fs::write(&empty, b"").unwrap();
        let e = load_gray(&empty).unwrap_err().to_string();
        assert!(e.contains("empty.png") && e.contains("0 bytes"), "{e}");

        let text = dir.path().join("text.png");
        std::fs::write(&text, b"this is not an image at all").unwrap();
        let e = load_rgb(&text).unwrap_err().to_string();
        assert!(e.contains("text.png"), "{e}");

        let zero = dir.path().join("zero.pgm");
        std::fs::write(&zero, b"P5\n0 0\n255\n").unwrap();
        let e = load_gray(&zero).unwrap_err().to_string();
        assert!(e.contains("zero.pgm"), "{e}");
    }

    #[test]
    fn truncated_png_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        GrayImage::from_fn(32, 32, |x, y| image::Luma([(x * 7 + y * 3) as u8]))
            .save(&p)
            .unwrap();
        let bytes = std::fs::read(&p).unwrap();
        for cut in [8, bytes.len() / 2, bytes.len() - 13] {
            let q = dir.path().join(format!("cut{cut}.png"));
            std::fs::write(&q, &bytes[..cut]).unwrap();
            let e = load_gray(&q).unwrap_err().to_string();
            assert!(e.contains(&format!("cut{cut}.png")), "{e}");
        }
    }
}
