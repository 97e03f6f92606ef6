#!/usr/bin/env python3
"""Images read by MuPDF (PyMuPDF), software the project did not write: for each file its size,
channels and maximum level, and for an RGB image the pixels that are pure red-tinted
(R 255, G = B) — what `stereoscope grab` marks as over the threshold.

usage: image_stats.py FILE… ; prints one JSON object per file, one a line.
"""
import json
import sys

import pymupdf


def main():
    for path in sys.argv[1:]:
        pix = pymupdf.Pixmap(path)
        n = pix.n
        data = pix.samples
        out = {"file": path, "width": pix.width, "height": pix.height, "channels": n,
               "max": max(data) if data else 0}
        if n == 3:
            out["red"] = sum(1 for i in range(0, len(data), 3)
                             if data[i] == 255 and data[i + 1] == data[i + 2] and data[i + 1] < 255)
        else:
            out["levels"] = list(data[::n]) if len(data) <= 1_000_000 else None
        print(json.dumps(out))


if __name__ == "__main__":
    main()
