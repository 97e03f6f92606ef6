#!/usr/bin/env bash
# The moment worker against OpenCV from C++ on the same frames (docs/performance.md, "Moment
# worker against OpenCV"):
#
#   services/stereoscope/benches/compare-live.sh [--quick] [--rounds N]
#
# Builds opencv_worker.cpp against Debian's OpenCV (installs libopencv-dev, nlohmann-json3-dev
# and g++ if missing), runs the worker's bench (`cargo bench -p stereoscope --bench live --
# --worker-only`), which writes each scene's 120 frames and what the worker found in each, then
# OpenCV on those frames: full frame (threshold + contours + moments every frame) and windowed
# (the same in windows round the last frame's blobs, a full pass every 10th frame), each checked
# to find the worker's blobs in every frame, each timed from memory, just written by its own
# thread, and handed over by another thread, as the worker is. Then N paired rounds: each
# scene's worker and OpenCV back to back, the ratio taken within the round; the median and the
# worst round are reported.
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
if ! pkg-config --exists opencv4 || [ ! -f /usr/include/nlohmann/json.hpp ] || ! command -v g++ >/dev/null; then
  apt-get install -y -qq libopencv-dev nlohmann-json3-dev g++ pkg-config
fi
rm -rf "$out" && mkdir -p "$out/frames"
# shellcheck disable=SC2046
g++ -O2 -std=c++17 "$here/opencv_worker.cpp" $(pkg-config --cflags --libs opencv4) -lpthread -o "$out/opencv_worker"
cd "$root"
scenes=(targets-640x480 targets-1920x1080 markers-640x480 markers-1920x1080)
cargo bench -p stereoscope --bench live -- "${quick[@]}" --worker-only --frames-dir "$out/frames" | tee "$out/report.md"
pairs="$out/paired.tsv"
: > "$pairs"
# One round: each scene's worker (its table row: median pass from memory, handed over, just
# written) and then OpenCV on the same frames.
round() {
  for s in "${scenes[@]}"; do
    row=$(cargo bench -q -p stereoscope --bench live -- "${quick[@]}" --worker-only --only "$s" 2>/dev/null | grep "^| ${s%%-*} ")
    "$out/opencv_worker" "$out/frames/worker-$s" "$out/frames/worker-$s.json" "$out/opencv.json" "${quick[@]}"
    python3 - "$out/opencv.json" "$row" "$1" "$s" >> "$pairs" <<'PY'
import json, sys
o = json.load(open(sys.argv[1]))
cells = [c.strip() for c in sys.argv[2].strip().strip("|").split("|")]
mem, handed, written = float(cells[2]), float(cells[3]), float(cells[4])
print("\t".join([sys.argv[3], sys.argv[4], o["opencv_version"], str(o["blobs_matched_full"]), str(o["blobs_matched_windowed"]),
                 "%.3f" % max(o["worst_centroid_px_full"], o["worst_centroid_px_windowed"])]
                + ["%.5f" % v for v in (mem, written, handed, o["full_ms"], o["full_ms_written"], o["full_ms_handed"],
                                        o["windowed_ms"], o["windowed_ms_written"], o["windowed_ms_handed"])]))
PY
  done
}
for r in $(seq "$(( rounds > 0 ? rounds : 1 ))"); do round "$r"; done
python3 - "$pairs" <<'PY' | tee -a "$out/report.md"
import statistics, sys
rows = [l.split("\t") for l in open(sys.argv[1]).read().splitlines() if l]
n = len({r[0] for r in rows})
print("\n## Moment worker against OpenCV %s from C++, one thread, same frames, %d round(s)" % (rows[0][2], n))
print("Ratio = OpenCV ms / worker ms within a round; median of the rounds (worst round). Both sides: the same 120 frames played forward and back, 25 passes, median pass; the same blobs checked in every frame.")
print("| scene | worker ms (memory / written / handed) | OpenCV full / worker: memory | written | handed | OpenCV windowed / worker: memory | written | handed | blobs checked (full, windowed) | worst centroid px |")
print("|---|---|---|---|---|---|---|---|---|---|")
for s in sorted({r[1] for r in rows}, key=lambda s: (s.split("-")[0], len(s))):
    rs = [r for r in rows if r[1] == s]
    v = lambda r, i: float(r[6 + i])
    cell = lambda num, den: "%.1f× (%.1f×)" % (statistics.median(v(r, num) / v(r, den) for r in rs), min(v(r, num) / v(r, den) for r in rs))
    print("| %s | %.4f / %.4f / %.4f | %s | %s | %s | %s | %s | %s | %s, %s | %s |" % (
        s, statistics.median(v(r, 0) for r in rs), statistics.median(v(r, 1) for r in rs), statistics.median(v(r, 2) for r in rs),
        cell(3, 0), cell(4, 1), cell(5, 2), cell(6, 0), cell(7, 1), cell(8, 2), rs[0][3], rs[0][4], max(r[5] for r in rs)))
PY
