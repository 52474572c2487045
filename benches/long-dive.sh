#!/usr/bin/env bash
# Long-dive benchmark (issue 18): the paper's scan length, 5,400 frames of 1920x1080
# MJPEG (3 minutes at 30 fps), simulated once and cached, then
#   1. `crossline reconstruct` of it: wall time, CPU time, peak RSS (from /usr/bin/time)
#      and the report's seconds per stage (decoding is part of background_s/extract_s),
#      and its accuracy against the simulator's truth (`crossline compare --truth`);
#   2. with LIVE=1, `serve --rate realtime` replaying it (benches/serve-replay.sh's
#      measurements: drops, latency p50/p95, CPU share) and the time from the last
#      frame to the final cloud.
# Targets (issue 18): 5,400 frames in <= 60 s wall with <= 2 GB RSS on two cores; the
# 1,800/600 wall ratio <= 3.6 (FRAMES=600 and FRAMES=1800 runs of this script).
#
#   cargo build --release && benches/long-dive.sh [WORKDIR]
#   FRAMES=600 benches/long-dive.sh          # the scaling points
#
# Environment: CROSSLINE (binary), FRAMES (5400), WORK (target/bench-dive); the
# simulation lives in WORK/sim-FRAMES and is reused while it exists (about 50 min to
# make on two cores at 5,400 frames).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${CROSSLINE:-target/release/crossline}
FRAMES=${FRAMES:-5400}
WORK=${1:-${WORK:-target/bench-dive}}
[ -x "$BIN" ] || { echo "build first: cargo build --release" >&2; exit 2; }
[ -x /usr/bin/time ] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 2; }
SIM="$WORK/sim-$FRAMES"
mkdir -p "$WORK"
if [ ! -f "$SIM/frames.dump" ]; then
    echo "simulating $FRAMES frames into $SIM (once)" >&2
    "$BIN" simulate --scene room --frames "$FRAMES" --seed 1 --format dump --out "$SIM"
fi
RUN="$WORK/run-$FRAMES"
rm -rf "$RUN"; mkdir -p "$RUN"
/usr/bin/time -v "$BIN" reconstruct --input "$SIM/frames.dump" --camera "$SIM/camera.yml" \
    --out "$RUN/cloud.ply" --report "$RUN/report.json" 2> "$RUN/reconstruct.log"
"$BIN" compare "$RUN/cloud.ply" --truth "$SIM" --json > "$RUN/compare.json" 2> /dev/null
python3 - "$RUN" <<'PY'
import json, re, sys
run = sys.argv[1]
log = open(f"{run}/reconstruct.log").read()
def field(name):
    m = re.search(re.escape(name) + r": (.*)", log)
    return m.group(1).strip() if m else "?"
wall = field("Elapsed (wall clock) time (h:mm:ss or m:ss)")
rss = int(field("Maximum resident set size (kbytes)")) / 1024
cpu = float(field("User time (seconds)")) + float(field("System time (seconds)"))
r = json.load(open(f"{run}/report.json"))
t = json.load(open(f"{run}/compare.json"))["truth"]
print(f"frames {r['frames']}  curves {r['curves']}  planes {r['planes']}  crossings {r['crossings']}  points {r['points']}")
print(f"wall {wall}  cpu {cpu:.1f} s  peak RSS {rss:.0f} MiB")
print("seconds per stage: " + "  ".join(f"{k[:-2]} {v:.1f}" for k, v in r["seconds"].items()))
e = t["relative_error"]
print(f"depth error median {100*e['median']:.4f} %  p95 {100*e['p95']:.3f} %  "
      f"points on wrong planes {100*t['points_on_wrong_planes_fraction']:.2f} %  "
      f"coverage {100*t['coverage']['fraction']:.1f} %")
PY
if [ "${LIVE:-0}" = 1 ]; then
    # The same recording, under the name serve-replay.sh looks for.
    mkdir -p "$WORK/live"
    ln -sfn "$(realpath "$SIM")" "$WORK/live/sim-room-$FRAMES"
    FRAMES=$FRAMES CROSSLINE="$BIN" benches/serve-replay.sh "$WORK/live"
fi
