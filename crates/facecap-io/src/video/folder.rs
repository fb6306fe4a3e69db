//! Folders of still images (and single images) as frame sources.
//!
//! The folder's files with an image extension ([`crate::image_io::IMAGE_EXTENSIONS`],
//! case-insensitive) are the frames, sorted by file name in natural order (runs of digits
//! compare as numbers, so `frame_2.png` comes before `frame_10.png`, and zero-padded
//! names keep their byte order); other files and sub-folders are ignored.
//! Timestamps are `index / folder_fps`. All images must have the size of the first.
//! Grey and RGB conversion follow [`crate::image_io`]; grey images are always full range,
//! so [`super::Luma`] does not apply.

use std::path::{Path, PathBuf};

use super::{ensure_gray, ensure_rgb, Frame, FrameSource, SourceKind, SourceOptions, VideoInfo};
use crate::image_io;
use facecap_core::error::{Error, Result};

/// Frames from image files.
#[derive(Debug)]
pub struct ImageFolderSource {
    path: PathBuf,
    files: Vec<PathBuf>,
    info: VideoInfo,
    next_index: u64,
    rgb: bool,
}

impl ImageFolderSource {
    /// Lists the images of `dir` (see the module docs).
    ///
    /// # Errors
    /// [`Error::Io`] if the folder cannot be read, [`Error::Decode`] naming the folder if
    /// it holds no image, or naming the first image if its header cannot be read.
    pub fn open_dir(dir: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        let mut files = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let entry = entry.map_err(|e| Error::io(dir, e))?;
            let p = entry.path();
            if p.is_file() && image_io::has_image_extension(&p) {
                files.push(p);
            }
        }
        if files.is_empty() {
            return Err(Error::Decode {
                path: dir.to_path_buf(),
                frame: None,
                reason: format!(
                    "folder contains no images (extensions {})",
                    image_io::IMAGE_EXTENSIONS.join(", ")
                ),
            });
        }
        files.sort_by(|a, b| {
            natural_cmp(
                &a.file_name().unwrap_or_default().to_string_lossy(),
                &b.file_name().unwrap_or_default().to_string_lossy(),
            )
            .then_with(|| a.cmp(b))
        });
        Self::from_files(dir, files, opts, SourceKind::ImageFolder)
    }

    /// A one-frame source for a single image file.
    pub fn open_image(file: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        Self::from_files(file, vec![file.to_path_buf()], opts, SourceKind::Image)
    }

    fn from_files(path: &Path, files: Vec<PathBuf>, opts: &SourceOptions, kind: SourceKind) -> Result<Self> {
        // The sequence's size is the first readable image's: a damaged first file is a
        // frame that fails on its own, not the end of the sequence.
        let mut first_err = None;
        let mut size = None;
        for f in &files {
            match image_io::image_dimensions(f) {
                Ok(d) => {
                    size = Some(d);
                    break;
                }
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        let (width, height) = match (size, first_err) {
            (Some(d), _) => d,
            (None, Some(e)) => return Err(e),
            (None, None) => (0, 0),
        };
        let n = files.len() as u64;
        Ok(ImageFolderSource {
            path: path.to_path_buf(),
            info: VideoInfo {
                width,
                height,
                fps: opts.folder_fps,
                frame_count: Some(n),
                duration_s: Some(n as f64 / opts.folder_fps),
                codec: "images".into(),
                kind,
            },
            files,
            next_index: 0,
            rgb: opts.rgb,
        })
    }

    /// The image files in frame order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }
}

impl FrameSource for ImageFolderSource {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn read_into(&mut self, frame: &mut Frame) -> Result<bool> {
        let Some(file) = usize::try_from(self.next_index).ok().and_then(|i| self.files.get(i)) else {
            return Ok(false);
        };
        let index = self.next_index;
        // A bad image consumes its frame index: the next call goes on with the next file.
        self.next_index += 1;
        let img = image_io::load_dynamic(file, Some(index))?;
        if (img.width(), img.height()) != (self.info.width, self.info.height) {
            return Err(Error::Decode {
                path: file.clone(),
                frame: Some(index),
                reason: format!(
                    "image is {}x{} but the sequence is {}x{} (all images must have the size of the first)",
                    img.width(),
                    img.height(),
                    self.info.width,
                    self.info.height
                ),
            });
        }
        ensure_gray(&mut frame.gray, self.info.width, self.info.height);
        image_io::dynamic_to_gray_into(&img, &mut frame.gray);
        ensure_rgb(&mut frame.rgb, self.rgb, self.info.width, self.info.height);
        if let Some(rgb) = frame.rgb.as_mut() {
            *rgb = img.into_rgb8();
        }
        frame.index = index;
        frame.timestamp_s = index as f64 / self.info.fps;
        Ok(true)
    }
}

/// Natural order of file names: runs of ASCII digits compare by value (then by length,
/// so `01` and `1` stay apart), everything else by character.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i].is_ascii_digit() && b[j].is_ascii_digit() {
            let (si, sj) = (i, j);
            while i < a.len() && a[i].is_ascii_digit() {
                i += 1;
            }
            while j < b.len() && b[j].is_ascii_digit() {
                j += 1;
            }
            let (da, db) = (&a[si..i], &b[sj..j]);
            let ta = &da[da.iter().take_while(|&&c| c == b'0').count()..];
            let tb = &db[db.iter().take_while(|&&c| c == b'0').count()..];
            let o = ta
                .len()
                .cmp(&tb.len())
                .then_with(|| ta.cmp(tb))
                .then_with(|| da.len().cmp(&db.len()));
            if o != Ordering::Equal {
                return o;
            }
        } else {
            if a[i] != b[j] {
                return a[i].cmp(&b[j]);
            }
            i += 1;
            j += 1;
        }
    }
    (a.len() - i).cmp(&(b.len() - j))
}

#[cfg(test)]
mod tests {
    use super::natural_cmp;

    #[test]
    fn natural_order_of_frame_names() {
        let mut v: Vec<String> = (1..=30).rev().map(|i| format!("frame_{i}.png")).collect();
        v.sort_by(|a, b| natural_cmp(a, b));
        let want: Vec<String> = (1..=30).map(|i| format!("frame_{i}.png")).collect();
        assert_eq!(v, want);
        // Zero-padded names keep their byte order.
        let mut p: Vec<String> = (0..120).rev().map(|i| format!("f{i:04}.png")).collect();
        let mut bytes = p.clone();
        bytes.sort();
        p.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(p, bytes);
        assert_eq!(natural_cmp("a01", "a1"), std::cmp::Ordering::Greater);
        assert_eq!(natural_cmp("a", "a1"), std::cmp::Ordering::Less);
        assert_eq!(natural_cmp("b", "a10"), std::cmp::Ordering::Greater);
    }
}
