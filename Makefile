# The two commands that matter: `make demo` and `make test`. Each installs what it needs first.
SHELL := /bin/bash
ROOT := $(abspath .)
PY := $(ROOT)/.venv/bin/python
SETUP := bash package-config/setup.sh
export XDG_RUNTIME_DIR ?= /tmp/worldsplat-xdg
export PATH := $(HOME)/.cargo/bin:$(PATH)

.PHONY: demo test setup test-lint test-python test-rust test-wasm test-browser wasm bench lock clean

demo: setup wasm
	$(ROOT)/.venv/bin/worldsplat serve --host 127.0.0.1 --port 8000

setup:
	@mkdir -p $(XDG_RUNTIME_DIR) && chmod 700 $(XDG_RUNTIME_DIR)
	@$(SETUP) all

# Stages run in order; each one's wall time is printed at the end (where the suite's time goes).
TEST_STAGES := test-lint test-rust test-wasm test-python test-browser
test: setup
	@times=""; for t in $(TEST_STAGES); do s=$$(date +%s); \
	  $(MAKE) --no-print-directory $$t || { echo "make test: $$t failed"; exit 1; }; \
	  times="$$times $$t=$$(( $$(date +%s) - s ))s"; done; echo "make test: stage wall times:$$times"

# Python layering (import-linter contracts in pyproject.toml), lint and format (ruff)
test-lint:
	$(ROOT)/.venv/bin/lint-imports
	$(ROOT)/.venv/bin/ruff check server models tests
	$(ROOT)/.venv/bin/ruff format --check server models tests

# pytest-xdist: one worker per core (tests are single-threaded: conftest pins torch to one thread); a file's tests
# stay on one worker so module fixtures are built once.
PYTEST_WORKERS ?= $(shell nproc)
test-python:
	$(PY) -m pytest -n $(PYTEST_WORKERS) --dist loadfile

test-rust: test-rust-lint
	@if [ -f wasm/Cargo.toml ]; then cd wasm && cargo test --workspace; else echo "wasm/: no workspace yet"; fi

.PHONY: test-rust-lint
test-rust-lint:
	@if [ -f wasm/Cargo.toml ]; then cd wasm && cargo fmt --all --check && cargo clippy --workspace --all-targets -- -D warnings; fi

wasm:
	@if [ -f wasm/build.sh ]; then bash wasm/build.sh; fi

test-wasm: wasm

test-browser:
	@if [ -d tests/browser ] && ls tests/browser/*.test.mjs >/dev/null 2>&1; then \
	  NODE_PATH=$(ROOT)/package-config/node_modules node --test tests/browser/; else echo "tests/browser: none yet"; fi

bench: setup
	$(ROOT)/.venv/bin/worldsplat bench --out web/docs/bench

lock:
	$(ROOT)/.venv/bin/pip freeze --all --exclude pip --exclude-editable --exclude commonroad-io --exclude nuscenes-devkit > package-config/requirements.lock

clean:
	rm -rf wasm/target .venv package-config/node_modules
