#!/usr/bin/env bash
# Times Stereoscope's blob extraction and OpenCV on the same frames in the same run, and prints
# the table recorded in docs/performance.md.
#
#   services/lib/vision/benches/compare-opencv.sh [--quick]
#
# Installs opencv-python-headless and numpy from PyPI into target/opencv-venv (once), and
# Debian's libopencv-dev and g++ when missing; runs the Rust benchmark (which writes its frames
# as PGM), times OpenCV on those frames from Python (the histogram's counts checked against
# ours, connected components) and from C++ (opencv_engine.cpp: threshold, and threshold +
# contours + moments, no interpreter in the loop: the figure the ratios use), and merges.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
out="$root/target/bench-opencv"
quick=()
[ "${1:-}" = "--quick" ] && quick=(--quick)
mkdir -p "$out/frames"
. "$here/opencv-venv.sh"
cd "$root"
cargo bench -p stereoscope-vision --bench moments -- "${quick[@]}" --frames-dir "$out/frames" --json "$out/rust.json"
"$venv/bin/python" "$here/opencv_bench.py" "$out/frames" "$out/rust.json" "$out/opencv.json" "${quick[@]}"
if ! pkg-config --exists opencv4 || ! command -v g++ >/dev/null; then
  apt-get install -y -qq libopencv-dev g++ pkg-config
fi
# shellcheck disable=SC2046
g++ -O2 -std=c++17 "$here/opencv_engine.cpp" $(pkg-config --cflags --libs opencv4) -o "$out/opencv_engine"
"$out/opencv_engine" "$out/frames" 128 "$out/opencv-cpp.json" "${quick[@]}"
"$venv/bin/python" "$here/merge_report.py" "$out/rust.json" "$out/opencv.json" "$out/opencv-cpp.json" | tee "$out/report.md"
