# shellcheck shell=bash
# 40-serve-loopback feeds the project's recorded fixture (100 MJPEG frames of the
# bricks table top at 480x270, see fixtures/README.md) and needs its camera.
cp "$(dirname "$0")/../../../fixtures/sim-bricks/frames.dump" "$DATA/serve-scan.dump"
cp "$(dirname "$0")/../../../fixtures/sim-bricks/camera.yml" "$DATA/serve-camera.yml"
