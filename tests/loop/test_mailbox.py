"""The loop process's mailbox: messages arrive whole and in order, a full box refuses after its wait (a stop
request still gets its slot), and nothing the loop takes blocks it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rehab_hil.loop.mailbox import SLOT_BYTES, SLOTS, Mailbox, MailboxFull


def test_messages_arrive_whole_and_in_order() -> None:
    box = Mailbox.create()
    try:
        table = np.linspace(0.0, 1.0, 60_000)
        box.post(("table", table, None))
        box.post(("stop", "SIGINT", "stop_request"), stop=True)
        assert box.waiting()
        (kind, got, retune), stop = box.take()
        assert kind == "table" and np.array_equal(got, table) and retune is None
        assert stop == ("stop", "SIGINT", "stop_request") and not box.waiting() and box.take() == []
    finally:
        box.close()


def test_a_full_box_refuses_after_its_wait_but_keeps_a_slot_for_a_stop() -> None:
    box = Mailbox.create()
    try:
        for i in range(SLOTS - 1):
            box.post(("table", i, None))
        with pytest.raises(MailboxFull, match=f"{SLOTS - 1} messages not taken"):
            box.post(("table", 99, None), timeout_s=0.05)
        box.post(("stop", "twin", "model_mismatch"), stop=True)
        assert [m[1] for m in box.take()] == [*range(SLOTS - 1), "twin"]
    finally:
        box.close()


def test_a_message_too_big_for_a_slot_is_refused_before_anything_is_written() -> None:
    box = Mailbox.create()
    try:
        with pytest.raises(ValueError, match="does not fit"):
            box.post(("table", np.zeros(SLOT_BYTES // 8 + 1), None))
        assert box.counts() == (0, 0)
    finally:
        box.close()


READER = """
import sys, time
from rehab_hil.loop.mailbox import Mailbox
box = Mailbox.attach(sys.argv[1])
got = []
deadline = time.monotonic() + 60
while len(got) < 10 and time.monotonic() < deadline:
    if box.waiting():
        got += [m[1] for m in box.take()]
print(got)
"""


def test_another_process_takes_what_this_one_posts() -> None:
    box = Mailbox.create()
    try:
        proc = subprocess.Popen([sys.executable, "-c", READER, box.name], stdout=subprocess.PIPE, text=True)
        for i in range(10):
            box.post(("n", i), timeout_s=30.0)
        out, _ = proc.communicate(timeout=120)
        assert out.strip() == str(list(range(10)))
    finally:
        box.close()
