#!/usr/bin/env bash
# Benchmark of the live daemon: real-time replay of a 1920x1080 MJPEG 30 fps dump with
# two cloud stream clients attached. Prints frames dropped, latency from a frame's
# capture to its points leaving the socket (p50, p95, max), and the CPU share of the
# machine's cores, over the whole run and over its live part (until the last frame,
# before the final solve), and the daemon's resident memory against the cloud it holds
# (sampled with each status line: /proc/PID/status VmRSS beside the line's points and
# crossings). Targets: zero drops, p95 < 150 ms, CPU < 60 % of two cores while live,
# the final cloud <= 10 s after the last frame, memory growing with the cloud only.
#
#   cargo build --release && benches/serve-replay.sh [WORKDIR]
#
# The dump is simulated once (crossline simulate --scene room --format dump) and kept
# in WORKDIR (default target/bench-serve). FRAMES=600 for a longer run; SERVE_ARGS adds
# serve arguments (word-split), e.g. SERVE_ARGS="--config my.toml".
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${CROSSLINE:-target/release/crossline}
WORK=${1:-target/bench-serve}
FRAMES=${FRAMES:-300}
SCENE=${SCENE:-room}
[ -x "$BIN" ] || { echo "build first: cargo build --release" >&2; exit 2; }
mkdir -p "$WORK"
SIM="$WORK/sim-$SCENE-$FRAMES"
if [ ! -f "$SIM/frames.dump" ]; then
    "$BIN" simulate --scene "$SCENE" --frames "$FRAMES" --format dump --jpeg-quality 90 \
        --seed 1 --out "$SIM"
fi
RUN="$WORK/run"
rm -rf "$RUN"; mkdir -p "$RUN"
PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
"$BIN" serve --camera "$SIM/camera.yml" --replay "$SIM/frames.dump" --rate realtime \
    --out-dir "$RUN/out" --out "$RUN/cloud.ply" --report "$RUN/report.json" \
    --status-socket "$RUN/status.sock" --stream-tcp "127.0.0.1:$PORT" --http "" \
    ${SERVE_ARGS:-} 2> "$RUN/serve.log" &
SERVE=$!
for _ in $(seq 200); do [ -S "$RUN/status.sock" ] && break; sleep 0.05; done
# Resident memory beside what the daemon holds, one row per status line, until it ends.
python3 - "$RUN/status.sock" "$SERVE" > "$RUN/memory.tsv" 2> /dev/null <<'PY' &
import json, socket, sys
sock = socket.socket(socket.AF_UNIX)
sock.connect(sys.argv[1])
print("uptime_s\tframes_in\tcrossings\tpoints\trss_kib")
for line in sock.makefile():
    try:
        s = json.loads(line)
        rss = next(l for l in open(f"/proc/{sys.argv[2]}/status") if l.startswith("VmRSS"))
    except (ValueError, OSError, StopIteration):
        break
    if s.get("type") == "status":
        print(f"{s['uptime_s']}\t{s['frames_in']}\t{s['crossings']}\t{s['points']}\t{rss.split()[1]}", flush=True)
PY
MEM=$!
"$BIN" tail --connect "127.0.0.1:$PORT" --out "$RUN/a.ply" 2> "$RUN/a.log" &
A=$!
"$BIN" tail --connect "127.0.0.1:$PORT" --out "$RUN/b.ply" 2> "$RUN/b.log" &
B=$!
wait $SERVE
wait $A
wait $B
wait $MEM || true
cmp -s "$RUN/a.ply" "$RUN/b.ply" && echo "both clients hold the same cloud"
python3 - "$RUN/report.json" "$RUN/memory.tsv" <<'PY'
import json, os, sys
r = json.load(open(sys.argv[1]))
rows = [l.split("\t") for l in open(sys.argv[2]).read().splitlines()[1:]]
rows = [tuple(float(x) for x in row) for row in rows if len(row) == 5]
cores = os.cpu_count()
rec = r.get("reconstruction") or {}
print(f"frames in {r['frames_in']}, dropped by the ring {r['frames_dropped_ring']}, "
      f"by the driver {r['frames_dropped_driver']}, processed {r['frames_processed']}")
l = r["latency"]
print(f"latency of a frame's points, placed on arrival (capture -> socket): p50 {l['p50_ms']:.1f} ms, "
      f"p95 {l['p95_ms']:.1f} ms, max {l['max_ms']:.1f} ms over {l['samples']} messages")
e = r["epoch_latency"]
print(f"age of an epoch's points (newest frame's capture -> socket): p50 {e['p50_ms']:.0f} ms, "
      f"p95 {e['p95_ms']:.0f} ms over {e['samples']} messages")
s = r["live_solver"]
print(f"frames placed on arrival: {s['frames_placed_on_arrival']} of {r['frames_processed']}, "
      f"late (from an epoch's backlog): {s['frames_placed_late']}")
f = r["solver_frame"]
print(f"solver thread per frame: p50 {f['p50_ms']:.1f} ms, p95 {f['p95_ms']:.1f} ms, max {f['max_ms']:.1f} ms")
print(f"CPU {r['cpu_seconds']:.1f} s over {r['wall_seconds']:.1f} s wall = "
      f"{100 * r['cpu_seconds'] / r['wall_seconds'] / cores:.0f} % of {cores} cores; "
      f"until the last frame (live, before the final solve) {r['live_cpu_seconds']:.1f} s over "
      f"{r['live_wall_seconds']:.1f} s = "
      f"{100 * r['live_cpu_seconds'] / max(r['live_wall_seconds'], 1e-9) / cores:.0f} %")
fin = r.get("final_cloud_after_last_frame_s")
print(f"final cloud written {fin:.1f} s after the last frame's capture" if fin is not None else "no final cloud")
print(f"epochs {r['epochs']}, points {r['points']}, planes solved "
      f"{rec.get('planes_solved')} of {rec.get('planes')}")
# Memory at each quarter of the frames, and what each point held costs over the run.
live = [row for row in rows if row[1] < r["frames_in"]] or rows
if len(live) >= 2:
    print("resident memory while live (frames in, crossings, points held: RSS):")
    for q in (0.25, 0.5, 0.75, 1.0):
        t, f, c, p, rss = live[min(len(live) - 1, int(q * (len(live) - 1)))]
        print(f"  {f:6.0f} frames  {c:9.0f} crossings  {p:9.0f} points  {rss / 1024:7.0f} MiB")
    (_, f0, _, p0, m0), (_, f1, _, p1, m1) = live[len(live) // 4], live[-1]
    if p1 > p0:
        print(f"  from a quarter of the frames to the last: {1024 * (m1 - m0) / (p1 - p0):.0f} bytes "
              f"of RSS per point added ({(m1 - m0) / 1024:.0f} MiB for {p1 - p0:.0f} points)")
    print(f"peak RSS sampled {max(row[4] for row in rows) / 1024:.0f} MiB")
PY
