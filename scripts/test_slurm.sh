#!/usr/bin/env bash
# `facecap batch` on a real Slurm: starts munged, slurmctld and slurmd for a one-node
# cluster on localhost (configs, keys, state and logs in a temporary folder), submits a
# job array over a manifest of two short clips (../shared/data/videos, or `facecap synth`
# clips when the data is absent) plus one broken file, waits, and checks every output and
# the merged batch_summary.csv. Then a rerun of the array skips the finished rows and
# retries the broken one.
#
#   bash scripts/test_slurm.sh [FACECAP_BINARY]
#
# Needs root (the daemons run as root here) and Debian's slurm-wlm and munge (installed by
# scripts/setup.sh). Where they are missing or the daemons do not come up, it prints a line
# starting with `SKIP:` and exits 0. Bounded: every wait has a timeout, and the whole run is
# killed after $SLURM_TEST_TIMEOUT seconds (default 600; it takes 16-70 s here).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TIMEOUT="${SLURM_TEST_TIMEOUT:-600}"

skip() { echo "SKIP: slurm batch test: $*"; exit 0; }
fail() { echo "slurm batch test: FAILED: $*" >&2; exit 1; }

if [ "${SLURM_TEST_INNER:-}" != 1 ]; then
  # Run the test under a hard time limit.
  SLURM_TEST_INNER=1 exec timeout --kill-after=20 "$TIMEOUT" bash "${BASH_SOURCE[0]}" "$@"
fi

FACECAP="${1:-}"
if [ -z "$FACECAP" ]; then
  # The test profile's binary is the one `cargo test` builds (opt-level 2).
  (cd "$ROOT" && cargo build -q --profile test -p facecap-cli --bin facecap)
  FACECAP="$ROOT/target/debug/facecap"
fi
[ -x "$FACECAP" ] || fail "no facecap binary at $FACECAP"
[ "$(id -u)" = 0 ] || skip "needs root to start munged, slurmctld and slurmd"
# The daemons live in /usr/sbin, which a non-login shell may not have on PATH.
export PATH="$PATH:/usr/sbin:/sbin"
for c in munged mungekey slurmctld slurmd sbatch sinfo scontrol; do
  command -v "$c" >/dev/null 2>&1 || skip "$c not installed (scripts/setup.sh installs slurm-wlm and munge)"
done

T="$(mktemp -d /tmp/facecap-slurm.XXXXXX)"
chmod 700 "$T"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  sleep 1
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
  if [ -n "${KEEP_SLURM_TEST:-}" ]; then echo "kept $T"; else rm -rf "$T"; fi
}
trap cleanup EXIT
# A timeout's SIGTERM (or Ctrl-C) still stops the daemons and removes the folder.
trap 'exit 124' TERM INT
started=$(date +%s)

# ---------------------------------------------------------------- munge
mkdir -p "$T/munge"
chmod 700 "$T/munge"
mungekey --create --keyfile="$T/munge/munge.key" >/dev/null 2>&1 || skip "mungekey could not create a key"
chmod 600 "$T/munge/munge.key"
SOCK="$T/munge/munge.socket"
munged --force --foreground --socket="$SOCK" --key-file="$T/munge/munge.key" \
  --log-file="$T/munge/munged.log" --pid-file="$T/munge/munged.pid" --seed-file="$T/munge/munged.seed" \
  >"$T/munge/stdout.log" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$SOCK" ] && break; sleep 0.2; done
[ -S "$SOCK" ] || skip "munged did not start: $(tail -3 "$T/munge/munged.log" "$T/munge/stdout.log" 2>/dev/null | tr '\n' ' ')"

