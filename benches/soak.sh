#!/usr/bin/env bash
# Soak test, run by hand: `crossline serve` replays a dump in a loop (realtime) for
# HOURS (default 2), and the daemon's RSS is sampled every SAMPLE_S seconds (default
# 1) into target/bench-soak/rss.tsv. A flat RSS after the warm-up is the pass mark;
# the script prints the first, the highest and the last sample and their spread.
#
#   benches/soak.sh [HOURS] [DUMP]     (default: fixtures/sim-bricks/frames.dump)
#   CROSSLINE=/tmp/bin/crossline benches/soak.sh 2   (a copy of the binary: rebuilding
#                                       target/release during the soak then changes nothing)
#
# The replay loop is a v4l2loopback-free stand-in for a long dive: `serve --replay`
# has no loop, so each pass is a new serve run on the same out_dir (a fresh scan),
# started as soon as the last ended; the samples show RSS and descriptors within each
# run and from run to run. One daemon for two hours needs a camera, or
# `crossline feed --loop` into a v4l2loopback device with `serve --device`.
set -euo pipefail
cd "$(dirname "$0")/.."
hours=${1:-2}
dump=${2:-fixtures/sim-bricks/frames.dump}
sample_s=${SAMPLE_S:-1}
out=target/bench-soak
mkdir -p "$out"
bin=${CROSSLINE:-target/release/crossline}
[[ -n ${CROSSLINE:-} ]] || cargo build --release
camera=$(dirname "$dump")/camera.yml
end=$(($(date +%s) + $(printf '%.0f' "$(echo "$hours * 3600" | bc)")))
printf 'elapsed_s\tpass\tpid\trss_kib\tfds\n' >"$out/rss.tsv"
start=$(date +%s)
pass=0
while (($(date +%s) < end)); do
    pass=$((pass + 1))
    "$bin" serve --camera "$camera" --replay "$dump" --rate realtime \
        --out-dir "$out/state" --out "$out/cloud.ply" --report "$out/report.json" \
        --status-socket "$out/status.sock" --stream-unix "$out/cloud.sock" --stream-tcp "" --http "" \
        2>>"$out/serve.log" &
    pid=$!
    while kill -0 "$pid" 2>/dev/null; do
        if [[ -r /proc/$pid/status ]]; then
            rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || echo 0)
            fds=$( (find "/proc/$pid/fd" -mindepth 1 2>/dev/null || true) | wc -l)
            printf '%s\t%s\t%s\t%s\t%s\n' "$(($(date +%s) - start))" "$pass" "$pid" "$rss" "$fds" >>"$out/rss.tsv"
        fi
        sleep "$sample_s" &
        wait $! || true
        (($(date +%s) < end)) || kill -TERM "$pid" 2>/dev/null || true
    done
    wait "$pid" || echo "benches/soak.sh: pass $pass exited $?" >&2
done
awk -F'\t' 'NR == 2 {first = $4} NR > 1 {if ($4 > max) max = $4; last = $4; n++}
    END {printf "samples %d  first %d KiB  max %d KiB  last %d KiB  (max-first %+d KiB)\n", n, first, max, last, max - first}' "$out/rss.tsv"
