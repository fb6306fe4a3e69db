"""OpenCV calcOpticalFlowPyrLK timing on exactly the inputs of
crates/facecap-landmarks/benches/lk.rs (same sitting comparison).

Frames: the first 40 frames of shared/data/videos/liveportrait_d9.mp4, decoded by
ffmpeg with `-vf pad=640:480:64:0,format=gray` (the bench's command). Points: the
first N points of the 2-D Halton sequence (bases 2, 3) mapped to x in [150, 490),
y in [80, 420) (the bench's `points(n)`). Per timed call: one consecutive frame pair
(k-1, k), k cycling over the 40 frames like the bench's `push_frame_and_track_*`;
winSize 21x21, maxLevel 3, criteria COUNT|EPS 30 / 0.01, one thread. OpenCV builds
both pyramids (and the Scharr derivatives of the previous one) inside every call.

Usage: /work/shared/anchors/.venv/bin/python bench_cv_lk_same_inputs.py [--reps 2000]
Prints median / p25 / p75 wall time and the median thread CPU time
(`time.thread_time_ns`) per call in microseconds for 68 and 500 points, and the
pyramid-only time (buildOpticalFlowPyramid, no derivatives, one frame). Thread CPU
time compares with the bench's `*_cpu` ids on a loaded machine.
"""
import argparse
import os
import subprocess
import time

for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[v] = "1"

import cv2  # noqa: E402
import numpy as np  # noqa: E402

W, H = 640, 480
WIN = (21, 21)
LEVEL = 3
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


def shared_video():
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.environ.get("FACECAP_SHARED_DATA") or os.path.join(here, "..", "..", "..", "shared", "data")
    for cand in (root, "/work/shared/data"):
        p = os.path.join(cand, "videos", "liveportrait_d9.mp4")
        if os.path.exists(p):
            return p
    raise SystemExit("liveportrait_d9.mp4 not found (set FACECAP_SHARED_DATA)")


def frames():
    raw = subprocess.run(
        ["ffmpeg", "-nostdin", "-v", "error", "-i", shared_video(), "-frames:v", "40",
         "-vf", "pad=640:480:64:0,format=gray", "-f", "rawvideo", "-"],
        check=True, capture_output=True).stdout
    return [np.frombuffer(raw[i:i + W * H], np.uint8).reshape(H, W).copy() for i in range(0, len(raw), W * H)]


def halton(i, b):
    f, r = 1.0, 0.0
    while i > 0:
        f /= b
        r += f * (i % b)
        i //= b
    return r


def points(n):
    return np.array([[150.0 + 340.0 * halton(i + 1, 2), 80.0 + 340.0 * halton(i + 1, 3)] for i in range(n)],
                    np.float32).reshape(-1, 1, 2)


def measure(fn, reps):
    """(median wall us, p25, p75, median thread-CPU us) per call."""
    for _ in range(20):
        fn()
    ts, cs = [], []
    for _ in range(reps):
        c = time.thread_time_ns()
        t = time.perf_counter_ns()
        fn()
        ts.append(time.perf_counter_ns() - t)
        cs.append(time.thread_time_ns() - c)
    ts = np.array(ts) * 1e-3
    return np.median(ts), np.percentile(ts, 25), np.percentile(ts, 75), np.median(np.array(cs) * 1e-3)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=2000)
    a = ap.parse_args()
    cv2.setNumThreads(1)
    fr = frames()
    print(f"cv2 {cv2.__version__}, threads {cv2.getNumThreads()}, {len(fr)} frames, load {os.getloadavg()}")
    for n in (68, 500):
        p = points(n)
        k = [1]

        def call():
            i = k[0]
            k[0] = (i + 1) % len(fr)
            cv2.calcOpticalFlowPyrLK(fr[i - 1], fr[i], p, None, winSize=WIN, maxLevel=LEVEL, criteria=CRIT)

        med, p25, p75, cpu = measure(call, a.reps if n == 68 else max(a.reps // 4, 50))
        print(f"calcOpticalFlowPyrLK {n} pts: median {med:.0f} us wall (p25 {p25:.0f}, p75 {p75:.0f}), "
              f"median thread CPU {cpu:.0f} us")
    g = [0]

    def pyr():
        g[0] = (g[0] + 1) % len(fr)
        cv2.buildOpticalFlowPyramid(fr[g[0]], WIN, LEVEL, withDerivatives=False)

    med, p25, p75, cpu = measure(pyr, a.reps)
    print(f"buildOpticalFlowPyramid (no derivatives) one frame: median {med:.0f} us wall "
          f"(p25 {p25:.0f}, p75 {p75:.0f}), median thread CPU {cpu:.0f} us")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
