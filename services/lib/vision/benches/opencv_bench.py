#!/usr/bin/env python3
"""Times OpenCV on the benchmark's frames, for the comparison in docs/performance.md.

Usage: opencv_bench.py FRAMES_DIR RUST.json OUT.json [--quick]

For every FRAMES_DIR/*.pgm (written by `cargo bench --bench moments -- --frames-dir`), single
threaded (cv2.setNumThreads(1)), median ms per frame of:
  threshold   cv2.threshold alone: one pass over the pixels, the floor;
  ccstats     threshold + cv2.connectedComponentsWithStats (area, bbox, centroid; no 2nd moments);
  contours    threshold + cv2.findContours + cv2.moments per contour (per-blob 2nd moments);
  histogram   cv2.calcHist of every k-th row (the moment worker's threshold histogram), after
              checking that its counts equal those the Rust bench wrote to RUST.json.
The threshold matches the Rust side: foreground is pixel >= 128, i.e. cv2's pixel > 127.
"""
import json
import pathlib
import statistics
import sys
import time

import cv2
import numpy as np

THRESHOLD = 128


def time_ms(fn, batches, min_batch_s):
    start = time.perf_counter()
    n = 0
    while time.perf_counter() - start < min_batch_s / 4 or n < 3:
        fn()
        n += 1
    per_call = (time.perf_counter() - start) / n
    iters = max(3, int(min_batch_s / per_call) + 1)
    samples = []
    for _ in range(batches):
        t = time.perf_counter()
        for _ in range(iters):
            fn()
        samples.append((time.perf_counter() - t) * 1e3 / iters)
    return statistics.median(samples)


def main():
    if len(sys.argv) < 4:
        sys.exit("usage: opencv_bench.py FRAMES_DIR RUST.json OUT.json [--quick]")
    frames_dir, out_path = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[3])
    rust_rows = {r["frame"]: r for r in json.load(open(sys.argv[2]))}
    quick = "--quick" in sys.argv[4:]
    batches, min_batch = (3, 0.01) if quick else (11, 0.025)
    cv2.setNumThreads(1)
    rows = []
    for path in sorted(frames_dir.glob("*.pgm")):
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            sys.exit(f"error: {path}: OpenCV cannot read it")
        binary = np.empty_like(img)

        def threshold():
            cv2.threshold(img, THRESHOLD - 1, 255, cv2.THRESH_BINARY, dst=binary)

        def ccstats():
            cv2.threshold(img, THRESHOLD - 1, 255, cv2.THRESH_BINARY, dst=binary)
            return cv2.connectedComponentsWithStats(binary, connectivity=8)

        def contours():
            cv2.threshold(img, THRESHOLD - 1, 255, cv2.THRESH_BINARY, dst=binary)
            cs, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            return [cv2.moments(c) for c in cs]

        # The moment worker's threshold histogram (every k-th row), counted by OpenCV; the
        # counts must equal ours (the Rust bench wrote them) for the timing to compare.
        rust = rust_rows.get(path.stem)
        if rust is None:
            sys.exit(f"error: {path.stem}: not in {sys.argv[2]}")
        step = rust["histogram_step"]
        rows_view = img[::step]

        def histogram():
            return cv2.calcHist([rows_view], [0], None, [256], [0, 256])

        counts = [int(c) for c in histogram().ravel()]
        if counts != rust["histogram_counts"]:
            sys.exit(f"error: {path.stem}: OpenCV's histogram of every {step}th row differs from ours")
        n_cc = ccstats()[0] - 1
        n_contours = len(contours())
        rows.append({
            "frame": path.stem,
            "opencv_version": cv2.__version__,
            "cc_blobs": int(n_cc),
            "contour_blobs": n_contours,
            "threshold_ms": time_ms(threshold, batches, min_batch),
            "ccstats_ms": time_ms(ccstats, batches, min_batch),
            "contours_ms": time_ms(contours, batches, min_batch),
            "histogram_ms": time_ms(histogram, batches, min_batch),
        })
        print(f"{path.stem}: done", file=sys.stderr)
    out_path.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
