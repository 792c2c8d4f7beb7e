#!/usr/bin/env bash
# Every demonstration of an action held out in turn (ABLATION.md, "Every
# demonstration as the test one"): the protocol fixes two or three test files
# per action, so an action's coverage and MSE there are those of two or three
# demonstrations. Here each of the action's demonstrations (train_* and
# test_* alike) is the test file once, and each seed trains on a random
# subset of the others of the protocol's size (the action's train_* count
# minus two), so every number is over all 9-12 demonstrations of the action.
# Prints the tables. Every fold's evaluate output is kept in OUT as
# OUT/ACTION/DEMONSTRATION.{json,md} (the JSON holds every number of the
# side files evaluate's -o also writes, which are not kept; in both, the one
# test file is named test_00.csv). A fold already in OUT with the same seeds,
# methods and training size is not fitted again, so a rerun resumes where it
# stopped and a rerun on results/rotate_20_seeds prints its tables at once.
#
#     bash scripts/rotate_nuisi.sh [SEEDS] [NUISI_DIR] [OUT] [METHODS]
#     # defaults: 20, ../shared/data/nuisi, a temporary folder, and the
#     # baselines of both unit systems beside auto (reg-rel=0.01 on metres is
#     # the paper's reg = 1e-2 on z-scores):
#     # hmm:states=7,tsc-hmm,auto,hmm:states=7,reg-rel=0.01,tsc-hmm:reg-rel=0.01
#
# 20 seeds took 58 min 47 s on 2 cores (115.6 min of CPU).
set -euo pipefail
shopt -s nullglob
seeds="${1:-20}"
data="$(cd "${2:-$(dirname "$0")/../../shared/data/nuisi}" && pwd)"
out="${3:-$(mktemp -d)}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
methods="${4:-hmm:states=7,tsc-hmm,auto,hmm:states=7,reg-rel=0.01,tsc-hmm:reg-rel=0.01}"
cd "$(dirname "$0")/.."
cargo build --release -q -p phasekit-cli
bin="$PWD/target/release/phasekit"
folds=$(mktemp -d)
trap 'rm -rf "$folds"' EXIT
echo "Every fold's output: $out" >&2
for dir in "$data"/*/; do
  action=$(basename "$dir")
  trains=("$dir"train_*.csv)
  files=("${trains[@]}" "$dir"test_*.csv)
  size=$((${#trains[@]} - 2))
  if [ "$size" -lt 1 ] || [ "${#files[@]}" -lt 3 ]; then
    echo "$action: skipped (${#trains[@]} train_* and ${#files[@]} files in all)" >&2
    continue
  fi
  mkdir -p "$out/$action"
  for held in "${files[@]}"; do
    name=$(basename "$held" .csv)
    result="$out/$action/$name"
    if [ -s "$result.json" ] && [ -s "$result.md" ]; then
      # Resume only a fold of this very run; anything else would mix runs.
      python3 - "$result.json" "$seeds" "$methods" "$size" <<'PY'
import json, sys
p = json.load(open(sys.argv[1]))["protocol"]
want = (int(sys.argv[2]), sys.argv[3], int(sys.argv[4]))
have = (p["seeds"], ",".join(p["methods"]), p["train_size"])
if have != want:
    sys.exit(f"{sys.argv[1]}: made with seeds, methods, train size {have}, not {want}; "
             "choose another OUT")
PY
      continue
    fi
    fold="$folds/$action/$name/$action"
    mkdir -p "$fold"
    ln -sf "$held" "$fold/test_00.csv"
    i=0
    for f in "${files[@]}"; do
      [ "$f" = "$held" ] && continue
      ln -sf "$f" "$fold/$(printf 'train_%02d.csv' "$i")"
      i=$((i + 1))
    done
    "$bin" evaluate --data "$fold" --train-size "$size" --seeds "$seeds" \
      --methods "$methods" -o "$folds/$name" > /dev/null
    # The Markdown first, the JSON last: a fold counts as done by its JSON.
    mv "$folds/$name.md" "$result.md"
    mv "$folds/$name.json" "$result.json"
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
for a in actions:
    demos = {m: sorted(d for d, _, _ in rows.get((a, m), [])) for m in methods}
    assert len({tuple(v) for v in demos.values()}) == 1, f"{a}: methods over different folds: {demos}"
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
