#!/usr/bin/env python3
"""The points the Rust bench fitted (written by `cargo bench -p stereoscope-bodies --bench
bodies -- --points FILE`), fitted again two ways: SciPy's Rotation.align_vectors, one Python
call per set (the interpreter is most of its time), and numpy's batched SVD over all the sets
at once (no interpreter per set: the like-for-like baseline for our loop). The same work on
every side (centre both point sets, the best rotation in the least-squares sense); each
one's rotation error against the truth beside ours, the largest angle between its answer and
ours, and its time per set in the same run.

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
        ours_us = r['ours_us_per_call']
        print(f"SciPy {scipy.__version__} align_vectors, {r['points']} points, one call a set: "
              f"{us:.2f} µs a set (ours {ours_us:.3f} µs: SciPy/ours {us / ours_us:.0f}×); "
              f"rotation error RMS {rms:.5f}° (ours {r['ours_rms_deg']:.5f}°); "
              f"largest angle between the two answers {max(diffs):.2e}°")

        # numpy, batched: every set in one call of each operation.
        bodies = np.stack([b for b, _, _, _ in cases])
        worlds = np.stack([w for _, w, _, _ in cases])

        def batched():
            b = bodies - bodies.mean(axis=1, keepdims=True)
            w = worlds - worlds.mean(axis=1, keepdims=True)
            h = np.einsum("nki,nkj->nij", b, w)
            u, _, vt = np.linalg.svd(h)
            d = np.sign(np.linalg.det(np.einsum("nji,nkj->nik", vt, u)))
            fix = np.ones((len(cases), 3))
            fix[:, 2] = d
            return np.einsum("nji,nj,nkj->nik", vt, fix, u)

        mats = batched()
        errs_b, diffs_b = [], []
        for m, (_, _, truth, ours) in zip(mats, cases):
            rot = Rotation.from_matrix(m)
            errs_b.append(np.degrees((rot * truth.inv()).magnitude()))
            diffs_b.append(np.degrees((rot * ours.inv()).magnitude()))
        samples_b = []
        for _ in range(21):
            t = time.perf_counter()
            batched()
            samples_b.append((time.perf_counter() - t) * 1e6 / len(cases))
        us_b = statistics.median(samples_b)
        rms_b = float(np.sqrt(np.mean(np.square(errs_b))))
        print(f"numpy {np.__version__} batched SVD, {len(cases)} sets of {r['points']} points in one "
              f"call: {us_b:.3f} µs a set, worst of 21 rounds {max(samples_b):.3f} µs (ours "
              f"{ours_us:.3f} µs: numpy/ours {us_b / ours_us:.1f}×, worst round "
              f"{max(samples_b) / ours_us:.1f}×); rotation error RMS {rms_b:.5f}°; largest angle "
              f"between its answers and ours {max(diffs_b):.2e}°")


if __name__ == "__main__":
    main()
