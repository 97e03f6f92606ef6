"""The viewer's cost (docs/performance.md, "Viewer"): the demo runs with and without the live
view, alternately; with it, two headless Chromium pages stay connected. For each run it
reads every service's CPU time from /proc over the same window and prints one JSON line:
the viewer's own CPU (percent of one core), all services' CPU, and the preview stream's
bytes per second for one camera (what a page showing that monitor receives).

  target/py-clients/bin/python services/viewer/benches/viewer_cost.py [RUNS] [SECONDS]

Needs the release binary (cargo build --release -p stereoscope), Chromium and the test
clients' venv (tests/clients/requirements.txt).
"""

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "../../../tests/clients"))
import viewer_check  # noqa: E402  (its Browser)
import websocket  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "../../.."))
BIN = os.path.join(ROOT, "target/release/stereoscope")
TICK = os.sysconf("SC_CLK_TCK")


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


def cpu_s(pid):
    try:
        f = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / TICK
    except OSError:
        return 0.0


def children(pid):
    out = []
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                if int(open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(p))
            except OSError:
                pass
    return out


def services(demo_pid):
    """Every process under the demo (launcher's children and the router), by name."""
    todo, found = [demo_pid], {}
    while todo:
        p = todo.pop()
        for c in children(p):
            try:
                cmd = open(f"/proc/{c}/cmdline").read().split("\0")
            except OSError:
                continue
            # "service capture …" → "capture"; the router's own command otherwise.
            name = next((x for x in cmd[2:3] if x and not x.startswith("-")), os.path.basename(cmd[0]))
            found[c] = name
            todo.append(c)
    return found


def one_run(view, seconds):
    port = free_port()
    args = [BIN, "demo", "--seconds", str(seconds + 30), "--quiet"]
    if view:
        args += ["--view", "--view-listen", f"127.0.0.1:{port}"]
    demo = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    browsers = []
    try:
        time.sleep(6)
        if view:
            for _ in range(2):
                b = viewer_check.Browser("chromium")
                b.call("Page.navigate", url=f"http://127.0.0.1:{port}/")
                browsers.append(b)
            time.sleep(3)
        procs = services(demo.pid)
        procs[demo.pid] = "demo (launcher, watcher)"
        before = {p: cpu_s(p) for p in procs}
        t0 = time.monotonic()
        preview_bytes = 0
        if view:
            ws = websocket.create_connection(f"ws://127.0.0.1:{port}/ws", timeout=5)
            ws.send(json.dumps({"type": "monitor", "cameras": ["cam0"]}))
            end = time.monotonic() + seconds
            counting_from = time.monotonic() + 1
            while time.monotonic() < end:
                m = ws.recv()
                if isinstance(m, bytes) and time.monotonic() > counting_from:
                    preview_bytes += len(m)
            ws.close()
        else:
            time.sleep(seconds)
        wall = time.monotonic() - t0
        used = {}
        for p in procs:
            used[procs[p]] = used.get(procs[p], 0.0) + cpu_s(p) - before[p]
        total = sum(used.values())
        viewer = sum(v for k, v in used.items() if "viewer" in k)
        return {
            "view": view,
            "seconds": round(wall, 1),
            "viewer_cpu_pct_of_core": round(100 * viewer / wall, 2),
            "services_cpu_pct_of_core": round(100 * total / wall, 1),
            "viewer_share_of_services_pct": round(100 * viewer / total, 2) if total else None,
            "preview_bytes_per_s_cam0": round(preview_bytes / (seconds - 1)) if view else None,
            "per_process_pct": {k: round(100 * v / wall, 2) for k, v in sorted(used.items())},
        }
    finally:
        for b in browsers:
            b.close()
        demo.terminate()
        try:
            demo.wait(20)
        except subprocess.TimeoutExpired:
            demo.kill()
            demo.wait()


def main():
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 20
    for _ in range(runs):
        for view in (False, True):
            print(json.dumps(one_run(view, seconds)), flush=True)


if __name__ == "__main__":
    main()
