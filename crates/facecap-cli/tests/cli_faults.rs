#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Fault tests of `facecap capture` on a shared clip (docs/reliability.md):
//!
//! * kill -9 and SIGTERM while tracking and while the outputs are written: every file
//!   under its final name is complete (CSVs of whole rows, JSON that parses, a glb the
//!   reader takes, an mp4 that decodes), no completion marker, and a rerun finishes with
//!   the outputs of an uninterrupted run;
//! * a full disk (a small tmpfs in a private mount namespace, `unshare -rm`): a clear
//!   error, rc != 0, nothing partial under a final name, no temporary file left;
//! * a read-only output folder (a read-only bind mount, or a 0555 folder when not root):
//!   a clear error, rc != 0, nothing written;
//! * the input deleted while it is tracked: the capture either completes with every
//!   frame or fails naming the file; never a success with frames missing.
//!
//! Where the machine cannot make a mount namespace the disk-full and read-only cases
//! print a `SKIP:` line.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Frames of the clip the tests capture.
const FRAMES: usize = 90;

/// The first [`FRAMES`] frames of a shared clip (480x480 mp4, stream-copied by ffmpeg)
/// as `dir/clip.mp4`, with the models present; `None` after a skip line.
fn shared_clip(test: &str, dir: &Path) -> Option<PathBuf> {
    facecap_core::paths::model_file_or_skip(test, facecap_core::paths::DLIB_68_MODEL)?;
    facecap_core::paths::model_file_or_skip(test, "dlib_frontal_face_detector.svm")?;
    let src = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d18.mp4")?;
    let out = dir.join("clip.mp4");
    let ok = Command::new("ffmpeg")
        .args(["-nostdin", "-y", "-loglevel", "error", "-i"])
        .arg(&src)
        .args(["-frames:v", &FRAMES.to_string(), "-an", "-c", "copy"])
        .arg(&out)
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        facecap_core::paths::skip_missing_data(&format!("{test}: ffmpeg could not cut the clip"));
        return None;
    }
    Some(out)
}

/// Every file of `dir` (recursively) with its path relative to `dir`.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else { continue };
        for e in rd {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

fn is_temp(rel: &Path) -> bool {
    rel.file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with('.') && n.to_string_lossy().contains(".tmp-"))
}

