#!/usr/bin/env python3
"""Several PCs as network namespaces, soaked with faults (docs/reliability.md, "Sixteen
cameras on four PCs"; issue 41 item 4). Needs root and iproute2; outside the default test run.

usage: netns_soak.py STEREOSCOPE_BINARY SECONDS [--captures N] [--cameras-per K] [--fps F]
                     [--markers M] [--faults yes|no] [--out DIR]

Makes a switch namespace with a bridge and one namespace per PC — N capture PCs (default 4)
with K synthetic 640 x 480 cameras each (default 4; F frames a second, default 120, from 240
frames rendered once and looped; the ring of soak.py, M markers, default 16), a fusion PC and
a consumer PC — joined by veth pairs; certificates from deploy/make-certs.sh, every link
mutual TLS. Each PC runs `stereoscope run RIG --host NAME`; the consumer runs Zenoh's Python
binding (tests/clients/zenoh_tls.py poses) with a consumer certificate, reading the pose
frames at the fusion PC's router. With faults (default), at a quarter, half and three
quarters of the run: capture2's cable cut for 5 s and restored; capture3 rebooted (its
launcher, router and services killed with -9 at once, its iceoryx2
files removed from /dev/shm, its launcher started again a second later); the fusion PC's
router process killed with -9 (its launcher starts it again). Every 10 s the resident memory and CPU of every Stereoscope process is sampled.

Prints one JSON object: pose frames/s at the consumer over the whole run and per 10 s window;
the share of frames with every camera; the latency from a frame's exposure to its receipt at
the consumer (one kernel clock in every namespace) p50/p99/max over the steady frames; each
fault with when it happened, how long no pose came and how long until every camera was back,
and the sequence numbers fusion published that never reached the consumer, as ranges; each
process's memory (first sample after warm-up, last, max) and CPU share after warm-up.
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import time

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.abspath(os.path.join(here, "..", "..", ".."))
sys.path.insert(0, here)
from soak import cpu_s, ring_rig, rss_kb  # noqa: E402


def ip(*args, check=True):
    r = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise SystemExit(f"ip {' '.join(args)}: {r.stderr.strip()}")
    return r


class Lan:
    def __init__(self, hosts):
        self.prefix = f"ss{os.getpid()}"
        self.hosts = hosts  # [(name, address)]
        sw = self.ns("sw")
        ip("netns", "add", sw)
        ip("-n", sw, "link", "add", "br0", "type", "bridge")
        ip("-n", sw, "link", "set", "br0", "up")
        for i, (host, address) in enumerate(hosts):
            ns = self.ns(host)
            ip("netns", "add", ns)
            ip("link", "add", f"v{i}", "netns", sw, "type", "veth", "peer", "name", "eth0",
               "netns", ns)
            ip("-n", sw, "link", "set", f"v{i}", "master", "br0", "up")
            ip("-n", ns, "addr", "add", f"{address}/24", "dev", "eth0")
            ip("-n", ns, "link", "set", "eth0", "up")
            ip("-n", ns, "link", "set", "lo", "up")

    def ns(self, host):
        return f"{self.prefix}{host}"

    def cable(self, host, up):
        i = [h for h, _ in self.hosts].index(host)
        ip("-n", self.ns("sw"), "link", "set", f"v{i}", "up" if up else "down")

    def start(self, host, argv, log, env=None):
        return subprocess.Popen(["ip", "netns", "exec", self.ns(host), *argv], stdout=log,
                                stderr=subprocess.STDOUT, env=env, start_new_session=True)

    def delete(self):
        for host, _ in self.hosts:
            ip("netns", "del", self.ns(host), check=False)
        ip("netns", "del", self.ns("sw"), check=False)


def rig_text(captures, per, fps, markers, addresses):
    text = ring_rig(captures * per, fps, markers).replace('name = "soak"', 'name = "soak16"')
    out = []
    for line in text.splitlines():
        out.append(line)
        if line.startswith('id = "cam'):
            i = int(line.split('"')[1][3:])
            out.append(f'host = "capture{i // per + 1}"')
        if line == "[fusion]":
            out.append('host = "fusion"')
            out.append("clock_window_ms = 500.0")
    out.append("")
    fusion = addresses["fusion"]
    for c in range(1, captures + 1):
        name = f"capture{c}"
        out += ["[[host]]", f'name = "{name}"',
                f'zenoh_listen = ["tls/{addresses[name]}:7447"]',
                f'zenoh_connect = ["tls/{fusion}:7447"]',
                f'tls = {{ ca = "certs/ca.pem", cert = "certs/{name}.pem", key = "certs/{name}.key" }}',
                ""]
    out += ["[[host]]", 'name = "fusion"', f'zenoh_listen = ["tls/{fusion}:7447"]',
            'tls = { ca = "certs/ca.pem", cert = "certs/fusion.pem", key = "certs/fusion.key" }', ""]
    return "\n".join(out)


def stereoscope_processes():
    """(pid, name) of every Stereoscope process: `run` launchers and their services."""
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
        except OSError:
            continue
        if not argv or not argv[0].endswith("stereoscope"):
            continue
        host = argv[argv.index("--host") + 1] if "--host" in argv else "?"
        if "service" in argv:
            rest = argv[argv.index("service") + 1:]
            cam = rest[rest.index("--camera") + 1] if "--camera" in rest else ""
            name = f"{host}:{rest[0]}" + (f"/{cam}" if cam else "")
        elif "run" in argv:
            name = f"{host}:launcher"
        else:
            continue
        out.append((int(pid), name))
    return out


def ranges(missing):
    out, start, prev = [], None, None
    for s in missing:
        if start is None:
            start = prev = s
        elif s == prev + 1:
            prev = s
        else:
            out.append([start, prev])
            start = prev = s
    if start is not None:
        out.append([start, prev])
    return out


def main():
    args = sys.argv[1:]
    if len(args) < 2:
        raise SystemExit(__doc__)
    binary, seconds = os.path.abspath(args[0]), float(args[1])
    opt = dict(zip(args[2::2], args[3::2]))
    captures = int(opt.get("--captures", 4))
    per = int(opt.get("--cameras-per", 4))
    fps = float(opt.get("--fps", 120))
    markers = int(opt.get("--markers", 16))
    faults = opt.get("--faults", "yes") == "yes"
    out_dir = opt.get("--out") or tempfile.mkdtemp(prefix="stereoscope-netns-soak-")
    os.makedirs(out_dir, exist_ok=True)
    names = [f"capture{c}" for c in range(1, captures + 1)] + ["fusion", "consumer"]
    addresses = {n: f"192.168.77.{10 + i}" for i, n in enumerate(names)}
    certs = os.path.join(out_dir, "certs")
    subprocess.run([os.path.join(root, "deploy/make-certs.sh"), certs,
                    *[f"{n}={addresses[n]}" for n in names]], check=True, capture_output=True)
    rig = os.path.join(out_dir, "rig.toml")
    with open(rig, "w") as f:
        f.write(rig_text(captures, per, fps, markers, addresses))
    python = os.path.join(root, "target/py-clients/bin/python")
    client = os.path.join(root, "tests/clients/zenoh_tls.py")
    env = dict(os.environ, TMPDIR=out_dir)
    lan = Lan([(n, addresses[n]) for n in names])
    procs = {}
    logs = {}
    try:
        def launch(host):
            logs[host] = open(os.path.join(out_dir, f"{host}.log"), "a")
            procs[host] = lan.start(host, [binary, "run", rig, "--host", host,
                                           "--iox-prefix", f"ss{os.getpid()}{host}_"],
                                    logs[host], env)
        for h in ["fusion"] + names[:captures]:
            launch(h)
        reader_log = open(os.path.join(out_dir, "poses.jsonl"), "w")
        reader = lan.start("consumer", [python, client, "poses",
                                        f"tls/{addresses['fusion']}:7447", "soak16",
                                        str(seconds), os.path.join(certs, "ca.pem"),
                                        os.path.join(certs, "consumer.pem"),
                                        os.path.join(certs, "consumer.key")], reader_log, env)
        start = time.time()
        schedule = []
        if faults:
            schedule = [(seconds * 0.25, "cable", "capture2"),
                        (seconds * 0.5, "reboot", "capture3" if captures >= 3 else "capture1"),
                        (seconds * 0.75, "router", "fusion")]
        done_faults = []
        samples, cpu = {}, {}
        next_sample = 0.0
        while reader.poll() is None:
            t = time.time() - start
            if schedule and t >= schedule[0][0]:
                _, kind, host = schedule.pop(0)
                at = time.time()
                if kind == "cable":
                    lan.cable(host, False)
                    time.sleep(5)
                    lan.cable(host, True)
                elif kind == "reboot":
                    # Every process of the PC at once (its launcher, router and services, by
                    # their --host), then its shared memory gone as after a reboot, and the
                    # PC back a second later.
                    victims = [pid for pid, name in stereoscope_processes()
                               if name.startswith(f"{host}:")]
                    os.killpg(procs[host].pid, signal.SIGKILL)
                    for pid in victims:
                        try:
                            os.kill(pid, signal.SIGKILL)
                        except ProcessLookupError:
                            pass
                    procs[host].wait()
                    prefix = f"ss{os.getpid()}{host}_"
                    for name in os.listdir("/dev/shm"):
                        if name.startswith(prefix):
                            os.remove(os.path.join("/dev/shm", name))
                    time.sleep(1)
                    launch(host)
                elif kind == "router":
                    for pid, name in stereoscope_processes():
                        if name == f"{host}:router":
                            os.kill(pid, signal.SIGKILL)
                done_faults.append({"kind": kind, "host": host, "at_s": round(at - start, 1),
                                    "t": at})
            if t >= next_sample:
                next_sample += 10.0
                # Per process name, the samples of its latest pid (a restarted process starts
                # its own series).
                for pid, name in stereoscope_processes():
                    kb, c = rss_kb(pid), cpu_s(pid)
                    for table, value in ((samples, kb), (cpu, c)):
                        if value is None or value == 0:
                            continue
                        series = table.setdefault(name, [])
                        if series and series[-1][2] != pid:
                            series.clear()
                        series.append((t, value, pid))
            time.sleep(0.2)
        reader_log.close()
        frames = []
        with open(reader_log.name) as f:
            for line in f:
                try:
                    v = json.loads(line)
                except ValueError:
                    continue
                if "sequence" in v:
                    # The cameras a frame set holds (fusion lists them).
                    if isinstance(v["cameras"], list):
                        v["cameras"] = len(v["cameras"])
                    frames.append(v)
        cams = captures * per
        warm = min(30.0, seconds / 5)
        steady = [f for f in frames if f["t"] - start >= warm]
        lat = sorted((f["t"] * 1e9 - f["exposure_ns"]) / 1e6 for f in steady)
        q = lambda p: round(lat[min(len(lat) - 1, int(p * (len(lat) - 1) + 0.5))], 2) if lat else None
        windows = {}
        for f in frames:
            windows.setdefault(int((f["t"] - start) // 10), 0)
            windows[int((f["t"] - start) // 10)] += 1
        ends = [f["t"] for f in done_faults[1:]] + [start + seconds + 60]
        for fault, end in zip(done_faults, ends):
            # What happened from the fault until the next one (at most 30 s).
            end = min(end, fault["t"] + 30)
            after = [f for f in frames if fault["t"] <= f["t"] < end]
            before = [f for f in frames if f["t"] < fault["t"]]
            gap = (after[0]["t"] - before[-1]["t"]) if after and before else None
            # Back: the first of ten frames in a row with every camera, once the fault showed
            # (its first partial frame, or the end of its longest silence); a frame missing a
            # camera now and then is ordinary (a late frame past the pairing's wait).
            # (The silence may begin before the fault's stamp: from the last frame before it.)
            around = before[-1:] + after
            gaps = [(b["t"] - a["t"], b["t"]) for a, b in zip(around, around[1:])]
            quiet_end = max(gaps)[1] if gaps and max(gaps)[0] > 0.1 else None
            first_partial = next((f["t"] for f in after if f["cameras"] < cams), None)
            shown = [x for x in (quiet_end, first_partial) if x is not None]
            whole, run = None, []
            for f in after:
                if shown and f["t"] < min(shown):
                    continue
                run = run + [f["t"]] if f["cameras"] == cams else []
                if len(run) == 10:
                    whole = run[0]
                    break
            fault["longest_gap_s"] = round(max((b["t"] - a["t"] for a, b in zip(frames, frames[1:])
                                                if fault["t"] - 1 <= a["t"] and b["t"] < end),
                                               default=0.0), 3)
            fault["first_gap_s"] = round(gap, 3) if gap is not None else None
            fault["all_cameras_again_s"] = round(whole - fault["t"], 2) if whole else None
            seq = [f["sequence"] for f in frames if fault["t"] - 1 <= f["t"] < end]
            missing = sorted(set(range(min(seq), max(seq) + 1)) - set(seq)) if seq else []
            fault["sequences_lost"] = ranges(missing)
            fault["frames_lost"] = len(missing)
            fault["frames_partial"] = sum(1 for f in after if f["cameras"] < cams)
            del fault["t"]
        seqs = [f["sequence"] for f in frames]
        missing_all = sorted(set(range(min(seqs), max(seqs) + 1)) - set(seqs)) if seqs else []
        memory = {}
        for name, s in samples.items():
            after = [kb for t, kb, _ in s if t >= warm]
            if after:
                memory[name] = {"first_kb": after[0], "last_kb": after[-1], "max_kb": max(after)}
        busy = {}
        for name, s in cpu.items():
            after = [(t, c) for t, c, _ in s if t >= warm]
            if len(after) >= 2 and after[-1][0] > after[0][0]:
                busy[name] = round((after[-1][1] - after[0][1]) / (after[-1][0] - after[0][0]), 3)
        span = (frames[-1]["t"] - frames[0]["t"]) if len(frames) > 1 else 0.0
        print(json.dumps({
            "pcs": names, "cameras": cams, "fps": fps, "markers": markers, "seconds": seconds,
            "pose_frames": len(frames),
            "poses_per_s": round(len(frames) / span, 2) if span else None,
            "per_10s": [windows.get(k, 0) / 10 for k in range(int(seconds // 10))],
            "all_cameras_share": round(sum(1 for f in steady if f["cameras"] == cams)
                                       / max(1, len(steady)), 4),
            "exposure_to_consumer_ms": {"p50": q(0.5), "p99": q(0.99), "max": q(1.0)},
            "faults": done_faults,
            "sequences_lost_total": len(missing_all),
            "memory": memory, "cpu_cores": busy,
            "cpu_cores_total": round(sum(busy.values()), 2), "out": out_dir}))
    finally:
        for p in procs.values():
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in procs.values():
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        lan.delete()


if __name__ == "__main__":
    main()
