"""MediaPipe FaceLandmarker's 478 landmarks on frames of the shared clips, for the
end-to-end agreement test of crates/facecap-mesh (tests/landmarker_agreement.rs).

Regenerate on purpose only, with mediapipe (tasks API) in a venv:

    FACECAP_REGENERATE=1 ../shared/anchors/.venv/bin/python testdata/mesh/make_landmarker_fixture.py

`frames`: IMAGE mode (every frame detected afresh, no smoothing). `videos`: VIDEO mode
over the first frames of a clip at timestamps `i * 33` ms (tracking from the previous
frame's landmarks and one-euro smoothing), landmarks stored for every STEP-th frame.
Model `face_landmarker.task`
from the model cache's source package (scripts/setup.sh keeps its members; this script
rebuilds the bundle path from $FACECAP_TASK, default ../shared/anchors/models/).
Frames are decoded to rgb24 by the `ffmpeg` on PATH (the test runs the same command).
Stored: per frame the landmarks in pixels (normalised x * width, y * height), rounded to
1/100 px; z is not stored.
"""
import json
import os
import pathlib
import subprocess
import sys

import mediapipe as mp
import numpy as np
from mediapipe.tasks.python import BaseOptions, vision

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent.parent
DATA = pathlib.Path(os.environ.get("FACECAP_DATA", ROOT.parent / "shared/data"))
TASK = pathlib.Path(os.environ.get("FACECAP_TASK", ROOT.parent / "shared/anchors/models/face_landmarker.task"))
# (clip, frame indices)
CLIPS = [
    ("videos/liveportrait_d9.mp4", [0, 40, 80]),
    ("videos/liveportrait_d18.mp4", [10, 60]),
    ("videos/liveportrait_d3.mp4", [25]),
    ("videos/sadtalker_WDA_KatieHill_000.mp4", [10, 50]),
]

VIDEO_CLIPS = [("videos/liveportrait_d9.mp4", 60), ("videos/sadtalker_WDA_KatieHill_000.mp4", 60)]
STEP = 20
FRAME_MS = 33


def frames(clip, wanted):
    path = DATA / clip
    w, h = map(int, subprocess.check_output(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", str(path)], text=True).strip().split(","))
    raw = subprocess.check_output(
        ["ffmpeg", "-nostdin", "-hide_banner", "-loglevel", "error", "-i", str(path), "-map", "0:V:0",
         "-frames:v", str(max(wanted) + 1), "-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
    size = w * h * 3
    for i in wanted:
        yield i, w, h, np.frombuffer(raw[i * size:(i + 1) * size], np.uint8).reshape(h, w, 3)


def main():
    if os.environ.get("FACECAP_REGENERATE") != "1":
        sys.exit("refusing to overwrite fixtures: set FACECAP_REGENERATE=1")
    lm = vision.FaceLandmarker.create_from_options(vision.FaceLandmarkerOptions(
        base_options=BaseOptions(model_asset_path=str(TASK)), running_mode=vision.RunningMode.IMAGE,
        num_faces=1))
    out = []
    for clip, wanted in CLIPS:
        for i, w, h, img in frames(clip, wanted):
            r = lm.detect(mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(img)))
            pts = None
            if r.face_landmarks:
                pts = [[round(p.x * w, 2), round(p.y * h, 2)] for p in r.face_landmarks[0]]
            out.append({"clip": clip, "frame": i, "width": w, "height": h, "points": pts})
            print(clip, i, "face" if pts else "none", pts[1] if pts else "")
    videos = []
    for clip, n in VIDEO_CLIPS:
        vlm = vision.FaceLandmarker.create_from_options(vision.FaceLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(TASK)), running_mode=vision.RunningMode.VIDEO,
            num_faces=1))
        stored = []
        for i, w, h, img in frames(clip, list(range(n))):
            r = vlm.detect_for_video(mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(img)),
                                     i * FRAME_MS)
            if i % STEP == 0 or i == n - 1:
                pts = [[round(p.x * w, 2), round(p.y * h, 2)] for p in r.face_landmarks[0]] if r.face_landmarks else None
                stored.append({"frame": i, "points": pts})
        videos.append({"clip": clip, "frames": n, "frame_ms": FRAME_MS, "width": w, "height": h, "stored": stored})
        vlm.close()
        print(clip, "video mode", n, "frames")
    json.dump({"tool": f"mediapipe {mp.__version__} FaceLandmarker (IMAGE and VIDEO modes)", "frames": out,
               "videos": videos},
              open(HERE / "landmarker_mediapipe.json", "w"), separators=(",", ":"))


if __name__ == "__main__":
    main()
