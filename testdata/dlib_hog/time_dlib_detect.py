#!/usr/bin/env python3
"""dlib's HOG detector on the frame `examples/detect_timing.rs --write DIR` wrote, for
same-sitting and instruction-count comparisons with facecap.

    python time_dlib_detect.py DIR/frame_640x480.gray N [UPSAMPLE]

Prints dlib's boxes and the median wall time of N calls. Under
`valgrind --tool=callgrind` the instruction count per frame is the difference of two
runs with different N divided by the difference of N (Python start-up cancels out).
"""
import os
import sys
import time

import dlib
import numpy as np


def read_gray(path):
    """Raw 8-bit grey pixels; the size is in the name (`frame_640x480.gray`)."""
    size = os.path.basename(path).rsplit(".", 1)[0].rsplit("_", 1)[1]
    w, h = (int(v) for v in size.split("x"))
    return np.fromfile(path, np.uint8)[: w * h].reshape(h, w).copy()


def main():
    img = read_gray(sys.argv[1])
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    up = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    det = dlib.get_frontal_face_detector()
    times = []
    rects = []
    for _ in range(n):
        t = time.perf_counter()
        rects = det(img, up)
        times.append((time.perf_counter() - t) * 1e3)
    times.sort()
    boxes = [(r.left(), r.top(), r.right(), r.bottom()) for r in rects]
    med = times[n // 2] if n else float("nan")
    print(f"dlib {img.shape[1]}x{img.shape[0]} upsample {up}: {n} calls, median {med:.2f} ms, "
          f"min {times[0] if n else float('nan'):.2f} ms; boxes {boxes}")


if __name__ == "__main__":
    main()
