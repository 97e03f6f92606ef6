#!/usr/bin/env python3
"""Latency from a pose frame's oldest exposure to its receipt at each lab protocol's client,
from what the clients themselves read (vr-latency.sh runs them): the mid-exposure stamp
OptiTrack's NatNet client decodes, the timestamp qtm-rt decodes, the header stamp of each ROS 2
PoseStamped (rosbags), and the exposure a pylsl inlet reads after LSL's clock correction — each
against the client's own clock at receipt (the same PC's system clock).

usage: lab_latency_join.py NATNET.jsonl QTM.jsonl ROS.jsonl LSL.jsonl
"""
import json
import sys


def pct(v, p):
    v = sorted(v)
    return v[min(len(v) - 1, int(p / 100 * len(v)))]


def lines(path):
    try:
        for line in open(path):
            try:
                yield json.loads(line)
            except ValueError:
                continue
    except OSError:
        return


def main():
    lat = {"natnet": [], "qualisys": [], "ros2": [], "lsl": []}
    for r in lines(sys.argv[1]):
        if r.get("client") == "natnetsdk" and "receipt_ns" in r and r.get("id") == 1:
            lat["natnet"].append(r["receipt_ns"] - r["timestamp_us"] * 1000)
    for r in lines(sys.argv[2]):
        if r.get("client") == "qtm-rt" and "receipt_ns" in r and r.get("name") == "head":
            lat["qualisys"].append(r["receipt_ns"] - r["timestamp_us"] * 1000)
    for r in lines(sys.argv[3]):
        if r.get("kind") == "sample" and r.get("topic") == "/stereoscope/head/pose":
            st = r["msg"]["header"]["stamp"]
            lat["ros2"].append(r["receipt_ns"] - (st["sec"] * 1_000_000_000 + st["nanosec"]))
    for r in lines(sys.argv[4]):
        if "unix" in r and "receipt_ns" in r:
            lat["lsl"].append(r["receipt_ns"] - r["unix"] * 1e9)
    for name, v in lat.items():
        if not v:
            print(f"  {name}: nothing received")
            continue
        ms = [x / 1e6 for x in v]
        print(f"  {name}: {len(ms)} frames, exposure → client p50 {pct(ms, 50):.2f} ms, "
              f"p99 {pct(ms, 99):.2f} ms, max {max(ms):.2f} ms")


main()
