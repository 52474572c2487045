# shellcheck shell=bash
# The dump that 30-record-feed-edges feeds (the same as 20-loopback's), and the
# helper that unplugs vivid (static: the VM has no C library of its own).
if [[ ! -f $DATA/bricks.dump ]]; then
    sim=$(mktemp -d)
    "$CROSSLINE" simulate --scene bricks --frames 20 --width 320 --format dump --out "$sim"
    mv "$sim/frames.dump" "$DATA/bricks.dump"
    rm -rf "$sim"
fi
gcc -static -O1 -o "$DATA/vivid-disconnect" "$(dirname "$0")/vivid-disconnect.c"
