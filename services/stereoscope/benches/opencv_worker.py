#!/usr/bin/env python3
"""OpenCV on the moment worker's frames, the same work checked (docs/performance.md, "One
moment worker").

usage: opencv_worker.py FRAMES_DIR WORKER.json OUT.json [--quick]

FRAMES_DIR holds the frames the worker was timed on (NNN.pgm, a second of the bench scene at
120 fps); WORKER.json what it found in each (its threshold, and the centroid and area of each
blob it tracked). OpenCV, one thread, does what a user without the worker would do on every
frame: threshold at the worker's threshold (pixel >= t, cv2's > t - 1), findContours
(external, simple) and cv2.moments per contour: area, centroid and second moments per blob.
Before timing, the script checks that both found the same blobs in every frame: the same
number (contours with an area of at least 4 px, the worker's smallest new object), and each
worker centroid within 0.5 px of one OpenCV centroid (polygon moments of the contour against
the worker's pixel moments); it exits 1 naming the first frame that differs. Blobs touching
the frame's edge are left out of the check on both sides: one coming into view is found by
OpenCV at once and by the worker at its next search (every 10th frame). Then it times
the loop over all frames (median of batches) and writes ms per frame: the frames as they lie
in memory, and each frame just copied into one buffer before it is timed (the worker's
"delivered" figure: a capture hands each frame over just written).
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
    frames = []
    for f in worker["frames"]:
        img = cv2.imread(str(frames_dir / f"{f['frame']}.pgm"), cv2.IMREAD_UNCHANGED)
        if img is None:
            sys.exit(f"error: {frames_dir}/{f['frame']}.pgm: OpenCV cannot read it")
        frames.append((img, f["threshold"], f["blobs"]))
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

    def every_frame():
        for img, t, _ in frames:
            cv2.threshold(img, t - 1, 255, cv2.THRESH_BINARY, dst=binary)
            cs, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            for c in cs:
                cv2.moments(c)

    staging = np.empty_like(frames[0][0])

    def every_frame_delivered():
        # Each frame just written into one buffer (as a capture hands it over), then timed.
        spent = 0.0
        for img, t, _ in frames:
            np.copyto(staging, img)
            t0 = time.perf_counter()
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
    }) + "\n")


if __name__ == "__main__":
    main()
