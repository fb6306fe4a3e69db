"""Fixture: dlib::find_min_bobyqa on 16-weight bounded blendshape fits (our problem).

Generates 12 problems of the anchor's recipe (shared/anchors/bench_bobyqa_fit.py) on a basis
made from the ICT FaceKit rig (MIT): 16 ARKit shapes, landmark deltas in a frontal orthographic
view at 25 px/cm (x, -y). w_true = clip(Dirichlet(0.5 * 1_16) * U(1, 2), 0, 1);
obs = neutral + w_true D + N(0, 1 px). Objective ||neutral + D^T w - obs||^2 + 1 * sum|w|.
dlib find_min_bobyqa (C++ driver shared/anchors/cpp/bobyqa_fit.cpp, Debian libdlib-dev), two
passes, npt 33, rho 0.075 -> 0.01, then 0.075 -> 0.005, cold start w = 0; plus the exact optimum
(scipy bvls on the shifted right-hand side, as in the anchor).

Writes bobyqa_dlib_fixture.json beside this script. Run only with FACECAP_REGENERATE=1:
  FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/solve/make_bobyqa_fixture.py
"""
import json
import os
import pathlib
import struct
import subprocess
import sys
import tempfile

import numpy as np
from scipy.optimize import lsq_linear

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DATA = ROOT.parent / "shared" / "data" / "models3d" / "ict_facekit"
ANCHORS = ROOT.parent / "shared" / "anchors"
SHAPES = ["browDown_L", "browInnerUp_L", "browOuterUp_L", "eyeBlink_L", "eyeBlink_R", "eyeWide_L",
          "jawOpen", "jawLeft", "mouthSmile_L", "mouthSmile_R", "mouthFunnel", "mouthPucker",
          "mouthStretch_L", "mouthUpperUp_L", "mouthLowerDown_R", "mouthFrown_L"]
P, K, LAMBDA, NPT = 12, 16, 1.0, 33
PX_PER_CM = 25.0


def ict_basis():
    meta = json.loads((DATA / "ict_face_deltas.json").read_text())
    names = meta["expression_deltas"]["names"]
    nv = 9409
    deltas = np.fromfile(DATA / "ict_face_expression_deltas_f32le.bin", dtype="<f4").reshape(len(names), nv, 3)
    verts = []
    with open(DATA / "generic_neutral_mesh.obj") as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
                if len(verts) == nv:
                    break
    verts = np.array(verts)
    lm = json.loads((DATA / "ict_landmarks68.json").read_text())["vertex_by_ibug_0based"]
    lm = np.array(lm)
    flip = np.array([1.0, -1.0])
    neutral = (verts[lm][:, :2] * flip * PX_PER_CM + np.array([256.0, 256.0])).reshape(-1)
    D = np.stack([(deltas[names.index(s)][lm][:, :2] * flip * PX_PER_CM).reshape(-1) for s in SHAPES])
    return neutral, D


def main():
    out_path = HERE / "bobyqa_dlib_fixture.json"
    if out_path.exists() and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{out_path.name} exists; set FACECAP_REGENERATE=1 to rebuild")
        return
    neutral, D = ict_basis()
    rng = np.random.default_rng(0)
    W = np.clip(rng.dirichlet(0.5 * np.ones(K), size=P) * rng.uniform(1, 2, size=(P, 1)), 0, 1)
    obs = neutral + W @ D + rng.normal(0, 1.0, size=(P, D.shape[1]))
    A, B = D.T, obs - neutral
    shift = (LAMBDA / 2) * A @ np.linalg.solve(A.T @ A, np.ones(K))
    w_opt = np.array([lsq_linear(A, b - shift, bounds=(0, 1), method="bvls").x for b in B])
    f_opt = [float(((A @ w - b) ** 2).sum() + LAMBDA * w.sum()) for w, b in zip(w_opt, B)]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        exe = tmp / "bobyqa_fit"
        subprocess.check_call(["g++", "-O3", "-DNDEBUG", "-DDLIB_NO_GUI_SUPPORT", "-std=c++17",
                               str(ANCHORS / "cpp" / "bobyqa_fit.cpp"), "-o", str(exe)])
        prob = tmp / "problem.bin"
        with open(prob, "wb") as f:
            f.write(struct.pack("<5i", P, D.shape[1], K, 1, 0))
            f.write(struct.pack("<4d", LAMBDA, 0.075, 0.01, 0.005))
            f.write(struct.pack("<2i", NPT, 30000))
            for arr in (neutral, D, obs, np.zeros((P, K))):
                f.write(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        text = subprocess.run([str(exe), str(prob)], capture_output=True, text=True, check=True).stdout
    rows = []
    for line in text.splitlines():
        if line.startswith("EVAL_NS"):
            continue
        v = line.split()
        rows.append({"evals": int(v[4]) + int(v[5]), "f": float(v[7]), "time_us": float(v[2]) + float(v[3]),
                     "w": [float(x) for x in v[10:10 + K]]})
    fixture = {
        "description": "dlib find_min_bobyqa (libdlib-dev, C++ -O3) on 12 blendshape fits; see make_bobyqa_fixture.py",
        "tool": "dlib find_min_bobyqa via shared/anchors/cpp/bobyqa_fit.cpp",
        "shapes": SHAPES, "lambda": LAMBDA, "npt": NPT, "rho_begin": 0.075, "rho_end": [0.01, 0.005],
        "neutral": neutral.round(6).tolist(), "deltas": D.round(6).tolist(),
        "problems": [{"obs": o.round(6).tolist(), "w_true": w.round(6).tolist(),
                      "exact_objective": fo, "dlib": r} for o, w, fo, r in zip(obs, W, f_opt, rows)],
    }
    out_path.write_text(json.dumps(fixture, indent=None, separators=(",", ":")))
    print(f"wrote {out_path} ({out_path.stat().st_size} bytes)")
    for p in fixture["problems"]:
        print(f"dlib f {p['dlib']['f']:.3f} exact {p['exact_objective']:.3f} evals {p['dlib']['evals']}")


if __name__ == "__main__":
    sys.exit(main())
