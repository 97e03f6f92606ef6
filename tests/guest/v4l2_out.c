/* Plays a grey PGM (P5, maxval 255) on a V4L2 video output device as YUYV frames (the grey
 * as luma, neutral chroma) by memory-mapped streaming, for the guest test (tests/vivid.rs): vivid loops its HDMI output
 * to its HDMI input, so the capture side sees the renderer's frame. Built statically by the
 * test with the host's C compiler. Usage: v4l2-out DEVICE FILE.pgm FRAMES FPS */
#include <fcntl.h>
#include <linux/videodev2.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: v4l2-out DEVICE FILE.pgm FRAMES FPS\n");
        return 2;
    }
    FILE *f = fopen(argv[2], "rb");
    if (!f) {
        perror(argv[2]);
        return 1;
    }
    int w, h, max;
    if (fscanf(f, "P5 %d %d %d", &w, &h, &max) != 3 || max != 255 || w <= 0 || h <= 0 ||
        w > 8192 || h > 8192) {
        fprintf(stderr, "%s: not an 8-bit P5 PGM\n", argv[2]);
        return 1;
    }
    fgetc(f);
    unsigned char *grey = malloc((size_t)w * h);
    unsigned char *yuyv = malloc((size_t)w * h * 2);
    if (!grey || !yuyv || fread(grey, 1, (size_t)w * h, f) != (size_t)w * h) {
        fprintf(stderr, "%s: short\n", argv[2]);
        return 1;
    }
    for (long i = 0; i < (long)w * h; i++) {
        yuyv[2 * i] = grey[i];
        yuyv[2 * i + 1] = 128;
    }
    int fd = open(argv[1], O_RDWR);
    if (fd < 0) {
        perror(argv[1]);
        return 1;
    }
    struct v4l2_format fmt;
    memset(&fmt, 0, sizeof fmt);
    fmt.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    fmt.fmt.pix.width = w;
    fmt.fmt.pix.height = h;
    fmt.fmt.pix.pixelformat = V4L2_PIX_FMT_YUYV;
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    if (ioctl(fd, VIDIOC_S_FMT, &fmt) != 0) {
        perror("VIDIOC_S_FMT");
        return 1;
    }
    if ((int)fmt.fmt.pix.width != w || (int)fmt.fmt.pix.height != h ||
        fmt.fmt.pix.pixelformat != V4L2_PIX_FMT_YUYV) {
        fprintf(stderr, "the output took %ux%u\n", fmt.fmt.pix.width, fmt.fmt.pix.height);
        return 1;
    }
    struct v4l2_requestbuffers req;
    memset(&req, 0, sizeof req);
    req.count = 4;
    req.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    req.memory = V4L2_MEMORY_MMAP;
    if (ioctl(fd, VIDIOC_REQBUFS, &req) != 0 || req.count == 0) {
        perror("VIDIOC_REQBUFS");
        return 1;
    }
    int frames = atoi(argv[3]);
    long period_ns = 1000000000L / atoi(argv[4]);
    struct v4l2_buffer b;
    for (unsigned i = 0; i < req.count; i++) {
        memset(&b, 0, sizeof b);
        b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
        b.memory = V4L2_MEMORY_MMAP;
        b.index = i;
        if (ioctl(fd, VIDIOC_QUERYBUF, &b) != 0) {
            perror("VIDIOC_QUERYBUF");
            return 1;
        }
        unsigned char *p = mmap(NULL, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, b.m.offset);
        if (p == MAP_FAILED) {
            perror("mmap");
            return 1;
        }
        for (int y = 0; y < h; y++)
            memcpy(p + (size_t)y * fmt.fmt.pix.bytesperline, yuyv + (size_t)y * w * 2, (size_t)w * 2);
        b.bytesused = fmt.fmt.pix.sizeimage;
        b.field = V4L2_FIELD_NONE;
        if (ioctl(fd, VIDIOC_QBUF, &b) != 0) {
            perror("VIDIOC_QBUF");
            return 1;
        }
    }
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    if (ioctl(fd, VIDIOC_STREAMON, &type) != 0) {
        perror("VIDIOC_STREAMON");
        return 1;
    }
    printf("playing %dx%d on %s\n", w, h, argv[1]);
    fflush(stdout);
    /* The same picture in every buffer: each one the driver gives back goes out again. */
    for (int i = 0; i < frames; i++) {
        memset(&b, 0, sizeof b);
        b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
        b.memory = V4L2_MEMORY_MMAP;
        if (ioctl(fd, VIDIOC_DQBUF, &b) != 0) {
            perror("VIDIOC_DQBUF");
            return 1;
        }
        b.bytesused = fmt.fmt.pix.sizeimage;
        b.field = V4L2_FIELD_NONE;
        if (ioctl(fd, VIDIOC_QBUF, &b) != 0) {
            perror("VIDIOC_QBUF");
            return 1;
        }
        struct timespec t = {0, period_ns};
        nanosleep(&t, NULL);
    }
    close(fd);
    return 0;
}
