#!/usr/bin/env bash
# Speed of phasekit against hmmlearn 0.3.3 and scikit-learn 1.5.2 (issue 6),
# everything single-threaded, in the same run on the same machine.
#
#   bash benches/compare/run.sh [FILTER]   # workloads 1-4 (names containing FILTER)
#   bash benches/compare/run.sh threads    # workload 2 on 1 and 2 threads (bit-identical?)
#   bash benches/compare/run.sh scaling    # one iteration at 1e4..1e7 frames: time, peak RSS
#
# Creates benches/compare/.venv (gitignored) with pinned versions, builds
# `examples/bench_compare.rs` in release mode, lets it write every workload's
# data and initial parameters to $OUT (raw f64 + manifest.json) and time
# phasekit, then times hmmlearn (implementation="log", its default, and
# "scaling") and scikit-learn on the same files, checks that the
# log-likelihoods agree and prints the table (also written to $OUT/table.md).
# Times are process CPU seconds (robust to other processes on a shared
# machine); wall-clock times are in $OUT/phasekit.json as well.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
VENV="$HERE/.venv"
OUT="${PHASEKIT_COMPARE_OUT:-$HERE/out}"
PYTHON="${PYTHON:-python3}"
PINS=(
  "hmmlearn==0.3.3"
  "numpy==1.26.4"
  "scipy==1.13.1"
  "scikit-learn==1.5.2"
  "joblib==1.4.2"
  "threadpoolctl==3.5.0"
)

# One thread everywhere: BLAS, OpenMP, rayon.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 RAYON_NUM_THREADS=1 PYTHONHASHSEED=0

echo "== machine =="
grep -m1 "model name" /proc/cpuinfo || true
echo "cores: $(grep -c ^processor /proc/cpuinfo)"
rustc --version
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"

echo "== build =="
(cd "$ROOT" && cargo build --release --example bench_compare)
BIN="${CARGO_TARGET_DIR:-$ROOT/target}/release/examples/bench_compare"

case "${1:-}" in
  threads)
    unset RAYON_NUM_THREADS
    "$BIN" threads "${2:-3}"
    ;;
  scaling)
    for n in 10000 100000 1000000 10000000; do
      "$BIN" scaling "$n"
    done
    ;;
  *)
    if [ ! -x "$VENV/bin/python" ]; then
      "$PYTHON" -m venv "$VENV"
    fi
    "$VENV/bin/python" -m pip install --disable-pip-version-check -q --only-binary=:all: "${PINS[@]}"
    mkdir -p "$OUT"
    echo "== phasekit =="
    "$BIN" run "$OUT" "${1:-}"
    echo "== hmmlearn / scikit-learn (same data, same initial parameters) =="
    "$VENV/bin/python" "$HERE/compare.py" "$OUT"
    ;;
esac
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
