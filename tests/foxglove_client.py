"""An independent Foxglove WebSocket client for the tests, written from the protocol's published spec
(github.com/foxglove/ws-protocol, docs/spec.md; the SDK's server speaks it as ``foxglove.sdk.v1``), not from
the project's code: JSON text frames ``serverInfo`` / ``advertise`` / ``status`` from the server,
``subscribe`` from the client, and binary ``Message Data`` frames (opcode 0x01, uint32 subscription id,
uint64 log time in ns, all little-endian, then the message's bytes as the channel's encoding has them).
"""

from __future__ import annotations

import asyncio
import json
import struct
import time

import websockets

#: The subprotocol the Foxglove SDK (0.30) answers; ``foxglove.websocket.v1`` is refused with HTTP 400.
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01
_HEADER = struct.Struct("<BIQ")


async def connect(url: str, deadline_s: float):
    """A connection to ``url``, retried until the server listens (the demo starts it per run) or the deadline."""
    end = time.monotonic() + deadline_s
    while True:
        try:
            return await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=2)
        except (OSError, websockets.InvalidHandshake, asyncio.TimeoutError):
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.05)


async def record(url: str, topics, seconds: float, connect_s: float = 60.0) -> dict:
    """Connect, subscribe to ``topics`` as they are advertised, collect for ``seconds`` after connecting (or until
    the server closes). Returns ``{"server": serverInfo, "channels": {topic: advertised channel}, "messages":
    {topic: [(log_time_ns, bytes)]}, "status": [status ops]}``."""
    ws = await connect(url, connect_s)
    channels, by_subscription, messages, status, server = {}, {}, {}, [], {}
    end = time.monotonic() + seconds
    try:
        while (left := end - time.monotonic()) > 0:
            try:
                frame = await asyncio.wait_for(ws.recv(), left)
            except (asyncio.TimeoutError, websockets.ConnectionClosed):
                break
            if isinstance(frame, bytes):
                opcode, subscription, log_time = _HEADER.unpack_from(frame)
                if opcode == MESSAGE_DATA:
                    topic = by_subscription[subscription]
                    messages.setdefault(topic, []).append((log_time, frame[_HEADER.size:]))
                continue
            op = json.loads(frame)
            if op["op"] == "serverInfo":
                server = op
            elif op["op"] == "status":
                status.append(op)
            elif op["op"] == "advertise":
                wanted = []
                for channel in op["channels"]:
                    channels[channel["topic"]] = channel
                    if channel["topic"] in topics:
                        sub_id = len(by_subscription) + 1
                        by_subscription[sub_id] = channel["topic"]
                        wanted.append({"id": sub_id, "channelId": channel["id"]})
                if wanted:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))
    finally:
        await ws.close()
    return {"server": server, "channels": channels, "messages": messages, "status": status}


async def misbehave(url: str, connect_s: float = 60.0) -> list:
    """What a broken or hostile client sends: garbage text, a subscription to a channel that does not exist,
    an unknown op, an unknown binary opcode; then, once the server has answered those, a binary frame over
    16 MiB. Returns the server's text answers and how the connection ended (``("closed", code)`` or
    ``("open", None)``)."""
    ws = await connect(url, connect_s)
    answers = []

    async def read(seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = await asyncio.wait_for(ws.recv(), left)
            except asyncio.TimeoutError:
                return
            if isinstance(frame, str):
                answers.append(json.loads(frame))

    try:
        await ws.send("this is not JSON {")
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": 987654321}]}))
        await ws.send(json.dumps({"op": "no such op"}))
        await ws.send(b"\x07" + bytes(64))
        await read(1.0)
        await ws.send(b"\x07" + bytes(16 * 1024 * 1024))
        await read(2.0)
        return answers + [("open", None)]
    except websockets.ConnectionClosed as closed:
        return answers + [("closed", closed.rcvd.code if closed.rcvd else None)]
    finally:
        await ws.close()
