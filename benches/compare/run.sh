#!/usr/bin/env bash
# Speed of phasekit against the current releases of hmmlearn, scikit-learn
# and dynamax (issue 18), every tool pinned to one core, in the same run on
# the same machine.
#
#   bash benches/compare/run.sh [FILTER]   # workloads 1-4 (names containing FILTER)
#   ROUNDS=3 bash benches/compare/run.sh   # phasekit and the peers alternating, 3 times
#   bash benches/compare/run.sh threads    # workload 2 on 1 and 2 threads (bit-identical?)
#   bash benches/compare/run.sh scaling    # one iteration at 1e4..1e7 frames: time, peak RSS
#
# Creates benches/compare/.venv (gitignored) with the current releases (the
# versions are printed with the table), builds
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
VENV="${VENV:-$HERE/.venv}"
OUT="${PHASEKIT_COMPARE_OUT:-$HERE/out}"
PYTHON="${PYTHON:-python3}"
# Current releases, upgraded on every run (the issue compares with what a
# user installs today); the table prints the versions.
PACKAGES=(hmmlearn numpy scipy scikit-learn dynamax jax)
# The core every tool is pinned to (taskset), and how many alternations.
CORE="${CORE:-1}"
ROUNDS="${ROUNDS:-1}"
PIN=()
if command -v taskset >/dev/null; then PIN=(taskset -c "$CORE"); fi

# One thread everywhere: BLAS, OpenMP, rayon.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 RAYON_NUM_THREADS=1 PYTHONHASHSEED=0

echo "== machine =="
grep -m1 "model name" /proc/cpuinfo || true
echo "cores: $(grep -c ^processor /proc/cpuinfo)"
rustc --version
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"

echo "== build =="
if [ -z "${BIN:-}" ]; then
  (cd "$ROOT" && cargo build --release --example bench_compare)
  BIN="${CARGO_TARGET_DIR:-$ROOT/target}/release/examples/bench_compare"
fi

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
    "$VENV/bin/python" -m pip install --disable-pip-version-check -q --only-binary=:all: --upgrade "${PACKAGES[@]}"
    # XLA: one thread (on top of the pinning).
    export XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    for round in $(seq 1 "$ROUNDS"); do
      mkdir -p "$OUT/round$round"
      echo "== round $round: phasekit (${PIN[*]:-unpinned}) =="
      "${PIN[@]}" "$BIN" run "$OUT/round$round" "${1:-}"
      echo "== round $round: hmmlearn / scikit-learn / dynamax (same data, same initial parameters) =="
      "${PIN[@]}" "$VENV/bin/python" "$HERE/compare.py" "$OUT/round$round"
    done
    ;;
esac
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
