#!/usr/bin/env bash
# The missing-data accuracy table on NuiSI (BENCHMARKS.md, "Missing data"):
# `phasekit evaluate --missing FRAC --missing-mode MODE` for every mode and
# fraction, the paper's protocol otherwise; prints one Markdown table.
#
#     bash scripts/missing_nuisi.sh [SEEDS] [NUISI_DIR]     # defaults: 20, ../shared/data/nuisi
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="${1:-20}"
data="${2:-../shared/data/nuisi}"
methods="hmm,hmm:states=7,tsc-hmm"
cargo build --release -q -p phasekit-cli
out=$(mktemp -d)
echo "| removed | fraction | method | handshake | parachute | rocket | waving |"
echo "|---|---:|---|---:|---:|---:|---:|"
for mode in values frames occlusions; do
  for frac in 0 0.1 0.2 0.3; do
    [ "$mode" != values ] && [ "$frac" = 0 ] && continue
    target/release/phasekit evaluate --data "$data" --methods "$methods" --seeds "$seeds" \
      --missing "$frac" --missing-mode "$mode" --format json > "$out/r.json"
    python3 - "$out/r.json" "$mode" "$frac" <<'PY'
import json, sys
rows = json.load(open(sys.argv[1]))["results"]
mode, frac = sys.argv[2], float(sys.argv[3])
methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "constant-mean"]
for m in methods:
    cells = []
    for a in ["handshake", "parachute", "rocket", "waving"]:
        r = next(r for r in rows if r["action"] == a and r["method"] == m)
        cells.append(f'{r["mse_mean"]:.1f} ± {r["mse_std"]:.1f}')
    label = "none" if frac == 0 else mode
    print(f"| {label} | {frac*100:.0f} % | {m} | " + " | ".join(cells) + " |")
PY
  done
done
rm -rf "$out"
