#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The capture report in a real browser: `facecap synth` makes a short clip,
//! `facecap capture` writes `report.html` with `preview.mp4`, and headless Chromium
//! (Debian's `chromium`, installed by scripts/setup.sh) loads it: no console messages,
//! every image loads, the video element plays and its duration is the clip's; a
//! screenshot of the page is saved (its path is printed). Prints `SKIP:` without
//! Chromium, ffmpeg or the model cache. Takes 12 s on a quiet 2-core machine, 75 s under
//! heavy load (each browser run is stopped after 120 s).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Frames and rate of the test clip: 1.2 s.
const FRAMES: u32 = 30;
const FPS: f64 = 25.0;
/// Longest a browser run may take.
const BROWSER_TIMEOUT: Duration = Duration::from_secs(120);

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn find_in_path(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .find(|p| p.is_file())
}

fn cache() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_CACHE") {
        return Some(p.into());
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache").join("facecap"))
}

fn models_present() -> bool {
    let Some(c) = cache() else { return false };
    let models = std::env::var_os("FACECAP_MODELS").map_or(c.join("models"), PathBuf::from);
    models.join("shape_predictor_68_face_landmarks.dat").is_file()
        && models.join("dlib_frontal_face_detector.svm").is_file()
}

/// Runs Chromium headless with `args` on `url`; returns (stdout, stderr).
fn chromium(browser: &Path, profile: &Path, args: &[&str], url: &str) -> (String, String) {
    let mut child = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--hide-scrollbars",
            "--mute-audio",
            "--autoplay-policy=no-user-gesture-required",
            "--enable-logging=stderr",
            "--v=0",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(url)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let so = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut out, &mut s);
        s
    });
    let se = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut err, &mut s);
        s
    });
    let t = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t.elapsed() > BROWSER_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("chromium did not finish within {} s", BROWSER_TIMEOUT.as_secs());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    (so.join().unwrap(), se.join().unwrap())
}

/// A page that loads the report in a frame and writes what it found into `#out`:
/// images that failed, the video's duration, and whether it played.
const CHECK_PAGE: &str = r#"<!DOCTYPE html><html><head><meta charset="utf-8"><link rel="icon" href="data:,"></head>
<body><pre id="out">pending</pre><iframe id="f" src="report.html" width="1400" height="900"></iframe><script>
const out = document.getElementById('out'), f = document.getElementById('f'), res = {errors: []};
const done = () => { out.textContent = 'RESULT ' + JSON.stringify(res); };
f.addEventListener('load', () => {
  const d = f.contentDocument;
  if (!d) { res.errors.push('cannot read the report'); return done(); }
  res.images = [...d.images].map(i => ({src: i.getAttribute('src'), ok: i.complete && i.naturalWidth > 0}));
  const v = d.querySelector('video');
  if (!v) { res.video = false; return done(); }
  res.video = true;
  v.addEventListener('error', () => { res.errors.push('video error ' + (v.error && v.error.code)); done(); });
  const go = () => {
    res.duration = v.duration;
    v.play().then(() => setTimeout(() => { res.currentTime = v.currentTime; res.paused = v.paused; done(); }, 600))
            .catch(e => { res.errors.push('play: ' + e); done(); });
  };
  if (v.readyState >= 1) go(); else v.addEventListener('loadedmetadata', go);
});
</script></body></html>
"#;

