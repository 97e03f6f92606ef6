"""libmotioncapture's frame loop, shared by the NatNet and Qualisys client scripts: waits for
each frame for SECONDS and emits one JSON line per rigid body ({"client", "name", "position",
"quat_xyzw", "receipt_ns"}), then {"client", "done": true, "frames"}. The Python binding
exposes bodies only (no stamps, no point cloud)."""
import time


def run(mc, client, seconds, emit):
    end = time.time() + seconds
    frames = 0
    while time.time() < end:
        mc.waitForNextFrame()
        receipt_ns = time.time_ns()
        frames += 1
        for name, body in mc.rigidBodies.items():
            q = body.rotation
            emit({"client": client, "name": name,
                  "position": [float(v) for v in body.position],
                  "quat_xyzw": [q.x, q.y, q.z, q.w], "receipt_ns": receipt_ns})
    emit({"client": client, "done": True, "frames": frames})
