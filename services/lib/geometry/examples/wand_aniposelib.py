"""The wand calibration against a peer on the same detections: aniposelib's bundle adjustment,
extrinsics only, every point, started from the same first estimate as this project's, on the
labelled wand points that `--export` writes (docs/performance.md, "Wand calibration"): its
single `bundle_adjust` pass (linear loss: the same work as ours, one adjustment) and its
`bundle_adjust_iter` (6–10 robust rounds, what aniposelib's own calibration runs).

  cargo run --release -p stereoscope-geometry --example wand -- --export /tmp/wand.json
  services/lib/geometry/examples/wand_aniposelib.sh /tmp/wand.json [RUNS]

The .sh pins aniposelib 0.8.0, numpy 2.4.6, scipy 1.17.1 and opencv-contrib-python 5.1.0.95. Both solutions are scored by the same code here: each
camera's pose relative to camera 0 against the truth (aniposelib's adjustment leaves the
scale free, so its positions are scaled by the wand's true length over its mean triangulated
length), and the reprojection RMS of the points aniposelib triangulates with each rig.
"""
import json
import sys
import time

import numpy as np
from aniposelib.cameras import Camera, CameraGroup
from scipy.spatial.transform import Rotation


def rig(data, which):
    return CameraGroup([
        Camera(matrix=np.array(c["matrix"]), dist=np.array(c["dist"]), size=c["size"],
               rvec=np.array(c[which]["rvec"]), tvec=np.array(c[which]["tvec"]), name=f"cam{i}")
        for i, c in enumerate(data["cameras"])])


def centre(rvec, tvec):
    r = Rotation.from_rotvec(rvec).as_matrix()
    return -r.T @ np.asarray(tvec)


def score(group, data, p2ds):
    """Worst camera position (mm) and rotation (deg) against the truth, the scale taken from
    the wand, and the reprojection RMS (px) of the triangulated points."""
    p3 = group.triangulate(p2ds)
    lengths = np.linalg.norm(p3[0::2] - p3[1::2], axis=1)
    scale = data["wand_m"] / np.nanmean(lengths)
    rv = [np.asarray(r).ravel() for r in group.get_rotations()]
    tv = [np.asarray(t).ravel() for t in group.get_translations()]
    # Relative to camera 0 (the truth's frame in the export).
    r0 = Rotation.from_rotvec(rv[0])
    worst_mm = worst_deg = 0.0
    for i, c in enumerate(data["cameras"]):
        ri = Rotation.from_rotvec(rv[i])
        rel_r = ri * r0.inv()
        rel_t = tv[i] - rel_r.apply(tv[0])
        got_c = centre(rel_r.as_rotvec(), rel_t * scale)
        want_c = centre(c["truth"]["rvec"], c["truth"]["tvec"])
        worst_mm = max(worst_mm, 1e3 * np.linalg.norm(got_c - want_c))
        d = rel_r * Rotation.from_rotvec(c["truth"]["rvec"]).inv()
        worst_deg = max(worst_deg, np.degrees(d.magnitude()))
    err = group.reprojection_error(p3, p2ds, mean=False)
    rms = float(np.sqrt(np.nanmean(np.sum(err ** 2, axis=-1))))
    sd_mm = 1e3 * float(np.nanstd(lengths * scale, ddof=1))
    return worst_mm, worst_deg, rms, sd_mm, scale


def main():
    data = json.load(open(sys.argv[1]))
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    p2ds = np.array([[p if p is not None else [np.nan, np.nan] for p in c["points"]]
                     for c in data["cameras"]], dtype=float)
    def timed(adjust):
        times, group = [], None
        for _ in range(runs):
            group = rig(data, "initial")
            t0 = time.perf_counter()
            adjust(group)
            times.append(time.perf_counter() - t0)
        times.sort()
        return group, times[len(times) // 2], times[-1]

    single, single_s, single_worst = timed(lambda g: g.bundle_adjust(
        p2ds, loss="linear", only_extrinsics=True, verbose=False))
    rounds, rounds_s, rounds_worst = timed(lambda g: g.bundle_adjust_iter(
        p2ds, n_samp_full=p2ds.shape[1], only_extrinsics=True))
    rows = [
        ("first estimate (both start here)", rig(data, "initial"), None),
        ("stereoscope (geometry::wand)", rig(data, "ours"), data["ours_solve_s"]),
        ("aniposelib 0.8.0 bundle_adjust (one pass, linear loss)", single, single_s),
        ("aniposelib 0.8.0 bundle_adjust_iter (robust rounds)", rounds, rounds_s),
    ]
    print(f"worst of {runs} runs: bundle_adjust {single_worst:.3f} s, bundle_adjust_iter {rounds_worst:.3f} s")
    print(f"{p2ds.shape[1] // 2} wand frames, {len(data['cameras'])} cameras, "
          f"{data['noise_px']} px noise; solve times are medians of {runs} runs")
    print("| solution | worst position mm | worst rotation ° | reprojection RMS px | wand SD mm | scale | solve s |")
    print("|---|---|---|---|---|---|---|")
    for name, g, t in rows:
        mm, deg, rms, sd, scale = score(g, data, p2ds)
        ts = "—" if t is None else f"{t:.3f}"
        print(f"| {name} | {mm:.3f} | {deg:.4f} | {rms:.3f} | {sd:.3f} | {scale:.5f} | {ts} |")


if __name__ == "__main__":
    main()
