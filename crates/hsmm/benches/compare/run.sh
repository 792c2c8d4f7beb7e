#!/usr/bin/env bash
# Speed of phasekit's HSMM against the explicit-duration implementations
# users have, one thread each, same models and data (crates/hsmm/BENCHMARKS.md):
#
#   bash crates/hsmm/benches/compare/run.sh [FILTER]
#
# * phasekit: the HSMM (forward, forward-backward, one EM iteration, Viterbi,
#   online step) and phasekit's own HMM on the expanded state space;
# * hmmlearn (current release, installed into ./.venv): the state expansion of
#   its HSMM pull request #582 (S·D states: (state, frames left)) on its
#   GaussianHMM (`implementation="log"`, its default), for the workloads with
#   at most 400 expanded states (HSMM_COMPARE_ALL=1: all);
# * pbdlib-python's HSMM forward variable, when `import pbdlib` works in the
#   virtual environment's Python (pbdlib is not on PyPI; put your checkout on
#   PYTHONPATH). This script does not install it.
#
# The example writes every workload's model and data to $OUT (manifest.json
# + raw little-endian f64), times phasekit and records its log-likelihoods
# and filtered marginals; compare.py times the others on the same files and
# checks that they compute the same numbers. Times are process CPU seconds.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../../../.." && pwd)"
VENV="$HERE/.venv"
OUT="${PHASEKIT_HSMM_COMPARE_OUT:-$HERE/out}"
PYTHON="${PYTHON:-python3}"

export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 RAYON_NUM_THREADS=1 PYTHONHASHSEED=0

echo "== machine =="
grep -m1 "model name" /proc/cpuinfo || true
echo "cores: $(grep -c ^processor /proc/cpuinfo)"
rustc --version
echo "date: $(date -u +%Y-%m-%d)"
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"

echo "== build =="
(cd "$ROOT" && cargo build --release -p phasekit-hsmm --example hsmm_compare)
BIN="${CARGO_TARGET_DIR:-$ROOT/target}/release/examples/hsmm_compare"

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install --disable-pip-version-check -q --only-binary=:all: hmmlearn numpy scipy scikit-learn
mkdir -p "$OUT"
echo "== phasekit =="
taskset -c 0 "$BIN" run "$OUT" "${1:-}"
echo "== hmmlearn (state expansion), pbdlib (same models, same data) =="
taskset -c 0 "$VENV/bin/python" "$HERE/compare.py" "$OUT"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
