# shellcheck shell=sh
# The camera is unplugged mid-scan (vivid's Disconnect control, as a cable or housing
# connector failing): crossline serve must report the device lost, keep running,
# reopen it when it comes back, and go on with the same scan.
. /vm/lib.sh
load_module vivid n_devs=1 node_types=0x1
wait_for_dev /dev/video0

cat >/tmp/loss.toml <<CONF
[serve]
formats = ["YUYV"]
width = 320
height = 180
fps = 30
status_socket = "/tmp/loss-status.sock"
status_interval_ms = 200
stream_tcp = ""
reconnect_max_backoff_s = 0.5
CONF
echo "+ crossline serve --device /dev/video0 &"
crossline serve --config /tmp/loss.toml --camera "$DATA/vivid-camera.yml" \
    --device /dev/video0 --out-dir "$RESULTS/out" --out "$RESULTS/cloud.ply" \
    --report "$RESULTS/report.json" 2>"$RESULTS/serve.log" &
serve=$!
wait_for_dev /tmp/loss-status.sock 20
crossline status --json --socket /tmp/loss-status.sock >"$RESULTS/status.jsonl" 2>&1 &
sleep 3
run "$DATA/vivid-disconnect" /dev/video0
# Once the daemon has let go of the old handle, vivid takes new ones again.
n=0
until grep -q '"device":"lost"' "$RESULTS/status.jsonl"; do
    n=$((n + 1))
    [ $n -le 100 ] || fail "status never reported the device lost"
    sleep 0.1
done
lost_at=$(grep '"device":"lost"' "$RESULTS/status.jsonl" | head -1 | sed 's/.*"frames_in":\([0-9]*\).*/\1/')
echo "device lost after $lost_at frames"
n=0
until tail -1 "$RESULTS/status.jsonl" | grep -q '"device":"streaming"'; do
    n=$((n + 1))
    [ $n -le 150 ] || fail "the daemon did not resume streaming after the camera came back"
    sleep 0.1
done
sleep 2
kill -TERM $serve
rc=0
wait $serve || rc=$?
cat "$RESULTS/serve.log"
[ $rc -eq 0 ] || fail "crossline serve exited $rc, expected 0"
total=$(sed -n 's/.*"frames_in": *\([0-9]*\).*/\1/p' "$RESULTS/report.json")
echo "frames before the loss: $lost_at, in all: $total"
[ "$total" -gt $((lost_at + 10)) ] || fail "no frames after the camera came back"
grep -q 'camera lost' "$RESULTS/serve.log" || fail "the log does not say the camera was lost"
rmmod vivid
