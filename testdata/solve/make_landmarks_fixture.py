"""Fixture: dlib 68-point landmarks on two shared clips, as facecap per-frame landmark CSVs.

dlib 20.0.1 (anchor venv): HOG frontal face detector (upsample 0) + shape_predictor_68_face_landmarks
on the first 120 frames of each clip, every 2nd frame (60 rows per clip), grey input, first face.
Coordinates are dlib's part() values (0-based pixel centres), rounded to 0.01 px.
Rows where no face is found have success = 0 and nan landmarks.

Clips (research-only, see shared/data/SOURCES.md): liveportrait_d3.mp4 (deliberate expressions),
liveportrait_d9.mp4 (talking, small head turns).

Run only with FACECAP_REGENERATE=1:
  FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/solve/make_landmarks_fixture.py
"""
import os
import pathlib
import sys

import cv2
import dlib

HERE = pathlib.Path(__file__).resolve().parent
VIDEOS = HERE.parents[1].parent / "shared" / "data" / "videos"
MODEL = pathlib.Path.home() / ".cache" / "facecap" / "models" / "shape_predictor_68_face_landmarks.dat"
CLIPS = ["liveportrait_d3", "liveportrait_d9"]
FRAMES, STEP = 120, 2


def main():
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(MODEL))
    for clip in CLIPS:
        out = HERE / f"landmarks_{clip}.csv"
        if out.exists() and os.environ.get("FACECAP_REGENERATE") != "1":
            print(f"{out.name} exists; set FACECAP_REGENERATE=1 to rebuild")
            continue
        cap = cv2.VideoCapture(str(VIDEOS / f"{clip}.mp4"))
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        header = ["frame", "timestamp", "success", "confidence"] + [f"x_{i}" for i in range(68)] + [f"y_{i}" for i in range(68)]
        lines = [",".join(header)]
        for i in range(FRAMES):
            ok, img = cap.read()
            if not ok:
                break
            if i % STEP:
                continue
            g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            rects = det(g, 0)
            ts = f"{i / fps:.6f}"
            if not rects:
                lines.append(",".join([str(i), ts, "0", "0"] + ["nan"] * 136))
                continue
            s = sp(g, rects[0])
            xs = [f"{s.part(k).x:.2f}" for k in range(68)]
            ys = [f"{s.part(k).y:.2f}" for k in range(68)]
            lines.append(",".join([str(i), ts, "1", "1"] + xs + ys))
        out.write_text("\n".join(lines) + "\n")
        print(f"wrote {out.name}: {len(lines) - 1} rows, {w}x{h} @ {fps} fps")


if __name__ == "__main__":
    sys.exit(main())
