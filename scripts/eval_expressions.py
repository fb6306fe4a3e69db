#!/usr/bin/env python3
"""Expression quality of `facecap capture` against MediaPipe FaceLandmarker's blendshapes.

For every clip, MediaPipe FaceLandmarker's 52 ARKit blendshape scores per frame are the
reference (an independently trained model, not ground truth). facecap's `weights.csv`
is compared with it shape by shape:

* Left/Right variants are merged by their mean (`eyeBlinkLeft` + `eyeBlinkRight` ->
  `eyeBlink`; ICT's `_L`/`_R` the same);
* a shape counts on a clip only where MediaPipe's curve moves there (std >= 0.05);
* the score is Pearson's r over the frames where both have a face; a constant facecap
  curve scores 0; a shape the rig does not have is listed as missing, not scored;
* "pinned": the fraction of frames where facecap's weight sits at its upper bound
  (>= 0.98) while MediaPipe's is below 0.5 there (the issue's "at its bound" check);
* also printed: the mean r over the pairs where MediaPipe's std reaches 0.10 and 0.15
  (the shapes it moves clearly; the headline figure stays the one over std >= 0.05);
* "offset": facecap's median over the clip minus MediaPipe's, for every shape both have
  (moving or not). Pearson's r cannot see a constant offset (a resting face that reads as
  a frown); the mean |offset| over all (clip, shape) pairs is printed per rig.

Usage (from the repository root; stdlib Python only):

    python3 scripts/eval_expressions.py                       # built-in rig and ICT rig
    python3 scripts/eval_expressions.py --rig builtin --clips liveportrait_d18
    python3 scripts/eval_expressions.py --json out/eval/result.json -- --neutral none

The MediaPipe scores are read from `--ref DIR/mp_blendshapes_<clip>.csv`; missing ones
are made with `--anchors-python` (the anchors virtualenv's python, see
`../shared/anchors/setup_env.sh`) running `../shared/anchors/mp_blendshapes.py`.
Arguments after `--` are passed to every `facecap capture`. The clips and the MediaPipe
model are research-only test material (see README.md, "Data and model licences").
"""
import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

MIN_REF_STD = 0.05
# also reported: the mean r over the pairs where MediaPipe's std reaches these
CLEAR_REF_STD = (0.10, 0.15)
BOUND = 0.98


def base_name(name):
    """`eyeBlinkLeft`/`eyeBlink_L` -> `eyeBlink`; `mouthLeft`, `jawRight` are directions, kept."""
    for suf in ("Left", "Right", "_L", "_R"):
        if name.endswith(suf) and len(name) > len(suf):
            base = name[: -len(suf)]
            return name if base in ("mouth", "jaw") else base
    return name


