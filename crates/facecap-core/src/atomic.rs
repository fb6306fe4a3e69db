//! Atomic file output: every file facecap writes goes through here.
//!
//! Data is written to a temporary file in the *same directory* as the target,
//! named `.<name>.tmp-<pid>` (a `-<n>` suffix is added if that name is taken),
//! flushed and `fsync`ed, then renamed over the target on [`AtomicFile::commit`].
//! A rename within one directory is atomic on POSIX file systems, so a reader sees
//! either the old file or the complete new one, never a half-written file. If the
//! writer is dropped without `commit` (an error, a panic, Ctrl-C unwinding), the
//! temporary file is removed and the target is left untouched.
//!
//! ```
//! use std::io::Write;
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("out.txt");
//! facecap_core::atomic::write_atomic(&path, |w| w.write_all(b"hello\n")).unwrap();
//! assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
//!
//! let mut f = facecap_core::atomic::AtomicFile::create(dir.path().join("never.txt")).unwrap();
//! f.write_all(b"partial").unwrap();
//! drop(f); // no commit: nothing appears
//! assert!(!dir.path().join("never.txt").exists());
//! ```

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// How many alternative temporary names are tried when `.<name>.tmp-<pid>` exists.
const MAX_TEMP_ATTEMPTS: u32 = 1000;

/// A file being written atomically; see the module docs.
///
/// Implements [`Write`] (buffered). Call [`AtomicFile::commit`] to publish it.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temp: PathBuf,
    writer: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates the temporary file beside `path`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when `path` has no file name; [`Error::Io`]
    /// (naming the temporary path) when the directory does not exist or is not writable.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        let target = path.as_ref().to_path_buf();
        let name = target
            .file_name()
            .ok_or_else(|| Error::invalid("output path", target.display(), "a path ending in a file name"))?
            .to_string_lossy()
            .into_owned();
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let pid = std::process::id();
        let mut attempt = 0u32;
        loop {
            let temp_name = if attempt == 0 {
                format!(".{name}.tmp-{pid}")
            } else {
                format!(".{name}.tmp-{pid}-{attempt}")
            };
            let temp = dir.join(temp_name);
            match OpenOptions::new().write(true).create_new(true).open(&temp) {
                Ok(file) => {
                    return Ok(AtomicFile {
                        target,
                        temp,
                        writer: Some(BufWriter::new(file)),
                    })
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < MAX_TEMP_ATTEMPTS => {
                    attempt += 1;
                }
                Err(e) => return Err(Error::io(temp, e)),
            }
        }
    }

    /// The final path the file is published at.
    pub fn target_path(&self) -> &Path {
        &self.target
    }

    /// The temporary path being written.
    pub fn temp_path(&self) -> &Path {
        &self.temp
    }

    /// Flushes, `fsync`s and renames the temporary file onto the target, then
    /// (best effort) `fsync`s the directory so the rename itself is durable.
    ///
    /// # Errors
    /// [`Error::Io`] naming the path involved; the temporary file is removed.
    pub fn commit(mut self) -> Result<()> {
        let Some(writer) = self.writer.take() else {
            return Err(Error::io(
                &self.temp,
                std::io::Error::other("atomic file already committed or failed"),
            ));
        };
        let file = writer.into_inner().map_err(|e| Error::io(&self.temp, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&self.temp, e))?;
        drop(file);
        std::fs::rename(&self.temp, &self.target).map_err(|e| Error::io(&self.target, e))?;
        // The temp name no longer exists; make Drop a no-op.
        self.temp = PathBuf::new();
        if let Some(dir) = self.target.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            if let Ok(d) = File::open(dir) {
                // Directory fsync is not supported everywhere; ignoring failure only
                // weakens durability after a power loss, never atomicity.
                let _ = d.sync_all();
            }
        }
        Ok(())
    }

    fn writer(&mut self) -> std::io::Result<&mut BufWriter<File>> {
        self.writer
            .as_mut()
            .ok_or_else(|| std::io::Error::other("atomic file already committed"))
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer()?.write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.writer()?.write_all(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.writer()?.flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        // Close the handle before unlinking (needed on some platforms).
        self.writer.take();
        if !self.temp.as_os_str().is_empty() {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

/// Writes `path` atomically with a closure doing plain I/O.
///
/// I/O errors from the closure are reported as [`Error::Io`] naming `path`;
/// on any error the target is left untouched and no temporary file remains.
///
/// # Errors
/// See [`AtomicFile::create`] and [`AtomicFile::commit`].
pub fn write_atomic(path: impl AsRef<Path>, f: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let path = path.as_ref();
    let mut file = AtomicFile::create(path)?;
    f(&mut file).map_err(|e| Error::io(path, e))?;
    file.commit()
}

/// Like [`write_atomic`] but the closure returns any error type that a core
/// [`Error`] converts into (e.g. a downstream crate's error enum), so it can
/// report format errors as well as I/O.
///
/// # Errors
/// Whatever the closure returns, or the core errors of create/commit converted into `E`.
pub fn write_atomic_with<E: From<Error>>(
    path: impl AsRef<Path>,
    f: impl FnOnce(&mut dyn Write) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let mut file = AtomicFile::create(path.as_ref())?;
    f(&mut file)?;
    file.commit()?;
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn commit_publishes_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.csv");
        let mut f = AtomicFile::create(&p).unwrap();
        assert_eq!(
            f.temp_path().file_name().unwrap().to_string_lossy(),
            format!(".a.csv.tmp-{}", std::process::id())
        );
        assert!(!p.exists());
        f.write_all(b"1,2\n").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "1,2\n");
        assert_eq!(entries(dir.path()), vec!["a.csv".to_string()]);
    }

    #[test]
    fn drop_without_commit_keeps_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        std::fs::write(&p, "old").unwrap();
        {
            let mut f = AtomicFile::create(&p).unwrap();
            f.write_all(b"new but unfinished").unwrap();
        }
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(entries(dir.path()), vec!["a.txt".to_string()]);
    }

    #[test]
    fn closure_error_leaves_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.txt");
        std::fs::write(&p, "old").unwrap();
        let r = write_atomic(&p, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("boom"))
        });
        assert!(matches!(r, Err(Error::Io { .. })));
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(entries(dir.path()), vec!["b.txt".to_string()]);
        write_atomic(&p, |w| w.write_all(b"new")).unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new");
    }

    #[test]
    fn write_atomic_with_propagates_custom_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.txt");
        let r: Result<()> = write_atomic_with(&p, |_w| Err(Error::invalid("x", 1, "2")));
        assert!(matches!(r, Err(Error::InvalidParameter { name: "x", .. })));
        assert!(entries(dir.path()).is_empty());
    }

    #[test]
    fn missing_directory_and_bad_path_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let r = AtomicFile::create(dir.path().join("no/such/dir/x.txt"));
        assert!(matches!(r, Err(Error::Io { .. })));
        assert!(matches!(AtomicFile::create("/"), Err(Error::InvalidParameter { .. })));
    }

    #[test]
    fn second_writer_gets_another_temp_name() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.txt");
        let mut a = AtomicFile::create(&p).unwrap();
        let mut b = AtomicFile::create(&p).unwrap();
        assert_ne!(a.temp_path(), b.temp_path());
        a.write_all(b"a").unwrap();
        b.write_all(b"b").unwrap();
        a.commit().unwrap();
        b.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "b");
        assert_eq!(entries(dir.path()), vec!["d.txt".to_string()]);
    }
}

