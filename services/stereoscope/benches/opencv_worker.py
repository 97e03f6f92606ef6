#!/usr/bin/env python3
"""OpenCV on the moment worker's frames, the same work checked (docs/performance.md, "One
moment worker").

usage: opencv_worker.py FRAMES_DIR WORKER.json OUT.json [--quick]

FRAMES_DIR holds the frames the worker was timed on (NNN.pgm, a second of the bench scene at
120 fps); WORKER.json what it found in each (its threshold, and the centroid and area of each
blob it tracked). OpenCV, one thread, does what a user without the worker would do on every
frame: threshold at the worker's threshold (pixel >= t, cv2's > t - 1), findContours
(external, simple) and cv2.moments per contour: area, centroid and second moments per blob.
It also pays for the threshold as the worker does: on every `threshold_every_frames`-th frame
(30) a cv2.calcHist of the rows the worker reads (every `threshold_rows_step`-th) and the
worker's `auto` rule on it (`auto_threshold` below, from services/lib/vision/src/histogram.rs).
Before timing, the script checks that this gives, on every frame, the threshold the worker's
own code takes from that frame (`own_threshold`): an outside check of the worker's histogram.
Before timing, the script checks that both found the same blobs in every frame: the same
number (contours with an area of at least 4 px, the worker's smallest new object), and each
worker centroid within 0.5 px of one OpenCV centroid (polygon moments of the contour against
the worker's pixel moments); it exits 1 naming the first frame that differs. Blobs touching
the frame's edge are left out of the check on both sides: one coming into view is found by
OpenCV at once and by the worker at its next search (every 10th frame). Then it times
the loop over all frames (median of batches) and writes ms per frame: the frames as they lie
in memory, and each frame just copied into one buffer by this thread before it is timed
(compared with the worker's frames copied by its own thread the same way, and shown beside
its frames handed over by another thread, as a capture process does).
"""
import json
import pathlib
import statistics
import sys
import time

import cv2
import numpy as np

MIN_AREA = 4.0
TOLERANCE_PX = 0.5


def auto_threshold(counts):
    """The worker's `auto` threshold (histogram.rs: the triangle knee from the peak to the
    brightest level, then halfway to the mean of the levels at or above the knee), clamped to
    1..255 as the worker clamps it."""
    h = np.asarray(counts, dtype=np.float64).ravel()
    nonzero = np.flatnonzero(h)
    if len(nonzero) == 0:
        sys.exit("error: an empty histogram")
    hi = int(nonzero[-1])
    peak = int(np.argmax(h))  # the first of equal maxima, as the worker's mode
    if peak >= hi:
        knee = hi + 1
    else:
        x0, y0 = float(peak), h[peak]
        dx, dy = float(hi + 1) - x0, -y0
        norm = np.sqrt(dx * dx + dy * dy)
        levels = np.arange(peak + 1, hi + 1, dtype=np.float64)
        d = ((levels - x0) * dy - (h[peak + 1:hi + 1] - y0) * dx) / norm
        best = int(np.argmax(d))
        knee = (peak + 1 + best if d[best] > -1.0 else peak) + 1
    above = h[knee:]
    n = above.sum()
    if n == 0:
        t = knee
    else:
        bright = float((np.arange(knee, knee + len(above)) * above).sum()) / n
        t = int(np.floor((knee + bright) / 2.0 + 0.5))  # Rust's round: half away from zero
    return min(max(t, 1), 255)


def frame_threshold(img, rows_step):
    return auto_threshold(cv2.calcHist([img[::rows_step]], [0], None, [256], [0, 256]))


