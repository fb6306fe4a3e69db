#!/usr/bin/env bash
# Validate glTF 2.0 files (.glb / .gltf) with the official Khronos glTF validator.
#
# Usage: scripts/validate_gltf.sh FILE...
#
# Installs the npm package `gltf-validator` (pinned below) into
# ${FACECAP_CACHE:-$HOME/.cache/facecap}/npm on first use and runs it with node.
# Prints one summary line per file (errors / warnings / infos / hints) and the
# messages of severity error and warning (all messages with
# VALIDATE_GLTF_VERBOSE=1). Exits 0 when no file has errors,
# 1 when some file has errors, 2 on usage or setup problems (node/npm missing).
set -euo pipefail

VALIDATOR_VERSION="2.0.0-dev.3.10"

if [ "$#" -eq 0 ]; then
  echo "usage: $0 FILE..." >&2
  exit 2
fi
for tool in node npm; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "validate_gltf: '$tool' not found; install Node.js (Debian: apt-get install nodejs npm)" >&2
    exit 2
  fi
done

cache="${FACECAP_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/facecap}"
prefix="$cache/npm"
pkg="$prefix/node_modules/gltf-validator"
if [ ! -f "$pkg/package.json" ] || ! grep -q "\"version\": *\"$VALIDATOR_VERSION\"" "$pkg/package.json"; then
  mkdir -p "$prefix"
  echo "validate_gltf: installing gltf-validator@$VALIDATOR_VERSION into $prefix" >&2
  # Install into a temporary prefix, then move it in place, so an interrupted
  # install never leaves a half-populated package behind.
  tmp="$(mktemp -d "$prefix/.install.XXXXXX")"
  trap 'rm -rf "$tmp"' EXIT
  if ! npm install --silent --no-audit --no-fund --prefix "$tmp" "gltf-validator@$VALIDATOR_VERSION" >&2; then
    echo "validate_gltf: npm install gltf-validator@$VALIDATOR_VERSION failed" >&2
    exit 2
  fi
  rm -rf "$prefix/node_modules"
  mv "$tmp/node_modules" "$prefix/node_modules"
fi

NODE_PATH="$prefix/node_modules" node - "$@" <<'JS'
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

const verbose = process.env.VALIDATE_GLTF_VERBOSE === '1';

async function main(files) {
  let failed = false;
  for (const file of files) {
    let bytes;
    try {
      bytes = new Uint8Array(fs.readFileSync(file));
    } catch (e) {
      console.log(`${file}: cannot read: ${e.message}`);
      failed = true;
      continue;
    }
    const dir = path.dirname(file);
    const report = await validator.validateBytes(bytes, {
      uri: path.basename(file),
      maxIssues: 100,
      externalResourceFunction: (uri) =>
        new Promise((resolve, reject) => {
          fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) =>
            err ? reject(err.toString()) : resolve(new Uint8Array(data)));
        }),
    });
    const s = report.issues;
    console.log(`${file}: errors=${s.numErrors} warnings=${s.numWarnings} infos=${s.numInfos} hints=${s.numHints}`);
    for (const m of s.messages) {
      if (m.severity <= 1 || verbose) {
        const sev = ['ERROR', 'WARNING', 'INFO', 'HINT'][m.severity] || 'NOTE';
        console.log(`  ${sev} ${m.code} ${m.pointer || ''}: ${m.message}`);
      }
    }
    if (s.numErrors > 0) failed = true;
  }
  process.exit(failed ? 1 : 0);
}

main(process.argv.slice(2)).catch((e) => {
  console.error(`validate_gltf: ${e}`);
  process.exit(2);
});
JS
