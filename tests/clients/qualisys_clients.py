"""Two Qualisys RT clients the project did not write, reading Stereoscope's QTM RT server:

- `qtm-rt` (PyPI, Qualisys's own Python SDK): connects to the little-endian port with protocol
  1.25, reads the parameters (General, 3D, 6D) and the state, takes the current frame, streams
  3D, 6D and 6DEuler at all frames and then 6D at a set frequency, and tries a command that would
  control QTM;
- `libmotioncapture` (PyPI `motioncapture`): its `qualisys` backend links Qualisys's C++ SDK
  (`qualisys_cpp_sdk`), asks protocol 1.19, reads the 6D settings and streams 6DEuler and
  3DNoLabels over UDP (to its fixed port 6734).

Prints JSON lines: per received body {"client", "name", "position", "rotation" (column-major
matrix, qtm-rt) or "quat_xyzw" (libmotioncapture), "timestamp_us", "frame", "receipt_ns"},
then one {"client", "done": true, ...} with the rest.

usage: qualisys_clients.py qtm-rt PORT SECONDS | libmotioncapture BASE_PORT SECONDS
"""
import asyncio
import json
import sys
import time
import xml.etree.ElementTree as ET

import mocap_loop


def emit(d):
    sys.stdout.write(json.dumps(d) + "\n")
    sys.stdout.flush()


async def run_qtm_rt(port, seconds):
    import qtm_rt
    from qtm_rt import QRTCommandException

    conn = await qtm_rt.connect("127.0.0.1", port=port, version="1.25", timeout=5)
    if conn is None:
        raise SystemExit("qtm-rt could not connect")
    xml = await conn.get_parameters(parameters=["general", "3d", "6d"])
    root = ET.fromstring(xml)
    bodies = [b.findtext("Name") for b in root.iter("Body")]
    labels = [l.findtext("Name") for l in root.iter("Label")]
    frequency = root.findtext("General/Frequency")
    state = await conn.get_state()
    current = await conn.get_current_frame(components=["3d", "6d"])
    current_bodies = len(current.get_6d()[1]) if current is not None and hasattr(current, "get_6d") else None

    done = {"all": 0, "rate": 0, "stamps": []}

    def on_all(packet):
        done["all"] += 1
        receipt_ns = time.time_ns()
        _, six = packet.get_6d()
        _, euler = packet.get_6d_euler()
        _, markers = packet.get_3d_markers()
        for i, (pos, rot) in enumerate(six):
            emit({"client": "qtm-rt", "name": bodies[i] if i < len(bodies) else None,
                  "position": [pos.x, pos.y, pos.z], "rotation": list(rot.matrix),
                  "euler": [euler[i][1].a1, euler[i][1].a2, euler[i][1].a3],
                  "markers": [[m.x, m.y, m.z] for m in markers],
                  "timestamp_us": packet.timestamp, "frame": packet.framenumber,
                  "receipt_ns": receipt_ns})

    await conn.stream_frames(frames="allframes", components=["3d", "6d", "6deuler"],
                             on_packet=on_all)
    await asyncio.sleep(seconds)
    await conn.stream_frames_stop()
    await asyncio.sleep(0.3)

    def on_rate(packet):
        done["rate"] += 1
        done["stamps"].append(packet.timestamp)

    await conn.stream_frames(frames="frequency:10", components=["6d"], on_packet=on_rate)
    await asyncio.sleep(2.0)
    await conn.stream_frames_stop()
    refused = None
    try:
        await conn.take_control("secret")
    except QRTCommandException as e:
        refused = str(e)
    version = (await conn.qtm_version()).decode()
    conn.disconnect()
    stamps = done.pop("stamps")
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    emit({"client": "qtm-rt", "done": True, "bodies": bodies, "labels": labels,
          "frequency": frequency, "state": state.name, "current_bodies": current_bodies,
          "refused": refused, "qtm_version": version, "rate_gaps_us": gaps, **done})


def run_libmotioncapture(base_port, seconds):
    import motioncapture

    mc = motioncapture.connect("qualisys", {"hostname": "127.0.0.1", "port": str(base_port)})
    mocap_loop.run(mc, "libmotioncapture", seconds, emit)


def main():
    which, port, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    if which == "qtm-rt":
        asyncio.run(run_qtm_rt(port, seconds))
    else:
        run_libmotioncapture(port, seconds)


main()