#[test]
fn report_loads_and_its_video_plays_in_headless_chromium() {
    const T: &str = "report_loads_and_its_video_plays_in_headless_chromium";
    let Some(browser) = find_in_path(&["chromium", "chromium-browser"]) else {
        facecap_core::paths::skip(&format!(
            "{T}: chromium not installed (Debian: apt-get install chromium; scripts/setup.sh does)"
        ));
        return;
    };
    let photo = ["data/astronaut.png", "astronaut.png"]
        .iter()
        .filter_map(|r| cache().map(|c| c.join(r)))
        .find(|p| p.is_file());
    let (Some(photo), true) = (photo, models_present()) else {
        facecap_core::paths::skip_missing_data(&format!(
            "{T}: astronaut.png or the dlib models not in the cache (run scripts/setup.sh)"
        ));
        return;
    };
    if facecap_io::video::ffmpeg::locate_ffmpeg(None).is_err() {
        facecap_core::paths::skip(&format!("{T}: no ffmpeg"));
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let synth = dir.path().join("synth");
    let st = facecap()
        .args([
            "synth",
            "--frames",
            &FRAMES.to_string(),
            "--fps",
            &FPS.to_string(),
            "--out",
        ])
        .arg(&synth)
        .arg("--photo")
        .arg(&photo)
        .status()
        .unwrap();
    assert!(st.success());
    let out = dir.path().join("cap");
    let st = facecap()
        .args(["capture", "--quiet", "--out"])
        .arg(&out)
        .arg(synth.join("synth.y4m"))
        .status()
        .unwrap();
    assert!(st.success());
    let cap = out.join("synth");
    assert!(cap.join("preview.mp4").is_file() && cap.join("report.html").is_file());
    let html = std::fs::read_to_string(cap.join("report.html")).unwrap();
    assert!(html.contains("<video") && html.contains("preview.mp4"));
    let profile = dir.path().join("chromium-profile");

    // 1. The page itself: a screenshot, and no console message at all.
    let shot = cap.join("report_screenshot.png");
    let (_, stderr) = chromium(
        &browser,
        &profile,
        &[
            "--window-size=1400,2400",
            &format!("--screenshot={}", shot.display()),
            "--virtual-time-budget=5000",
        ],
        &format!("file://{}", cap.join("report.html").display()),
    );
    let console: Vec<&str> = stderr.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:#?}");
    let img = image::open(&shot)
        .unwrap_or_else(|e| panic!("no screenshot at {}: {e}\n{stderr}", shot.display()))
        .to_rgb8();
    assert_eq!(img.width(), 1400);
    let colours: std::collections::HashSet<[u8; 3]> = img.pixels().step_by(7).map(|p| p.0).collect();
    assert!(
        colours.len() > 500,
        "the screenshot looks blank ({} colours)",
        colours.len()
    );
    if let Some(d) = std::env::var_os("FACECAP_DEBUG_DIR") {
        std::fs::copy(&shot, Path::new(&d).join("report_screenshot.png")).unwrap();
    }
    println!("screenshot: {}", shot.display());

    // 2. Images load, the video plays and lasts as long as the clip.
    std::fs::write(cap.join("check.html"), CHECK_PAGE).unwrap();
    let (dom, stderr) = chromium(
        &browser,
        &profile,
        &[
            "--allow-file-access-from-files",
            "--virtual-time-budget=15000",
            "--dump-dom",
        ],
        &format!("file://{}", cap.join("check.html").display()),
    );
    let start = dom
        .find("<pre id=\"out\">RESULT ")
        .unwrap_or_else(|| panic!("the check page did not finish:\n{dom}\n{stderr}"));
    let rest = &dom[start + "<pre id=\"out\">RESULT ".len()..];
    let json = &rest[..rest.find("</pre>").unwrap()];
    let res: serde_json::Value = serde_json::from_str(json).unwrap();
    assert_eq!(res["errors"].as_array().map(Vec::len), Some(0), "{res}");
    let images = res["images"].as_array().unwrap();
    assert!(images.len() >= 5, "{res}");
    assert!(
        images.iter().all(|i| i["ok"] == true),
        "images that did not load: {res}"
    );
    let duration = res["duration"].as_f64().unwrap();
    let clip = f64::from(FRAMES) / FPS;
    assert!(
        (duration - clip).abs() <= 0.5 / FPS + 1e-3,
        "video lasts {duration} s, the clip {clip} s"
    );
    assert!(
        res["currentTime"].as_f64().unwrap() > 0.0 && res["paused"] == false,
        "{res}"
    );
}
