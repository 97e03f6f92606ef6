"""A VRPN client the project did not write: libmotioncapture's VRPN backend (the PyPI wheel
`motioncapture`, which links the C++ VRPN client library). Connects to HOST:PORT the way
`vrpn_get_connection_by_name` does by default (a UDP request; the server connects back),
collects every tracker's poses for SECONDS and prints one JSON line per pose:
{"name", "position": [x, y, z], "quat_xyzw": [x, y, z, w], "receipt_ns"}, receipt_ns the
system clock when libmotioncapture handed the frame over (the latency bench's end point).

usage: vrpn_client.py HOST:PORT SECONDS
"""
import json
import sys
import time

import motioncapture


def main():
    address, seconds = sys.argv[1], float(sys.argv[2])
    mc = motioncapture.connect("vrpn", {"hostname": address})
    end = time.time() + seconds
    while time.time() < end:
        mc.waitForNextFrame()
        receipt_ns = time.time_ns()
        for name, body in mc.rigidBodies.items():
            q = body.rotation
            print(json.dumps({
                "name": name,
                "position": [float(v) for v in body.position],
                "quat_xyzw": [q.x, q.y, q.z, q.w],
                "receipt_ns": receipt_ns,
            }), flush=True)


main()
