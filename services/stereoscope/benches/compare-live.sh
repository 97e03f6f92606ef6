#!/usr/bin/env bash
# The live system's benchmark with OpenCV timed on the moment worker's frames in the same run
# (the table in docs/performance.md, "Live system").
#
#   services/stereoscope/benches/compare-live.sh [--quick] [--rounds N]
#
# With --rounds N, N paired rounds follow the report: in each, every scene's worker and then
# OpenCV on the same frames, one right after the other, and the report adds each scene's
# median ratio of the rounds and their range. This machine's speed moves within minutes; a
# ratio of two figures taken seconds apart moves with it far less than one of figures taken
# minutes apart (the main table's: the worker's four scenes first, then OpenCV's).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
out="$root/target/bench-live"
quick=()
rounds=0
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) quick=(--quick) ;;
    --rounds) rounds="${2:?--rounds needs a count}"; shift ;;
    *) echo "usage: $0 [--quick] [--rounds N]" >&2; exit 2 ;;
  esac
  shift
done
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
print("Frames from memory: all 120 read in turn, each cold in the cache. Frames just written: each copied into a buffer by the timing thread itself just before it is timed, on both sides (the frame in that core's cache). Last columns: the worker's frames handed over by another thread instead (another core's cache, as a capture process hands them over), against OpenCV's same figure as before (its own thread's copy).")
print("| scene | frame | worker (threshold every 30, search every 10, windows) | OpenCV (calcHist + the auto rule every 30; threshold+contours+moments every frame) | OpenCV / worker | worker, frames just written | OpenCV, frames just written | OpenCV / worker, frames just written | worker, frames from another thread | OpenCV (own thread) / worker (another thread) | blobs matched | worst centroid px |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for p, r in sorted(zip(sys.argv[1:], rows), key=lambda x: (x[1]["scene"], len(x[1]["frame"]))):
    print("| %s | %s | %.4f | %.4f | %.1f× | %.4f | %.4f | %.1f× | %.4f | %.1f× | %d | %.3f |" % (r["scene"], r["frame"], r["worker_ms"], r["contours_ms"], r["contours_ms"] / r["worker_ms"], r["worker_ms_copied"], r["contours_ms_delivered"], r["contours_ms_delivered"] / r["worker_ms_copied"], r["worker_ms_delivered"], r["contours_ms_delivered"] / r["worker_ms_delivered"], r["blobs_matched"], r["worst_centroid_px"]))
PY

# Paired rounds: the worker (its median pass, as in the main table) and OpenCV on the same
# scene back to back, each round's two ratios kept.
if [ "$rounds" -gt 0 ]; then
  pairs="$out/paired.tsv"
  : > "$pairs"
  for r in $(seq "$rounds"); do
    for scene in targets markers; do
      for size in 640x480 1920x1080; do
        row=$(cargo bench -q -p stereoscope --bench live -- --worker-only --only "$scene-$size" 2>/dev/null | grep "^| $scene ")
        "$venv/bin/python" "$here/opencv_worker.py" "$out/frames/worker-$scene-$size" "$out/frames/worker-$scene-$size.json" "$out/paired-opencv.json" >/dev/null
        "$venv/bin/python" - "$out/paired-opencv.json" "$row" "$r" >> "$pairs" <<'PY'
import json, sys
o = json.load(open(sys.argv[1]))
cells = [c.strip() for c in sys.argv[2].strip().strip("|").split("|")]
worker_ms, worker_handed_ms, worker_written_ms = float(cells[2]), float(cells[3]), float(cells[4])
print("\t".join([sys.argv[3], o["scene"], o["frame"], "%.4f" % worker_ms, "%.4f" % o["contours_ms"], "%.4f" % worker_written_ms, "%.4f" % o["contours_ms_delivered"], "%.4f" % worker_handed_ms]))
PY
      done
    done
  done
  "$venv/bin/python" - "$pairs" "$rounds" <<'PY' | tee -a "$out/report.md"
import statistics, sys
rows = [l.split("\t") for l in open(sys.argv[1]).read().splitlines() if l]
print("\n## Paired rounds: the worker and OpenCV on each scene back to back, %s rounds" % sys.argv[2])
print("Each round runs each scene's worker (median pass, frames from memory, just written by its own thread, and handed over by another thread) and then OpenCV on the same frames; the ratio is taken within the round. Median of the rounds' ratios, and their range.")
print("| scene | frame | OpenCV / worker (median) | range | worker ms (median) | OpenCV ms (median) | OpenCV / worker, frames just written (median) | range | OpenCV (own thread) / worker (frames from another thread) (median) | range |")
print("|---|---|---|---|---|---|---|---|---|---|")
keys = sorted({(r[1], r[2]) for r in rows}, key=lambda k: (k[0], len(k[1])))
for scene, frame in keys:
    rs = [r for r in rows if (r[1], r[2]) == (scene, frame)]
    mem = [float(r[4]) / float(r[3]) for r in rs]
    written = [float(r[6]) / float(r[5]) for r in rs]
    handed = [float(r[6]) / float(r[7]) for r in rs]
    print("| %s | %s | %.1f× | %.1f–%.1f× | %.4f | %.4f | %.1f× | %.1f–%.1f× | %.1f× | %.1f–%.1f× |" % (
        scene, frame, statistics.median(mem), min(mem), max(mem),
        statistics.median(float(r[3]) for r in rs), statistics.median(float(r[4]) for r in rs),
        statistics.median(written), min(written), max(written),
        statistics.median(handed), min(handed), max(handed)))
PY
fi
