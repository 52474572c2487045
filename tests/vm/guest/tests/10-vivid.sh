# shellcheck shell=sh
# crossline record against vivid, the kernel's virtual camera: a format it offers
# (YUYV) and one it lacks (MJPEG), where record must fall back and say so. The dumps
# are checked on the host (tests/vm/host/10-vivid.check.sh).
. /vm/lib.sh
load_module vivid n_devs=1 node_types=0x1
wait_for_dev /dev/video0

for fmt in yuyv mjpg; do
    echo "+ crossline record --device /dev/video0 --format $fmt --size 640x360 --fps 30 --frames 30"
    crossline record --device /dev/video0 --format $fmt --size 640x360 --fps 30 --frames 30 \
        --out "$RESULTS/vivid-$fmt.dump" 2>"$RESULTS/record-$fmt.stderr" ||
        {
            cat "$RESULTS/record-$fmt.stderr"
            fail "record --format $fmt failed"
        }
    cat "$RESULTS/record-$fmt.stderr"
done

# vivid has no MJPEG: the fallback must be on stderr, naming what was asked for.
if ! grep -qiE '(asked for|requested|wanted).*(mjpg|mjpeg)' "$RESULTS/record-mjpg.stderr" ||
    ! grep -qiE 'using|fall|instead|not (offer|support|availab)' "$RESULTS/record-mjpg.stderr"; then
    fail "record --format mjpg on vivid (no MJPEG) did not report a fallback on stderr"
fi
rmmod vivid