/// The temporary name [`AtomicFile`] would use first for `path` (`.<name>.tmp-<pid>`
/// beside it), for files another program writes (e.g. ffmpeg encoding a video) that
/// are then renamed onto `path`. [`clean_stale_temps`] removes it if the process dies.
pub fn temp_path_for(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    dir.join(format!(".{name}.tmp-{}", std::process::id()))
}

/// The process id in a temporary name `.<name>.tmp-<pid>[-<n>]`, if it is one.
fn temp_owner(file_name: &str) -> Option<u32> {
    let rest = file_name.strip_prefix('.')?;
    let (_, tail) = rest.rsplit_once(".tmp-")?;
    let pid = tail.split('-').next()?;
    pid.parse().ok()
}

/// Whether process `pid` is alive (Linux: `/proc/<pid>` exists; elsewhere assumed alive,
/// so nothing is removed).
fn process_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists()
}

/// Removes temporary files of [`AtomicFile`] left in `dir` (not recursively) by processes
/// that no longer run (killed with SIGKILL, or a power loss); returns how many were
/// removed. Files of running processes, and every other file, are left alone.
pub fn clean_stale_temps(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = temp_owner(&name.to_string_lossy()) else {
            continue;
        };
        if !process_alive(pid) && e.file_type().is_ok_and(|t| t.is_file()) && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod stale_tests {
    use super::*;

    #[test]
    fn stale_temps_of_dead_processes_are_removed_others_kept() {
        let dir = tempfile::tempdir().unwrap();
        // pid 0x7FFFFFF0 cannot exist (above Linux's pid_max limit of 2^22).
        let dead = dir.path().join(".landmarks.csv.tmp-2147483632");
        let dead2 = dir.path().join(".summary.json.tmp-2147483632-3");
        let mine = temp_path_for(&dir.path().join("weights.csv"));
        let other = dir.path().join("notes.tmp-1");
        for p in [&dead, &dead2, &mine, &other] {
            std::fs::write(p, b"x").unwrap();
        }
        let n = clean_stale_temps(dir.path());
        if Path::new("/proc/self").exists() {
            assert_eq!(n, 2);
            assert!(!dead.exists() && !dead2.exists());
        }
        assert!(mine.exists() && other.exists());
        assert_eq!(temp_owner(".a.csv.tmp-12-4"), Some(12));
        assert_eq!(temp_owner("a.csv"), None);
    }
}
