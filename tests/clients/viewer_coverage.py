"""Headless Chromium (driven as in viewer_check.py) on a camera's page of the viewer while a
live wand calibration runs: the monitor must draw the coverage it was sent — each cell the
wand was seen in tinted green, each other cell red — checked on a screenshot.

usage: viewer_coverage.py CHROMIUM URL CAMERA OUT_PNG
Prints one JSON line: cells checked, covered, agreeing.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
import viewer_check  # noqa: E402  (Browser, wait_for, fail)


def compare(b, cov, out):
    """One screenshot of the monitor against the coverage drawn: (agreeing cells, covered
    cells, the disagreeing cells described)."""
    rect = b.eval("(() => { const r = document.querySelector('.monitor canvas.image').getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()")
    dpr = b.eval("window.devicePixelRatio")
    pm = b.screenshot(out)
    cols, rows = cov["cols"], cov["rows"]
    agree = covered = 0
    wrong = []
    for i, n in enumerate(cov["counts"]):
        cx = rect[0] + ((i % cols) + 0.5) * rect[2] / cols
        cy = rect[1] + ((i // cols) + 0.5) * rect[3] / rows
        # The median of a patch round the cell's centre (a marker may sit on it).
        patch = [viewer_check.pixel(pm, (cx + dx) * dpr, (cy + dy) * dpr)
                 for dx in range(-6, 7, 3) for dy in range(-6, 7, 3)]
        if None in patch:
            viewer_check.fail(f"cell {i} at ({cx:.0f}, {cy:.0f}) is outside the {pm.width}x{pm.height} screenshot (monitor at {rect})")
        r, g = (sorted(p[k] for p in patch)[len(patch) // 2] for k in (0, 1))
        green = g > r + 12
        covered += n > 0
        agree += green == (n > 0)
        if green != (n > 0):
            wrong.append(f"cell {i} (col {i % cols}, row {i // cols}) count {n} drawn r {r} g {g}")
    return agree, covered, wrong


def main():
    chromium, url, camera, out = sys.argv[1], sys.argv[2].rstrip("/"), sys.argv[3], sys.argv[4]
    b = viewer_check.Browser(chromium)
    try:
        b.call("Page.navigate", url=f"{url}/camera/{camera}")
        viewer_check.wait_for(
            "coverage drawn on the monitor",
            lambda: b.eval(f"(window.stereoscope?.drawnCoverage ?? {{}})['{camera}']?.counts.some(n => n > 0) ?? false"),
            60)
        b.eval("stereoscope.freeze(true)")
        b.pump(0.3)
        cov = b.eval(f"stereoscope.drawnCoverage['{camera}']")
        # The page is frozen, so the canvas no longer changes; but on a loaded machine the
        # compositor may still present an older frame for a while (once in CI one cell of 48
        # disagreed while the coverage was growing). Compare again, up to 10 s, until the
        # screenshot shows the frozen frame; a drawing that is wrong stays wrong and fails.
        for attempt in range(1, 21):
            agree, covered, wrong = compare(b, cov, out)
            if agree == len(cov["counts"]):
                break
            b.pump(0.5)
        cells = cov["cols"] * cov["rows"]
        print(json.dumps({"cells": cells, "covered": covered, "agree": agree, "screenshots": attempt}))
        if agree < cells:
            viewer_check.fail(f"{cells - agree} of {cells} cells drawn against the coverage sent: " + "; ".join(wrong) + f" (screenshot {out})")
        if b.errors:
            viewer_check.fail("console errors: " + "; ".join(b.errors[:5]))
    finally:
        b.close()


if __name__ == "__main__":
    main()
