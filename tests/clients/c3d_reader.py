"""Clients the project did not write: opens a C3D file with the PyPI readers `c3d` (py-c3d)
and `ezc3d`, and prints what each found as one JSON line:
{"reader", "rate", "markers", "labels", "units", "frames": [[[x, y, z] or null, ...], ...],
 "residuals": [[residual as the reader gives it, ...], ...]}.

usage: c3d_reader.py FILE.c3d
"""
import json
import sys

import c3d
import ezc3d
import numpy as np


def with_py_c3d(path):
    with open(path, "rb") as f:
        r = c3d.Reader(f)
        labels = [l.strip() for l in r.point_labels]
        frames, residuals = [], []
        for _, points, _ in r.read_frames():
            frames.append([None if p[3] < 0 else [float(p[0]), float(p[1]), float(p[2])]
                           for p in points])
            residuals.append([float(p[3]) for p in points])
        units = r.get("POINT:UNITS").string_value.strip()
        return {"reader": "c3d " + getattr(c3d, "__version__", "?"), "rate": float(r.point_rate),
                "markers": int(r.point_used), "labels": labels, "units": units, "frames": frames,
                "residuals": residuals}


def with_ezc3d(path):
    f = ezc3d.c3d(path)
    point = f["parameters"]["POINT"]
    labels = [l.strip() for l in point["LABELS"]["value"]]
    xyz = f["data"]["points"]  # 4 × markers × frames
    residuals = f["data"]["meta_points"]["residuals"]  # 1 × markers × frames
    frames = []
    for k in range(xyz.shape[2]):
        frames.append([None if residuals[0, m, k] < 0 or np.isnan(xyz[0, m, k])
                       else [float(xyz[0, m, k]), float(xyz[1, m, k]), float(xyz[2, m, k])]
                       for m in range(xyz.shape[1])])
    res = [[float(residuals[0, m, k]) for m in range(xyz.shape[1])] for k in range(xyz.shape[2])]
    return {"reader": "ezc3d", "rate": float(point["RATE"]["value"][0]),
            "markers": int(point["USED"]["value"][0]), "labels": labels,
            "units": point["UNITS"]["value"][0].strip(), "frames": frames, "residuals": res}


if __name__ == "__main__":
    for read in (with_py_c3d, with_ezc3d):
        print(json.dumps(read(sys.argv[1])), flush=True)
