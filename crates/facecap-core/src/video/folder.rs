//! Folders of still images (and single images) as frame sources.
//!
//! The folder's files with an image extension ([`crate::image_io::IMAGE_EXTENSIONS`],
//! case-insensitive) are the frames, sorted by file name in byte order (so name them
//! with zero-padded numbers: `frame_0001.png`); other files and sub-folders are ignored.
//! Timestamps are `index / folder_fps`. All images must have the size of the first.
//! Grey and RGB conversion follow [`crate::image_io`]; grey images are always full range,
//! so [`super::Luma`] does not apply.

use std::path::{Path, PathBuf};

use super::{ensure_gray, ensure_rgb, Frame, FrameSource, SourceKind, SourceOptions, VideoInfo};
use crate::error::{Error, Result};
use crate::image_io;

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
        files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
        Self::from_files(dir, files, opts, SourceKind::ImageFolder)
    }

    /// A one-frame source for a single image file.
    pub fn open_image(file: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        Self::from_files(file, vec![file.to_path_buf()], opts, SourceKind::Image)
    }

    fn from_files(path: &Path, files: Vec<PathBuf>, opts: &SourceOptions, kind: SourceKind) -> Result<Self> {
        let (width, height) = match files.first() {
            Some(f) => image_io::image_dimensions(f)?,
            None => (0, 0),
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
