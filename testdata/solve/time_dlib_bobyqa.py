"""Times dlib::find_min_bobyqa on the 12 problems of bobyqa_dlib_fixture.json (the same problems
as the criterion bench `solve/bobyqa/16` and the example `bobyqa_timing`), in the current sitting.

Builds the anchor's C++ driver (shared/anchors/cpp/bobyqa_fit.cpp, Debian libdlib-dev headers,
g++ -O3 -DNDEBUG, as the anchor does) into a temporary folder, feeds it the fixture's problems
(two passes, npt 33, rho 0.075 -> 0.01 then 0.075 -> 0.005, lambda 1, cold start w = 0) and
prints the per-solve wall time (mean, median, min over REPS x 12 solves) and evaluations.
Nothing is written to the repo. Usage:
  /work/shared/anchors/.venv/bin/python testdata/solve/time_dlib_bobyqa.py [REPS]
"""
import json
import pathlib
import statistics
import struct
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
ANCHORS = HERE.parents[1].parent / "shared" / "anchors"


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    fx = json.loads((HERE / "bobyqa_dlib_fixture.json").read_text())
    neutral, deltas = fx["neutral"], fx["deltas"]
    obs = [p["obs"] for p in fx["problems"]]
    P, M, K = len(obs), len(neutral), len(deltas)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        exe = tmp / "bobyqa_fit"
        subprocess.check_call(["g++", "-O3", "-DNDEBUG", "-DDLIB_NO_GUI_SUPPORT", "-std=c++17",
                               str(ANCHORS / "cpp" / "bobyqa_fit.cpp"), "-o", str(exe)])
        prob = tmp / "problem.bin"
        with open(prob, "wb") as f:
            f.write(struct.pack("<5i", P, M, K, reps, 0))
            f.write(struct.pack("<4d", fx["lambda"], fx["rho_begin"], fx["rho_end"][0], fx["rho_end"][1]))
            f.write(struct.pack("<2i", fx["npt"], 30000))
            vals = list(neutral) + [v for row in deltas for v in row] + [v for o in obs for v in o] + [0.0] * (P * K)
            f.write(struct.pack(f"<{len(vals)}d", *vals))
        out = subprocess.run([str(exe), str(prob)], capture_output=True, text=True, check=True).stdout
    t, cpu, ev = [], [], []
    eval_ns = None
    for line in out.splitlines():
        v = line.split()
        if v[0] == "EVAL_NS":
            eval_ns = float(v[1])
            continue
        t.append(float(v[2]) + float(v[3]))
        cpu.append(float(v[9]))
        ev.append(int(v[4]) + int(v[5]))
    print(f"dlib find_min_bobyqa, {P} fixture problems x {reps} reps (after one warm-up pass):")
    print(f"  wall per solve: mean {statistics.mean(t):.0f} us, median {statistics.median(t):.0f} us, "
          f"min {min(t):.0f} us; thread CPU median {statistics.median(cpu):.0f} us")
    print(f"  evaluations per solve: median {statistics.median(ev):.0f} (range {min(ev)}-{max(ev)}); "
          f"one objective evaluation {eval_ns:.0f} ns")


if __name__ == "__main__":
    main()
