"""dlib per-frame landmarks (detection on every frame) for the tracker test.

Regenerate (only on purpose):
    FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/dlib_track/make_fixture.py

Every frame of every shared clip is decoded to 8-bit grey with the command the Rust
test uses (`ffmpeg -nostdin -v error -i CLIP -f rawvideo -pix_fmt gray -`); dlib 20
(dlib-bin) runs its HOG frontal face detector (upsample 0) and, on the largest box,
shape_predictor_68_face_landmarks.dat. Stored per frame: null when no face, else
the box [l, t, r, b] (dlib inclusive) and the 68 points as integers (dlib returns
whole pixels) flattened x0 y0 x1 y1 ... The shared videos are research-only data
(see shared/data/SOURCES.md); only derived coordinates are stored.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import dlib
import numpy as np

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("FACECAP_DATA", HERE.parents[1] / ".." / "shared" / "data")).resolve()
MODELS = Path(os.environ.get("FACECAP_MODELS", Path.home() / ".cache" / "facecap" / "models"))
CLIPS = ["liveportrait_d18.mp4", "liveportrait_d3.mp4", "liveportrait_d6.mp4", "liveportrait_d9.mp4",
         "sadtalker_WDA_KatieHill_000.mp4"]


def decode(path):
    w, h = [int(v) for v in subprocess.check_output(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", str(path)]).decode().strip().split(",")]
    raw = subprocess.check_output(["ffmpeg", "-nostdin", "-v", "error", "-i", str(path),
                                   "-f", "rawvideo", "-pix_fmt", "gray", "-"])
    return np.frombuffer(raw, np.uint8).reshape(-1, h, w)


def main():
    out_path = HERE / "fixture.json"
    if out_path.exists() and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{out_path} exists; set FACECAP_REGENERATE=1 to rebuild")
        return 0
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(MODELS / "shape_predictor_68_face_landmarks.dat"))
    clips = []
    for name in CLIPS:
        frames = decode(DATA / "videos" / name)
        per = []
        for g in frames:
            rects = det(g, 0)
            if not len(rects):
                per.append(None)
                continue
            r = max(rects, key=lambda r: r.area())
            s = sp(g, r)
            pts = []
            for i in range(68):
                pts += [s.part(i).x, s.part(i).y]
            per.append({"box": [r.left(), r.top(), r.right(), r.bottom()], "pts": pts})
        found = sum(p is not None for p in per)
        print(name, len(frames), "frames, face on", found)
        clips.append({"clip": "videos/" + name, "width": int(frames.shape[2]), "height": int(frames.shape[1]),
                      "frames": per})
    doc = {"generator": "testdata/dlib_track/make_fixture.py", "dlib": dlib.__version__,
           "decode": "ffmpeg -nostdin -v error -i CLIP -f rawvideo -pix_fmt gray -",
           "detector": "get_frontal_face_detector, upsample 0, largest box",
           "predictor": "shape_predictor_68_face_landmarks.dat", "clips": clips}
    out_path.write_text(json.dumps(doc, separators=(",", ":")))
    print("wrote", out_path, out_path.stat().st_size, "bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