/// Panics unless the file under its final name is complete for its kind.
fn assert_complete(path: &Path) {
    let name = path.display();
    let bytes = std::fs::read(path).unwrap();
    assert!(!bytes.is_empty(), "{name}: empty file under its final name");
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "csv" => {
            let text = std::str::from_utf8(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(text.ends_with('\n'), "{name}: last row cut");
            let mut lines = text.lines();
            let n = lines.next().unwrap().split(',').count();
            for (k, l) in lines.enumerate() {
                assert_eq!(l.split(',').count(), n, "{name}: row {k} has a wrong field count");
            }
        }
        "json" => {
            serde_json::from_slice::<Value>(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        "glb" | "gltf" => {
            facecap_io::gltf_io::read_morph_file(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        "png" => {
            image::load_from_memory(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        "mp4" => {
            let o = facecap().arg("info").arg(path).output().unwrap();
            assert!(o.status.success(), "{name}: {}", stderr(&o));
        }
        "html" => {
            let text = String::from_utf8_lossy(&bytes);
            assert!(text.trim_end().ends_with("</html>"), "{name}: cut html");
        }
        "obj" => {
            facecap_io::obj::read_obj(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        _ => {}
    }
}

/// Every file under a final name in `dir` is complete; returns those names.
fn assert_all_complete(dir: &Path) -> Vec<PathBuf> {
    let mut finals = Vec::new();
    for rel in files(dir) {
        if !is_temp(&rel) {
            assert_complete(&dir.join(&rel));
            finals.push(rel);
        }
    }
    finals
}

fn capture_cmd(clip: &Path, out: &Path) -> Command {
    let mut c = facecap();
    c.args(["capture", "--quiet", "--jobs", "1", "--out"])
        .arg(out)
        .arg(clip);
    c
}

/// The files that must match between an uninterrupted run and a rerun (the report and
/// summary carry timings).
const SAME_FILES: &[&str] = &[
    "landmarks.csv",
    "weights.csv",
    "pose.csv",
    "openface.csv",
    "livelink.csv",
    "animation.glb",
];

/// Waits until `cond` holds (polling every 5 ms), at most 60 s, or until the child exits.
fn wait_for(child: &mut Child, cond: impl Fn() -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(60) {
        if cond() {
            return true;
        }
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// A temporary file of the landmarks CSV exists: tracking has started.
fn tracking(dir: &Path) -> bool {
    files(dir)
        .iter()
        .any(|r| is_temp(r) && r.to_string_lossy().contains("landmarks.csv"))
}

/// The CSVs are in place but not the completion marker: the preview and report are
/// being written.
fn writing_outputs(dir: &Path) -> bool {
    dir.join("weights.csv").is_file() && !dir.join("summary.json").exists()
}

/// Interrupts a capture with `sig` while it tracks and again while it writes its
/// outputs; checks what is left and that a rerun ends like an uninterrupted run.
fn interrupt_and_rerun(test: &str, sig: i32) {
    let tmp = tempfile::tempdir().unwrap();
    let Some(clip) = shared_clip(test, tmp.path()) else {
        return;
    };
    let reference = tmp.path().join("ref");
    let o = capture_cmd(&clip, &reference).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let ref_dir = reference.join("clip");
    let ref_files = assert_all_complete(&ref_dir);
    for f in SAME_FILES {
        assert!(ref_dir.join(f).is_file(), "reference run lacks {f}");
    }
    assert!(ref_dir.join("preview.mp4").is_file());

    type Phase = fn(&Path) -> bool;
    let cases: [(&str, Phase); 2] = [("tracking", tracking), ("writing", writing_outputs)];
    for (what, phase) in cases {
        let out = tmp.path().join(format!("sig{sig}-{what}"));
        let what = format!("signal {sig} while {what}");
        let dir = out.join("clip");
        let mut child = capture_cmd(&clip, &out)
            .stderr(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let reached = wait_for(&mut child, || phase(&dir));
        assert!(reached, "{what}: the capture ended before the phase to interrupt");
        let st = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(st.success());
        let o = child.wait_with_output().unwrap();
        assert!(!o.status.success(), "{what}: an interrupted capture reported success");
        if sig == libc_sig::TERM {
            assert_eq!(o.status.code(), Some(130), "{what}: {}", stderr(&o));
            assert!(stderr(&o).contains("interrupted"), "{what}: {}", stderr(&o));
        }
        let finals = assert_all_complete(&dir);
        assert!(
            !dir.join("summary.json").exists(),
            "{what}: an interrupted capture has a completion marker"
        );
        if sig == libc_sig::TERM {
            // Handled: the unfinished capture is discarded whole, temporary files too.
            let left = files(&dir);
            assert!(left.is_empty(), "{what}: SIGTERM left {left:?}");
        }
        eprintln!("{what}: left {} files under final names: {finals:?}", finals.len());
        // The rerun (no --force) redoes the capture and ends like the reference run.
        let o = capture_cmd(&clip, &out).output().unwrap();
        assert!(o.status.success(), "{what}: rerun: {}", stderr(&o));
        assert!(!stderr(&o).contains("skip"), "{what}: rerun skipped: {}", stderr(&o));
        let again = assert_all_complete(&dir);
        assert_eq!(again, ref_files, "{what}: rerun files differ from the reference run");
        for f in SAME_FILES {
            assert!(
                std::fs::read(dir.join(f)).unwrap() == std::fs::read(ref_dir.join(f)).unwrap(),
                "{what}: {f} differs from the uninterrupted run"
            );
        }
        let (a, b): (Value, Value) = (
            serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap(),
            serde_json::from_slice(&std::fs::read(ref_dir.join("summary.json")).unwrap()).unwrap(),
        );
        for k in ["frames", "success_frames", "undecodable_frames"] {
            assert_eq!(a[k], b[k], "{what}: summary.json {k}");
        }
    }
}

#[test]
fn kill_9_mid_capture_leaves_no_partial_file_and_a_rerun_completes() {
    interrupt_and_rerun(
        "kill_9_mid_capture_leaves_no_partial_file_and_a_rerun_completes",
        libc_sig::KILL,
    );
}

#[test]
fn sigterm_mid_capture_leaves_no_partial_file_and_a_rerun_completes() {
    interrupt_and_rerun(
        "sigterm_mid_capture_leaves_no_partial_file_and_a_rerun_completes",
        libc_sig::TERM,
    );
}

/// Signal numbers (Linux) without a libc dependency.
mod libc_sig {
    pub const KILL: i32 = 9;
    pub const TERM: i32 = 15;
}

/// Runs `script` (sh) in a private mount namespace as root of a user namespace
/// (`unshare -rm`), or `None` with a SKIP line when the machine does not allow one.
fn in_mount_namespace(test: &str, script: &str) -> Option<Output> {
    let probe = Command::new("unshare")
        .args(["-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /tmp && echo ok"])
        .output();
    match probe {
        Ok(o) if o.status.success() && String::from_utf8_lossy(&o.stdout).contains("ok") => {}
        _ => {
            facecap_core::paths::skip(&format!("{test}: cannot make a mount namespace (unshare -rm); not run"));
            return None;
        }
    }
    Some(
        Command::new("unshare")
            .args(["-rm", "sh", "-c", script])
            .output()
            .unwrap(),
    )
}

fn sh_quote(p: &Path) -> String {
    format!("'{}'", p.display().to_string().replace('\'', r"'\''"))
}

#[test]
fn a_full_disk_fails_clearly_and_leaves_no_partial_file() {
    const T: &str = "a_full_disk_fails_clearly_and_leaves_no_partial_file";
    let tmp = tempfile::tempdir().unwrap();
    let Some(clip) = shared_clip(T, tmp.path()) else { return };
    // Sizes: the first CSV cannot be written at all; the CSVs and the glb fit but not the
    // preview and the report.
    for size_k in [8, 1024] {
        let mnt = tmp.path().join(format!("mnt{size_k}"));
        let copy = tmp.path().join(format!("copy{size_k}"));
        std::fs::create_dir_all(&mnt).unwrap();
        std::fs::create_dir_all(&copy).unwrap();
        let script = format!(
            "mount -t tmpfs -o size={size_k}k tmpfs {m} || exit 99; {bin} capture --quiet --jobs 1 --out {m}/out {clip} 2> {c}/stderr; echo $? > {c}/rc; df -k {m} > {c}/df; cp -a {m}/. {c}/",
            m = sh_quote(&mnt),
            c = sh_quote(&copy),
            bin = sh_quote(Path::new(env!("CARGO_BIN_EXE_facecap"))),
            clip = sh_quote(&clip),
        );
        let Some(o) = in_mount_namespace(T, &script) else {
            return;
        };
        assert!(o.status.success(), "{size_k} KiB: script: {}", stderr(&o));
        let rc: i32 = std::fs::read_to_string(copy.join("rc"))
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        let err = std::fs::read_to_string(copy.join("stderr")).unwrap();
        eprintln!("{size_k} KiB tmpfs: rc {rc}, stderr: {err}");
        assert_ne!(rc, 0, "{size_k} KiB: a capture on a full disk reported success");
        assert!(
            err.contains("No space left on device") || err.contains("is the disk full?"),
            "{size_k} KiB: unclear error: {err}"
        );
        let dir = copy.join("out").join("clip");
        let left = files(&dir);
        let temps: Vec<_> = left.iter().filter(|r| is_temp(r)).collect();
        assert!(temps.is_empty(), "{size_k} KiB: temporary files left: {temps:?}");
        let finals = assert_all_complete(&dir);
        assert!(!dir.join("summary.json").exists(), "{size_k} KiB: completion marker");
        eprintln!("{size_k} KiB: files under final names: {finals:?}");
    }
}

#[test]
fn a_read_only_output_folder_fails_clearly_and_writes_nothing() {
    const T: &str = "a_read_only_output_folder_fails_clearly_and_writes_nothing";
    let tmp = tempfile::tempdir().unwrap();
    let Some(clip) = shared_clip(T, tmp.path()) else { return };
    let ro = tmp.path().join("ro");
    std::fs::create_dir_all(&ro).unwrap();
    let bin = sh_quote(Path::new(env!("CARGO_BIN_EXE_facecap")));
    let is_root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
    let (rc, err) = if is_root {
        // root writes through 0555 folders: a read-only bind mount instead.
        let script = format!(
            "mount --bind {r} {r} && mount -o remount,bind,ro {r} {r} || exit 99; {bin} capture --quiet --out {r} {clip}",
            r = sh_quote(&ro),
            clip = sh_quote(&clip),
        );
        let Some(o) = in_mount_namespace(T, &script) else {
            return;
        };
        (o.status.code(), stderr(&o))
    } else {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let o = capture_cmd(&clip, &ro).output().unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
        (o.status.code(), stderr(&o))
    };
    eprintln!("read-only --out: rc {rc:?}, stderr: {err}");
    assert_ne!(rc, Some(99), "the read-only mount could not be made");
    assert_ne!(rc, Some(0), "a capture into a read-only folder reported success");
    assert!(
        err.contains("Read-only file system") || err.contains("Permission denied"),
        "unclear error: {err}"
    );
    assert!(
        err.contains(&ro.display().to_string()),
        "the error does not name the folder: {err}"
    );
    assert!(
        files(&ro).is_empty(),
        "written into a read-only folder: {:?}",
        files(&ro)
    );
    assert_eq!(std::fs::read_dir(&ro).unwrap().count(), 0);
}

#[test]
fn an_input_deleted_mid_run_completes_or_fails_clearly() {
    const T: &str = "an_input_deleted_mid_run_completes_or_fails_clearly";
    let tmp = tempfile::tempdir().unwrap();
    let Some(clip) = shared_clip(T, tmp.path()) else { return };
    let input = clip;
    let out = tmp.path().join("out");
    let dir = out.join("clip");
    let mut child = capture_cmd(&input, &out)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    assert!(
        wait_for(&mut child, || tracking(&dir)),
        "the capture never started tracking"
    );
    std::fs::remove_file(&input).unwrap();
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    eprintln!("input deleted mid-run: rc {:?}, stderr: {err}", o.status.code());
    assert_all_complete(&dir);
    if o.status.success() {
        // Completed from the file it had open: every frame, all decoded.
        let s: Value = serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap();
        assert_eq!(s["frames"], FRAMES, "{s}");
        assert_eq!(s["undecodable_frames"], 0, "{s}");
        let rows = std::fs::read_to_string(dir.join("landmarks.csv"))
            .unwrap()
            .lines()
            .count();
        assert_eq!(rows, FRAMES + 1);
    } else {
        assert!(err.contains("clip.mp4"), "the error does not name the input: {err}");
        assert!(!dir.join("summary.json").exists());
    }
}
