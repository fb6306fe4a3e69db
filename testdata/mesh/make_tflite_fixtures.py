"""Raw outputs of MediaPipe's face models under Google's TFLite runtime, for the
agreement tests of crates/facecap-mesh (tests/tflite_agreement.rs).

Regenerate on purpose only:

    python3 -m venv /tmp/litert && /tmp/litert/bin/pip install ai-edge-litert==2.3.0 numpy
    FACECAP_REGENERATE=1 /tmp/litert/bin/python testdata/mesh/make_tflite_fixtures.py

Inputs are made deterministically, so the Rust test rebuilds the same tensors:

* `pattern`: an integer formula image, `v = (3x + 5y + 50c + (x*y) // 37) % 256`;
* `clip`: frame N of a shared clip, decoded to rgb24 by the `ffmpeg` on PATH
  (`-map 0:V:0 -f rawvideo -pix_fmt rgb24`, the test runs the same command), then a square crop
  `[x0, x0 + size) x [y0, y0 + size)` resampled to the model size by nearest neighbour,
  source index `x0 + (2 i + 1) * size // (2 * n)`.

u8 values become floats as MediaPipe feeds them: `v / 255` for the landmark model
(range [0, 1]), `v / 127.5 - 1` for the detector (range [-1, 1]), in float32. The sha256
of each u8 input is stored so the test can tell a different decoder from a real
disagreement. No frame is stored, only model outputs.

Models: $FACECAP_MODELS or ~/.cache/facecap/models (scripts/setup.sh). Shared clips:
$FACECAP_DATA or ../shared/data next to the repository.
"""
import hashlib
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
from ai_edge_litert.interpreter import Interpreter, OpResolverType

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent.parent
MODELS = pathlib.Path(os.environ.get("FACECAP_MODELS", pathlib.Path.home() / ".cache/facecap/models"))
DATA = pathlib.Path(os.environ.get("FACECAP_DATA", ROOT.parent / "shared/data"))

# (clip, frame index, x0, y0, crop size); the 480x480 LivePortrait clips hold one
# centred face, the SadTalker clip is 512x512.
LANDMARK_CLIPS = [
    ("videos/liveportrait_d9.mp4", 0, 100, 90, 280),
    ("videos/liveportrait_d18.mp4", 30, 90, 80, 300),
    ("videos/sadtalker_WDA_KatieHill_000.mp4", 10, 100, 90, 340),
]
DETECTOR_CLIPS = [
    ("videos/liveportrait_d9.mp4", 0, 0, 0, 480),
    ("videos/liveportrait_d6.mp4", 12, 0, 0, 480),
    ("videos/sadtalker_WDA_KatieHill_000.mp4", 10, 0, 0, 512),
]
# Detector regressors are stored for the anchors with the highest scores only.
TOP_ANCHORS = 12


def pattern(n):
    y, x, c = np.meshgrid(np.arange(n), np.arange(n), np.arange(3), indexing="ij")
    return ((3 * x + 5 * y + 50 * c + (x * y) // 37) % 256).astype(np.uint8)


def frame(clip, index):
    path = DATA / clip
    probe = subprocess.check_output(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries", "stream=width,height",
         "-of", "csv=p=0", str(path)], text=True).strip().split(",")
    w, h = int(probe[0]), int(probe[1])
    raw = subprocess.check_output(
        ["ffmpeg", "-nostdin", "-hide_banner", "-loglevel", "error", "-i", str(path), "-map", "0:V:0",
         "-frames:v", str(index + 1), "-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
    size = w * h * 3
    return np.frombuffer(raw[index * size:(index + 1) * size], np.uint8).reshape(h, w, 3)


def crop_nearest(img, x0, y0, size, n):
    idx = np.array([(2 * i + 1) * size // (2 * n) for i in range(n)])
    return img[y0 + idx][:, x0 + idx]


def run(model, x, reference):
    kind = OpResolverType.BUILTIN_REF if reference else OpResolverType.AUTO
    it = Interpreter(model_path=str(model), experimental_op_resolver_type=kind)
    it.allocate_tensors()
    it.set_tensor(it.get_input_details()[0]["index"], x[None])
    it.invoke()
    return [it.get_tensor(d["index"]).reshape(-1).astype(np.float64) for d in it.get_output_details()]


def r(v, digits=6):
    return [float(f"{a:.{digits}g}") for a in v]


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main():
    if os.environ.get("FACECAP_REGENERATE") != "1":
        sys.exit("refusing to overwrite fixtures: set FACECAP_REGENERATE=1")
    lm_model = MODELS / "face_landmarks_detector.tflite"
    det_model = MODELS / "face_detector.tflite"

    cases = [("pattern", None, pattern(256))]
    for clip, i, x0, y0, s in LANDMARK_CLIPS:
        cases.append((f"{pathlib.Path(clip).stem}#{i}", [clip, i, x0, y0, s], crop_nearest(frame(clip, i), x0, y0, s, 256)))
    out = []
    for name, source, img in cases:
        x = img.astype(np.float32) / np.float32(255.0)
        o = run(lm_model, x, reference=False)
        ref = run(lm_model, x, reference=True)
        out.append({
            "name": name,
            "source": source,
            "input_sha256": hashlib.sha256(img.tobytes()).hexdigest(),
            "landmarks": r(o[0]),
            "face_flag": r(o[1]),
            "score": r(o[2]),
            "max_abs_diff_xnnpack_vs_reference": float(max(np.abs(a - b).max() for a, b in zip(o, ref))),
        })
        print(name, "landmarks[0:3]", o[0][:3], "flag", o[1], "score", o[2])
    json.dump({"model": lm_model.name, "model_sha256": sha(lm_model), "input": [256, 256, 3], "range": [0, 1],
               "runtime": "ai-edge-litert (TFLite, XNNPACK)", "cases": out},
              open(HERE / "landmarks_tflite.json", "w"), indent=None, separators=(",", ":"))

    cases = [("pattern", None, pattern(128))]
    for clip, i, x0, y0, s in DETECTOR_CLIPS:
        cases.append((f"{pathlib.Path(clip).stem}#{i}", [clip, i, x0, y0, s], crop_nearest(frame(clip, i), x0, y0, s, 128)))
    out = []
    for name, source, img in cases:
        x = img.astype(np.float32) / np.float32(127.5) - np.float32(1.0)
        o = run(det_model, x, reference=False)
        ref = run(det_model, x, reference=True)
        reg, cls = o[0].reshape(896, 16), o[1]
        top = np.argsort(-cls)[:TOP_ANCHORS]
        out.append({
            "name": name,
            "source": source,
            "input_sha256": hashlib.sha256(img.tobytes()).hexdigest(),
            "scores": r(cls),
            "top": [{"anchor": int(a), "regressors": r(reg[a])} for a in top],
            "regressors_abs_sum": float(np.abs(reg).sum()),
            "max_abs_diff_xnnpack_vs_reference": float(max(np.abs(a - b).max() for a, b in zip(o, ref))),
        })
        print(name, "best anchor", top[0], "logit", cls[top[0]])
    json.dump({"model": det_model.name, "model_sha256": sha(det_model), "input": [128, 128, 3], "range": [-1, 1],
               "runtime": "ai-edge-litert (TFLite, XNNPACK)", "cases": out},
              open(HERE / "detector_tflite.json", "w"), indent=None, separators=(",", ":"))


if __name__ == "__main__":
    main()
