"""MediaPipe FaceLandmarker iris centres and eyeLook* blendshape scores per frame, for the
gaze test (crates/facecap-landmarks/tests/gaze_mediapipe.rs).

Regenerate (only on purpose), in the anchors venv (mediapipe tasks API, model
face_landmarker.task; see ../shared/anchors/):
    FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/gaze/make_fixture.py
(`FACECAP_MP_MODEL` overrides the model path, `FACECAP_DATA` the shared data folder.)

Every frame of every shared clip is decoded to RGB by ffmpeg in presentation order (the
same frames, same order, as facecap's `open_source`), and FaceLandmarker runs in VIDEO
mode (timestamps i * 1000 / 30 ms), one face, blendshapes on. Per frame it stores:

* `rx, ry`: the iris centre of the subject's RIGHT eye (image left: the eye next to
  MediaPipe's landmarks 33 / 133), `lx, ly`: the subject's LEFT eye (image right, next to
  362 / 263), in image pixels, top-left pixel centre = (0, 0) (MediaPipe's normalised
  x * width - 0.5). Which of MediaPipe's iris centres (468 or 473) belongs to which eye is
  decided per frame by the distance to the eye-corner midpoints and written to the header.
* the eight `eyeLook{In,Out,Up,Down}{Left,Right}` scores (ARKit naming: Left = subject's
  left eye).

The shared videos are research-only data (see shared/data/SOURCES.md): only these derived
numbers are stored, never frames.
"""
import csv
import os
import subprocess
import sys
from pathlib import Path

import mediapipe as mp
import numpy as np
from mediapipe.tasks.python import BaseOptions, vision

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("FACECAP_DATA", HERE.parents[1] / ".." / "shared" / "data")).resolve()
MODEL = Path(os.environ.get("FACECAP_MP_MODEL", HERE.parents[1] / ".." / "shared" / "anchors" / "models" /
                            "face_landmarker.task"))
CLIPS = ["liveportrait_d18.mp4", "liveportrait_d3.mp4", "liveportrait_d6.mp4", "liveportrait_d9.mp4",
         "sadtalker_WDA_KatieHill_000.mp4"]
SHAPES = ["eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeLookDownLeft",
          "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight", "eyeLookDownRight"]


def frames(path):
    w, h = [int(v) for v in subprocess.check_output(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", str(path)]).decode().strip().split(",")]
    p = subprocess.Popen(["ffmpeg", "-nostdin", "-v", "error", "-i", str(path), "-f", "rawvideo",
                          "-pix_fmt", "rgb24", "-"], stdout=subprocess.PIPE)
    n = w * h * 3
    while True:
        b = p.stdout.read(n)
        if len(b) < n:
            break
        yield w, h, np.frombuffer(b, np.uint8).reshape(h, w, 3)
    p.wait()


def main():
    out_path = HERE / "mediapipe_iris.csv"
    if out_path.exists() and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{out_path} exists; set FACECAP_REGENERATE=1 to rebuild")
        return 0
    opts = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(MODEL)),
                                        running_mode=vision.RunningMode.VIDEO, num_faces=1,
                                        output_face_blendshapes=True)
    rows = []
    first_of_right = {}
    for name in CLIPS:
        lm = vision.FaceLandmarker.create_from_options(opts)
        clip = os.path.splitext(name)[0]
        n_face = 0
        for i, (w, h, f) in enumerate(frames(DATA / "videos" / name)):
            r = lm.detect_for_video(mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(f)),
                                    int(i * 1000 / 30))
            if not r.face_landmarks or not r.face_blendshapes:
                rows.append([clip, i, 0] + [""] * (4 + len(SHAPES)))
                continue
            n_face += 1
            pts = r.face_landmarks[0]
            px = lambda k: np.array([pts[k].x * w - 0.5, pts[k].y * h - 0.5])
            right_mid = 0.5 * (px(33) + px(133))
            left_mid = 0.5 * (px(362) + px(263))
            a, b = px(468), px(473)
            if np.linalg.norm(a - right_mid) + np.linalg.norm(b - left_mid) <= \
                    np.linalg.norm(b - right_mid) + np.linalg.norm(a - left_mid):
                right, left, right_idx = a, b, 468
            else:
                right, left, right_idx = b, a, 473
            first_of_right[right_idx] = first_of_right.get(right_idx, 0) + 1
            scores = {c.category_name: c.score for c in r.face_blendshapes[0]}
            rows.append([clip, i, 1, f"{right[0]:.2f}", f"{right[1]:.2f}", f"{left[0]:.2f}", f"{left[1]:.2f}"]
                        + [f"{scores[s]:.4f}" for s in SHAPES])
        lm.close()
        print(clip, i + 1, "frames,", n_face, "with a face", file=sys.stderr)
    with open(out_path, "w", newline="") as fh:
        fh.write(f"# MediaPipe FaceLandmarker {mp.__version__} (face_landmarker.task); made by make_fixture.py; "
                 f"subject's right iris = landmark {'/'.join(str(k) for k in sorted(first_of_right))} "
                 f"on {first_of_right} frames\n")
        wr = csv.writer(fh)
        wr.writerow(["clip", "frame", "face", "rx", "ry", "lx", "ly"] + SHAPES)
        wr.writerows(rows)
    print(out_path, len(rows), "rows", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
