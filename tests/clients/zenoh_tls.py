"""A client the project did not write (the eclipse-zenoh package from PyPI), reaching a rig's
router over mutual TLS as a PC on the network would, following docs/protocol.md and
docs/deploy.md ("Security") only.

usage:
  zenoh_tls.py watch ENDPOINT RIG SECONDS CA CERT KEY
      Subscribes to the rig's pose frames and its synthetic cameras' truth, and to every key of
      the rig. Prints one JSON line per pose frame: {"t": wall-clock seconds, "sequence",
      "cameras", "objects", "error_mm": the median over its poses of the distance to the
      nearest true target at the nearest truth time (null without truth)}; one line
      {"forged": KEY} for any sample that is a forged one (a JSON object with the key FORGED);
      at the end {"done": frames}.
  zenoh_tls.py poses ENDPOINT RIG SECONDS CA CERT KEY
      Subscribes to the rig's pose frames only (a light reader for long runs). Prints one JSON
      line per pose frame: {"t": wall-clock seconds at receipt, "sequence", "cameras",
      "objects", "exposure_ns": the frame's timestamp_ns}; at the end {"done": frames}.
  zenoh_tls.py forge ENDPOINT RIG CA CERT KEY SECONDS SUFFIX...
      Publishes {"FORGED": true} on each key stereoscope/RIG/SUFFIX and declares the
      liveliness token stereoscope/RIG/alive/fusion/FORGED, for SECONDS. Prints
      {"opened": true} once connected and {"token": true} once the token is declared.
  zenoh_tls.py stress ENDPOINT RIG SECONDS CA CERT KEY OTHER_CA OTHER_CERT OTHER_KEY GAP_S
      For SECONDS, from three threads at once: sessions with the rig's certificate opened,
      forging the poses, a camera's observations and a liveliness token, and closed again;
      sessions with another authority's certificate (refused in the handshake); raw TCP
      connections to the endpoint's port sending garbage, or a TLS record header claiming a
      huge length, then closed, GAP_S seconds apart. Prints {"forgers": n, "refused": n, "garbage": n,
      "forger_errors": n, "accepted_foreign": n} at the end.
  zenoh_tls.py alive ENDPOINT RIG CA CERT KEY
      Prints {"alive": [the rig's liveliness tokens]}.
  zenoh_tls.py connect ENDPOINT CA CERT KEY
      Tries to open a session (3 s); prints {"connected": true|false, "error": text}.
  zenoh_tls.py connect-plain ENDPOINT
      The same with no certificate and no TLS settings at all.
"""
import bisect
import json
import statistics
import sys
import time

import zenoh


def config(endpoint, ca, cert, key):
    return zenoh.Config.from_json5(json.dumps({
        "mode": "client",
        "connect": {"endpoints": [endpoint], "timeout_ms": 3000, "exit_on_failure": True},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "link": {"tls": {
                "root_ca_certificate": ca,
                "connect_certificate": cert,
                "connect_private_key": key,
                "enable_mtls": True,
            }},
            # The services speak no shared memory; with the wheel's default a client can end
            # leaving a segment behind (/dev/shm/NNN.zenoh, docs/reliability.md).
            "shared_memory": {"enabled": False},
        },
    }))


def watch(endpoint, rig, seconds, ca, cert, key):
    session = zenoh.open(config(endpoint, ca, cert, key))
    frames = session.declare_subscriber(f"stereoscope/{rig}/poses")
    truths = session.declare_subscriber(f"stereoscope/{rig}/truth/*")
    everything = session.declare_subscriber(f"stereoscope/{rig}/**")
    truth_times = []  # sorted timestamp_ns
    truth_at = {}  # timestamp_ns -> [positions]
    got = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        idle = True
        s = everything.try_recv()
        while s is not None:
            idle = False
            try:
                m = json.loads(s.payload.to_bytes())
            except ValueError:
                m = None
            if isinstance(m, dict) and "FORGED" in m:
                print(json.dumps({"forged": str(s.key_expr)}), flush=True)
            s = everything.try_recv()
        s = truths.try_recv()
        while s is not None:
            idle = False
            t = json.loads(s.payload.to_bytes())
            ts = t["timestamp_ns"]
            if ts not in truth_at:
                bisect.insort(truth_times, ts)
                truth_at[ts] = [x["position_m"] for x in t["targets"]]
                if len(truth_times) > 2000:
                    del truth_at[truth_times.pop(0)]
            s = truths.try_recv()
        s = frames.try_recv()
        if s is not None:
            idle = False
            m = json.loads(s.payload.to_bytes())
            error = None
            if truth_times and m["poses"]:
                i = bisect.bisect_left(truth_times, m["timestamp_ns"])
                near = [truth_times[j] for j in (i - 1, i) if 0 <= j < len(truth_times)]
                ts = min(near, key=lambda x: abs(x - m["timestamp_ns"]))
                if abs(ts - m["timestamp_ns"]) < 20_000_000:
                    targets = truth_at[ts]
                    error = statistics.median(
                        min(sum((a - b) ** 2 for a, b in zip(p["position_m"], q)) ** 0.5
                            for q in targets) * 1000.0
                        for p in m["poses"])
            got += 1
            print(json.dumps({"t": time.time(), "sequence": m["sequence"],
                              "cameras": m["cameras"], "objects": len(m["poses"]),
                              "error_mm": error}), flush=True)
        if idle:
            time.sleep(0.002)
    print(json.dumps({"done": got}), flush=True)
    session.close()


