"""The live view's memory over bursts of WebSocket connections (docs/reliability.md, "The
viewer's browsers"): what a hostile or buggy page can make it hold. Starts `stereoscope demo
--view` (the demo rig, the viewer a process of its own), then runs ROUNDS bursts of each kind
against it and prints the viewer process's resident memory (VmRSS) before and after each:

- "held": N connections opened 10 at a time and closed 10 at a time (each served: the
  viewer's 16 browser slots turn over);
- "concurrent": N connections opened at once from N threads, each held 0.5 s (past the 16
  slots most are answered 503; past 256 open connections they are closed at once).

The clients are websocket-client (PyPI), from the system tests' environment
(target/py-clients).

usage: burst_memory.py BINARY [ROUNDS] [N]
"""
import re
import socket
import subprocess
import sys
import threading
import time

import websocket


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def viewer_pid(demo_pid):
    out = subprocess.run(["ps", "-eo", "pid,ppid,args"], capture_output=True, text=True).stdout
    for line in out.splitlines()[1:]:
        pid, ppid, args = line.split(None, 2)
        if "service viewer" in args:
            return int(pid)
    return None


def held(url, n):
    ok, socks = 0, []
    for _ in range(n):
        try:
            socks.append(websocket.create_connection(url, timeout=5))
            ok += 1
        except Exception:
            pass
        if len(socks) >= 10:
            for s in socks:
                s.close()
            socks = []
    for s in socks:
        s.close()
    return ok


def concurrent(url, n):
    got = {"ok": 0}
    lock = threading.Lock()

    def one():
        try:
            ws = websocket.create_connection(url, timeout=10)
            time.sleep(0.5)
            ws.close()
            with lock:
                got["ok"] += 1
        except Exception:
            pass

    threads = [threading.Thread(target=one) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return got["ok"]


def main():
    binary = sys.argv[1]
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 7
    n = int(sys.argv[3]) if len(sys.argv) > 3 else 1000
    port = free_port()
    demo = subprocess.Popen(
        [binary, "demo", "--view", "--view-listen", f"127.0.0.1:{port}", "--seconds", "600"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 30
        pid = None
        while pid is None and time.monotonic() < end:
            time.sleep(0.5)
            pid = viewer_pid(demo.pid)
        if pid is None:
            sys.exit("no viewer process in 30 s")
        url = f"ws://127.0.0.1:{port}/ws"
        end = time.monotonic() + 30
        while time.monotonic() < end:
            try:
                websocket.create_connection(url, timeout=2).close()
                break
            except Exception:
                time.sleep(0.5)
        base = rss_kib(pid)
        print(f"viewer pid {pid}: {base / 1024:.1f} MiB at start")
        for kind, burst in (("held", held), ("concurrent", concurrent)):
            for r in range(rounds):
                served = burst(url, n)
                time.sleep(1)
                print(f"{kind} burst {r + 1}: {served} of {n} served, "
                      f"{rss_kib(pid) / 1024:.1f} MiB")
        time.sleep(5)
        print(f"5 s later: {rss_kib(pid) / 1024:.1f} MiB (start {base / 1024:.1f} MiB)")
    finally:
        demo.terminate()
        demo.wait(timeout=30)


if __name__ == "__main__":
    main()
