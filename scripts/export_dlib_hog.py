#!/usr/bin/env python3
"""Export dlib's default frontal face detector (HOG + linear SVM) to a file.

Usage: python scripts/export_dlib_hog.py OUT_PATH

Runs in a venv with `dlib-bin==20.0.1.post1` (scripts/setup.sh creates it at
$FACECAP_CACHE/venv). `dlib.get_frontal_face_detector()` is built into dlib (the
weights are compiled into the library); `.save()` writes dlib's own serialisation of
`object_detector<scan_fhog_pyramid<pyramid_down<6>>>`, which facecap parses natively
(crates/facecap-landmarks/src/detect/model.rs). The output is deterministic: the
script writes twice, checks both copies are identical, and prints the sha256.
Licence: dlib and its built-in detector are Boost Software License 1.0; dlib's
frontal_face_detector.h says the 5 filters were trained on Labeled Faces in the Wild
subsets (frontal/left/right faces), see docs/detection.md.
"""
import hashlib
import os
import sys
import tempfile


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read())
    return h.hexdigest()


def main():
    if len(sys.argv) != 2:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    out = os.path.abspath(sys.argv[1])
    import dlib  # noqa: E402  (only needed here)

    det = dlib.get_frontal_face_detector()
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        a, b = os.path.join(tmp, "a.svm"), os.path.join(tmp, "b.svm")
        det.save(a)
        dlib.get_frontal_face_detector().save(b)
        ha, hb = sha256(a), sha256(b)
        if ha != hb:
            print(f"non-deterministic export: {ha} != {hb}", file=sys.stderr)
            return 1
        tmp_out = out + ".tmp"
        with open(a, "rb") as src, open(tmp_out, "wb") as dst:
            dst.write(src.read())
        os.replace(tmp_out, out)
    print(f"dlib {dlib.__version__}: wrote {out} ({os.path.getsize(out)} bytes)")
    print(f"sha256 {sha256(out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
