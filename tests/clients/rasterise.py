#!/usr/bin/env python3
"""A page (SVG or PDF) rasterised by MuPDF (PyMuPDF), software the project did not write, as a
grey PNG: what a printer and a camera looking straight at the print would make of it.

usage: rasterise.py PAGE PNG DPI
prints one JSON object: the page's size in points and the image's in pixels.
"""
import json
import sys

import pymupdf


def main():
    page_path, png_path, dpi = sys.argv[1], sys.argv[2], int(sys.argv[3])
    doc = pymupdf.open(page_path)
    page = doc[0]
    pix = page.get_pixmap(dpi=dpi, colorspace=pymupdf.csGRAY, alpha=False)
    pix.save(png_path)
    print(json.dumps({"width_pt": page.rect.width, "height_pt": page.rect.height,
                      "width_px": pix.width, "height_px": pix.height}))


if __name__ == "__main__":
    main()
