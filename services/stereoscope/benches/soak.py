#!/usr/bin/env python3
"""Load and soak test of the live chain, outside the default test run (docs/performance.md,
"Load: many cameras"; docs/reliability.md).

usage: soak.py STEREOSCOPE_BINARY CAMERAS SECONDS [--fps F] [--markers M] [--out DIR]
                  [--realtime PRIORITY]   (the rig's [realtime] priority: docs/deploy.md)

Writes a rig of CAMERAS synthetic 640 x 480 cameras on a ring 3 m across, 2.4 m up, looking
at the middle of a 2 m volume where M markers (default 16) move, each camera at F frames per
second (default 120) from 240 frames rendered once and looped (rendering live would measure
the renderer); runs `stereoscope demo --rig RIG --seconds SECONDS --json`, and every 10 s
samples the resident memory (VmRSS) of the demo and each of its child processes. Prints one
JSON object: the demo's summary (pose frames/s, latency percentiles, losses), each process's
resident memory from its first sample after warm-up (the first 30 s, or a fifth of the run) to
its last, and the CPU each used after warm-up (in cores) with their total.
"""
import json
import math
import os
import subprocess
import sys
import tempfile
import time


def ring_rig(cameras, fps, markers):
    out = ['name = "soak"', 'units = "mm"', ""]
    for i in range(cameras):
        a = 2 * math.pi * i / cameras
        x, y = 1500.0 * math.cos(a), 1500.0 * math.sin(a)
        out += [
            "[[camera]]",
            f'id = "cam{i}"',
            "image_size = [640, 480]",
            "focal_length_mm = 3.6",
            "pixel_pitch_um = [3.0, 3.0]",
            f"pose = {{ position = [{x:.1f}, {y:.1f}, 2400.0], look_at = [0.0, 0.0, 900.0], up = [0.0, 0.0, 1.0] }}",
            f'source = {{ kind = "synthetic", fps = {fps}, loop_frames = 240 }}',
            f"moments = {{ threshold = \"auto\", max_objects = {markers + 4} }}",
            "",
        ]
    out += ["[fusion]", "max_skew_ms = 2.0", "max_wait_ms = 20.0", "",
            "[synthetic]", "seed = 3", "noise_sigma = 2.0", "background = 20.0", ""]
    # Markers on circles of different radii, heights and speeds: apart in most views.
    for k in range(markers):
        r = 150.0 + 45.0 * k
        z = 500.0 + 50.0 * (k % 8)
        period = 6.0 + 0.7 * k
        out += [
            "[[synthetic.target]]",
            'shape = "sphere"',
            "radius = 12.0",
            f"motion = {{ kind = \"circle\", centre = [0.0, 0.0, {z:.1f}], radius = {r:.1f}, period_s = {period:.2f} }}",
            "",
        ]
    return "\n".join(out)


def rss_kb(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def name_of(pid):
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = f.read().split(b"\0")
    except OSError:
        return None
    argv = [a.decode(errors="replace") for a in argv if a]
    if "service" in argv:
        i = argv.index("service")
        rest = argv[i + 1:]
        cam = rest[rest.index("--camera") + 1] if "--camera" in rest else ""
        return f"{rest[0]}/{cam}" if cam else rest[0]
    return "demo"


def children(pid):
    """Child processes of every thread of `pid` (the launcher starts services from its own
    thread)."""
    out = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for t in tasks:
        try:
            with open(f"/proc/{pid}/task/{t}/children") as f:
                out += [int(c) for c in f.read().split()]
        except OSError:
            pass
    return out


def cpu_s(pid):
    """User + system CPU seconds of `pid` so far."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def main():
    args = sys.argv[1:]
    if len(args) < 3:
        raise SystemExit(__doc__)
    binary, cameras, seconds = args[0], int(args[1]), float(args[2])
    opt = dict(zip(args[3::2], args[4::2]))
    fps = float(opt.get("--fps", 120))
    markers = int(opt.get("--markers", 16))
    out_dir = opt.get("--out") or tempfile.mkdtemp(prefix="stereoscope-soak-")
    os.makedirs(out_dir, exist_ok=True)
    rig = os.path.join(out_dir, f"ring{cameras}.toml")
    with open(rig, "w") as f:
        f.write(ring_rig(cameras, fps, markers))
        if "--realtime" in opt:
            f.write(f"\n[realtime]\npriority = {int(opt['--realtime'])}\n")
    log = open(os.path.join(out_dir, "demo.log"), "w")
    demo = subprocess.Popen([binary, "demo", "--rig", rig, "--seconds", str(seconds), "--json"],
                            stdout=subprocess.PIPE, stderr=log, text=True)
    samples = {}  # name -> [(t, kB)]
    cpu = {}  # name -> [(t, CPU seconds)]
    start = time.monotonic()
    while demo.poll() is None:
        t = time.monotonic() - start
        for pid in [demo.pid] + children(demo.pid):
            name, kb, c = name_of(pid), rss_kb(pid), cpu_s(pid)
            if name and kb:
                samples.setdefault(name, []).append((round(t, 1), kb))
            if name and c is not None:
                cpu.setdefault(name, []).append((t, c))
        for _ in range(100):
            if demo.poll() is not None:
                break
            time.sleep(0.1)
    stdout = demo.stdout.read()
    summary = None
    for line in stdout.splitlines():
        if line.startswith("{"):
            summary = json.loads(line)
    warm = min(30.0, seconds / 5)
    growth = {}
    for name, s in samples.items():
        after = [kb for t, kb in s if t >= warm]
        if len(after) >= 2:
            # One sample a minute, to tell a steady climb from a step.
            per_minute = [kb for t, kb in s if t >= warm][::6]
            growth[name] = {"first_kb": after[0], "last_kb": after[-1], "max_kb": max(after),
                            "growth_kb": after[-1] - after[0], "per_minute_kb": per_minute}
    # CPU share (of one core) after warm-up, per process and in all.
    busy = {}
    for name, s in cpu.items():
        after = [(t, c) for t, c in s if t >= warm]
        if len(after) >= 2 and after[-1][0] > after[0][0]:
            busy[name] = round((after[-1][1] - after[0][1]) / (after[-1][0] - after[0][0]), 3)
    print(json.dumps({"cameras": cameras, "fps": fps, "markers": markers, "seconds": seconds,
                      "exit": demo.returncode, "summary": summary, "memory": growth,
                      "cpu_cores": busy, "cpu_cores_total": round(sum(busy.values()), 2),
                      "cpus": os.cpu_count(), "log": log.name}))


if __name__ == "__main__":
    main()
