"""A Foxglove WebSocket client that subscribes to every channel and then never reads (bench section 12).

    python -m bench.stalled_client ws://127.0.0.1:8765 SECONDS [--read]

It reads frames only until the server has advertised its channels (the loop's topics), subscribes to all of
them, prints ``subscribed N``, and then stops reading for SECONDS: the ``websockets`` client's receive queue
holds one frame (``max_queue=1``), so the socket's buffers fill and the server has to drop or skip what it
cannot send. With ``--read`` it reads everything instead (the client a stalled one is compared with).
Written from the protocol's spec, as tests/foxglove_client.py.
"""

from __future__ import annotations

import json
import sys
import time

from websockets.sync.client import connect

WANTED = 6  # the SMIB's loop channels: pmu, battery/command, plant/state, controller/state, invariant set, diagnostics


def main(url: str, seconds: float, read: bool = False) -> int:
    deadline = time.monotonic() + 60.0
    while True:
        try:
            ws = connect(url, subprotocols=["foxglove.sdk.v1"], max_queue=1, open_timeout=2)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    channels = {}
    with ws:  # max_queue=1: once a frame waits unread, the client stops reading its socket
        while len([c for c in channels.values() if c["encoding"] == "cdr"]) < WANTED:
            frame = ws.recv(timeout=60)
            if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                channels.update({c["id"]: c for c in json.loads(frame)["channels"]})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": k, "channelId": c}
                                                                  for k, c in enumerate(channels, start=1)]}))
        print(f"subscribed {len(channels)}", flush=True)
        end = time.monotonic() + seconds
        while read and time.monotonic() < end:
            try:
                ws.recv(timeout=max(0.01, end - time.monotonic()))
            except TimeoutError:
                break
        if not read:
            time.sleep(seconds)  # never read again
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], float(sys.argv[2]), "--read" in sys.argv[3:]))
