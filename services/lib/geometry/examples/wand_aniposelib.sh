#!/usr/bin/env bash
# aniposelib on the wand example's exported detections, versions pinned (wand_aniposelib.py).
#
#   services/lib/geometry/examples/wand_aniposelib.sh WAND.json [RUNS]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
venv="$root/target/anipose-venv"
pins=(aniposelib==0.8.0 numpy==2.4.6 scipy==1.17.1 opencv-contrib-python==5.1.0.95)
for p in "${pins[@]}"; do
  if [ ! -x "$venv/bin/pip" ] || ! "$venv/bin/pip" freeze 2>/dev/null | grep -qix "$p"; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet "${pins[@]}"
    break
  fi
done
"$venv/bin/python" "$here/wand_aniposelib.py" "$@"
