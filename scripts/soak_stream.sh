#!/usr/bin/env bash
# Soak test of `phasekit stream` (not part of the test suite): streams FRAMES
# human frames (default 10^7: 31 hours of a 90 Hz tracker, 3.9 days at NuiSI's
# 30 Hz, fed here as fast as the stream reads, about a minute) through the
# release build, samples
# the process's resident memory along the way, and prints the samples and the
# stream's own summary (statuses, latency percentiles from its fixed-size
# histogram).
#
#   bash scripts/soak_stream.sh            # 10^7 frames
#   bash scripts/soak_stream.sh 1000000    # 10^6 frames
#
# The input cycles through the generated test demonstrations of `phasekit demo`
# (human wrist x, y, z), with a `#reset` line between demonstrations, one
# missing value every 997 frames, and it is written into the stream as fast as
# it reads; the output (one flushed line per frame) goes to /dev/null.
# Memory: VmRSS of the stream process every SAMPLE seconds (default 2), and
# VmHWM (its peak) at the end; the frames read so far are estimated from the
# bytes it has read. Results for the README's robustness section.
set -euo pipefail

FRAMES=${1:-10000000}
SAMPLE=${SAMPLE:-2}
root=$(cd "$(dirname "$0")/.." && pwd)
cargo build --release -q -p phasekit-cli --manifest-path "$root/Cargo.toml"
P=$root/target/release/phasekit
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

"$P" demo -o "$work/demo" > /dev/null
model=$work/demo/tsc-hmm.json
# The human's columns of the test demonstrations, one demonstration per block.
for f in "$work"/demo/data/test_*.csv; do
    tail -n +2 "$f" | cut -d, -f1-3
    echo '#reset'
done > "$work/cycle.txt"
bytes_per_line=$(awk '{ n += length($0) + 1 } END { printf "%.3f", n / NR }' "$work/cycle.txt")

generate() {
    awk -v frames="$FRAMES" '
        { line[NR] = $0 }
        END {
            print "p1_wrist_x,p1_wrist_y,p1_wrist_z"
            n = 0; i = 0
            while (n < frames) {
                i = i % NR + 1
                l = line[i]
                if (l != "#reset") {
                    n++
                    if (n % 997 == 0) { sub(/^[^,]*/, "", l) }   # x not observed
                }
                print l
            }
        }' "$work/cycle.txt"
}

mkfifo "$work/in"
generate > "$work/in" &
gen=$!
start=$(date +%s.%N)
"$P" stream --model "$model" < "$work/in" > /dev/null 2> "$work/stderr" &
pid=$!

hwm=""
echo "| elapsed (s) | frames read (≈) | resident memory (MB) |"
echo "|---:|---:|---:|"
while kill -0 "$pid" 2> /dev/null; do
    if [[ -r /proc/$pid/status ]]; then
        rss=$(awk '/^VmRSS:/ { printf "%.1f", $2 / 1024 }' "/proc/$pid/status" 2> /dev/null || true)
        rchar=$(awk '/^rchar:/ { print $2 }' "/proc/$pid/io" 2> /dev/null || echo 0)
        hwm=$(awk '/^VmHWM:/ { printf "%.1f", $2 / 1024 }' "/proc/$pid/status" 2> /dev/null || echo "$hwm")
        now=$(date +%s.%N)
        if [[ -n "$rss" ]]; then
            printf "| %.0f | %.0f | %s |\n" "$(echo "$now - $start" | bc)" \
                "$(echo "$rchar / $bytes_per_line" | bc)" "$rss"
        fi
    fi
    sleep "$SAMPLE"
done
wait "$pid"
wait "$gen"
end=$(date +%s.%N)
echo
echo "peak resident memory (VmHWM, last sample): ${hwm:-?} MB"
printf "wall time: %.1f s for %s frames\n" "$(echo "$end - $start" | bc)" "$FRAMES"
echo "stream's summary (stderr):"
cat "$work/stderr"
