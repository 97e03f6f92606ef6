"""Drives a real browser (headless Chromium, over the DevTools protocol) against a running
viewer of a rig with a kinematic model (tests/viewer.rs starts the robot-arm demo with --view),
and checks that the page draws each model as its chain: in a screenshot of the top view, every
link's origin of the frozen frame's valid fit, and the middle of every line from a link's
parent to it, is magenta where an independent pinhole projection puts it; a place off the
chain is not.

Usage: viewer_chain.py CHROMIUM URL OUT_DIR
Prints one JSON line of figures; writes the screenshot to OUT_DIR. Exits 1 with a message on a
failed check.
"""

import json
import os
import sys

from viewer_check import Browser, fail, get, near, project, wait_for


def is_chain(p):
    # CHAIN_COLOUR, 0xff00ff: red and blue high, green low.
    r, g, b = p
    return r > 170 and b > 170 and g < 110


def main():
    chromium, url, out = sys.argv[1], sys.argv[2].rstrip("/"), sys.argv[3]
    os.makedirs(out, exist_ok=True)
    rig = json.loads(get(url + "/api/rig")[1])
    if not rig.get("models"):
        fail(f"/api/rig lists no model: {rig.get('models')}")
    b = Browser(chromium)
    try:
        b.call("Page.navigate", url=url + "/")
        wait_for("a valid model drawn",
                 lambda: any(c["valid"] for c in b.eval("window.stereoscope?.drawnChains ?? []")),
                 60)
        b.eval("stereoscope.topView()")
        b.pump(0.5)
        # Frozen on a frame whose fit is valid.
        for _ in range(50):
            b.eval("stereoscope.freeze(true)")
            b.pump(0.3)
            chains = b.eval("stereoscope.drawnChains")
            if chains and all(c["valid"] for c in chains):
                break
            b.eval("stereoscope.freeze(false)")
            b.pump(0.1)
        else:
            fail("no frame with every model's fit valid to freeze on")
        view = b.eval("stereoscope.view()")
        pm = b.screenshot(os.path.join(out, "viewer-chain.png"))
        tol = 4
        misses, origins, lines = [], 0, 0
        for c in chains:
            links = c["links"]
            for i, p in enumerate(links):
                q = project(view, p)
                if q is None or not near(pm, *q, tol, is_chain):
                    misses.append(f"{c['name']} link {i} origin at {p} -> {q}")
                origins += 1
                parent = c["parents"][i]
                if parent is None:
                    continue
                mid = [(a + b_) / 2 for a, b_ in zip(links[parent], p)]
                q = project(view, mid)
                # A line shorter than a few pixels is covered by its ends' spheres.
                if q is None or not near(pm, *q, tol, is_chain):
                    misses.append(f"{c['name']} line {parent}->{i} middle at {mid} -> {q}")
                lines += 1
        if near(pm, 40 * view["dpr"], (view["rect"][1] + view["rect"][3] - 60) * view["dpr"], tol,
                is_chain):
            misses.append("an empty corner passes the chain's colour test")
        if misses:
            fail("not where the projection puts them: " + "; ".join(misses))
        if b.errors:
            fail("; ".join(b.errors))
        print(json.dumps({"models": len(chains), "origins_checked": origins,
                          "lines_checked": lines}), flush=True)
    finally:
        b.close()


if __name__ == "__main__":
    main()