def blobs(img, t):
    _, binary = cv2.threshold(img, t - 1, 255, cv2.THRESH_BINARY)
    cs, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in cs:
        m = cv2.moments(c)
        # A contour's polygon area is smaller than its pixel count by about half its
        # perimeter; count its pixels for the size filter.
        x, y, w, h = cv2.boundingRect(c)
        pixels = int(np.count_nonzero(binary[y:y + h, x:x + w]))
        if pixels >= MIN_AREA and m["m00"] > 0:
            edge = x == 0 or y == 0 or x + w >= img.shape[1] or y + h >= img.shape[0]
            out.append((m["m10"] / m["m00"], m["m01"] / m["m00"], pixels, edge))
    return out


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    frames_dir, worker_json, out_path = (pathlib.Path(a) for a in sys.argv[1:4])
    quick = "--quick" in sys.argv[4:]
    cv2.setNumThreads(1)
    worker = json.loads(worker_json.read_text())
    if worker["threshold_method"] != "Auto":
        sys.exit(f"error: the worker's threshold is {worker['threshold_method']}; this script "
                 "times OpenCV with the `auto` rule only")
    every = worker["threshold_every_frames"]
    rows_step = worker["threshold_rows_step"]
    frames = []
    for f in worker["frames"]:
        img = cv2.imread(str(frames_dir / f"{f['frame']}.pgm"), cv2.IMREAD_UNCHANGED)
        if img is None:
            sys.exit(f"error: {frames_dir}/{f['frame']}.pgm: OpenCV cannot read it")
        frames.append((img, f["threshold"], f["blobs"]))
        ours = frame_threshold(img, rows_step)
        if ours != f["own_threshold"]:
            sys.exit(f"frame {f['frame']}: OpenCV's histogram (every {rows_step}th row) and the "
                     f"auto rule give threshold {ours}, the worker's code {f['own_threshold']}")
    # The same blobs, frame by frame.
    matched = 0
    worst = 0.0
    for (img, t, theirs), f in zip(frames, worker["frames"]):
        ours = [b[:3] for b in blobs(img, t) if not b[3]]
        theirs = [b[:3] for b in theirs if not b[3]]
        if len(ours) != len(theirs):
            sys.exit(f"frame {f['frame']}: OpenCV finds {len(ours)} blobs at threshold {t}, "
                     f"the worker {len(theirs)}: {ours} vs {theirs}")
        for x, y, _area in theirs:
            d = min(((x - a) ** 2 + (y - b) ** 2) ** 0.5 for a, b, _ in ours)
            if d > TOLERANCE_PX:
                sys.exit(f"frame {f['frame']}: the worker's blob at ({x:.2f}, {y:.2f}) is "
                         f"{d:.2f} px from every OpenCV blob {ours}")
            worst = max(worst, d)
            matched += 1
    binary = np.empty_like(frames[0][0])

    # Each side refreshes its threshold on every `every`-th frame. Each frame is binarised at
    # the worker's threshold for it (so both find the same blobs, checked above); the refresh
    # is timed, its result (equal to the worker's rule on that frame, checked above) unused.
    def every_frame():
        for i, (img, t, _) in enumerate(frames):
            if i % every == 0:
                frame_threshold(img, rows_step)
            cv2.threshold(img, t - 1, 255, cv2.THRESH_BINARY, dst=binary)
            cs, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            for c in cs:
                cv2.moments(c)

    staging = np.empty_like(frames[0][0])

    def every_frame_delivered():
        # Each frame just written into one buffer (as a capture hands it over), then timed.
        spent = 0.0
        for i, (img, t, _) in enumerate(frames):
            np.copyto(staging, img)
            t0 = time.perf_counter()
            if i % every == 0:
                frame_threshold(staging, rows_step)
            cv2.threshold(staging, t - 1, 255, cv2.THRESH_BINARY, dst=binary)
            cs, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            for c in cs:
                cv2.moments(c)
            spent += time.perf_counter() - t0
        return spent

    batches = 3 if quick else 9
    samples = []
    delivered = []
    for _ in range(batches):
        t0 = time.perf_counter()
        every_frame()
        samples.append((time.perf_counter() - t0) * 1e3 / len(frames))
        delivered.append(every_frame_delivered() * 1e3 / len(frames))
    h, w = frames[0][0].shape
    out_path.write_text(json.dumps({
        "scene": frames_dir.name.split("-")[1], "frame": f"{w}x{h}", "opencv_version": cv2.__version__, "frames": len(frames),
        "blobs_matched": matched, "worst_centroid_px": round(worst, 4),
        "contours_ms": statistics.median(samples),
        "contours_ms_delivered": statistics.median(delivered),
        "worker_ms": worker["ms_per_frame"],
        "worker_ms_delivered": worker["ms_per_frame_delivered"],
        "worker_ms_copied": worker["ms_per_frame_copied"],
    }) + "\n")


if __name__ == "__main__":
    main()
