#!/usr/bin/env bash
# The feed's latency benchmark (docs/performance.md, "VR feed" and "Lab protocols"): two
# synthetic 640 × 480 cameras at 240 fps (480 frames rendered once and played back and forth),
# three rigid bodies and four loose markers, the whole chain as processes (`stereoscope demo
# --rig`), every protocol on at once, each with a client the project did not write connected
# throughout: libmotioncapture's VRPN client, python-osc for VMT, opentrack's packet,
# OptiTrack's NatNet client (natnetsdk), Qualisys's qtm-rt, a Zenoh router with a raw ROS 2
# subscriber (rosbags decoding), and a pylsl inlet. Prints per run the demo's summary
# (vr_latency_p50_us / p99: the feed's own figure, newest frame published → bytes handed to the
# sockets), the feed process's CPU, and per protocol the latency from the pose frame's oldest
# exposure to its receipt at the client: for VRPN, VMT and opentrack the feed's trace
# (STEREOSCOPE_VR_TRACE) joined with what the clients received (vr_latency_join.py); for the
# lab protocols the exposure each client reads in the frame itself (lab_latency_join.py).
#
#   services/vrfeed/benches/vr-latency.sh [RUNS] [SECONDS] [BINARY]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
runs=${1:-3}
seconds=${2:-20}
bin=${3:-$root/target/release/stereoscope}
out="$root/target/bench-vr"
mkdir -p "$out"
free() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
port=$(free)
vmt=$(free)
vmc=$(free)
ot=$(free)
natnet=$(free)
natdata=$(free)
qtm=$(free)
ros=$(free)
lsl_source="vrbench-$$"
liblsl=$(ls "$root"/target/py-clients/lib/python3*/site-packages/pylsl/lib/liblsl.so 2>/dev/null | head -1)
cat > "$out/rig.toml" <<RIG
name = "vrbench"
units = "cm"

