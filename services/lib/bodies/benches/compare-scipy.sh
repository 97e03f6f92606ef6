#!/usr/bin/env bash
# Kabsch against numpy's batched SVD and SciPy's Rotation.align_vectors on the same points,
# and the identification timing (docs/performance.md, "Rigid bodies"). The versions are pinned.
#
#   services/lib/bodies/benches/compare-scipy.sh [--quick]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
out="$root/target/bench-bodies"
mkdir -p "$out"
venv="$root/target/scipy-venv"
pins=(scipy==1.17.1 numpy==2.4.6)
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/pip" freeze | grep -qx "${pins[0]}" || ! "$venv/bin/pip" freeze | grep -qx "${pins[1]}"; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet "${pins[@]}"
fi
cd "$root"
cargo bench -p stereoscope-bodies --bench bodies -- "$@" --points "$out/points.json" | tee "$out/report.md"
"$venv/bin/python" "$here/scipy_kabsch.py" "$out/points.json" | tee -a "$out/report.md"
