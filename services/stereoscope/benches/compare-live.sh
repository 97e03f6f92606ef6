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
# OpenCV on the worker's own frames, after checking it finds the same blobs in each.
for scene in targets markers; do
  for size in 640x480 1920x1080; do
    "$venv/bin/python" "$here/opencv_worker.py" "$out/frames/worker-$scene-$size" "$out/frames/worker-$scene-$size.json" "$out/opencv-$scene-$size.json" "${quick[@]}"
  done
done
"$venv/bin/python" - "$out"/opencv-*.json <<'PY' | tee -a "$out/report.md"
import json, sys
rows = [json.load(open(p)) for p in sys.argv[1:]]
print("\n## Moment worker against OpenCV on the same frames (one thread), ms per frame")
print("Both on the same %d frames (a second at 120 fps); the same blobs found in every frame (checked: centroids within 0.5 px); both take the threshold from a histogram of the same rows every 30th frame by the same rule (checked: the same threshold from every frame)." % rows[0]["frames"])
print("Frames from memory: all 120 read in turn, each cold in the cache. Frames just written: each copied into a buffer just before it is timed, as a capture process hands it over (the worker's copy by another thread, OpenCV's by its own).")
print("| scene | frame | worker (threshold every 30, search every 10, windows) | OpenCV (calcHist + the auto rule every 30; threshold+contours+moments every frame) | OpenCV / worker | worker, frames just written | OpenCV, frames just written | OpenCV / worker, frames just written | blobs matched | worst centroid px |")
print("|---|---|---|---|---|---|---|---|---|---|")
for p, r in sorted(zip(sys.argv[1:], rows), key=lambda x: (x[1]["scene"], len(x[1]["frame"]))):
    print("| %s | %s | %.4f | %.4f | %.1f× | %.4f | %.4f | %.1f× | %d | %.3f |" % (r["scene"], r["frame"], r["worker_ms"], r["contours_ms"], r["contours_ms"] / r["worker_ms"], r["worker_ms_delivered"], r["contours_ms_delivered"], r["contours_ms_delivered"] / r["worker_ms_delivered"], r["blobs_matched"], r["worst_centroid_px"]))
PY
