#!/usr/bin/env bash
set -euo pipefail
clip=$1; n=$2; FF=${FF:-ffmpeg}
run() { local label=$1; shift
  local TIMEFORMAT='%U %S %R' t
  t=$( { time $FF -nostdin -hide_banner -nostats -loglevel error "$@" </dev/null 2>/dev/null | cat >/dev/null; } 2>&1 | tail -1)
  read u s e <<<"$t"
  printf '| %s | %.2f | %.0f | %.2f |\n' "$label" "$(echo "$u + $s" | bc)" "$(echo "$n / ($u + $s)" | bc -l)" "$e"
}
b() { echo -copyts -i "$clip" -map 0:V:0 "$@" -fps_mode passthrough -f rawvideo; }
run "yuv420p, showinfo (chosen, grey)" $(b -vf showinfo=checksum=0) -pix_fmt yuv420p pipe:1
run "yuv420p, no showinfo" $(b) -pix_fmt yuv420p pipe:1
run "gray (-pix_fmt gray)" $(b) -pix_fmt gray pipe:1
run "yuv444p, showinfo (chosen, RGB)" $(b -vf showinfo=checksum=0) -pix_fmt yuv444p pipe:1
run "rgb24" $(b) -pix_fmt rgb24 pipe:1
run "yuv420p, -threads 1" -threads 1 $(b) -pix_fmt yuv420p pipe:1
run "yuv420p, showinfo with checksum" $(b -vf showinfo) -pix_fmt yuv420p pipe:1
