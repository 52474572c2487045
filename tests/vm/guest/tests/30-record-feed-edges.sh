# shellcheck shell=sh
# The edges of record and feed that only real drivers show: Ctrl-C, a busy camera,
# an unplugged one, a v4l2loopback node without its writer, feeding the same node
# twice (v4l2loopback 0.12.7 hides OUTPUT after a write()-only writer unless it
# called STREAMON), a feeder that vanishes for a while and one that stops for good.
. /vm/lib.sh
load_module vivid n_devs=1 node_types=0x1
wait_for_dev /dev/video0

echo "+ crossline record --list-formats"
crossline record --device /dev/video0 --list-formats >"$RESULTS/formats.txt" ||
    fail "record --list-formats failed"
head -n 20 "$RESULTS/formats.txt"
grep -q '^YUYV' "$RESULTS/formats.txt" || fail "--list-formats does not list YUYV"
grep -q '^  640x360 at .*30' "$RESULTS/formats.txt" || fail "--list-formats does not list 640x360 at 30 fps"

echo "+ crossline record (no limit), then SIGINT"
crossline record --device /dev/video0 --format yuyv --size 320x180 --fps 30 \
    --out "$RESULTS/int.dump" 2>"$RESULTS/int.stderr" &
p=$!
sleep 2
kill -INT $p
rc=0
wait $p || rc=$?
cat "$RESULTS/int.stderr"
[ $rc -eq 0 ] || fail "record stopped by SIGINT exited $rc"
grep -q 'stopped by signal' "$RESULTS/int.stderr" || fail "record did not say it was stopped by the signal"
[ "$(wc -c <"$RESULTS/int.dump")" -gt 100000 ] || fail "SIGINT left a dump without frames"

echo "+ two records from one camera: the second is refused as busy"
crossline record --device /dev/video0 --format yuyv --size 320x180 --seconds 4 \
    --out "$RESULTS/first.dump" 2>"$RESULTS/first.stderr" &
p=$!
sleep 1.5
rc=0
crossline record --device /dev/video0 --frames 5 --out "$RESULTS/second.dump" \
    2>"$RESULTS/second.stderr" || rc=$?
cat "$RESULTS/second.stderr"
first=0
wait $p || first=$?
[ $rc -eq 1 ] || fail "the second record exited $rc, expected 1"
grep -q 'is busy' "$RESULTS/second.stderr" || fail "the second record did not say the camera is busy"
[ $first -eq 0 ] || fail "the first record exited $first"

echo "+ the camera is unplugged while record runs (vivid's Disconnect control)"
crossline record --device /dev/video0 --format yuyv --size 320x180 --fps 30 \
    --out "$RESULTS/unplug.dump" 2>"$RESULTS/unplug.stderr" &
p=$!
sleep 2
run "$DATA/vivid-disconnect" /dev/video0
rc=0
wait $p || rc=$?
cat "$RESULTS/unplug.stderr"
[ $rc -eq 1 ] || fail "record from an unplugged camera exited $rc, expected 1"
grep -q 'camera lost' "$RESULTS/unplug.stderr" || fail "record did not say the camera was lost"
grep -q '/dev/video0 went away' "$RESULTS/unplug.stderr" || fail "record did not name the lost device"
[ "$(wc -c <"$RESULTS/unplug.dump")" -gt 100000 ] || fail "the frames before the unplug are not in the dump"
echo "+ and plugged back in: once every handle is closed, vivid reconnects"
run crossline record --device /dev/video0 --format yuyv --size 320x180 --frames 3 \
    --out "$RESULTS/replug.dump"
rmmod vivid

load_module v4l2loopback video_nr=10 exclusive_caps=1 card_label=crossline-loop
wait_for_dev /dev/video10

echo "+ record from a loopback node that has no writer"
rc=0
crossline record --device /dev/video10 --frames 5 --out "$RESULTS/nowriter.dump" \
    2>"$RESULTS/nowriter.stderr" || rc=$?
cat "$RESULTS/nowriter.stderr"
[ $rc -eq 1 ] || fail "record without a writer exited $rc, expected 1"
grep -q '/dev/video10 is not a V4L2 capture device' "$RESULTS/nowriter.stderr" ||
    fail "record without a writer did not name the device and the problem"

echo "+ feed the node twice in a row"
run crossline feed --device /dev/video10 --input "$DATA/bricks.dump" --fps 60 --stop-after 10
run crossline feed --device /dev/video10 --input "$DATA/bricks.dump" --fps 60 --stop-after 10

echo "+ a YUYV recording (from vivid above) through the loopback: uncompressed frames"
crossline feed --device /dev/video10 --input "$RESULTS/int.dump" --fps 30 --loop \
    --stop-after 150 >"$RESULTS/feed-yuyv.log" 2>&1 &
f=$!
sleep 1
rc=0
crossline record --device /dev/video10 --format yuyv --frames 20 --timeout 5 \
    --out "$RESULTS/yuyv-loop.dump" 2>"$RESULTS/yuyv-loop.stderr" || rc=$?
kill $f 2>/dev/null
wait $f 2>/dev/null
cat "$RESULTS/yuyv-loop.stderr" "$RESULTS/feed-yuyv.log"
[ $rc -eq 0 ] || fail "record of fed YUYV frames exited $rc"
grep -q 'negotiated YUYV 320x180 (640 bytes per line)' "$RESULTS/yuyv-loop.stderr" ||
    fail "the loopback did not carry YUYV 320x180"
[ "$(wc -c <"$RESULTS/yuyv-loop.dump")" -gt $((20 * 115200)) ] || fail "fewer than 20 whole YUYV frames"

# The pause starts 3 s in, well after record has opened the node: a reader that
# opens it while no writer holds it is refused (the previous test shows how).
echo "+ feed closes the node for 3 s while record reads it (--timeout 8)"
crossline feed --device /dev/video10 --input "$DATA/bricks.dump" --fps 30 --loop \
    --pause-after 90 --pause-seconds 3 --close-during-pause --stop-after 200 \
    >"$RESULTS/feed-close.log" 2>&1 &
f=$!
sleep 1
rc=0
crossline record --device /dev/video10 --frames 120 --timeout 8 --out "$RESULTS/close.dump" || rc=$?
frc=0
wait $f || frc=$?
cat "$RESULTS/feed-close.log"
[ $rc -eq 0 ] || fail "record across the feeder's 3 s absence exited $rc"
[ $frc -eq 0 ] || fail "feed --close-during-pause exited $frc"
grep -q 'resuming' "$RESULTS/feed-close.log" || fail "feed did not resume after its pause"

echo "+ the feeder stops for good: record --timeout 2 gives up"
crossline feed --device /dev/video10 --input "$DATA/bricks.dump" --fps 30 --loop \
    --stop-after 45 >"$RESULTS/feed-stop.log" 2>&1 &
f=$!
sleep 1
rc=0
crossline record --device /dev/video10 --timeout 2 --out "$RESULTS/stop.dump" \
    2>"$RESULTS/stop.stderr" || rc=$?
wait $f || true
cat "$RESULTS/stop.stderr"
[ $rc -eq 1 ] || fail "record from a stopped feeder exited $rc, expected 1"
grep -q -- '--timeout' "$RESULTS/stop.stderr" || fail "record did not say it timed out"
grep -q 'holds the frames' "$RESULTS/stop.stderr" || fail "record did not say where its frames are"
rmmod v4l2loopback
