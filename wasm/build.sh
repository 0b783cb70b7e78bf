#!/usr/bin/env bash
# Build the browser bundle: splat-web -> wasm32 (profile wasm-release) -> wasm-bindgen --target web -> web/pkg/.
# Called by `make wasm` / `make test`. Needs the wasm32 target and wasm-bindgen-cli pinned to the crate version
# (package-config/setup.sh installs both into .tools/bin).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WBG="${WASM_BINDGEN:-$ROOT/.tools/bin/wasm-bindgen}"
[[ -x "$WBG" ]] || WBG="$(command -v wasm-bindgen || true)"
[[ -n "$WBG" ]] || { echo "wasm/build.sh: wasm-bindgen not found (run: bash package-config/setup.sh rust)" >&2; exit 1; }
WANT="$(grep -o 'wasm-bindgen = "=[0-9.]*"' "$ROOT/wasm/crates/splat-web/Cargo.toml" | grep -o '[0-9][0-9.]*')"
"$WBG" --version | grep -q " $WANT" || { echo "wasm/build.sh: $("$WBG" --version) does not match the crate's $WANT" >&2; exit 1; }
cd "$ROOT/wasm"
nice -n 10 cargo build -p splat-web --target wasm32-unknown-unknown --profile wasm-release
TARGET_DIR="${CARGO_TARGET_DIR:-target}"  # honour a caller's target dir (a second build beside a native one)
"$WBG" --target web --out-dir "${WASM_PKG_OUT:-$ROOT/web/pkg}" "$TARGET_DIR/wasm32-unknown-unknown/wasm-release/splat_web.wasm"
ls -l "${WASM_PKG_OUT:-$ROOT/web/pkg}/splat_web_bg.wasm" | awk '{print "wasm/build.sh:", $9, $5, "bytes"}'