def read_curves(path, first_value_col):
    """Returns (frames -> success, {name: {frame: value}}) of a per-frame CSV."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    header = [h.strip() for h in rows[0]]
    names = header[first_value_col:]
    fi = header.index("frame")
    si = header.index("success")
    curves = {n: {} for n in names}
    ok = {}
    for r in rows[1:]:
        if not r:
            continue
        f = int(float(r[fi]))
        good = r[si].strip() in ("1", "true", "True")
        ok[f] = good
        if not good:
            continue
        for n, v in zip(names, r[first_value_col:]):
            try:
                x = float(v)
            except ValueError:
                continue
            if math.isfinite(x):
                curves[n][f] = x
    return ok, curves


def merge_lr(curves):
    groups = {}
    for n, c in curves.items():
        groups.setdefault(base_name(n), []).append(c)
    merged = {}
    for b, cs in groups.items():
        frames = set(cs[0])
        for c in cs[1:]:
            frames &= set(c)
        merged[b] = {f: sum(c[f] for c in cs) / len(cs) for f in frames}
    return merged


def mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


def std(xs):
    m = mean(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / len(xs)) if xs else 0.0


def pearson(a, b):
    ma, mb = mean(a), mean(b)
    sa = math.sqrt(sum((x - ma) ** 2 for x in a))
    sb = math.sqrt(sum((y - mb) ** 2 for y in b))
    if sa < 1e-12 or sb < 1e-12:
        return 0.0
    return sum((x - ma) * (y - mb) for x, y in zip(a, b)) / (sa * sb)


def evaluate_clip(weights_csv, ref_csv):
    """Per-shape scores of one clip: {base: {r, ref_std, ours_std, pinned, frames}}, missing."""
    _, ours = read_curves(weights_csv, 4)
    _, ref = read_curves(ref_csv, 2)
    ours_m = merge_lr(ours)
    ref_m = merge_lr({n: c for n, c in ref.items() if n != "_neutral"})
    shapes, missing = {}, []
    for b, rc in sorted(ref_m.items()):
        if b not in ours_m:
            vals = list(rc.values())
            if std(vals) >= MIN_REF_STD:
                missing.append(b)
            continue
        oc = ours_m[b]
        frames = sorted(set(rc) & set(oc))
        if len(frames) < 10:
            continue
        rv = [rc[f] for f in frames]
        ov = [oc[f] for f in frames]
        rs = std(rv)
        offset = statistics.median(ov) - statistics.median(rv)
        pinned = sum(1 for o, r in zip(ov, rv) if o >= BOUND and r < 0.5) / len(frames)
        shapes[b] = {
            "r": pearson(ov, rv) if rs >= MIN_REF_STD else None,
            "ref_std": rs,
            "ours_std": std(ov),
            "pinned": pinned,
            "offset": offset,
            "frames": len(frames),
        }
    # shapes facecap has but MediaPipe does not (tongueOut): pinned check only
    for b, oc in ours_m.items():
        if b in shapes or b in ref_m:
            continue
        ov = list(oc.values())
        if ov:
            shapes[b] = {
                "r": None,
                "ref_std": None,
                "ours_std": std(ov),
                "pinned": sum(1 for o in ov if o >= BOUND) / len(ov),
                "frames": len(ov),
            }
    return shapes, missing


def ensure_refs(clips, ref_dir, anchors_python, data):
    need = [c for c in clips if not os.path.isfile(os.path.join(ref_dir, f"mp_blendshapes_{c}.csv"))]
    if not need:
        return
    if not anchors_python:
        sys.exit(
            f"eval: no MediaPipe reference for {', '.join(need)} in {ref_dir}; pass --anchors-python "
            "(the python of the anchors virtualenv, ../shared/anchors/setup_env.sh)"
        )
    script = os.path.join(data, "..", "anchors", "mp_blendshapes.py")
    os.makedirs(ref_dir, exist_ok=True)
    vids = [os.path.join(data, "videos", c + ".mp4") for c in need]
    subprocess.check_call([anchors_python, script, "--out", ref_dir] + vids)


RIGS = {
    "builtin": [],
    "ict": [
        "--rig",
        "{data}/models3d/ict_facekit/ict_face_arkit53.glb",
        "--landmark-map",
        "{data}/models3d/ict_facekit/ict_landmarks68.json",
    ],
}


def main():
    argv = sys.argv[1:]
    extra = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1 :]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--facecap", default=os.path.join(ROOT, "target", "release", "facecap"))
    ap.add_argument("--data", default=os.environ.get("FACECAP_DATA", os.path.join(ROOT, "..", "shared", "data")))
    ap.add_argument("--ref", default=os.path.join(ROOT, "out", "eval", "mediapipe"))
    ap.add_argument("--anchors-python", default=None)
    ap.add_argument("--rig", default="both", choices=["builtin", "ict", "both"])
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "eval", "capture"))
    ap.add_argument("--clips", default=None, help="comma-separated clip stems (default: every clip in DATA/videos)")
    ap.add_argument("--no-capture", action="store_true", help="score existing captures in --out")
    ap.add_argument("--json", default=None, help="also write the scores as JSON here")
    ap.add_argument("--per-shape", action="store_true", help="print every shape of every clip")
    a = ap.parse_args(argv)

    vid_dir = os.path.join(a.data, "videos")
    if not os.path.isdir(vid_dir):
        print(f"SKIP: no shared videos at {vid_dir}")
        return 0
    clips = (
        a.clips.split(",")
        if a.clips
        else sorted(os.path.splitext(f)[0] for f in os.listdir(vid_dir) if f.endswith(".mp4"))
    )
    ensure_refs(clips, a.ref, a.anchors_python, a.data)
    rigs = ["builtin", "ict"] if a.rig == "both" else [a.rig]
    result = {"clips": clips, "extra_args": extra, "rigs": {}}
    for rig in rigs:
        out = os.path.join(a.out, rig)
        if not a.no_capture:
            cmd = [a.facecap, "capture"] + [os.path.join(vid_dir, c + ".mp4") for c in clips]
            cmd += ["--out", out, "--force", "--quiet"] + [x.format(data=a.data) for x in RIGS[rig]] + extra
            print("+", " ".join(cmd), flush=True)
            subprocess.check_call(cmd)
        per_clip, all_r, per_shape, offsets = {}, [], {}, []
        for c in clips:
            shapes, missing = evaluate_clip(
                os.path.join(out, c, "weights.csv"), os.path.join(a.ref, f"mp_blendshapes_{c}.csv")
            )
            rs = {b: s["r"] for b, s in shapes.items() if s["r"] is not None}
            pinned = {b: round(s["pinned"], 3) for b, s in shapes.items() if s["pinned"] > 0.05}
            offs = {b: s["offset"] for b, s in shapes.items() if s.get("offset") is not None}
            offsets += [abs(v) for v in offs.values()]
            per_clip[c] = {
                "mean_r": mean(list(rs.values())),
                "r": rs,
                "missing": missing,
                "pinned": pinned,
                "offsets": offs,
                "shapes": shapes,
            }
            all_r += list(rs.values())
            for b, r in rs.items():
                per_shape.setdefault(b, []).append(r)
        mean_r = mean(all_r)
        mean_offset = mean(offsets)
        # the same mean over the pairs where the reference moves more (its small motions
        # are where its own noise and habits weigh most)
        by_motion = {}
        for t in CLEAR_REF_STD:
            rs_t = [
                s["r"]
                for pc in per_clip.values()
                for s in pc["shapes"].values()
                if s["r"] is not None and s["ref_std"] >= t
            ]
            by_motion[f"{t:.2f}"] = {"mean_r": mean(rs_t), "pairs": len(rs_t)}
        result["rigs"][rig] = {
            "mean_r": mean_r,
            "mean_r_by_ref_std": by_motion,
            "mean_abs_offset": mean_offset,
            "per_clip": per_clip,
            "per_shape": {b: mean(v) for b, v in per_shape.items()},
        }
        print(f"\n== rig {rig}: mean r {mean_r:.3f} over {len(all_r)} (clip, shape) pairs")
        print(f"   mean |median offset| {mean_offset:.4f} over {len(offsets)} (clip, shape) pairs")
        print(
            "   where the reference moves more: "
            + ", ".join(f"std >= {t}: mean r {v['mean_r']:.3f} over {v['pairs']}" for t, v in by_motion.items())
        )
        for c in clips:
            pc = per_clip[c]
            print(f"  {c:34s} mean r {pc['mean_r']:.3f}  shapes {len(pc['r']):2d}  pinned>5%: {pc['pinned'] or '-'}")
            big = {b: round(v, 2) for b, v in sorted(pc["offsets"].items()) if abs(v) >= 0.15}
            if big:
                print(f"  {'':34s} median offsets >= 0.15: {big}")
            if a.per_shape:
                for b, r in sorted(pc["r"].items()):
                    s = pc["shapes"][b]
                    print(f"      {b:22s} r {r:+.3f}  ref std {s['ref_std']:.3f}  ours std {s['ours_std']:.3f}")
        print("  per shape (mean over clips where the reference moves):")
        for b, v in sorted(per_shape.items(), key=lambda kv: mean(kv[1])):
            print(f"      {b:22s} {mean(v):+.3f}  ({len(v)} clips)")
        miss = sorted({m for c in clips for m in per_clip[c]["missing"]})
        if miss:
            print(f"  shapes the reference moves that this rig lacks: {', '.join(miss)}")
    if a.json:
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        with open(a.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
