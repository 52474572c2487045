# shellcheck shell=bash
# The dump that 30-record-feed-edges feeds (the same as 20-loopback's).
[[ -f $DATA/bricks.dump ]] && exit 0
sim=$(mktemp -d)
"$CROSSLINE" simulate --scene bricks --frames 20 --width 320 --format dump --out "$sim"
mv "$sim/frames.dump" "$DATA/bricks.dump"
rm -rf "$sim"
