"""A Lab Streaming Layer inlet the project did not write: pylsl (PyPI, with the liblsl it
bundles). Resolves the stream whose source id is SOURCE_ID and whose type is MoCap, reads its
description, then every sample for SECONDS, and prints one JSON line per sample: {"t": its
timestamp on the outlet's clock corrected to this process's LSL clock, "unix": that time on the
system clock, "values": [...], "receipt_ns"}, then {"done": true, "info": {...}, "correction": ...}.

usage: lsl_client.py SOURCE_ID SECONDS
"""
import json
import sys
import time

import pylsl


def main():
    source_id, seconds = sys.argv[1], float(sys.argv[2])
    found = pylsl.resolve_bypred(f"source_id='{source_id}' and type='MoCap'", 1, 20.0)
    if not found:
        raise SystemExit(f"no MoCap stream with source id {source_id}")
    inlet = pylsl.StreamInlet(found[0], max_buflen=30)
    info = inlet.info(timeout=10.0)
    labels = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty():
        labels.append([ch.child_value("label"), ch.child_value("type"), ch.child_value("unit")])
        ch = ch.next_sibling()
    correction = inlet.time_correction(timeout=10.0)
    inlet.open_stream(timeout=10.0)
    end = time.time() + seconds
    n = 0
    while time.time() < end:
        values, t = inlet.pull_sample(timeout=0.5)
        receipt_ns = time.time_ns()
        if values is None:
            continue
        # LSL's clock to the system's (the same PC as the outlet): of three readings, the one
        # read closest together, as the outlet does.
        offset = min(
            ((b - a, (a + b) / 2 - lsl) for a, lsl, b in
             ((time.time(), pylsl.local_clock(), time.time()) for _ in range(3))),
        )[1]
        corrected = t + correction
        # NaN (a body not measured) as null: JSON has no NaN.
        values = [None if v != v else v for v in values]
        print(json.dumps({"t": corrected, "unix": corrected + offset, "values": values,
                          "receipt_ns": receipt_ns}), flush=True)
        n += 1
    print(json.dumps({"done": True, "samples": n, "correction": correction, "info": {
        "name": info.name(), "type": info.type(), "channel_count": info.channel_count(),
        "nominal_srate": info.nominal_srate(), "source_id": info.source_id(),
        "channel_format": info.channel_format(), "labels": labels}}), flush=True)


main()
