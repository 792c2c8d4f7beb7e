#!/usr/bin/env bash
# Every test of the repository, Rust and Python, on a fresh machine with a Rust
# toolchain and Python >= 3.9 (PyPI reachable on the first run):
#
#   bash scripts/test.sh
#
# 1. `cargo test --workspace` (it also builds the `phasekit` command, which the
#    Python pipeline tests compare with);
# 2. a virtual environment at python/.venv (PHASEKIT_TEST_VENV overrides) with
#    the pinned test dependencies of python/requirements-test.txt (hmmlearn,
#    scikit-learn, dask[distributed], pandas, pytest, maturin, numpy);
# 3. the Python package built by maturin in the dev profile, so that it reuses
#    the artifacts `cargo test` just built in target/ (the binding crate is a
#    workspace member: one Cargo.lock, one target dir);
# 4. pytest on python/tests (live parity with hmmlearn and scikit-learn, the
#    Dask fit on a two-worker LocalCluster, the pipeline against the command).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$(pwd)"
VENV="${PHASEKIT_TEST_VENV:-$ROOT/python/.venv}"
PYTHON="${PYTHON:-python3}"

echo "== cargo test --workspace =="
cargo test --workspace

echo "== Python test environment ($VENV) =="
if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
# No-op (and no network) when everything pinned is already installed;
# --no-compile: Python compiles only the modules the tests import.
"$VENV/bin/python" -m pip install --disable-pip-version-check -q --only-binary=:all: --no-compile \
  -r python/requirements-test.txt

echo "== building the Python package (maturin, dev profile) =="
(
  export VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
  cd python
  maturin develop --profile dev --skip-install 2>&1 | grep -v '^\s*$' | tail -n 3
)

echo "== pytest python/tests =="
export PHASEKIT_BIN="$ROOT/target/debug/phasekit"
[ -x "$PHASEKIT_BIN" ] || cargo build -q -p phasekit-cli
"$VENV/bin/python" -m pytest python/tests -q -rs -p no:cacheprovider
