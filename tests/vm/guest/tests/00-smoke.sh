# The VM itself: crossline runs (its libraries are in place) and the kernel's V4L2
# test driver loads and makes a capture node.
. /vm/lib.sh
run crossline --version
run modprobe vivid n_devs=1 node_types=0x1
wait_for_dev /dev/video0
cat /sys/class/video4linux/video0/name
run modprobe v4l2loopback video_nr=10 exclusive_caps=0 card_label=crossline-loop
wait_for_dev /dev/video10
cat /sys/class/video4linux/video10/name
ls -l /dev/video*
