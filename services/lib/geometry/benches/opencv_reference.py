#!/usr/bin/env python3
"""OpenCV's answers on the geometry fixtures, for tests/opencv_comparison.rs.

Usage: opencv_reference.py DATA_DIR   (writes DATA_DIR/opencv_reference.json)

- calibration: cv2.calibrateCamera on tests/data/calibration_points.csv with OpenCV's
  default model (fx, fy, cx, cy, k1, k2, p1, p2, k3; no skew), its RMS and parameters; and
  again with CALIB_FIX_K3 (k1 k2 p1 p2, the model `--distortion tangential` fits);
- triangulation: cv2.triangulatePoints on cameras 0 and 1 of tests/data/triangulation.json,
  after cv2.undistortPoints with a convergence criterion (converged, so that undistortion is not what differs), and
  each point's error against the truth.
"""
import csv
import json
import pathlib
import statistics
import sys
import time

import cv2
import numpy as np


def main():
    data = pathlib.Path(sys.argv[1])
    views = {}
    with open(data / "calibration_points.csv") as f:
        for row in csv.DictReader(f):
            v = views.setdefault(row["view"], ([], []))
            v[0].append([float(row["X"]), float(row["Y"]), float(row["Z"])])
            v[1].append([float(row["u"]), float(row["v"])])
    obj = [np.array(v[0], np.float32) for v in views.values()]
    img = [np.array(v[1], np.float32) for v in views.values()]
    # To convergence, as ours runs (its default stops after 30 iterations or a step of
    # DBL_EPSILON, whichever first).
    converged = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, (640, 480), None, None, criteria=converged)
    rms3, k3, dist3, _, _ = cv2.calibrateCamera(obj, img, (640, 480), None, None,
                                                flags=cv2.CALIB_FIX_K3, criteria=converged)
    tri = json.loads((data / "triangulation.json").read_text())
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    norm = []
    proj = []
    for c in tri["cameras"][:2]:
        kk = np.array(c["K"], np.float64)
        dd = np.array(c["dist"], np.float64)
        norm.append((kk, dd))
        proj.append(np.hstack([np.array(c["R"], np.float64), np.array(c["t"], np.float64).reshape(3, 1)]))
    errors = []
    for p in tri["points"]:
        xs = []
        for ci in range(2):
            kk, dd = norm[ci]
            px = np.array([[p["pixels"][ci]]], np.float64)
            xs.append(cv2.undistortPoints(px, kk, dd, None, None, None, crit).reshape(2, 1))
        h = cv2.triangulatePoints(proj[0], proj[1], xs[0], xs[1])
        x = (h[:3] / h[3]).ravel()
        errors.append(float(np.linalg.norm(x - np.array(p["truth"]))))
    # Timings on the same input (median of repeated runs), for docs/performance.md.
    def median_ms(fn, runs):
        samples = []
        for _ in range(runs):
            t = time.perf_counter()
            fn()
            samples.append((time.perf_counter() - t) * 1e3)
        return statistics.median(samples)

    cv2.setNumThreads(1)
    # The same work as ours (to convergence), and OpenCV's default stopping for reference.
    calib_ms = median_ms(lambda: cv2.calibrateCamera(obj, img, (640, 480), None, None,
                                                     criteria=converged), 7)
    calib_default_ms = median_ms(lambda: cv2.calibrateCamera(obj, img, (640, 480), None, None), 7)
    rms_default = cv2.calibrateCamera(obj, img, (640, 480), None, None)[0]
    px = [np.array([[p["pixels"][ci]] for p in tri["points"]], np.float64) for ci in range(2)]

    def tri_all():
        xs = [cv2.undistortPoints(px[ci], norm[ci][0], norm[ci][1], None, None, None, crit).reshape(-1, 2).T for ci in range(2)]
        return cv2.triangulatePoints(proj[0], proj[1], xs[0], xs[1])

    tri_ms = median_ms(tri_all, 50)
    out = {
        "opencv_version": cv2.__version__,
        "timing_one_thread_ms": {"calibrateCamera_fixture_converged": calib_ms,
                                 "calibrateCamera_fixture_default_stopping": calib_default_ms,
                                 "undistort_and_triangulatePoints_300_points_2_views": tri_ms},
        "calibration_default_stopping_rms_px": float(rms_default),
        "calibration": {
            "rms_px": float(rms),
            "fx": float(k[0, 0]), "fy": float(k[1, 1]), "cx": float(k[0, 2]), "cy": float(k[1, 2]),
            "dist": [float(v) for v in dist.ravel()[:5]],
        },
        "calibration_fix_k3": {
            "rms_px": float(rms3),
            "fx": float(k3[0, 0]), "fy": float(k3[1, 1]), "cx": float(k3[0, 2]), "cy": float(k3[1, 2]),
            "dist": [float(v) for v in dist3.ravel()[:5]],
        },
        "triangulation_two_view_errors_m": errors,
    }
    (data / "opencv_reference.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"calibration RMS {rms:.5f} px; two-view triangulation mean error {np.mean(errors) * 1000:.3f} mm")
    print(f"OpenCV {cv2.__version__}, one thread: calibrateCamera on the fixture {calib_ms:.2f} ms to "
          f"convergence (default stopping: {calib_default_ms:.2f} ms, RMS {rms_default:.5f} px); "
          f"undistortPoints + triangulatePoints, 300 points, 2 views {tri_ms:.3f} ms")


if __name__ == "__main__":
    main()
