"""A front for the Foxglove SDK's WebSocket server that also accepts the classic subprotocol.

The SDK server (foxglove-sdk) accepts only ``foxglove.sdk.v1``; Foxglove's own
``@foxglove/ws-protocol`` clients and many lab tools ask for ``foxglove.websocket.v1``, the same
wire protocol under its former name. ``SubprotocolFront`` listens on the public address and relays
each TCP connection to the SDK server on a private loopback port, byte for byte, except for the
HTTP upgrade: a request offering ``foxglove.websocket.v1`` but not ``foxglove.sdk.v1`` reaches the
SDK server as ``foxglove.sdk.v1`` and the answer names the subprotocol the client asked for. The
WebSocket frames after the handshake do not depend on the subprotocol's name, so nothing else
changes (``Sec-WebSocket-Accept`` depends only on the client's key).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import threading

__all__ = ["CLASSIC", "SDK", "SUBPROTOCOLS", "SubprotocolFront", "rewrite_request", "rewrite_response"]

SDK = "foxglove.sdk.v1"
CLASSIC = "foxglove.websocket.v1"
SUBPROTOCOLS = (SDK, CLASSIC)
_HEADER = re.compile(rb"^(sec-websocket-protocol[ \t]*:[ \t]*)([^\r\n]*)\r?$", re.IGNORECASE | re.MULTILINE)
_MAX_HEAD = 64 * 1024


def rewrite_request(head: bytes) -> tuple[bytes, str | None]:
    """The upgrade request for the SDK server, and the classic name to give back (None: unchanged)."""
    m = _HEADER.search(head)
    if m is None:
        return head, None
    offered = [p.strip() for p in m.group(2).decode("latin-1").split(",")]
    if SDK in offered or CLASSIC not in offered:
        return head, None
    return head[:m.start(2)] + SDK.encode() + head[m.end(2):], CLASSIC


def rewrite_response(head: bytes, name: str) -> bytes:
    """The SDK server's upgrade answer with the subprotocol the client asked for."""
    return _HEADER.sub(lambda m: m.group(1) + name.encode() + (b"\r" if m.group(0).endswith(b"\r") else b""),
                       head, count=1)


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


class SubprotocolFront:
    """Listens on ``host:port`` (0: any free port) and relays to ``127.0.0.1:upstream_port``; raises
    ``OSError`` when it cannot bind. ``close()`` stops it."""

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        self.upstream_port = upstream_port
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._server: asyncio.Server | None = None
        self._thread = threading.Thread(target=self._run, args=(host, port), name="foxglove-front", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join(5.0)
            raise self._error
        assert self._server is not None
        self.port: int = self._server.sockets[0].getsockname()[1]

    def _run(self, host: str, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._server = self._loop.run_until_complete(
                asyncio.start_server(self._client, host, port, limit=_MAX_HEAD))
        except OSError as e:
            self._error = e
            self._ready.set()
            self._loop.close()
            return
        self._ready.set()
        try:
            self._loop.run_forever()
        finally:
            self._server.close()
            tasks = asyncio.all_tasks(self._loop)
            for t in tasks:
                t.cancel()
            with contextlib.suppress(Exception):
                self._loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
            self._loop.close()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_writer = None
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            head, classic = rewrite_request(head)
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port, limit=_MAX_HEAD)
            up_writer.write(head)
            await up_writer.drain()
            answer = await up_reader.readuntil(b"\r\n\r\n")
            writer.write(rewrite_response(answer, classic) if classic else answer)
            await writer.drain()
            await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass
        finally:
            for w in (writer, up_writer):
                if w is not None:
                    with contextlib.suppress(Exception):
                        w.close()

    def close(self) -> None:
        """Stop listening and drop the connections; idempotent."""
        if self._loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)
