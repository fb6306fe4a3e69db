#!/usr/bin/env bash
# The main job on a sample input: `facecap info` on a shared clip when ../shared/data is
# present (or $FACECAP_DATA), else on a small Y4M video this script generates.
#
#   bash scripts/setup.sh && bash scripts/demo.sh
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
BIN="$ROOT/target/release/facecap"
[ -x "$BIN" ] || { echo "demo: $BIN missing; run: bash scripts/setup.sh" >&2; exit 1; }

DATA="${FACECAP_DATA:-$ROOT/../shared/data}"
CLIP="$DATA/videos/liveportrait_d9.mp4"
if [ ! -f "$CLIP" ]; then
  echo "demo: $CLIP not found; generating a synthetic Y4M clip instead"
  OUT="$ROOT/out/demo"
  mkdir -p "$OUT"
  CLIP="$OUT/synthetic.y4m"
  # 64 frames of 320x240 4:2:0: a bright disc moving over a gradient.
  python3 - "$CLIP" <<'PY'
import sys
w, h, n = 320, 240, 64
with open(sys.argv[1], "wb") as f:
    f.write(b"YUV4MPEG2 W%d H%d F30:1 Ip A1:1 C420jpeg\n" % (w, h))
    for k in range(n):
        cx, cy = 40 + 3 * k, 120
        y = bytearray(16 + (x * 200) // w for x in range(w)) * h
        for r in range(cy - 30, cy + 30):
            for c in range(max(0, cx - 30), min(w, cx + 30)):
                if (r - cy) ** 2 + (c - cx) ** 2 < 900:
                    y[r * w + c] = 235
        f.write(b"FRAME\n" + bytes(y) + bytes([128]) * (2 * (w // 2) * (h // 2)))
PY
fi
echo "demo: $BIN info $CLIP"
"$BIN" info "$CLIP"