def poses(endpoint, rig, seconds, ca, cert, key):
    session = zenoh.open(config(endpoint, ca, cert, key))
    frames = session.declare_subscriber(f"stereoscope/{rig}/poses")
    got = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        s = frames.try_recv()
        if s is None:
            time.sleep(0.001)
            continue
        m = json.loads(s.payload.to_bytes())
        got += 1
        print(json.dumps({"t": time.time(), "sequence": m["sequence"], "cameras": m["cameras"],
                          "objects": len(m["poses"]), "exposure_ns": m["timestamp_ns"]}),
              flush=True)
    print(json.dumps({"done": got}), flush=True)
    session.close()


def stress(endpoint, rig, seconds, ca, cert, key, oca, ocert, okey, gap_s):
    import os
    import socket
    import threading

    counts = {"forgers": 0, "refused": 0, "garbage": 0, "forger_errors": 0,
              "accepted_foreign": 0}
    lock = threading.Lock()
    end = time.monotonic() + seconds
    host, port = endpoint.split("/", 1)[1].rsplit(":", 1)

    def count(k):
        with lock:
            counts[k] += 1

    def forgers():
        while time.monotonic() < end:
            try:
                session = zenoh.open(config(endpoint, ca, cert, key))
                token = session.liveliness().declare_token(
                    f"stereoscope/{rig}/alive/fusion/FORGED")
                for _ in range(50):
                    for k in ("poses", "observations/cam0", "pose/1"):
                        session.put(f"stereoscope/{rig}/{k}",
                                    json.dumps({"FORGED": True}).encode())
                token.undeclare()
                session.close()
                count("forgers")
            except Exception as e:
                count("forger_errors")
                with lock:
                    if len(counts.setdefault("forger_error_texts", [])) < 3:
                        counts["forger_error_texts"].append(str(e)[:200])

    def foreign():
        while time.monotonic() < end:
            try:
                session = zenoh.open(config(endpoint, oca, ocert, okey))
                session.close()
                count("accepted_foreign")
            except Exception:
                count("refused")

    def garbage():
        while time.monotonic() < end:
            try:
                with socket.create_connection((host, int(port)), timeout=2) as c:
                    if counts["garbage"] % 2:
                        c.sendall(os.urandom(512))
                    else:
                        # A TLS handshake record header stating 16 KiB, then a little.
                        c.sendall(bytes([0x16, 0x03, 0x01, 0x40, 0x00]) + os.urandom(64))
                count("garbage")
            except OSError:
                count("garbage")
            time.sleep(gap_s)

    threads = [threading.Thread(target=f) for f in (forgers, foreign, garbage)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(json.dumps(counts), flush=True)


def alive(endpoint, rig, ca, cert, key):
    session = zenoh.open(config(endpoint, ca, cert, key))
    tokens = sorted(str(r.ok.key_expr) for r in
                    session.liveliness().get(f"stereoscope/{rig}/alive/**", timeout=2.0)
                    if r.ok is not None)
    print(json.dumps({"alive": tokens}), flush=True)
    session.close()


def forge(endpoint, rig, ca, cert, key, seconds, suffixes):
    session = zenoh.open(config(endpoint, ca, cert, key))
    print(json.dumps({"opened": True}), flush=True)
    token = session.liveliness().declare_token(f"stereoscope/{rig}/alive/fusion/FORGED")
    print(json.dumps({"token": True}), flush=True)
    keys = [f"stereoscope/{rig}/{s}" for s in suffixes]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for k in keys:
            session.put(k, json.dumps({"FORGED": True, "rig": rig}).encode())
        time.sleep(0.02)
    token.undeclare()
    session.close()


def connect(endpoint, ca, cert, key):
    try_open(config(endpoint, ca, cert, key))


def connect_plain(endpoint):
    try_open(zenoh.Config.from_json5(json.dumps({
        "mode": "client",
        "connect": {"endpoints": [endpoint], "timeout_ms": 3000, "exit_on_failure": True},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False}},
    })))


def try_open(cfg):
    try:
        session = zenoh.open(cfg)
        session.close()
        print(json.dumps({"connected": True, "error": None}), flush=True)
    except Exception as e:  # zenoh raises its own error type
        print(json.dumps({"connected": False, "error": str(e)}), flush=True)


def main():
    a = sys.argv[1:]
    if a[0] == "watch":
        watch(a[1], a[2], float(a[3]), a[4], a[5], a[6])
    elif a[0] == "stress":
        stress(a[1], a[2], float(a[3]), a[4], a[5], a[6], a[7], a[8], a[9], float(a[10]))
    elif a[0] == "poses":
        poses(a[1], a[2], float(a[3]), a[4], a[5], a[6])
    elif a[0] == "forge":
        forge(a[1], a[2], a[3], a[4], a[5], float(a[6]), a[7:])
    elif a[0] == "alive":
        alive(a[1], a[2], a[3], a[4], a[5])
    elif a[0] == "connect":
        connect(a[1], a[2], a[3], a[4])
    elif a[0] == "connect-plain":
        connect_plain(a[1])
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    main()
