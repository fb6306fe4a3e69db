#!/usr/bin/env bash
# The main job: `facecap capture` on the ground-truth demo made by `facecap synth` (a
# public-domain photo animated with known weights and head pose) and, when the shared
# research data is present (../shared/data or $FACECAP_DATA), on a shared clip too.
# Prints where the outputs are.
#
#   bash scripts/setup.sh && bash scripts/demo.sh
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
BIN="$ROOT/target/release/facecap"
[ -x "$BIN" ] || { echo "demo: $BIN missing; run: bash scripts/setup.sh" >&2; exit 1; }
OUT="${FACECAP_DEMO_OUT:-$ROOT/out/demo}"
mkdir -p "$OUT"

echo "demo: facecap synth --out $OUT/synth"
"$BIN" synth --out "$OUT/synth" --frames 90
VIDEOS=("$OUT/synth/synth.y4m")

DATA="${FACECAP_DATA:-$ROOT/../shared/data}"
CLIP="$DATA/videos/liveportrait_d18.mp4"
if [ -f "$CLIP" ]; then
  "$BIN" info "$CLIP"
  VIDEOS+=("$CLIP")
else
  echo "demo: shared data not found ($CLIP); capturing the synthetic demo only"
fi

echo "demo: facecap capture ${VIDEOS[*]} --out $OUT/capture --solver exact3d --neutral auto --muscles default --force"
"$BIN" capture "${VIDEOS[@]}" --out "$OUT/capture" --solver exact3d --neutral auto --muscles default --force

echo
echo "demo outputs:"
for v in "${VIDEOS[@]}"; do
  stem="$(basename "${v%.*}")"
  echo "  $OUT/capture/$stem/  (report: $OUT/capture/$stem/report.html, summary: $OUT/capture/$stem/summary.json)"
done
