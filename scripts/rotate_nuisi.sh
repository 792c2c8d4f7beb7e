#!/usr/bin/env bash
# Every demonstration of an action held out in turn (ABLATION.md, "Every
# demonstration as the test one"): the protocol fixes two or three test files
# per action, so an action's coverage and MSE there are those of two or three
# demonstrations. Here each of the action's demonstrations (train_* and
# test_* alike) is the test file once, and each seed trains on a random
# subset of the others of the protocol's size (the action's train_* count
# minus two), so every number is over all 9-12 demonstrations of the action.
# Prints the tables; every fold's evaluate output is kept in OUT as
# OUT/ACTION/DEMONSTRATION.{json,md}, and a fold already there is not fitted
# again (so a rerun on results/rotate_20_seeds prints its tables at once).
#
#     bash scripts/rotate_nuisi.sh [SEEDS] [NUISI_DIR] [OUT] [METHODS]
#     # defaults: 20, ../shared/data/nuisi, a temporary folder, and the
#     # baselines of both unit systems beside auto (reg-rel=0.01 on metres is
#     # the paper's reg = 1e-2 on z-scores):
#     # hmm:states=7,tsc-hmm,auto,hmm:states=7,reg-rel=0.01,tsc-hmm:reg-rel=0.01
#
# 20 seeds took 58 min 47 s on 2 cores (115.6 min of CPU).
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="${1:-20}"
data="$(cd "${2:-../shared/data/nuisi}" && pwd)"
out="${3:-$(mktemp -d)}"
methods="${4:-hmm:states=7,tsc-hmm,auto,hmm:states=7,reg-rel=0.01,tsc-hmm:reg-rel=0.01}"
cargo build --release -q -p phasekit-cli
bin="$PWD/target/release/phasekit"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
folds=$(mktemp -d)
tmp_result=$(mktemp -d)
trap 'rm -rf "$folds" "$tmp_result"' EXIT
for dir in "$data"/*/; do
  action=$(basename "$dir")
  files=("$dir"/train_*.csv "$dir"/test_*.csv)
  n_train=$(ls "$dir"/train_*.csv | wc -l)
  size=$((n_train - 2))
  for held in "${files[@]}"; do
    name=$(basename "$held" .csv)
    fold="$folds/$action/$name/$action"
    mkdir -p "$fold"
    ln -sf "$held" "$fold/test_00.csv"
    i=0
    for f in "${files[@]}"; do
      [ "$f" = "$held" ] && continue
      ln -sf "$f" "$fold/$(printf 'train_%02d.csv' "$i")"
      i=$((i + 1))
    done
    result="$out/$action/$name"
    mkdir -p "$out/$action"
    [ -s "$result.json" ] && continue   # a rerun resumes where it stopped
    "$bin" evaluate --data "$fold" --train-size "$size" --seeds "$seeds" \
      --methods "$methods" -o "$tmp_result/r" > /dev/null
    mv "$tmp_result/r.json" "$result.json"
    mv "$tmp_result/r.md" "$result.md"
  done
done
python3 - "$out" <<'PY'
import glob, json, os, statistics, sys
out = sys.argv[1]
rows = {}  # (action, method) -> [(demonstration, frames, evaluate's row)], one per fold
for path in sorted(glob.glob(os.path.join(out, "*", "*.json"))):
    action, demo = path.split(os.sep)[-2], os.path.basename(path)[:-5]
    for r in json.load(open(path))["results"]:
        if r["method"] == "constant-mean":
            continue
        if r["failures"]:
            sys.exit(f"{path}: {r['method']} failed on seeds {r['failures']}")
        (line,) = r["by_test_demonstration"]  # one test file per fold
        rows.setdefault((action, r["method"]), []).append((demo, line["frames"], r))
actions = sorted({a for a, _ in rows})
methods = list(dict.fromkeys(m for _, m in rows))
target = "auto" if "auto" in methods else methods[-1]

def frames_of(lines):
    return sum(f for _, f, _ in lines)

def weighted(lines, key):
    """Frame-weighted mean over the demonstrations of a per-fold mean over seeds."""
    return sum(f * r[key] for _, f, r in lines) / frames_of(lines)

def per_seed(lines):
    """Seed k's MSE over every demonstration's frames (each held out by its own fold)."""
    seeds = {len(r["per_seed_mse"]) for _, _, r in lines}
    assert len(seeds) == 1, f"folds with different seed counts: {seeds}"
    return [sum(f * r["per_seed_mse"][k] for _, f, r in lines) / frames_of(lines)
            for k in range(seeds.pop())]

print("| action | method | demonstrations | frames | MSE (cm², mean ± sd over seeds) | "
      "coverage 95 % | NLPD (nats) | demonstrations covered 90–98 % | lowest, highest |")
print("|---|---|---:|---:|---:|---:|---:|---:|---|")
for a in actions:
    for m in methods:
        lines = rows[(a, m)]
        mse = per_seed(lines)
        by_cov = sorted(lines, key=lambda l: l[2]["coverage_mean"])
        inside = sum(0.90 <= r["coverage_mean"] <= 0.98 for _, _, r in lines)
        ends = ", ".join(f"{d} {100 * r['coverage_mean']:.1f} %" for d, _, r in (by_cov[0], by_cov[-1]))
        print(f"| {a} | {m} | {len(lines)} | {frames_of(lines)} | "
              f"{statistics.fmean(mse):.2f} ± {statistics.pstdev(mse):.2f} | "
              f"{100 * weighted(lines, 'coverage_mean'):.1f} % | {weighted(lines, 'nlpd_mean'):.3f} | "
              f"{inside} of {len(lines)} | {ends} |")
print()
print(f"| action | {target} vs | Δ MSE (mean over seeds) | seeds won | (demonstration, seed) pairs won |")
print("|---|---|---:|---:|---:|")
for a in actions:
    mine = per_seed(rows[(a, target)])
    mine_by_demo = {d: r["per_seed_mse"] for d, _, r in rows[(a, target)]}
    for m in methods:
        if m == target:
            continue
        other = per_seed(rows[(a, m)])
        change = statistics.fmean((x - y) / y for x, y in zip(mine, other))
        seeds_won = sum(x < y for x, y in zip(mine, other)) / len(mine)
        pairs = [(x, y) for d, _, r in rows[(a, m)] for x, y in zip(mine_by_demo[d], r["per_seed_mse"])]
        pairs_won = sum(x < y for x, y in pairs) / len(pairs)
        print(f"| {a} | {m} | {100 * change:+.1f} % | {100 * seeds_won:.0f} % | {100 * pairs_won:.0f} % |")
print()
print(f"{target}'s coverage of each demonstration (mean over seeds):")
print()
for a in actions:
    cells = ", ".join(f"{d} {100 * r['coverage_mean']:.1f}" for d, _, r in sorted(rows[(a, target)]))
    print(f"- {a}: {cells} %")
PY
