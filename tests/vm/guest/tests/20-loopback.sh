# shellcheck shell=sh
# crossline feed writes a simulated dump into a v4l2loopback device and crossline
# record captures it from the other side: the payloads must come through unchanged
# (compared on the host, tests/vm/host/20-loopback.check.sh).
. /vm/lib.sh
# exclusive_caps=0: the node reports CAPTURE and OUTPUT at all times, so record can
# open it whether or not the feeder is writing yet.
load_module v4l2loopback video_nr=10 exclusive_caps=0 card_label=crossline-loop
wait_for_dev /dev/video10

echo "+ crossline feed --device /dev/video10 --input $DATA/bricks.dump --fps 30 --loop &"
crossline feed --device /dev/video10 --input "$DATA/bricks.dump" --fps 30 --loop \
    >"$RESULTS/feed.log" 2>&1 &
feeder=$!
# The capture side has no format until the writer has started; v4l2loopback shows
# it in sysfs ("MJPG:320x180@30") from then on.
n=0
until [ -n "$(cat /sys/class/video4linux/video10/format 2>/dev/null)" ]; do
    kill -0 $feeder 2>/dev/null || {
        cat "$RESULTS/feed.log"
        fail "crossline feed exited before writing a frame"
    }
    n=$((n + 1))
    [ $n -le 200 ] || fail "no format on /dev/video10 after 20 s of crossline feed"
    sleep 0.1
done
echo "/dev/video10 format: $(cat /sys/class/video4linux/video10/format)"
echo "+ crossline record --device /dev/video10 --frames 20"
crossline record --device /dev/video10 --frames 20 --out "$RESULTS/loop.dump" ||
    rc=$?
kill $feeder 2>/dev/null || true
wait $feeder 2>/dev/null || true
echo "--- feed output:"
cat "$RESULTS/feed.log"
[ "${rc:-0}" -eq 0 ] || fail "record from /dev/video10 failed (status $rc)"
rmmod v4l2loopback
