#!/usr/bin/env python3
"""Runs the mesh front end's two models under Google's TFLite runtime (XNNPACK, one
thread), N plain inferences each, for pairing the whole process against

    target/release/examples/profile_models N --run-only

(the same models run N times each by facecap's interpreter). Anchor only: facecap
never depends on this runtime. Set-up (PyPI, by name and version):

    python3 -m venv /tmp/litert && /tmp/litert/bin/pip install ai-edge-litert==2.3.0 numpy

Usage (one core, alternated with the command above, e.g. with hyperfine or
`/usr/bin/time -v taskset -c 1 ...`):

    /tmp/litert/bin/python scripts/bench_litert_models.py [N] [--models DIR]

DIR defaults to facecap's model folder (`FACECAP_MODELS`, else `$FACECAP_CACHE/models`,
else `$XDG_CACHE_HOME/facecap/models`, else `~/.cache/facecap/models`). Prints each model's median and mean time per inference
(timed in process, after 20 warm-up runs that are not counted).
"""
import os
import sys
import time

import numpy as np
from ai_edge_litert.interpreter import Interpreter

MODELS = ["face_landmarks_detector.tflite", "face_detector.tflite"]


def main():
    args = sys.argv[1:]
    n = next((int(a) for a in args if a.isdigit()), 300)
    cache = os.environ.get("FACECAP_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "facecap")
    d = os.environ.get("FACECAP_MODELS") or os.path.join(cache, "models")
    if "--models" in args:
        d = args[args.index("--models") + 1]
    for name in MODELS:
        path = os.path.join(d, name)
        if not os.path.exists(path):
            sys.exit(f"{path} not found: run scripts/setup.sh (it fetches the models) or give --models DIR")
        it = Interpreter(model_path=path, num_threads=1)
        it.allocate_tensors()
        inp = it.get_input_details()[0]
        it.set_tensor(inp["index"], np.random.default_rng(0).random(inp["shape"], dtype=np.float32))
        for _ in range(20):
            it.invoke()
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            it.invoke()
            ts.append(time.perf_counter() - t0)
        ts.sort()
        print(f"{name}: median {1e3 * ts[n // 2]:.3f} ms, mean {1e3 * sum(ts) / n:.3f} ms per run over {n}")


if __name__ == "__main__":
    main()
