"""Listens to the viewer's WebSocket (websocket-client, not this project's code) for a while
and prints one JSON object: how many messages of each type came, and the last of each
text type.

usage: ws_collect.py WS_URL SECONDS
"""
import json
import sys
import time

import websocket


def main():
    url, seconds = sys.argv[1], float(sys.argv[2])
    end = time.monotonic() + seconds
    ws = None
    while ws is None:
        try:
            ws = websocket.create_connection(url, timeout=2)
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)
    counts, last = {}, {}
    while time.monotonic() < end:
        try:
            m = ws.recv()
        except websocket.WebSocketTimeoutException:
            continue
        if isinstance(m, bytes):
            counts["preview"] = counts.get("preview", 0) + 1
            continue
        msg = json.loads(m)
        counts[msg["type"]] = counts.get(msg["type"], 0) + 1
        last[msg["type"]] = msg
    ws.close()
    print(json.dumps({"counts": counts, "last": {k: v for k, v in last.items() if k in ("coverage", "hello")}}))


if __name__ == "__main__":
    main()
