"""A client the project did not write: exercises a rig's liveliness tokens and token renewal
with the eclipse-zenoh package from PyPI, following docs/protocol.md only (no Stereoscope code).

usage:
  zenoh_tokens.py ghost ENDPOINT RIG HOST SERVICE SECONDS
      Publishes a health report for HOST/SERVICE every half second without declaring its
      liveliness token, as a service whose token a router lost would look, and prints each
      token renewal request for it as a JSON line, until one came or SECONDS passed.
  zenoh_tokens.py renew ENDPOINT RIG HOST SERVICE SECONDS
      Watches the liveliness token of HOST/SERVICE (with history), asks the service to declare
      it again, and prints each change of the token ({"kind": "put" | "delete", "t": seconds
      since the request}) for SECONDS.
The last line is {"done": ...}. Exits 1 on a request that does not follow the protocol.
"""
import json
import os
import sys
import time

import zenoh

RENEWAL_FIELDS = {"schema", "rig", "host", "service", "asked_by", "missing_s"}


def session(endpoint):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)


def health(rig, host, service, started_ns):
    now = time.time_ns()
    return {"schema": 1, "rig": rig, "host": host, "service": service, "pid": os.getpid(),
            "started_ns": started_ns, "published_ns": now, "processed": 0, "rate_hz": 0.0,
            "dropped": 0, "rejected": 0, "last_error": None, "detail": {}}


def ghost(endpoint, rig, host, service, seconds):
    s = session(endpoint)
    asked, bad = [], []

    def on_request(sample):
        r = json.loads(sample.payload.to_bytes())
        (asked if set(r) == RENEWAL_FIELDS else bad).append(r)

    sub = s.declare_subscriber(f"stereoscope/{rig}/renew/{host}/{service}", on_request)
    pub = s.declare_publisher(f"stereoscope/{rig}/health/{host}/{service}")
    started = time.time_ns()
    end = time.time() + seconds
    printed = 0
    while time.time() < end and not asked and not bad:
        pub.put(json.dumps(health(rig, host, service, started)))
        time.sleep(0.5)
    if bad:
        raise ValueError(f"renewal fields {sorted(bad[0])}")
    for r in asked:
        print(json.dumps(r), flush=True)
        printed += 1
    sub.undeclare()
    s.close()
    print(json.dumps({"done": True, "requests": printed}), flush=True)


def renew(endpoint, rig, host, service, seconds):
    s = session(endpoint)
    events = []
    t0 = [None]

    def on_token(sample):
        kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
        t = None if t0[0] is None else time.time() - t0[0]
        events.append({"kind": kind, "key": str(sample.key_expr), "t": t})

    key = f"stereoscope/{rig}/alive/{host}/{service}"
    sub = s.liveliness().declare_subscriber(key, on_token, history=True)
    end = time.time() + 5
    while not events and time.time() < end:
        time.sleep(0.05)
    t0[0] = time.time()
    request = {"schema": 1, "rig": rig, "host": host, "service": service,
               "asked_by": "python-client", "missing_s": 0.0}
    s.put(f"stereoscope/{rig}/renew/{host}/{service}", json.dumps(request))
    time.sleep(seconds)
    for e in events:
        print(json.dumps(e), flush=True)
    sub.undeclare()
    s.close()
    print(json.dumps({"done": True, "events": len(events)}), flush=True)


def main():
    if len(sys.argv) != 7 or sys.argv[1] not in ("ghost", "renew"):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    _, cmd, endpoint, rig, host, service, seconds = sys.argv
    try:
        (ghost if cmd == "ghost" else renew)(endpoint, rig, host, service, float(seconds))
    except ValueError as e:
        print(f"protocol error: {e}", file=sys.stderr)
        sys.exit(1)


main()
