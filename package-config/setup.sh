#!/usr/bin/env bash
# One idempotent set-up for every ecosystem the project uses. Each step checks
# first, so the second run takes a few seconds. Usage: setup.sh [python|qc|rust|browser|all]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
HERE="$ROOT/package-config"
source "$HERE/versions.env"
WHAT="${1:-all}"
log() { printf '[setup] %s\n' "$*" >&2; }

setup_apt() {
  local missing=()
  while read -r pkg; do
    [[ -z "$pkg" || "$pkg" == \#* ]] && continue
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
  done < "$HERE/apt-packages.txt"
  if ((${#missing[@]})); then
    log "apt: installing ${missing[*]}"
    local sudo=""; [[ $(id -u) -ne 0 ]] && sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
  fi
}

# Free space the Python step needs at its peak (installed ~5.8 GB, most of it torch's CUDA libraries, which PyPI's
# Linux torch needs at import even on a CPU, plus the largest wheel being unpacked).
PYTHON_DISK_GB=7

check_free_disk() {  # DIR GB WHAT: fail early, naming the need, rather than half-way through an install
  local free_kb; free_kb=$(df -Pk "$1" | awk 'NR==2 {print $4}')
  if ((free_kb < $2 * 1024 * 1024)); then
    log "not enough disk for $3: needs about $2 GB free in $(df -P "$1" | awk 'NR==2 {print $6}'), has $((free_kb / 1024)) MB"
    exit 1
  fi
}

# requirements.lock is a whole `pip freeze`, so it installs with --no-deps: pip resolves nothing, and a package only
# a GPU uses (triton, torch.compile's CUDA back end) is left out where no NVIDIA driver is. No pip cache (it would
# keep a second copy of every wheel), and the large wheels one pip call each, so at most one is unpacked at a time.
install_locked() {
  local pip="$1" big=() rest=() line
  while read -r line; do
    [[ -z "$line" || "$line" == \#* ]] && continue
    [[ "$line" == triton==* ]] && ! command -v nvidia-smi >/dev/null && continue
    case "$line" in nvidia-*|torch==*|triton==*|ray==*) big+=("$line") ;; *) rest+=("$line") ;; esac
  done < "$HERE/requirements.lock"
  for line in "${big[@]}"; do "$pip" install -q --no-cache-dir --no-deps "$line"; done
  "$pip" install -q --no-cache-dir --no-deps "${rest[@]}"
}

setup_python() {
  local venv="$ROOT/.venv" stamp="$ROOT/.venv/.lock-stamp"
  if [[ ! -x "$venv/bin/python" ]]; then
    check_free_disk "$ROOT" "$PYTHON_DISK_GB" "the Python dependencies (.venv)"
    log "python: creating .venv"; python3 -m venv "$venv"
  fi
  if ! cmp -s "$HERE/requirements.lock" "$stamp" 2>/dev/null; then
    log "python: installing pinned dependencies"
    "$venv/bin/pip" install -q --no-cache-dir --upgrade pip
    install_locked "$venv/bin/pip"
    "$venv/bin/pip" install -q --no-cache-dir --no-deps -r "$HERE/requirements-nodeps.lock"
    cp "$HERE/requirements.lock" "$stamp"
  fi
  # The project itself, editable, so `worldsplat` runs the working tree.
  if ! "$venv/bin/python" -c "import worldsplat" 2>/dev/null; then
    log "python: installing worldsplat (editable)"
    "$venv/bin/pip" install -q --no-deps --no-build-isolation -e "$ROOT"
  fi
  # The onnxruntime graphs are derived from the committed weights (not committed themselves); a no-op when
  # models/weights/onnx/VERSION already names the weights.
  "$venv/bin/worldsplat" export-onnx >/dev/null
}

setup_qc() {
  # The ASAM OpenSCENARIO XML checker (tests/python/test_scenario_export.py) pins lxml < 6 while the project pins
  # lxml 6, so it lives in a venv of its own.
  local venv="$ROOT/.venv-qc"
  if ! "$venv/bin/python" -c "import qc_openscenario" 2>/dev/null; then
    log "qc: installing asam-qc-openscenarioxml $ASAM_QC_OPENSCENARIOXML_VERSION into .venv-qc"
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q "asam-qc-openscenarioxml==$ASAM_QC_OPENSCENARIOXML_VERSION"
  fi
}

setup_rust() {
  command -v cargo >/dev/null || { log "rust: cargo missing; install rustup first"; exit 1; }
  rustup target list --installed | grep -qx "$RUST_WASM_TARGET" || rustup target add "$RUST_WASM_TARGET"
  # wasm-bindgen-cli must match the wasm-bindgen crate exactly. It goes to cargo's own bin dir so that every
  # clone on this machine (CI runs on a fresh one) reuses it instead of rebuilding for minutes.
  if ! wasm-bindgen --version 2>/dev/null | grep -q " $WASM_BINDGEN_VERSION\$"; then
    log "rust: installing wasm-bindgen-cli $WASM_BINDGEN_VERSION (a few minutes, once per machine)"
    cargo install -q wasm-bindgen-cli --version "$WASM_BINDGEN_VERSION" --force
  fi
}

setup_browser() {
  # playwright-core (browser tests), the dev-only @playcanvas/splat-transform (format interop tests,
  # tests/python/test_interop_splat_transform.py) and the dev-only peer viewers of the `peers` bench section
  # (gsplat, @sparkjsdev/spark + three, @mkkellogg/gaussian-splats-3d), all pinned in package.json / package-lock.json
  local pkg missing=0
  for pkg in playwright-core @playcanvas/splat-transform gsplat @sparkjsdev/spark three @mkkellogg/gaussian-splats-3d; do
    [[ -f "$HERE/node_modules/$pkg/package.json" ]] || missing=1
  done
  if ((missing)); then
    log "browser: npm install (playwright-core, splat-transform, peer viewers)"
    (cd "$HERE" && npm install --no-audit --no-fund --silent)
  fi
}

case "$WHAT" in
  python) setup_python ;;
  qc) setup_qc ;;
  rust) setup_rust ;;
  browser) setup_apt; setup_browser ;;
  apt) setup_apt ;;
  all) setup_apt; setup_python; setup_qc; setup_rust; setup_browser ;;
  *) log "unknown target '$WHAT' (python|qc|rust|browser|apt|all)"; exit 2 ;;
esac
