#!/usr/bin/env python3
"""SciPy's Rotation.align_vectors on the points the Rust bench fitted (written by
`cargo bench -p stereoscope-bodies --bench bodies -- --points FILE`): the same work (centre
both point sets, best rotation in the least-squares sense), its rotation error against the
truth beside ours, the largest angle between its answer and ours, and its time per call in
the same run.

usage: scipy_kabsch.py POINTS.json
"""
import json
import statistics
import sys
import time

import numpy as np
import scipy
from scipy.spatial.transform import Rotation


def main():
    rows = json.load(open(sys.argv[1]))
    for r in rows:
        cases = [(np.array(c["body"]), np.array(c["world"]), Rotation.from_quat(c["truth_xyzw"]),
                  Rotation.from_quat(c["ours_xyzw"])) for c in r["cases"]]

        def fit(b, w):
            return Rotation.align_vectors(w - w.mean(axis=0), b - b.mean(axis=0))[0]

        errs, diffs = [], []
        for b, w, truth, ours in cases:
            rot = fit(b, w)
            errs.append(np.degrees((rot * truth.inv()).magnitude()))
            diffs.append(np.degrees((rot * ours.inv()).magnitude()))
        samples = []
        for _ in range(5):
            t = time.perf_counter()
            for b, w, _, _ in cases:
                fit(b, w)
            samples.append((time.perf_counter() - t) * 1e6 / len(cases))
        us = statistics.median(samples)
        rms = float(np.sqrt(np.mean(np.square(errs))))
        print(f"SciPy {scipy.__version__} align_vectors, {r['points']} points: {us:.2f} µs per call "
              f"(ours {r['ours_us_per_call']:.3f} µs: {us / r['ours_us_per_call']:.0f}× faster); "
              f"rotation error RMS {rms:.5f}° (ours {r['ours_rms_deg']:.5f}°); "
              f"largest angle between the two answers {max(diffs):.2e}°")


if __name__ == "__main__":
    main()
