# shellcheck shell=sh
# vm-timeout: 600
# The daemon end to end on a camera: crossline feed writes the simulated laser scan
# into v4l2loopback; crossline serve captures it from the capture side exactly as
# from a camera, records it, processes it and, on SIGTERM, writes its cloud. The host
# check (tests/vm/host/40-serve-loopback.check.sh) compares the recording with the
# fed frames and the cloud with `crossline reconstruct` of the same frames.
# The final self-calibration of the 100 frames takes about 3 s natively and 270 s under
# TCG (software floating point, one CPU; measured 2026-12-03), hence its vm-timeout.
. /vm/lib.sh
load_module v4l2loopback video_nr=11 exclusive_caps=0 card_label=crossline-serve
wait_for_dev /dev/video11

# One frame gives the node its format; the pause lets the daemon start before the
# scan proper. 10 fps: the VM has one emulated CPU.
echo "+ crossline feed --device /dev/video11 --fps 10 --pause-after 1 --pause-seconds 6 &"
crossline feed --device /dev/video11 --input "$DATA/serve-scan.dump" --fps 10 \
    --pause-after 1 --pause-seconds 6 >"$RESULTS/feed.log" 2>&1 &
feeder=$!
n=0
until [ -n "$(cat /sys/class/video4linux/video11/format 2>/dev/null)" ]; do
    n=$((n + 1))
    [ $n -le 200 ] || fail "no format on /dev/video11 after 20 s of crossline feed"
    sleep 0.1
done

cat >/tmp/serve.toml <<CONF
[serve]
formats = ["MJPG"]
width = 480
height = 270
fps = 10
status_socket = "/tmp/crossline-status.sock"
stream_tcp = ""
checkpoint_interval_s = 0.5
CONF
echo "+ crossline serve --device /dev/video11 &"
crossline serve --config /tmp/serve.toml --camera "$DATA/serve-camera.yml" \
    --device /dev/video11 --out-dir "$RESULTS/out" --out "$RESULTS/cloud.ply" \
    --report "$RESULTS/report.json" 2>"$RESULTS/serve.log" &
serve=$!
wait_for_dev /tmp/crossline-status.sock 20
crossline status --json --socket /tmp/crossline-status.sock >"$RESULTS/status.jsonl" 2>&1 &
wait $feeder || fail "crossline feed failed: $(cat "$RESULTS/feed.log")"
sleep 2
kill -TERM $serve
rc=0
wait $serve || rc=$?
cat "$RESULTS/serve.log"
[ $rc -eq 0 ] || fail "crossline serve exited $rc after SIGTERM, expected 0"
[ -s "$RESULTS/cloud.ply" ] || fail "no cloud written at shutdown"
grep -q '"type":"status"' "$RESULTS/status.jsonl" || fail "no status line on the socket"
grep -q '"device":"streaming"' "$RESULTS/status.jsonl" || fail "status never said streaming"
rmmod v4l2loopback
