#!/usr/bin/env python3
"""Fixture for facecap's HOG face detector: what dlib's default frontal face detector
finds on the shared annotated images and on up to 13 frames (every 20th) of each shared video.

Run (only on purpose; the JSON is checked in):
    FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/dlib_hog/make_fixture.py

Inputs are decoded by ffmpeg to rgb24 (`ffmpeg -nostdin -i FILE -f rawvideo -pix_fmt
rgb24 -`, video frames with `-vf select='not(mod(n\\,20))' -fps_mode passthrough
-frames:v 13`), exactly as the Rust test does, then converted to grey with image-rs's
`to_luma8` rule  grey = (2126 R + 7152 G + 722 B) / 10000  (integer division), so dlib
and facecap see identical 8-bit grey pixels (the JSON stores a checksum of them).
dlib: dlib-bin 20.0.1 (`detector.run(grey, upsample, adjust_threshold)`), default
upsample 0 and threshold 0 for every input, plus upsample 1 for the small-face
dlib_faces images and threshold -0.5 on the video frames (more, weaker boxes to compare
scores on). Boxes are dlib's inclusive rectangles (left, top, right, bottom).
The data under shared/data is research-only / mixed licence (see its SOURCES.md); only
derived numbers are stored here.
"""
import json
import os
import subprocess
import sys

import dlib
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("FACECAP_DATA", os.path.join(HERE, "..", "..", "..", "shared", "data"))
OUT = os.path.join(HERE, "fixture.json")
VIDEO_STEP = 20
FRAMES_PER_VIDEO = 13
IMAGE_EXT = (".jpg", ".jpeg", ".png", ".ppm")


def probe(path):
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", path], check=True, capture_output=True, text=True).stdout
    w, h = out.strip().split("\n")[0].split(",")[:2]
    return int(w), int(h)


def decode_rgb(path, video=False):
    w, h = probe(path)
    cmd = ["ffmpeg", "-nostdin", "-loglevel", "error", "-i", path]
    if video:
        cmd += ["-vf", f"select=not(mod(n\\,{VIDEO_STEP}))", "-fps_mode", "passthrough",
                "-frames:v", str(FRAMES_PER_VIDEO)]
    cmd += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
    raw = subprocess.run(cmd, check=True, capture_output=True).stdout
    n = len(raw) // (w * h * 3)
    return np.frombuffer(raw, np.uint8)[: n * w * h * 3].reshape(n, h, w, 3)


def to_grey(rgb):
    r, g, b = (rgb[..., i].astype(np.uint32) for i in range(3))
    return ((2126 * r + 7152 * g + 722 * b) // 10000).astype(np.uint8)


def run(det, grey, upsample, adjust):
    rects, scores, idx = det.run(grey, upsample, adjust)
    return [{"ltrb": [r.left(), r.top(), r.right(), r.bottom()], "score": float(s), "detector": int(i)}
            for r, s, i in zip(rects, scores, idx)]


def synthetic(w, h):
    """Deterministic test pattern, the same formula as the Rust test."""
    y, x = np.mgrid[0:h, 0:w].astype(np.int64)
    return ((x * 7 + y * 13 + (x * y) % 31 + (x * x) % 17) % 256).astype(np.uint8)


def checksum(img):
    flat = img.astype(np.uint64).ravel()
    idx = np.arange(flat.size, dtype=np.uint64) % np.uint64(251) + np.uint64(1)
    return [int(flat.sum()), int((flat * idx).sum())]


def pyramid_checks():
    """dlib's pyramid_down<6> on synthetic images: size and checksums of 4 levels."""
    pyr = dlib.pyramid_down(6)
    out = []
    for w, h in [(640, 480), (101, 77), (37, 64), (333, 250)]:
        img = synthetic(w, h)
        levels = []
        for _ in range(4):
            img = np.ascontiguousarray(pyr(img))
            levels.append({"width": img.shape[1], "height": img.shape[0], "checksum": checksum(img)})
        out.append({"width": w, "height": h, "levels": levels})
    return out


def main():
    if os.path.exists(OUT) and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{OUT} exists; set FACECAP_REGENERATE=1 to rebuild it")
        return 0
    det = dlib.get_frontal_face_detector()
    cases = []
    ann = os.path.join(DATA, "annotated")
    for root, _, files in sorted(os.walk(ann)):
        for f in sorted(files):
            if not f.lower().endswith(IMAGE_EXT):
                continue
            path = os.path.join(root, f)
            rel = os.path.relpath(path, DATA)
            grey = to_grey(decode_rgb(path)[0])
            grey = np.ascontiguousarray(grey)
            runs = [{"upsample": 0, "adjust_threshold": 0.0, "dets": run(det, grey, 0, 0.0)}]
            if "dlib_faces" in rel:
                runs.append({"upsample": 1, "adjust_threshold": 0.0, "dets": run(det, grey, 1, 0.0)})
            cases.append({"source": rel, "frame": None, "width": grey.shape[1], "height": grey.shape[0],
                          "grey_sum": int(grey.astype(np.uint64).sum()), "runs": runs})
            print(rel, grey.shape, [len(r["dets"]) for r in runs])
    vids = os.path.join(DATA, "videos")
    for f in sorted(os.listdir(vids)):
        if not f.endswith(".mp4"):
            continue
        path = os.path.join(vids, f)
        rel = os.path.relpath(path, DATA)
        frames = decode_rgb(path, video=True)
        for k, rgb in enumerate(frames):
            grey = np.ascontiguousarray(to_grey(rgb))
            runs = [{"upsample": 0, "adjust_threshold": 0.0, "dets": run(det, grey, 0, 0.0)},
                    {"upsample": 0, "adjust_threshold": -0.5, "dets": run(det, grey, 0, -0.5)}]
            cases.append({"source": rel, "frame": k * VIDEO_STEP, "width": grey.shape[1], "height": grey.shape[0],
                          "grey_sum": int(grey.astype(np.uint64).sum()), "runs": runs})
        print(rel, len(frames), "frames")
    fixture = {
        "generator": "testdata/dlib_hog/make_fixture.py",
        "dlib": dlib.__version__,
        "grey": "(2126 R + 7152 G + 722 B) / 10000 of ffmpeg rgb24",
        "video_select": f"not(mod(n,{VIDEO_STEP})), first {FRAMES_PER_VIDEO}",
        "pyramid_down6": pyramid_checks(),
        "cases": cases,
    }
    with open(OUT, "w") as fo:
        json.dump(fixture, fo, indent=1)
    print("wrote", OUT, len(cases), "cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
