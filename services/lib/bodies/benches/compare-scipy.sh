#!/usr/bin/env bash
# Kabsch against SciPy's Rotation.align_vectors on the same points, and the identification
# timing (docs/performance.md, "Rigid bodies").
#
#   services/lib/bodies/benches/compare-scipy.sh [--quick]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
out="$root/target/bench-bodies"
mkdir -p "$out"
venv="$root/target/scipy-venv"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import scipy, numpy" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet scipy numpy
fi
cd "$root"
cargo bench -p stereoscope-bodies --bench bodies -- "$@" --points "$out/points.json" | tee "$out/report.md"
"$venv/bin/python" "$here/scipy_kabsch.py" "$out/points.json" | tee -a "$out/report.md"
