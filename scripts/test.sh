#!/usr/bin/env bash
# Every test of the repository, Rust and Python, on a fresh machine with a Rust
# toolchain and Python >= 3.9 (PyPI reachable on the first run):
#
#   bash scripts/test.sh
#
# 1. `cargo test --workspace` (it also builds the `phasekit` command, which the
#    Python pipeline tests compare with);
# 2. the Python package's compiled core (`phasekit._core`, the workspace member
#    python/) built by the same cargo, with the same profile and features as the
#    tests, so that nothing but the binding and pyo3 is compiled again; it is
#    copied next to the Python sources in python/phasekit/ (gitignored). This is
#    what `maturin develop` does, without compiling the workspace a second time
#    for another feature set;
# 3. a virtual environment with the pinned test dependencies of
#    python/requirements-test.txt (hmmlearn, scikit-learn, dask[distributed],
#    pandas, pytest, numpy), kept between runs outside the clone:
#    ~/.cache/phasekit/test-venv-<python>-<hash of the pins> (PHASEKIT_TEST_VENV
#    overrides); a change of the pins makes a new one;
# 4. pytest on python/tests (live parity with hmmlearn and scikit-learn, the
#    Dask fit on a two-worker LocalCluster, the pipeline against the command).
#
# `pip install ./python` (maturin, release profile) is the user's install; it is
# not needed for the tests.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$(pwd)"
PYTHON="${PYTHON:-python3}"

echo "== cargo test --workspace =="
cargo test --workspace

echo "== the Python package's compiled core (cargo, dev profile) =="
cargo build -q --workspace --lib --tests --features phasekit-python/extension-module
suffix="$("$PYTHON" -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')"
rm -f python/phasekit/_core.*.so
cp target/debug/lib_core.so "python/phasekit/_core$suffix"

echo "== Python test environment =="
pins_hash="$(sha256sum python/requirements-test.txt | cut -c1-12)"
pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
VENV="${PHASEKIT_TEST_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/phasekit/test-venv-py$pyver-$pins_hash}"
echo "$VENV"
if [ ! -x "$VENV/bin/python" ]; then
  mkdir -p "$(dirname "$VENV")"
  "$PYTHON" -m venv "$VENV"
fi
# No-op (and no network) when everything pinned is already installed;
# --no-compile: Python compiles only the modules the tests import.
"$VENV/bin/python" -m pip install --disable-pip-version-check -q --only-binary=:all: --no-compile \
  -r python/requirements-test.txt

echo "== pytest python/tests =="
export PHASEKIT_BIN="$ROOT/target/debug/phasekit"
"$VENV/bin/python" -m pytest python/tests -q -rs -p no:cacheprovider
