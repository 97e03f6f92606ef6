"""A client the project did not write: subscribes to a rig's poses with the eclipse-zenoh
package from PyPI and decodes them following docs/protocol.md only (no Stereoscope code).

usage: zenoh_poses.py ENDPOINT RIG COUNT SECONDS
Prints one JSON line per pose frame received on stereoscope/<RIG>/poses (sequence, cameras,
per pose object id, position in metres, heading and body label, per body its name, position
and quaternion) and counts the pose updates on stereoscope/<RIG>/pose/* and body updates on
stereoscope/<RIG>/bodies/*, until COUNT pose frames came or SECONDS passed; then a last line
{"done": ...}. Exits 1 on a message that does not follow the protocol.
"""
import json
import math
import sys
import time

import zenoh

POSE_FIELDS = {"object_id", "position_m", "velocity_m_per_s", "heading_deg", "heading_directed",
               "method", "cameras", "residual_px", "out_of_range", "body", "model"}
FRAME_FIELDS = {"schema", "rig", "sequence", "timestamp_ns", "frame_published_ns",
                "published_ns", "cameras", "poses", "bodies", "models"}
MODEL_FIELDS = {"name", "valid", "rms_mm", "markers_seen", "markers", "joints", "links"}
JOINT_FIELDS = {"name", "values", "determined", "at_limit", "residual_mm"}
LINK_FIELDS = {"name", "position_m", "orientation_xyzw"}
BODY_FIELDS = {"name", "position_m", "orientation_xyzw", "velocity_m_per_s",
               "angular_velocity_rad_per_s", "residual_mm", "markers_seen", "markers", "held",
               "roll_unobservable"}
BODY_UPDATE_FIELDS = {"schema", "rig", "sequence", "timestamp_ns", "frame_published_ns",
                      "published_ns", "body"}
UPDATE_FIELDS = {"schema", "rig", "sequence", "timestamp_ns", "frame_published_ns",
                 "published_ns", "pose"}


def check_pose(p):
    if set(p) != POSE_FIELDS:
        raise ValueError(f"pose fields {sorted(p)}")
    if len(p["position_m"]) != 3 or not all(isinstance(v, (int, float)) for v in p["position_m"]):
        raise ValueError(f"position_m {p['position_m']}")
    h = p["heading_deg"]
    if h is not None and not 0.0 <= h < 360.0:
        raise ValueError(f"heading_deg {h}")
    if p["method"] not in ("triangulated", "depth_from_area"):
        raise ValueError(f"method {p['method']}")
    label = p["body"]
    if label is not None and (set(label) != {"name", "marker"} or not isinstance(label["marker"], int)):
        raise ValueError(f"body label {label}")
    model = p["model"]
    if model is not None and (set(model) != {"name", "link", "marker"}
                              or not all(isinstance(v, str) and v for v in model.values())):
        raise ValueError(f"model label {model}")
    return [p["object_id"], p["position_m"], h, label]


def check_body(b):
    if set(b) != BODY_FIELDS:
        raise ValueError(f"body fields {sorted(b)}")
    q = b["orientation_xyzw"]
    if len(q) != 4 or abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-3:
        raise ValueError(f"orientation_xyzw {q}")
    if not 0 <= b["markers_seen"] <= b["markers"]:
        raise ValueError(f"markers {b['markers_seen']} of {b['markers']}")
    return [b["name"], b["position_m"], q, b["held"]]


def check_model(m):
    if set(m) != MODEL_FIELDS:
        raise ValueError(f"model fields {sorted(m)}")
    for j in m["joints"]:
        if set(j) != JOINT_FIELDS or len(j["values"]) > 4:
            raise ValueError(f"joint {j}")
    for link in m["links"]:
        q = link["orientation_xyzw"]
        if set(link) != LINK_FIELDS or abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-3:
            raise ValueError(f"link {link}")
    return m["name"]


def main():
    endpoint, rig, count, seconds = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
    conf = zenoh.Config.from_json5(json.dumps({
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        # The services speak no shared memory; with the wheel's default a client can end
        # leaving a segment behind (/dev/shm/NNN.zenoh, docs/reliability.md).
        "transport": {"shared_memory": {"enabled": False}},
    }))
    session = zenoh.open(conf)
    frames = session.declare_subscriber(f"stereoscope/{rig}/poses")
    updates = session.declare_subscriber(f"stereoscope/{rig}/pose/*")
    bodies = session.declare_subscriber(f"stereoscope/{rig}/bodies/*")
    got = 0
    got_updates = 0
    got_bodies = 0
    end = time.monotonic() + seconds
    while got < count and time.monotonic() < end:
        idle = True
        sample = frames.try_recv()
        if sample is not None:
            idle = False
            m = json.loads(sample.payload.to_bytes())
            if set(m) != FRAME_FIELDS or m["schema"] != 1 or m["rig"] != rig:
                raise ValueError(f"pose frame {m}")
            for model in m["models"]:
                check_model(model)
            print(json.dumps({"key": str(sample.key_expr), "sequence": m["sequence"],
                              "timestamp_ns": m["timestamp_ns"], "cameras": m["cameras"],
                              "poses": [check_pose(p) for p in m["poses"]],
                              "bodies": [check_body(b) for b in m["bodies"]]}), flush=True)
            got += 1
        sample = updates.try_recv()
        if sample is not None:
            idle = False
            m = json.loads(sample.payload.to_bytes())
            if set(m) != UPDATE_FIELDS or m["schema"] != 1:
                raise ValueError(f"pose update {m}")
            oid = check_pose(m["pose"])[0]
            if str(sample.key_expr) != f"stereoscope/{rig}/pose/{oid}":
                raise ValueError(f"pose of object {oid} on {sample.key_expr}")
            got_updates += 1
        sample = bodies.try_recv()
        if sample is not None:
            idle = False
            m = json.loads(sample.payload.to_bytes())
            if set(m) != BODY_UPDATE_FIELDS or m["schema"] != 1:
                raise ValueError(f"body update {m}")
            name = check_body(m["body"])[0]
            if str(sample.key_expr) != f"stereoscope/{rig}/bodies/{name}":
                raise ValueError(f"body {name} on {sample.key_expr}")
            got_bodies += 1
        if idle:
            time.sleep(0.002)
    print(json.dumps({"done": True, "frames": got, "updates": got_updates,
                      "body_updates": got_bodies}), flush=True)
    session.close()


if __name__ == "__main__":
    try:
        main()
    except ValueError as e:
        print(f"not the documented protocol: {e}", file=sys.stderr)
        sys.exit(1)
