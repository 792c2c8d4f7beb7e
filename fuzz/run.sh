#!/usr/bin/env bash
# Runs every fuzz target for a bounded time each (default 60 s):
#
#     bash fuzz/run.sh          # 60 s per target
#     bash fuzz/run.sh 600      # 10 min per target
#
# Installs cargo-fuzz if it is missing; uses the nightly toolchain when rustup
# has one, else the stable one with RUSTC_BOOTSTRAP=1 (cargo-fuzz needs the
# sanitizer flags of nightly). The committed seed corpus is in fuzz/corpus/;
# new inputs the fuzzer finds go to fuzz/.work/ (not committed); a crash is
# written to fuzz/artifacts/<target>/ and stops the run with a non-zero exit.
set -euo pipefail
cd "$(dirname "$0")"
secs="${1:-60}"
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
if rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
  toolchain=(+nightly)
else
  toolchain=()
  export RUSTC_BOOTSTRAP=1
fi
for target in csv_reader npy_reader model_file; do
  mkdir -p ".work/$target" "artifacts/$target"
  dict=()
  [ -f "$target.dict" ] && dict=(-dict="$target.dict")
  echo "== $target: $secs s =="
  cargo "${toolchain[@]}" fuzz run "$target" ".work/$target" "corpus/$target" -- \
    -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=1024 \
    -max_len=262144 -print_final_stats=1 "${dict[@]}"
done
