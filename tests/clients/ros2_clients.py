"""ROS 2 over Zenoh, read without ROS by software the project did not write:

- a Zenoh router (Zenoh's Python binding) on 127.0.0.1:PORT, standing where `rmw_zenohd` would;
- raw subscribers on the domain's keys, each payload decoded by `rosbags` (an independent CDR
  implementation, with ROS 2 Jazzy's types) and each key's type hash checked against the hash
  rosbags computes (RIHS01); the attachment (sequence, source time, gid) read as rmw_zenoh
  writes it; the graph's liveliness tokens listed;
- `zenoh-ros2-sdk` (an independent rmw_zenoh-compatible client): a `ROS2Subscriber` on the pose
  topic, which builds its own key and type hash from the message definitions below.

Prints JSON lines: {"kind": "sample", "topic", "type_ok", "msg", "attachment", "receipt_ns"} per raw sample
(at most MAX_PER_TOPIC, default 400, a topic),
{"kind": "sdk", "msg"} per SDK message, then {"kind": "done", "tokens": [...]}.

usage: ros2_clients.py PORT DOMAIN SECONDS [MAX_PER_TOPIC]
"""
import json
import os
import struct
import sys
import tempfile
import time

# Interface definitions of ROS 2 Jazzy (the fields; the SDK hashes them as ROS does).
DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n",
}

TYPES = {
    "geometry_msgs::msg::dds_::PoseStamped_": "geometry_msgs/msg/PoseStamped",
    "geometry_msgs::msg::dds_::TwistStamped_": "geometry_msgs/msg/TwistStamped",
    "tf2_msgs::msg::dds_::TFMessage_": "tf2_msgs/msg/TFMessage",
    "sensor_msgs::msg::dds_::JointState_": "sensor_msgs/msg/JointState",
}


def emit(d):
    sys.stdout.write(json.dumps(d) + "\n")
    sys.stdout.flush()


def plain(msg):
    """A rosbags message as JSON-able values."""
    if isinstance(msg, (int, float, str, bool)) or msg is None:
        return msg
    if isinstance(msg, (list, tuple)):
        return [plain(m) for m in msg]
    if hasattr(msg, "__dataclass_fields__"):
        return {k: plain(getattr(msg, k)) for k in msg.__dataclass_fields__ if k != "__msgtype__"}
    if hasattr(msg, "tolist"):
        return msg.tolist()
    return repr(msg)


def main():
    port, domain, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    cap = int(sys.argv[4]) if len(sys.argv) > 4 else 400
    import zenoh
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(conf)
    counts = {}

    def on_sample(sample):
        receipt_ns = time.time_ns()
        key = str(sample.key_expr)
        parts = key.split("/")
        dds_type, hash_ = parts[-2], parts[-1]
        topic = "/" + "/".join(parts[1:-2])
        ros_type = TYPES.get(dds_type)
        if ros_type is None:
            return
        counts[topic] = counts.get(topic, 0) + 1
        if counts[topic] > cap:
            return
        payload = bytes(sample.payload.to_bytes())
        att = sample.attachment.to_bytes() if sample.attachment is not None else b""
        a = None
        if len(att) == 33 and att[16] == 16:
            seq, src = struct.unpack("<qq", att[:16])
            a = {"sequence": seq, "source_ns": src, "gid": att[17:].hex()}
        emit({"kind": "sample", "topic": topic, "domain": parts[0],
              "type_ok": hash_ == store.hash_rihs01(ros_type),
              "msg": plain(store.deserialize_cdr(payload, ros_type)),
              "attachment": a, "attachment_len": len(att), "receipt_ns": receipt_ns})

    sub = router.declare_subscriber(f"{domain}/**", on_sample)

    # The SDK's subscriber, with the definitions above (its registry reads them, nested types
# included) instead of its download from GitHub.
    os.environ["ZENOH_CONFIG_OVERRIDE"] = "scouting/multicast/enabled=false"
    from zenoh_ros2_sdk.message_registry import get_registry
    from zenoh_ros2_sdk import ROS2Subscriber

    defs = tempfile.mkdtemp()
    for name, text in DEFINITIONS.items():
        path = os.path.join(defs, name + ".msg")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
    get_registry(defs)
    sdk_got = []
    sdk = ROS2Subscriber(topic="/stereoscope/head/pose", msg_type="geometry_msgs/msg/PoseStamped",
                         callback=lambda m: sdk_got.append(plain(m)), router_ip="127.0.0.1",
                         router_port=port, domain_id=domain)
    time.sleep(seconds)
    tokens = sorted(str(r.ok.key_expr) for r in router.liveliness().get("@ros2_lv/**", timeout=2.0)
                    if r.ok is not None)
    sdk.close()
    for m in sdk_got[:200]:
        emit({"kind": "sdk", "msg": m})
    hashes = {dds: store.hash_rihs01(ros) for dds, ros in TYPES.items()}
    emit({"kind": "done", "done": True, "tokens": tokens, "hashes": hashes, "counts": counts,
          "sdk_messages": len(sdk_got),
          "sdk_key": sdk.keyexpr})
    sub.undeclare()
    router.close()


main()
