# shellcheck shell=bash
# A camera file at vivid's 320x180 (any intrinsics do: vivid shows no laser), and the
# helper that unplugs vivid (static: the VM has no C library of its own).
sim=$(mktemp -d)
"$CROSSLINE" simulate --scene bricks --frames 1 --width 320 --format dump --out "$sim" >/dev/null 2>&1
cp "$sim/camera.yml" "$DATA/vivid-camera.yml"
rm -rf "$sim"
[[ -x $DATA/vivid-disconnect ]] ||
    gcc -static -O1 -o "$DATA/vivid-disconnect" "$(dirname "$0")/vivid-disconnect.c"
