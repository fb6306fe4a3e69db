"""OpenCV calcOpticalFlowPyrLK fixture for facecap's pyramidal LK.

Regenerate (only on purpose):
    FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/opencv_lk/make_fixture.py

For each clip, frames are decoded to 8-bit grey with exactly the command the Rust
test uses (`ffmpeg -nostdin -v error -i CLIP -frames:v N -f rawvideo -pix_fmt gray -`),
so both sides see identical pixels (a per-frame byte sum is stored to check that).
For ~10 frame pairs (t, t+1) per clip the input points are dlib's 68 landmarks on
frame t (HOG detector, upsample 0, + shape_predictor_68_face_landmarks.dat) and 200
cv2.goodFeaturesToTrack corners (quality 0.01, min distance 5); OpenCV 4.14 tracks
them with winSize (21, 21), maxLevel 3, criteria (COUNT|EPS, 30, 0.01),
minEigThreshold 1e-4, one thread. Stored: input points (exact float32 values),
OpenCV's output points (rounded to 1e-4 px), status and err (1e-4).
The shared videos are research-only data (see shared/data/SOURCES.md); only
derived point coordinates are stored here.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import dlib
import numpy as np

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("FACECAP_DATA", HERE.parents[1] / ".." / "shared" / "data")).resolve()
MODELS = Path(os.environ.get("FACECAP_MODELS", Path.home() / ".cache" / "facecap" / "models"))
CLIPS = ["videos/liveportrait_d18.mp4", "videos/liveportrait_d9.mp4"]
PAIR_STARTS = list(range(0, 100, 10))
N_FRAMES = max(PAIR_STARTS) + 2
WIN, LEVEL = (21, 21), 3
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


def decode(path, n):
    w, h = [int(v) for v in subprocess.check_output(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", str(path)]).decode().strip().split(",")]
    raw = subprocess.check_output(["ffmpeg", "-nostdin", "-v", "error", "-i", str(path), "-frames:v", str(n),
                                   "-f", "rawvideo", "-pix_fmt", "gray", "-"])
    frames = np.frombuffer(raw, np.uint8).reshape(-1, h, w)
    return frames


def main():
    out_path = HERE / "fixture.json"
    if out_path.exists() and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{out_path} exists; set FACECAP_REGENERATE=1 to rebuild")
        return 0
    cv2.setNumThreads(1)
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(MODELS / "shape_predictor_68_face_landmarks.dat"))
    clips = []
    for rel in CLIPS:
        frames = decode(DATA / rel, N_FRAMES)
        pairs = []
        for t in PAIR_STARTS:
            a, b = frames[t], frames[t + 1]
            rects = det(a, 0)
            pts = []
            if len(rects):
                r = max(rects, key=lambda r: r.area())
                s = sp(a, r)
                pts += [[float(s.part(i).x), float(s.part(i).y)] for i in range(68)]
            corners = cv2.goodFeaturesToTrack(a, maxCorners=200, qualityLevel=0.01, minDistance=5)
            pts += corners.reshape(-1, 2).astype(np.float32).tolist()
            p = np.array(pts, np.float32).reshape(-1, 1, 2)
            q, st, err = cv2.calcOpticalFlowPyrLK(a, b, p, None, winSize=WIN, maxLevel=LEVEL, criteria=CRIT,
                                                  minEigThreshold=1e-4)
            pairs.append({
                "frame": t,
                "n_landmarks": 68 if len(rects) else 0,
                "byte_sum_prev": int(a.sum(dtype=np.uint64)),
                "byte_sum_next": int(b.sum(dtype=np.uint64)),
                "prev": [[float(x), float(y)] for x, y in p.reshape(-1, 2)],
                "next": [[round(float(x), 4), round(float(y), 4)] for x, y in q.reshape(-1, 2)],
                "status": [int(s) for s in st.ravel()],
                "err": [round(float(e), 4) for e in err.ravel()],
            })
            print(rel, t, "points", len(pts), "tracked", int(st.sum()))
        clips.append({"clip": rel, "width": int(frames.shape[2]), "height": int(frames.shape[1]), "pairs": pairs})
    doc = {
        "generator": "testdata/opencv_lk/make_fixture.py",
        "opencv": cv2.__version__,
        "dlib": dlib.__version__,
        "decode": "ffmpeg -nostdin -v error -i CLIP -frames:v N -f rawvideo -pix_fmt gray -",
        "n_frames_decoded": N_FRAMES,
        "win": 21, "max_level": LEVEL, "criteria": "COUNT|EPS 30 0.01", "min_eig_threshold": 1e-4,
        "clips": clips,
    }
    out_path.write_text(json.dumps(doc, separators=(",", ":")))
    print("wrote", out_path, out_path.stat().st_size, "bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
