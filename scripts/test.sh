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
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
set +e
cargo test --workspace 2>&1 | tee "$log"
status="${PIPESTATUS[0]}"
set -e
# `facecap batch` as a Slurm job array on a one-node cluster started on localhost
# (16-70 s here; hard limit SLURM_TEST_TIMEOUT, default 600 s; SKIP: without root).
# It uses the facecap binary `cargo test` built for the CLI's integration tests.
step "Slurm job array (scripts/test_slurm.sh)"
set +e
if [ -x "$ROOT/target/debug/facecap" ]; then
  bash scripts/test_slurm.sh "$ROOT/target/debug/facecap" </dev/null 2>&1 | tee -a "$log"
else
  bash scripts/test_slurm.sh </dev/null 2>&1 | tee -a "$log"
fi
slurm_status="${PIPESTATUS[0]}"
set -e
if [ "$status" = 0 ]; then status="$slurm_status"; fi
skips="$(grep -c '^SKIP:' "$log" || true)"
if [ "$data_present" = 0 ]; then
  echo "SKIP: shared data absent: $skips test(s) skipped their data-dependent part (see SKIP: lines above)"
elif [ "$skips" -gt 0 ]; then
  echo "SKIP: $skips test(s) printed SKIP lines (see above)"
fi
exit "$status"
