/* Presses a V4L2 button control by its name, for the guest test (tests/vivid.rs): vivid's
 * "Disconnect" unplugs its device while another process streams from it. Built statically by
 * the test with the host's C compiler. Usage: v4l2-button DEVICE NAME */
#include <fcntl.h>
#include <linux/videodev2.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/ioctl.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: v4l2-button DEVICE NAME\n");
        return 2;
    }
    int fd = open(argv[1], O_RDWR | O_NONBLOCK);
    if (fd < 0) {
        perror(argv[1]);
        return 1;
    }
    struct v4l2_queryctrl q;
    memset(&q, 0, sizeof q);
    q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
    while (ioctl(fd, VIDIOC_QUERYCTRL, &q) == 0) {
        if (strcasecmp((const char *)q.name, argv[2]) == 0) {
            struct v4l2_control c = {.id = q.id, .value = 1};
            if (ioctl(fd, VIDIOC_S_CTRL, &c) != 0) {
                perror("VIDIOC_S_CTRL");
                return 1;
            }
            printf("pressed %s\n", q.name);
            close(fd);
            return 0;
        }
        q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
    }
    fprintf(stderr, "%s: no control named %s\n", argv[1], argv[2]);
    return 1;
}
