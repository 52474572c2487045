# shellcheck shell=sh
# The VM itself: crossline runs (its libraries are in place) and both V4L2 drivers
# load and make their nodes.
. /vm/lib.sh
run crossline --version
load_module vivid n_devs=1 node_types=0x1
wait_for_dev /dev/video0
cat /sys/class/video4linux/video0/name
load_module v4l2loopback video_nr=10 exclusive_caps=0 card_label=crossline-loop
wait_for_dev /dev/video10
cat /sys/class/video4linux/video10/name
ls -l /dev/video*
