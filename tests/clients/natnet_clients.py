"""Two NatNet clients the project did not write, reading a Stereoscope NatNet server:

- `libmotioncapture` (PyPI `motioncapture`, C++): its `optitrack` backend, which asks the
  server's version, reads the model definitions and listens on the data port (multicast);
- `natnetsdk` (PyPI, OptiTrack's own Python sample client `NatNetClient.py`): it decodes every
  frame section by section; this script also checks that each decode consumed the whole packet.
  Its multicast socket is bound to the group's port on every address rather than on the
  client's address: the sample is written for Windows, where a socket bound to an interface
  address receives the group's datagrams; on Linux it receives none. Only that bind changes.

Each prints one JSON line per rigid body per frame: {"client", "name" or "id", "position",
"quat_xyzw", "tracking_valid", "timestamp_us", "receipt_ns"}, then {"client", "done": true,
...} with what else it saw (versions, model names, whole-packet checks).

usage: natnet_clients.py libmotioncapture|natnetsdk COMMAND_PORT DATA_PORT SECONDS
"""
import contextlib
import io
import json
import sys
import time

import mocap_loop

real_stdout = sys.stdout


def emit(d):
    real_stdout.write(json.dumps(d) + "\n")
    real_stdout.flush()


def run_libmotioncapture(command_port, seconds):
    import motioncapture

    mc = motioncapture.connect(
        "optitrack",
        {"hostname": "127.0.0.1", "interface_ip": "127.0.0.1", "port_command": str(command_port)},
    )
    mocap_loop.run(mc, "libmotioncapture", seconds, emit)


def run_natnetsdk(command_port, data_port, seconds):
    from natnetsdk import MoCapData
    from natnetsdk.NatNetClient import NatNetClient

    client = NatNetClient()
    client.set_client_address("127.0.0.1")
    client.set_server_address("127.0.0.1")
    client.set_use_multicast(True)
    client.command_port = command_port
    client.data_port = data_port
    seen = {"frames": 0, "whole": 0, "short": [], "models": [], "timestamps": [],
            "before_version": 0}
    bodies = []

    unpack = client._NatNetClient__unpack_mocap_data

    def checked(data, packet_size, major, minor):
        if major == 0:
            # A multicast frame that arrived before the server's version did: the sample would
            # decode it as version 0.0 — a layout without the 4.1 byte counts — and its data
            # thread dies on the first string that is not UTF-8 (its own race, whatever the
            # server). Such frames are counted and passed over, as an empty frame.
            seen["before_version"] += 1
            empty = MoCapData.MoCapData()
            empty.set_prefix_data(MoCapData.FramePrefixData(-1))
            return packet_size, empty
        offset, mocap = unpack(data, packet_size, major, minor)
        seen["frames"] += 1
        if offset == packet_size:
            seen["whole"] += 1
        elif len(seen["short"]) < 5:
            seen["short"].append([offset, packet_size])
        s = mocap.suffix_data
        seen["timestamps"].append([s.stamp_camera_mid_exposure, s.stamp_data_received,
                                   s.stamp_transmit])
        for rb in mocap.rigid_body_data.rigid_body_list:
            bodies.append({
                "client": "natnetsdk",
                "id": rb.id_num,
                "position": list(rb.pos),
                "quat_xyzw": list(rb.rot),
                "tracking_valid": rb.tracking_valid,
                "error": rb.error,
                "timestamp_us": s.stamp_camera_mid_exposure // 1000,
                "receipt_ns": time.time_ns(),
            })
        return offset, mocap

    client._NatNetClient__unpack_mocap_data = checked

    def data_socket(port):
        import socket
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, 0)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                     socket.inet_aton(client.multicast_address) + socket.inet_aton("127.0.0.1"))
        s.bind(("", port))
        return s

    client._NatNetClient__create_data_socket = data_socket
    describe = client._NatNetClient__unpack_data_descriptions

    def models(data, packet_size, major, minor):
        offset, descs = describe(data, packet_size, major, minor)
        for rb in descs.rigid_body_list:
            seen["models"].append({"name": rb.sz_name.decode() if isinstance(rb.sz_name, bytes)
                                   else rb.sz_name, "id": rb.id_num,
                                   "markers": len(rb.rb_marker_list)})
        return offset, descs

    client._NatNetClient__unpack_data_descriptions = models
    # The sample prints every frame; that goes to stderr here.
    with contextlib.redirect_stdout(sys.stderr):
        if not client.run():
            raise SystemExit("natnetsdk: could not open its sockets")
        time.sleep(0.5)
        client.send_request(client.command_socket, client.NAT_REQUEST_MODELDEF, "",
                            (client.server_ip_address, client.command_port))
        time.sleep(seconds)
        client.shutdown()
    for b in bodies:
        emit(b)
    ts = seen.pop("timestamps")
    emit({"client": "natnetsdk", "done": True, "server_version":
          list(client.get_nat_net_version_server()), "last_stamps": ts[-1] if ts else None,
          **seen})


def main():
    which, command_port, data_port, seconds = (sys.argv[1], int(sys.argv[2]), int(sys.argv[3]),
                                               float(sys.argv[4]))
    if which == "libmotioncapture":
        run_libmotioncapture(command_port, seconds)
    else:
        run_natnetsdk(command_port, data_port, seconds)


main()
