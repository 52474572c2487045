# shellcheck shell=bash
# The dump that 20-loopback feeds: 20 simulated MJPEG frames, small enough for TCG.
sim=$(mktemp -d)
"$CROSSLINE" simulate --scene bricks --frames 20 --width 320 --format dump --out "$sim"
mv "$sim/frames.dump" "$DATA/bricks.dump"
rm -rf "$sim"
