#!/usr/bin/env bash
# Regenerates the geometry fixtures, OpenCV's answers on them, and prints the comparison
# recorded in docs/geometry.md.
#
#   services/lib/geometry/benches/compare-opencv.sh
#
# Installs opencv-python-headless and numpy from PyPI into target/opencv-venv (once).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
venv="$root/target/opencv-venv"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import cv2, numpy" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet opencv-python-headless numpy
fi
cd "$root"
cargo run --quiet -p stereoscope-geometry --example opencv_fixtures
"$venv/bin/python" "$here/opencv_reference.py" services/lib/geometry/tests/data
cargo test --quiet -p stereoscope-geometry --test opencv_comparison -- --nocapture --test-threads 1 2>&1 | grep -E "calibration RMS|triangulation error|test result"
cargo bench --quiet -p stereoscope-geometry --bench geometry 2>&1 | grep -E "^[a-z].*|time:"
