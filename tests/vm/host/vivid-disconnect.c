/* Presses vivid's "Disconnect" button control: the driver then behaves as a USB
 * camera whose cable was pulled (poll gives POLLERR | POLLHUP, ioctls ENODEV) until
 * every open file handle is closed. Built static by 30-record-feed-edges.prepare.sh
 * because the VM has no v4l2-ctl. Usage: vivid-disconnect /dev/videoN */
#include <fcntl.h>
#include <linux/videodev2.h>
#include <stdio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

int main(int argc, char **argv)
{
	if (argc != 2) {
		fprintf(stderr, "usage: %s /dev/videoN\n", argv[0]);
		return 2;
	}
	int fd = open(argv[1], O_RDWR);
	if (fd < 0) {
		perror(argv[1]);
		return 1;
	}
	struct v4l2_queryctrl q;
	memset(&q, 0, sizeof q);
	q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
	while (ioctl(fd, VIDIOC_QUERYCTRL, &q) == 0) {
		if (strcmp((const char *)q.name, "Disconnect") == 0) {
			struct v4l2_control c = { .id = q.id, .value = 1 };
			if (ioctl(fd, VIDIOC_S_CTRL, &c) != 0) {
				perror("VIDIOC_S_CTRL Disconnect");
				return 1;
			}
			printf("%s: disconnected (control %#x)\n", argv[1], q.id);
			return 0;
		}
		q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
	}
	fprintf(stderr, "%s: no Disconnect control (not vivid?)\n", argv[1]);
	return 1;
}
