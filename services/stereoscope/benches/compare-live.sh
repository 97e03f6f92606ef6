#!/usr/bin/env bash
# The live system's benchmark with OpenCV timed on the moment worker's frames in the same run
# (the table in docs/performance.md, "Live system").
#
#   services/stereoscope/benches/compare-live.sh [--quick]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
out="$root/target/bench-live"
quick=()
[ "${1:-}" = "--quick" ] && quick=(--quick)
rm -rf "$out" && mkdir -p "$out/frames"
. "$root/services/lib/vision/benches/opencv-venv.sh"
cd "$root"
cargo bench -p stereoscope --bench live -- "${quick[@]}" --frames-dir "$out/frames" --json "$out/live.json" | tee "$out/report.md"
"$venv/bin/python" "$root/services/lib/vision/benches/opencv_bench.py" "$out/frames" "$out/opencv.json" "${quick[@]}"
"$venv/bin/python" - "$out/live.json" "$out/opencv.json" <<'PY' | tee -a "$out/report.md"
import json, sys
live = json.load(open(sys.argv[1]))
cv = json.load(open(sys.argv[2]))
print("\n## Moment worker against OpenCV on the same frame (one thread), ms per frame")
print("OpenCV %s; it finds %d contours in the 640×480 frame." % (cv[0]["opencv_version"], cv[0]["contour_blobs"]))
print("| frame | worker (tracking, windows, observation) | OpenCV threshold | OpenCV threshold+contours+moments | OpenCV / worker |")
print("|---|---|---|---|---|")
for r in live:
    if r.get("section") != "worker":
        continue
    name = "worker-%s" % r["frame"]
    row = next((c for c in cv if c["frame"] == name), None)
    if row is None:
        print("| %s | %.4f | - | - | - |" % (r["frame"], r["ms_per_frame"]))
        continue
    print("| %s | %.4f | %.4f | %.4f | %.1f× |" % (r["frame"], r["ms_per_frame"], row["threshold_ms"], row["contours_ms"], row["contours_ms"] / r["ms_per_frame"]))
PY
