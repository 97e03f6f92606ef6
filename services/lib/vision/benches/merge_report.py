#!/usr/bin/env python3
"""Merges the Rust and OpenCV timings of one compare-opencv.sh run into a Markdown table."""
import json
import platform
import subprocess
import sys


def cpu_name():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main():
    rust = {r["frame"]: r for r in json.load(open(sys.argv[1]))}
    ocv = {r["frame"]: r for r in json.load(open(sys.argv[2]))}
    cpp = {r["frame"]: r for r in json.load(open(sys.argv[3]))}
    date = subprocess.run(["date", "-u", "+%Y-%m-%d"], capture_output=True, text=True).stdout.strip()
    any_r = next(iter(rust.values()))
    any_o = next(iter(ocv.values()))
    print(f"Run {date} on {cpu_name()}, {any_r['cores']} cores; OpenCV {any_o['opencv_version']} "
          f"(opencv-python-headless) and {next(iter(cpp.values()))['opencv_version']} (Debian, from C++), "
          f"one thread. Milliseconds per frame, median of timed batches. The ratio to contours uses "
          f"OpenCV from C++ (no interpreter in its loop).\n")
    print("| frame | blobs | OpenCV threshold | OpenCV threshold+CCstats | OpenCV threshold+contours+moments "
          "| OpenCV C++ threshold | OpenCV C++ threshold+contours+moments "
          "| ours 1 thread | ours all cores | ours windowed (as many markers) | ours vs C++ contours | ours vs C++ threshold | full vs windowed |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in sorted(rust, key=lambda n: (rust[n]["width"], rust[n]["blobs"])):
        r, o, c = rust[name], ocv.get(name), cpp.get(name)
        if o is None or c is None:
            continue
        win = r["window_1t_ms"]
        win_s = "-" if win is None else f"{win:.4f}"
        ratio_s = "-" if win is None else f"{r['window_frame_full_1t_ms'] / win:.0f}×"
        print(f"| {r['width']}×{r['height']} | {r['blobs']} (found {r['found']}) | {o['threshold_ms']:.4f} | {o['ccstats_ms']:.3f} | "
              f"{o['contours_ms']:.3f} | {c['threshold_ms']:.4f} | {c['contours_ms']:.3f} | "
              f"{r['full_1t_ms']:.4f} | {r['full_all_ms']:.4f} | "
              f"{win_s} | {c['contours_ms'] / r['full_1t_ms']:.1f}× faster | "
              f"{r['full_1t_ms'] / c['threshold_ms']:.2f}× its time | "
              f"{ratio_s} |")
    print("\nThe moment worker's threshold histogram (every k-th row, at least 240 rows), the same "
          "counts from both (checked by opencv_bench.py):\n")
    print("| frame | blobs | rows | ours ms | OpenCV calcHist ms | OpenCV / ours |")
    print("|---|---|---|---|---|---|")
    for name in sorted(rust, key=lambda n: (rust[n]["width"], rust[n]["blobs"])):
        r, o = rust[name], ocv.get(name)
        if o is None:
            continue
        print(f"| {r['width']}×{r['height']} | {r['blobs']} | every {r['histogram_step']} | "
              f"{r['histogram_ms']:.4f} | {o['histogram_ms']:.4f} | {o['histogram_ms'] / r['histogram_ms']:.2f}× |")
    # The goal row: 1920×1080, 50 blobs, single thread; windowed tracking of 4 objects against a
    # full pass of the same frame (the bench checks both found the same 4 blobs).
    g = rust.get("1920x1080_50")
    w = rust.get("1920x1080_4")
    if g and w and w["window_1t_ms"] and "1920x1080_50" in cpp:
        o = cpp["1920x1080_50"]
        print(f"\nGoal check at 1920×1080, 50 blobs, one thread, OpenCV from C++: {o['contours_ms'] / g['full_1t_ms']:.1f}× faster than "
              f"findContours+moments (goal ≥ 3×); {g['full_1t_ms'] / o['threshold_ms']:.2f}× the bare threshold "
              f"(goal ≤ 3×). Windowed tracking of 4 objects {w['window_frame_full_1t_ms'] / w['window_1t_ms']:.0f}× cheaper "
              f"than a full-frame pass of the same frame, same 4 blobs found (goal ≥ 50×).")


if __name__ == "__main__":
    main()
