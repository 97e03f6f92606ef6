#!/usr/bin/env bash
# Sourced by the comparison scripts: makes target/opencv-venv with opencv-python-headless and
# numpy from PyPI (once) and sets $venv to it. Needs $root (the repository).
venv="$root/target/opencv-venv"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import cv2, numpy" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet opencv-python-headless numpy
fi
