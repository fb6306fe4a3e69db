#!/usr/bin/env bash
# The whole test suite: dependencies (fast when already installed), formatting, lints,
# unit + integration tests and doctests of every crate, then `facecap batch` on a real
# one-node Slurm cluster (scripts/test_slurm.sh).
#
#   bash scripts/test.sh
#
# Tests that need the shared research data (../shared/data, or $FACECAP_DATA) or the
# model cache print `SKIP:` lines and pass when it is absent; this script then also
# prints a SKIP summary line.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

step() { echo; echo "==> $*"; }

# A CI run builds everything once from a clean clone: incremental compilation caches would
# only take disk space there (several hundred MB).
if [ -n "${CI:-}" ]; then
  export CARGO_INCREMENTAL=0
fi

step "setup (dependencies only)"
bash scripts/setup.sh --deps-only </dev/null

if [ -z "${FACECAP_DATA:-}" ] && [ -d "$ROOT/../shared/data" ]; then
  DATA="$ROOT/../shared/data"
else
  DATA="${FACECAP_DATA:-}"
fi
if [ -n "$DATA" ] && [ -d "$DATA" ]; then
  echo "shared data: $DATA"
  data_present=1
else
  echo "SKIP: shared data not found (../shared/data or \$FACECAP_DATA): tests that need it will skip"
  data_present=0
fi

step "cargo fmt --all --check"
cargo fmt --all --check

step "cargo clippy --workspace --all-targets -- -D warnings"
cargo clippy --workspace --all-targets -- -D warnings

step "cargo test --workspace"
# The test harness hides what passing tests print, so their SKIP: lines on stderr are
# never seen: every skip also goes to this file (facecap_core::paths::skip), which is
# counted and listed below. With CI=true and the shared data present, a test whose data
# or model is missing fails instead of skipping (paths::skip_missing_data).
skiplog="$(mktemp)"
trap 'rm -f "$skiplog"' EXIT
export FACECAP_SKIP_LOG="$skiplog"
set +e
cargo test --workspace --no-fail-fast 2>&1
status="$?"
set -e
# Every criterion benchmark of the workspace once in test mode (each bench function runs
# one iteration and its own checks: the per-frame pipeline bench asserts the face is
# tracked on every frame); timing runs are `cargo bench`. `--workspace --bench '*'`
# resolves features as the step above did, so it reuses its build (~20 s on 2 cores);
# `-p facecap-benches` alone resolved them anew and rebuilt the dependencies (~23 min
# from a clean clone).
step "cargo test --workspace --bench '*' (one pass of each benchmark)"
set +e
cargo test --workspace --bench '*' 2>&1
bench_status="$?"
set -e
if [ "$bench_status" -ne 0 ]; then status="$bench_status"; fi
# `facecap batch` as a Slurm job array on a one-node cluster started on localhost
# (16-70 s here; hard limit SLURM_TEST_TIMEOUT, default 600 s; SKIP: without root).
# It uses the facecap binary `cargo test` built for the CLI's integration tests.
step "Slurm job array (scripts/test_slurm.sh)"
# prints its output and adds its SKIP: lines to the skip log
keep_skips() {
  while IFS= read -r line; do
    printf '%s\n' "$line"
    case "$line" in SKIP:*) printf '%s\n' "$line" >> "$skiplog" ;; esac
  done
}
set +e
if [ -x "$ROOT/target/debug/facecap" ]; then
  bash scripts/test_slurm.sh "$ROOT/target/debug/facecap" </dev/null 2>&1 | keep_skips
else
  bash scripts/test_slurm.sh </dev/null 2>&1 | keep_skips
fi
slurm_status="${PIPESTATUS[0]}"
set -e
if [ "$status" = 0 ]; then status="$slurm_status"; fi
skips="$(grep -c '^SKIP:' "$skiplog" || true)"
step "skipped tests: $skips"
sort "$skiplog" | uniq -c | sed 's/^ *//'
if [ "$data_present" = 0 ]; then
  echo "SKIP: shared data absent: $skips skip(s) of data-dependent parts (listed above)"
elif [ "$skips" -gt 0 ]; then
  echo "SKIP: $skips skip(s) (listed above)"
fi
exit "$status"
