#!/usr/bin/env bash
# Offline processing's speed (docs/performance.md, "Offline processing"): two 640 × 480
# cameras at 120 fps, the VR bench's scene (three bodies of four markers, four loose markers),
# 10 s of frames rendered once by `stereoscope grab` into PGM folders and packed into one Y4M
# file per camera (as a recording is), then `stereoscope process` over the Y4M files RUNS
# times; prints each run's summary and the median and worst.
#
#   services/stereoscope/benches/process-bench.sh [RUNS] [SECONDS] [BINARY] [CAMERAS]
#
# With CAMERAS (more than 2), the scene is the soak bench's instead: CAMERAS 640 × 480 cameras
# on a ring 3 m across and 16 markers (soak.py's rig, its 240 frames looped).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
runs=${1:-3}
seconds=${2:-10}
bin=${3:-$root/target/release/stereoscope}
cameras=${4:-2}
out="$root/target/bench-process"
rm -rf "$out" && mkdir -p "$out"
frames=$((seconds * 120))
if [ "$cameras" -gt 2 ]; then
  python3 -c "import sys; sys.path.insert(0, '$here'); import soak; print(soak.ring_rig($cameras, 120.0, 16))" > "$out/scene.toml"
else
  # The VR bench's rig at 120 fps, its VR feed left out.
  sed -n '/^cat > "$out\/rig.toml" <<RIG$/,/^RIG$/p' "$root/services/vrfeed/benches/vr-latency.sh" |
    sed '1d;$d' | sed 's/fps = 240.0, loop_frames = 480/fps = 120.0/' |
    sed '/^\[vr\]/,/^$/d' > "$out/scene.toml"
fi
cams=$(grep -o '^id = "cam[0-9]*"' "$out/scene.toml" | cut -d'"' -f2)
for cam in $cams; do
  "$bin" grab "$out/scene.toml" --camera "$cam" --count "$frames" --every 0 "$out/$cam" > /dev/null
  rm -f "$out/$cam/$cam-preview.png"
done
# PGM P5 (8-bit) frames into a Y4M `Cmono` file at 120 fps, in name order.
for cam in $cams; do
  python3 - "$out/$cam" "$out/$cam.y4m" <<'PY'
import pathlib, sys
files = sorted(pathlib.Path(sys.argv[1]).glob("*.pgm"))
with open(sys.argv[2], "wb") as y4m:
    for i, f in enumerate(files):
        data = f.read_bytes()
        fields, at = [], 0
        while len(fields) < 4:
            while data[at:at + 1].isspace():
                at += 1
            end = at
            while not data[end:end + 1].isspace():
                end += 1
            fields.append(data[at:end].decode())
            at = end
        magic, w, h, maxval = fields[0], int(fields[1]), int(fields[2]), int(fields[3])
        assert magic == "P5" and maxval < 256, f"{f}: not an 8-bit P5 PGM"
        if i == 0:
            y4m.write(f"YUV4MPEG2 W{w} H{h} F120:1 Ip A1:1 Cmono\n".encode())
        y4m.write(b"FRAME\n" + data[at + 1:at + 1 + w * h])
PY
done
sed -E "s#source = \{ kind = \"synthetic\", fps = 120(\.0)?(, loop_frames = 240)? \}#source = { kind = \"y4m\", path = \"CAMERA.y4m\" }#" "$out/scene.toml" |
  awk -v d="$out" '/CAMERA/ { n++; sub("CAMERA", d "/cam" (n - 1)) } { print }' > "$out/files.toml"
for r in $(seq "$runs"); do
  "$bin" process "$out/files.toml" --out "$out/session-$r" --json | tee -a "$out/runs.jsonl"
done
python3 - "$out/runs.jsonl" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
x = [r["times_real_time"] for r in rows]
print(f"{rows[0]['frames']} frames of each camera, {len(rows)} runs: {statistics.median(x):.1f}× real time (worst {min(x):.1f}×), "
      f"{statistics.median(r['frames'] / r['seconds'] for r in rows):.0f} frames/s of each camera; "
      f"{rows[0]['pose_frames']} pose frames, {rows[0]['object_poses']} object poses")
PY
