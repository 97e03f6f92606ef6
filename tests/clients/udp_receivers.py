"""The VR feed's UDP receivers, decoded by code the project did not write where it exists:
python-osc's server for VirtualMotionTracker (/VMT/Room/Driver) and VMC (/VMC/Ext/Tra/Pos),
and opentrack's "UDP over network" packet decoded as opentrack's UDP input reads it (48
bytes: six little-endian doubles, x y z yaw pitch roll). Listens for SECONDS and prints one
JSON line per message: {"feed": "vmt" | "vmc" | "opentrack", "values": [...], "receipt_ns"},
receipt_ns the system clock when the message was decoded (the latency bench's end point).

usage: udp_receivers.py VMT_PORT VMC_PORT OPENTRACK_PORT SECONDS
"""
import json
import socket
import struct
import sys
import threading
import time

from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import ThreadingOSCUDPServer


PRINT = threading.Lock()


def emit(feed, values, receipt_ns):
    """One line per message; the servers' threads print whole lines, one at a time."""
    line = json.dumps({"feed": feed, "values": values, "receipt_ns": receipt_ns})
    with PRINT:
        print(line, flush=True)


def osc_server(port, address, feed):
    d = Dispatcher()
    d.map(address, lambda _addr, *args: emit(feed, list(args), time.time_ns()))
    server = ThreadingOSCUDPServer(("127.0.0.1", port), d)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def main():
    vmt, vmc, opentrack = (int(a) for a in sys.argv[1:4])
    seconds = float(sys.argv[4])
    servers = [osc_server(vmt, "/VMT/Room/Driver", "vmt"), osc_server(vmc, "/VMC/Ext/Tra/Pos", "vmc")]
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", opentrack))
    s.settimeout(0.1)
    emit("ready", [], time.time_ns())
    end = time.time() + seconds
    while time.time() < end:
        try:
            data = s.recv(2048)
        except socket.timeout:
            continue
        if len(data) == 48:
            receipt_ns = time.time_ns()
            emit("opentrack", list(struct.unpack("<6d", data)), receipt_ns)
    for server in servers:
        server.shutdown()


main()
