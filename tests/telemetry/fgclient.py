"""A real Foxglove WebSocket client for tests (the ``websockets`` package; subprotocol ``foxglove.sdk.v1``
or, asked for, the classic ``foxglove.websocket.v1``).

It runs its own asyncio loop on a thread: connects, collects the server's advertisements, subscribes
to the topics asked for, and decodes binary message frames (opcode 1: subscription id u32, log time
u64, payload) into JSON.
"""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time
from typing import Any

import websockets

SUBPROTOCOL = "foxglove.sdk.v1"


class FoxgloveClient:
    """Connects to ``ws://127.0.0.1:port`` and subscribes to ``topics`` as soon as they are advertised."""

    def __init__(self, port: int, topics: list[str], subprotocol: str = SUBPROTOCOL) -> None:
        self.port, self.wanted, self.subprotocol = port, set(topics), subprotocol
        self.negotiated: str | None = None  # the subprotocol the server's handshake answered
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> advertised channel
        self.messages: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
        self.subscribed: set[str] = set()
        self.error: BaseException | None = None
        self._subs: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self._thread.start()

    async def _main(self) -> None:
        try:
            async with websockets.connect(f"ws://127.0.0.1:{self.port}", subprotocols=[self.subprotocol],
                                          max_size=None) as ws:
                self.negotiated = ws.subprotocol
                while not self._stop.is_set():
                    try:
                        frame = await asyncio.wait_for(ws.recv(), 0.1)
                    except TimeoutError:
                        continue
                    if isinstance(frame, str):
                        await self._control(ws, json.loads(frame))
                    elif frame[0] == 1:
                        sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                        self.messages[self._subs[sub_id]].append(json.loads(frame[13:]))
        except BaseException as e:  # reported to the test
            self.error = e

    async def _control(self, ws: Any, msg: dict[str, Any]) -> None:
        if msg["op"] == "serverInfo":
            self.server_info = msg
        elif msg["op"] == "advertise":
            subs = []
            for ch in msg["channels"]:
                self.channels[ch["topic"]] = ch
                if ch["topic"] in self.wanted and ch["topic"] not in self.subscribed:
                    sub_id = len(self._subs) + 1
                    self._subs[sub_id] = ch["topic"]
                    subs.append({"id": sub_id, "channelId": ch["id"]})
                    self.subscribed.add(ch["topic"])
            if subs:
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def wait_subscribed(self, timeout_s: float = 10.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and self.subscribed != self.wanted and self.error is None:
            time.sleep(0.01)
        return self.subscribed == self.wanted

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
