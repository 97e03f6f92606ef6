#!/usr/bin/env bash
# Times Stereoscope's blob extraction and OpenCV on the same frames in the same run, and prints
# the table recorded in docs/performance.md.
#
#   services/lib/vision/benches/compare-opencv.sh [--quick]
#
# Installs opencv-python-headless and numpy from PyPI into target/opencv-venv (once), runs the
# Rust benchmark (which writes its frames as PGM), times OpenCV on those frames, and merges.
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
"$venv/bin/python" "$here/merge_report.py" "$out/rust.json" "$out/opencv.json" | tee "$out/report.md"