[[camera]]
id = "cam0"
image_size = [640, 480]
focal_length_mm = 12.5
pixel_pitch_um = [10.75, 12.5]
pose = { position = [-10.0, 0.0, 280.0], look_at = [-10.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }
source = { kind = "synthetic", fps = 240.0, loop_frames = 480 }
moments = { threshold = "auto", max_objects = 24 }

[[camera]]
id = "cam1"
image_size = [640, 480]
focal_length_mm = 12.5
pixel_pitch_um = [10.75, 12.5]
pose = { position = [10.0, 0.0, 277.5], look_at = [10.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }
source = { kind = "synthetic", fps = 240.0, loop_frames = 480 }
moments = { threshold = "auto", max_objects = 24 }

[fusion]
max_skew_ms = 2.0
max_wait_ms = 5.0

[[body]]
name = "head"
markers = [[0.0, 0.0, 0.0], [18.0, 0.0, 0.0], [0.0, 11.0, 0.0], [6.0, 6.0, 8.0]]
tolerance = 1.0

[[body]]
name = "tool"
markers = [[0.0, 0.0, 0.0], [13.0, 0.0, 0.0], [3.0, 8.0, 0.0], [7.0, -5.0, 6.0]]
tolerance = 0.5

[[body]]
name = "bat"
markers = [[0.0, 0.0, 0.0], [26.0, 0.0, 0.0], [9.0, 5.0, 0.0], [4.0, -4.0, 5.0]]
tolerance = 0.5

[vr]
vrpn = { listen = "127.0.0.1:$port" }
vmt = { send_to = "127.0.0.1:$vmt" }
opentrack = { send_to = "127.0.0.1:$ot", body = "head" }
natnet = { command = "127.0.0.1:$natnet", data_port = $natdata }
qualisys = { base = "127.0.0.1:$((qtm - 1))" }
ros2 = { router = "tcp/127.0.0.1:$ros" }
lsl = { library = "$liblsl", source_id = "$lsl_source" }

[synthetic]
seed = 3
light = "ring"

[[synthetic.target]]
shape = "body"
body = "head"
radius = 1.0
motion = { kind = "head", centre = [-25.0, 25.0, 60.0], radius = 5.0, period_s = 12.0, turn_period_s = 9.0, nod_deg = 20.0 }

[[synthetic.target]]
shape = "body"
body = "tool"
radius = 1.0
motion = { kind = "circle", centre = [22.0, 22.0, 50.0], radius = 4.0, period_s = 7.0 }

[[synthetic.target]]
shape = "body"
body = "bat"
radius = 1.0
motion = { kind = "wander", centre = [0.0, -28.0, 60.0], extent = [6.0, 3.0, 10.0], seed = 5 }

[[synthetic.target]]
shape = "sphere"
radius = 1.0
motion = { kind = "static", position = [-40.0, -5.0, 40.0] }

[[synthetic.target]]
shape = "sphere"
radius = 1.0
motion = { kind = "static", position = [40.0, -5.0, 40.0] }

[[synthetic.target]]
shape = "sphere"
radius = 1.0
motion = { kind = "circle", centre = [0.0, 5.0, 30.0], radius = 8.0, period_s = 6.0 }

[[synthetic.target]]
shape = "sphere"
radius = 1.0
motion = { kind = "line", from = [-30.0, -45.0, 30.0], to = [30.0, -45.0, 30.0], period_s = 8.0 }
RIG
# The VRPN client is libmotioncapture's, in the venv the system tests install it into.
py="$root/target/py-clients/bin/python"
if [ ! -x "$py" ]; then
  echo "error: $py is missing: run 'cargo test -p stereoscope --test vrfeed' once to install the real clients" >&2
  exit 1
fi
for r in $(seq "$runs"); do
  # The client connects once the feed listens, and stays until the run ends.
  ( sleep 4; timeout $((seconds + 10)) "$py" "$root/tests/clients/vrpn_client.py" "127.0.0.1:$port" "$((seconds - 2))" > "$out/vrpn-$r.jsonl" 2> "$out/vrpn-$r.log" || true ) &
  ( timeout $((seconds + 10)) "$py" "$root/tests/clients/udp_receivers.py" "$vmt" "$vmc" "$ot" "$((seconds + 2))" > "$out/udp-$r.jsonl" 2> "$out/udp-$r.log" || true ) &
  ( timeout $((seconds + 10)) "$py" "$root/tests/clients/ros2_clients.py" "$ros" 0 "$((seconds + 2))" 1000000 > "$out/ros-$r.jsonl" 2> "$out/ros-$r.log" || true ) &
  ( sleep 4; timeout $((seconds + 10)) "$py" "$root/tests/clients/natnet_clients.py" natnetsdk "$natnet" "$natdata" "$((seconds - 4))" > "$out/natnet-$r.jsonl" 2> "$out/natnet-$r.log" || true ) &
  ( sleep 4; timeout $((seconds + 10)) "$py" "$root/tests/clients/qualisys_clients.py" qtm-rt "$qtm" "$((seconds - 8))" > "$out/qtm-$r.jsonl" 2> "$out/qtm-$r.log" || true ) &
  ( sleep 2; timeout $((seconds + 10)) "$py" "$root/tests/clients/lsl_client.py" "$lsl_source" "$((seconds - 4))" > "$out/lsl-$r.jsonl" 2> "$out/lsl-$r.log" || true ) &
  # The feed's CPU from its own accounting, over the middle of the run.
  ( sleep 6; pid=$(pgrep -f "stereoscope service vrfeed" | head -1); t0=$(awk '{print $14 + $15}' /proc/$pid/stat); sleep $((seconds - 10)); t1=$(awk '{print $14 + $15}' /proc/$pid/stat); python3 -c "import os,sys; print(f'feed CPU {100 * ($t1 - $t0) / os.sysconf(\"SC_CLK_TCK\") / ($seconds - 10):.1f} % of a core')" > "$out/cpu-$r.txt" ) &
  rm -f "$out/trace-$r.jsonl"
  STEREOSCOPE_VR_TRACE="$out/trace-$r.jsonl" "$bin" demo --rig "$out/rig.toml" --seconds "$seconds" --json 2> "$out/demo-$r.log" | tail -1 > "$out/summary-$r.json"
  wait
  python3 - "$out/summary-$r.json" "$out/vrpn-$r.jsonl" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
n = sum(1 for _ in open(sys.argv[2]))
bodies = ", ".join(f"{b['name']} {b['matched']}/{b['matched'] + b['missed']} {b['position_rms_m'] * 1e3:.2f} mm {b['rotation_rms_deg']:.2f}°" for b in s["bodies"])
print(f"pose frames/s {s['poses_per_s']:.1f}; poses p50 {s['latency_p50_ms']:.3f} ms p99 {s['latency_p99_ms']:.3f} ms; "
      f"VR feed p50 {s['vr_latency_p50_us']} µs p99 {s['vr_latency_p99_us']} µs; VRPN poses received {n}; bodies: {bodies}")
PY
  python3 "$here/vr_latency_join.py" "$out/trace-$r.jsonl" "$out/vrpn-$r.jsonl" "$out/udp-$r.jsonl"
  python3 "$here/lab_latency_join.py" "$out/natnet-$r.jsonl" "$out/qtm-$r.jsonl" "$out/ros-$r.jsonl" "$out/lsl-$r.jsonl"
  cat "$out/cpu-$r.txt"
done
