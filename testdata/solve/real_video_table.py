"""Real-video evidence table of docs/solvers.md: every shared clip, landmarks from our tracker,
every solver method through the CLI.

For each clip in shared/data/videos: `facecap landmarks VIDEO --out WORK/CLIP` (skipped when
WORK/CLIP/landmarks.csv exists), then `facecap solve` with each method on the ICT FaceKit
ARKit-53 rig, once on the 16-shape subset (all five methods) and once with all 53 shapes (every
method but BOBYQA, which needs ~0.3 s per 53-shape frame), each with `--temporal 0` and
`--temporal 200`. Reports the mean landmark reprojection error (the CLI's summary line), the
CLI's median solve time per frame, and the weight jitter on the clip's stillest 30-frame stretch
(the window with the least landmark motion): the mean over consecutive frame pairs of the RMS
weight change.

Plain python3 (stdlib only); nothing is written to the repo. Usage:
  python3 testdata/solve/real_video_table.py FACECAP_BINARY WORK_DIR > table.md
"""
import csv
import json
import math
import pathlib
import re
import subprocess
import sys

HERE = pathlib.Path(__file__).resolve().parent
SHARED = HERE.parents[1].parent / "shared" / "data"
RIG = SHARED / "models3d" / "ict_facekit" / "ict_face_arkit53.glb"
MAP = SHARED / "models3d" / "ict_facekit" / "ict_landmarks68.json"
SUBSET16 = ["browDown_L", "browInnerUp_L", "browOuterUp_L", "eyeBlink_L", "eyeBlink_R", "eyeWide_L",
            "jawOpen", "jawLeft", "mouthSmile_L", "mouthSmile_R", "mouthFunnel", "mouthPucker",
            "mouthStretch_L", "mouthUpperUp_L", "mouthLowerDown_R", "mouthFrown_L"]
METHODS = ["bobyqa", "region", "pca", "exact", "exact3d"]
STILL = 30
MU = 200.0


def frame_size(video):
    out = subprocess.run(["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries",
                          "stream=width,height", "-of", "json", str(video)],
                         capture_output=True, text=True, check=True).stdout
    s = json.loads(out)["streams"][0]
    return int(s["width"]), int(s["height"])


def read_landmarks(path):
    rows = []
    with open(path) as f:
        for r in csv.DictReader(f):
            if r["success"] != "1":
                rows.append(None)
                continue
            rows.append([(float(r[f"x_{i}"]), float(r[f"y_{i}"])) for i in range(68)])
    return rows


def still_stretch(lms, length):
    best = (math.inf, 0)
    for s in range(0, len(lms) - length):
        win = lms[s:s + length]
        if any(w is None for w in win):
            continue
        m = sum(math.dist(p, q) for a, b in zip(win, win[1:]) for p, q in zip(a, b))
        best = min(best, (m, s))
    return best[1]


def read_weights(path):
    with open(path) as f:
        rd = csv.reader(f)
        next(rd)
        return [[float(v) for v in row[2:]] for row in rd]


def jitter(ws):
    d = [math.sqrt(sum((a - b) ** 2 for a, b in zip(u, v)) / len(u)) for u, v in zip(ws, ws[1:])]
    return sum(d) / len(d)


def solve(exe, lm_csv, out, w, h, method, shapes, mu):
    cmd = [exe, "solve", str(lm_csv), "--rig", str(RIG), "--landmark-map", str(MAP), "--width", str(w),
           "--height", str(h), "--method", method, "--temporal", str(mu), "--out", str(out)]
    if shapes:
        cmd += ["--shapes", ",".join(shapes)]
    p = subprocess.run(cmd, capture_output=True, text=True, check=True)
    m = re.search(r"mean landmark error ([0-9.]+) px, median solve time ([0-9.]+) us/frame", p.stderr)
    return float(m.group(1)), float(m.group(2))


def main():
    exe, work = sys.argv[1], pathlib.Path(sys.argv[2])
    print("| clip (frames, still stretch) | shapes | method | mean reprojection error (px), mu = 0 | "
          f"error, mu = {MU:g} | median time/frame (us), mu = 0 | jitter, mu = 0 | jitter, mu = {MU:g} |")
    print("|---|---|---|---|---|---|---|---|")
    for video in sorted((SHARED / "videos").glob("*.mp4")):
        clip = video.stem
        d = work / clip
        lm_csv = d / "landmarks.csv"
        if not lm_csv.exists():
            d.mkdir(parents=True, exist_ok=True)
            subprocess.run([exe, "landmarks", str(video), "--out", str(d)], check=True,
                           capture_output=True)
        w, h = frame_size(video)
        lms = read_landmarks(lm_csv)
        s0 = still_stretch(lms, STILL)
        for shapes, label in ((SUBSET16, "16"), (None, "53")):
            for method in METHODS:
                if method == "bobyqa" and shapes is None:
                    continue
                res = {}
                for mu in (0.0, MU):
                    out = d / f"{method}_{label}_mu{mu:g}"
                    err, t = solve(exe, lm_csv, out, w, h, method, shapes, mu)
                    ws = read_weights(out / "weights.csv")
                    res[mu] = (err, t, jitter(ws[s0:s0 + STILL]))
                print(f"| {clip} ({len(lms)}, rows {s0}-{s0 + STILL - 1}) | {label} | {method} | "
                      f"{res[0.0][0]:.2f} | {res[MU][0]:.2f} | {res[0.0][1]:.0f} | "
                      f"{res[0.0][2]:.4f} | {res[MU][2]:.4f} |", flush=True)


if __name__ == "__main__":
    main()