# ---------------------------------------------------------------- slurm.conf
HOST="$(hostname -s)"
NODE_CPUS="$(slurmd -C 2>/dev/null | sed -n 's/.* CPUs=\([0-9]*\).*/\1/p' | head -1)"
NODE_MEM="$(slurmd -C 2>/dev/null | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' | head -1)"
NODE_CPUS="${NODE_CPUS:-1}"
NODE_MEM="${NODE_MEM:-1024}"
PORT=$((20000 + RANDOM % 20000))
mkdir -p "$T/state" "$T/spool" "$T/log"
export SLURM_CONF="$T/slurm.conf"
cat >"$SLURM_CONF" <<EOF
ClusterName=facecap-test
SlurmctldHost=$HOST(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$SOCK
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/log/slurmctld.log
SlurmdLogFile=$T/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SwitchType=switch/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
ReturnToService=2
SlurmdTimeout=60
InactiveLimit=0
KillWait=5
NodeName=$HOST NodeAddr=127.0.0.1 CPUs=$NODE_CPUS RealMemory=$NODE_MEM State=UNKNOWN
PartitionName=test Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
EOF

slurmctld -D -i -f "$SLURM_CONF" >"$T/log/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" -N "$HOST" >"$T/log/slurmd.out" 2>&1 &
pids+=($!)
up=0
for _ in $(seq 60); do
  if sinfo -h -N -o '%t' 2>/dev/null | grep -Eq '^(idle|mix|alloc)'; then up=1; break; fi
  sleep 0.5
done
if [ "$up" != 1 ]; then
  skip "slurmctld/slurmd did not come up in 30 s: $(tail -2 "$T/log/slurmctld.log" "$T/log/slurmd.log" "$T/log/slurmd.out" 2>/dev/null | tr '\n' ' ')"
fi
echo "slurm: one-node cluster up on $HOST:$PORT ($NODE_CPUS cpus, $NODE_MEM MiB) in $(($(date +%s) - started)) s"

# ---------------------------------------------------------------- manifest
DATA="${FACECAP_DATA:-$ROOT/../shared/data}"
mkdir -p "$T/clips"
if [ -f "$DATA/videos/liveportrait_d18.mp4" ] && [ -f "$DATA/videos/liveportrait_d3.mp4" ]; then
  CLIPS=("$DATA/videos/liveportrait_d18.mp4" "$DATA/videos/liveportrait_d3.mp4")
  echo "clips: liveportrait_d18.mp4 (216 frames), liveportrait_d3.mp4 (354 frames) from $DATA/videos"
else
  echo "shared data absent: two facecap synth clips instead"
  "$FACECAP" --quiet synth --frames 24 --seed 1 --out "$T/clips/a" || fail "facecap synth"
  "$FACECAP" --quiet synth --frames 24 --seed 2 --out "$T/clips/b" || fail "facecap synth"
  CLIPS=("$T/clips/a/synth.y4m" "$T/clips/b/synth.y4m")
fi
printf 'this is not a video\n' >"$T/clips/broken.mp4"
{
  echo "video,neutral"
  echo "${CLIPS[0]},"
  echo "${CLIPS[1]},"
  echo "$T/clips/broken.mp4,"
} >"$T/manifest.csv"
OUT="$T/out"

# ---------------------------------------------------------------- the job array
set +e
# No --mem/--time: batch measures row 0 locally first (peak memory, seconds) and sizes the
# array's limits from it; the array then skips row 0.
"$FACECAP" batch "$T/manifest.csv" --out "$OUT" --slurm --tasks 3 \
  --submit --wait -- --sheet-frames 4 >"$T/submit.out" 2>"$T/submit.err"
rc=$?
set -e
cat "$T/submit.out"
[ "$rc" = 1 ] || fail "batch --submit --wait should exit 1 (one broken row), got $rc: $(cat "$T/submit.err")"
grep -q '^#SBATCH --array=0-2$' "$OUT/batch.sbatch" || fail "no --array=0-2 in $OUT/batch.sbatch"
grep -q '^# memory: measured per-video peak' "$OUT/batch.sbatch" || fail "memory not from a measured peak"
grep -E '^#SBATCH --(mem|time|cpus-per-task)=' "$OUT/batch.sbatch"
grep -q '^job [0-9]* ended' "$T/submit.out" || fail "no job id in the output"
JOB="$(sed -n 's/^job \([0-9]*\) ended.*/\1/p' "$T/submit.out")"
SUMMARY="$OUT/batch_summary.csv"
[ -f "$SUMMARY" ] || fail "no merged $SUMMARY"
echo "--- $SUMMARY"
cat "$SUMMARY"
[ "$(head -1 "$SUMMARY")" = "row,video,status,frames,faces,seconds,error" ] || fail "summary header"
[ "$(wc -l <"$SUMMARY")" = 4 ] || fail "summary must have 3 rows"
check_done_rows() { # the statuses rows 0 and 1 must have
  for r in 0 1; do
    line="$(grep "^$r," "$SUMMARY")"
    status="$(echo "$line" | cut -d, -f3)"
    want="$1"
    [ "$r" = 1 ] && want="$2"
    frames="$(echo "$line" | cut -d, -f4)"
    faces="$(echo "$line" | cut -d, -f5)"
    [ "$status" = "$want" ] || fail "row $r: status $status, expected $want"
    [ "$frames" -gt 0 ] && [ "$faces" -gt 0 ] || fail "row $r: frames $frames faces $faces"
  done
  grep -q '^2,.*broken.mp4,failed,,,,' "$SUMMARY" || fail "row 2 (broken.mp4) must be failed with an error"
}
check_done_rows skipped done
# Every row ran in its own array task and wrote its own folder.
for k in 0 1 2; do
  ls "$OUT"/.batch/logs/slurm-*_$k.out >/dev/null 2>&1 || fail "missing the log of array task $k"
done
n=0
for d in "$OUT"/*/; do
  [ -f "$d/batch_row.json" ] || continue
  n=$((n + 1))
  if grep -q '"status": "done"' "$d/batch_row.json"; then
    for f in landmarks.csv pose.csv weights.csv openface.csv livelink.csv animation.glb report.html summary.json; do
      [ -s "$d/$f" ] || fail "$d: missing $f"
    done
    pngs="$(find "$d/report" -name 'frame_*.png' | wc -l)"
    [ "$pngs" = 4 ] || fail "$d: $pngs contact-sheet frames, expected 4"
    rows="$(($(wc -l <"$d/landmarks.csv") - 1))"
    frames="$(sed -n 's/^  "frames": \([0-9]*\),$/\1/p' "$d/summary.json")"
    [ "$rows" = "$frames" ] || fail "$d: landmarks.csv has $rows rows, summary says $frames frames"
  fi
  if find "$d" -name '.*.tmp-*' | grep -q .; then fail "$d: temporary files left"; fi
done
[ "$n" = 3 ] || fail "expected 3 row folders, found $n"
shards="$(cat "$OUT"/*/batch_row.json | sed -n 's/.*"shard": "\(.*\)".*/\1/p' | sort | tr '\n' ' ')"
# Row 0 was measured before the array (shard 0/1) and skipped by task 0; rows 1, 2 by tasks 1, 2.
[ "$shards" = "0/3 1/3 2/3 " ] || fail "each row should come from its own shard, got: $shards"
[ "$(grep -l "\"job\": \"$JOB\"" "$OUT"/*/batch_row.json | wc -l)" = 3 ] || fail "row statuses not from array job $JOB"
# One merge by the array's last task (the measuring run wrote its summary as a single process).
[ "$(find "$OUT/.batch" -name 'merge-*' | wc -l)" = 1 ] || fail "the array merged more than once"

# ---------------------------------------------------------------- rerun: skip + retry
set +e
"$FACECAP" batch "$T/manifest.csv" --out "$OUT" --slurm --tasks 2 --mem 2048 --time 20 \
  --submit --wait -- --sheet-frames 4 >"$T/submit2.out" 2>"$T/submit2.err"
rc=$?
set -e
[ "$rc" = 1 ] || fail "the rerun should exit 1 (the broken row again), got $rc"
echo "--- rerun (2 tasks)"
cat "$SUMMARY"
check_done_rows skipped skipped
[ "$(find "$OUT/.batch" -name 'merge-*' | wc -l)" = 2 ] || fail "the second array must merge exactly once"
grep -q '"shard": "0/2"' "$(dirname "$(grep -l broken.mp4 "$OUT"/*/batch_row.json)")/batch_row.json" \
  || fail "the broken row was not retried by shard 0/2"
echo "slurm batch test: passed in $(($(date +%s) - started)) s"
