#!/usr/bin/env python3
"""Joins what the VR feed sent (its trace, STEREOSCOPE_VR_TRACE) with what clients the project
did not write received (tests/clients/vrpn_client.py: libmotioncapture's VRPN client;
udp_receivers.py: python-osc for VMT, opentrack's packet layout), and prints, per protocol,
the latency from the pose frame's oldest exposure to its receipt at the client, and the
feed's own part (exposure to the bytes handed to the socket).

A received pose is matched to the sent pose of the same body (VRPN: name; VMT: tracker index;
opentrack: its one body) with the same position — bit for bit: opentrack's doubles as sent,
VRPN's and VMT's as the 32-bit floats the clients hand over — among those sent in the second
before its receipt. A pose sent more than once
(a body held while unseen repeats its last pose) matches several sends: it is counted as
ambiguous and left out, not guessed.

usage: vr_latency_join.py TRACE.jsonl VRPN.jsonl UDP.jsonl
"""
import bisect
import json
import statistics
import struct
import sys


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def pct(v, p):
    v = sorted(v)
    return v[min(len(v) - 1, int(p / 100 * len(v)))]


def main():
    sent = {}  # (feed, key) -> sorted list of (sent_ns, exposure_ns, position)
    for line in open(sys.argv[1]):
        t = json.loads(line)
        for feed, key, x, y, z in t["sent"]:
            sent.setdefault((feed, key), []).append((t["sent_ns"], t["exposure_ns"], (x, y, z)))
    for v in sent.values():
        v.sort()
    received = []
    for line in open(sys.argv[2]):
        r = json.loads(line)
        received.append(("vrpn", r["name"], r["position"], r["receipt_ns"]))
    for line in open(sys.argv[3]):
        r = json.loads(line)
        if r["feed"] == "vmt":
            received.append(("vmt", str(int(r["values"][0])), r["values"][3:6], r["receipt_ns"]))
        elif r["feed"] == "opentrack":
            received.append(("opentrack", "", r["values"][0:3], r["receipt_ns"]))
    out = {}
    for feed, key, pos, receipt in received:
        rows = sent.get((feed, key), [])
        lo = bisect.bisect_left(rows, (receipt - 1_000_000_000,))
        hi = bisect.bisect_right(rows, (receipt, float("inf")))
        exact = (lambda p: tuple(p)) if feed == "opentrack" else (lambda p: tuple(f32(c) for c in p))
        want = tuple(pos)
        hits = [(s_ns, e_ns) for s_ns, e_ns, p in rows[lo:hi] if exact(p) == want]
        o = out.setdefault(feed, {"received": 0, "matched": 0, "ambiguous": 0, "total": [], "feed": [], "wire": []})
        o["received"] += 1
        if len({e for _, e in hits}) > 1:
            o["ambiguous"] += 1
        elif hits:
            s_ns, e_ns = hits[-1]
            o["matched"] += 1
            o["total"].append((receipt - e_ns) / 1e3)
            o["feed"].append((s_ns - e_ns) / 1e3)
            o["wire"].append((receipt - s_ns) / 1e3)
    sent_n = {f: sum(len(v) for (g, _), v in sent.items() if g == f) for f, _ in sent}
    for feed in ("vrpn", "vmt", "opentrack"):
        o = out.get(feed)
        if not o or not o["total"]:
            print(f"{feed}: nothing matched ({sent_n.get(feed, 0)} sent, {o['received'] if o else 0} received)")
            continue
        t, f, w = o["total"], o["feed"], o["wire"]
        print(f"{feed}: {o['matched']} of {o['received']} received matched, {o['ambiguous']} ambiguous ({sent_n.get(feed, 0)} sent); "
              f"oldest exposure → client receipt p50 {statistics.median(t):.0f} µs, p99 {pct(t, 99):.0f} µs, "
              f"worst {max(t):.0f} µs; of which exposure → socket p50 {statistics.median(f):.0f} µs, "
              f"socket → client p50 {statistics.median(w):.0f} µs p99 {pct(w, 99):.0f} µs")


main()
