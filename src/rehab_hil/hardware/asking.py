"""Asking the device, again over a link that may lose a frame (``SerialHardware``): a request
(CONFIGURE, CLEAR, ESTOP, SET_ENCODER) until one copy is acknowledged, HELLO_REQ until a HELLO comes.

A request not acknowledged ``RESEND_S`` is sent again, with a new seq: a byte lost in the 328P's
2-byte receive buffer (the firmware busy for two byte times; tests/firmware/test_bootloader.py) loses
the frame, and with it the ACK, for good. The last copy's ACK is waited for (until the caller's
timeout) before the request returns: the link keeps order, so by then every earlier copy was applied
or lost, and no late copy can restart the device's stream after the caller went on. All four are
idempotent.

The functions take the link's two moves as callables: ``send`` (a frame out, its seq back) and
``pump`` (wait up to so many seconds for bytes and book the frames they hold).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

from rehab_hil.hardware.interface import HardwareError
from rehab_hil.protocol import Hello, Message

__all__ = ["HELLO_RESEND_S", "RESEND_S", "acked", "hello"]

RESEND_S = 0.5
HELLO_RESEND_S = 0.25  # HELLO_REQ is asked again sooner: nothing else can start before it


def acked(msg: Message, timeout: float, resend_s: float, send: Callable[[Message], int],
          pump: Callable[[float], None], acks: dict[tuple[int, int], int]) -> tuple[int, int]:
    """Send ``msg``, again every ``resend_s`` while no copy is acknowledged; returns its first ACK's
    result and how many copies went. The link keeps order, so the last copy's ACK says every copy has
    been applied or lost; until it comes (or ``timeout``), a copy may still be on its way to restart
    what the caller goes on to do. ``acks`` is where ``pump`` books each ACK by (type, seq)."""
    deadline = time.perf_counter() + timeout
    seqs: list[int] = []
    result: int | None = None
    last_answered = False
    resend_at = 0.0
    while True:
        now = time.perf_counter()
        for seq in seqs:
            got = acks.pop((msg.TYPE, seq), None)
            if got is not None:
                result = got if result is None else result
                last_answered = last_answered or seq == seqs[-1]
        if result is not None and (last_answered or now >= deadline):
            return result, len(seqs)
        if now >= deadline:
            raise HardwareError(f"no ACK for {type(msg).__name__} (seq {', '.join(map(str, seqs))}) "
                                f"within {timeout:.2f} s")
        if result is None and now >= resend_at:
            seqs.append(send(msg))
            resend_at = now + resend_s
        pump(min(deadline, resend_at if result is None else deadline) - now)


def hello(ask: Callable[[], object], pump: Callable[[float], None], hellos: deque[Hello], timeout: float,
          resend_s: float) -> Hello | None:
    """The device's HELLO: ``ask`` (a HELLO_REQ out) every ``HELLO_RESEND_S`` (once if ``resend_s`` is
    infinite) until ``pump`` books one in ``hellos``; None if none came within ``timeout``."""
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        ask()
        again_s = HELLO_RESEND_S if math.isfinite(resend_s) else math.inf
        resend = min(deadline, time.perf_counter() + again_s)
        while time.perf_counter() < resend:
            pump(resend - time.perf_counter())
            if hellos:
                return hellos[-1]
    return None
