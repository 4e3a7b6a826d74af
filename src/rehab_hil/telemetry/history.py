"""What a subscriber knows of the state batches a rig published, and where the ones it lacks went.

The rig's ``AdvancedPublisher`` keeps its last puts (history for late joiners, recovery of misses);
each batch carries an attachment (``BATCH_ATTACHMENT``: the records and device samples of the
publisher's earlier batches), so the samples of a batch that never arrived are known exactly: those
before the first batch received were older than the publisher's history when the subscriber joined,
those in a gap were lost in transit (zenoh's recovery could not bring them back), those after the
last one received are known from the rig's final count. docs/telemetry.md, "History and losses".
"""

from __future__ import annotations

import struct

__all__ = ["BATCH_ATTACHMENT", "BatchLedger"]

# records_before:u64, samples_before:u64 - what the publisher's earlier batches held
BATCH_ATTACHMENT = struct.Struct("<QQ")
_SEQ = 0xFFFFFFFF


def read_attachment(att: bytes | None) -> tuple[int, int] | None:
    """(records, device samples) in the publisher's earlier batches, or None (no or foreign attachment)."""
    if att is None or len(att) != BATCH_ATTACHMENT.size:
        return None
    records, samples = BATCH_ATTACHMENT.unpack(att)
    return int(records), int(samples)


class BatchLedger:
    """Counts the batches and device samples received from one rig and those missing between them.

    ``add`` is called once per batch in the order zenoh delivers them (per publisher, in order). A
    batch number lower than expected is a new publisher (the rig restarted): counting starts over."""

    def __init__(self) -> None:
        self.batches = 0  # batches received
        self.samples = 0  # device samples in them
        self.first_batch: int | None = None  # number of the first batch received
        self.batches_before_first = 0  # batches published before the first one received
        self.samples_before_first: int | None = 0  # their device samples (None: no attachment told)
        self.batches_lost = 0  # batches missing between received ones (lost in transit, not recovered)
        self.samples_lost: int | None = 0  # their device samples (None: no attachment told)
        self.restarts = 0  # times the batch numbers started over (a new publisher)
        self.next_batch: int | None = None
        self._next_before: int | None = None  # samples_before the next batch should carry

    def add(self, batch_seq: int, n_samples: int, attachment: bytes | None) -> int:
        """Count one received batch; returns the batches missing right before it (0: none)."""
        told = read_attachment(attachment)
        before = None if told is None else told[1]
        gap = 0
        if self.next_batch is not None and batch_seq != self.next_batch:
            gap = (batch_seq - self.next_batch) & _SEQ
            if gap >= 0x80000000:  # a step back: a new publisher, counted from its start
                self.restarts += 1
                self.next_batch, gap = None, 0
        if self.next_batch is None:  # the first batch of this publisher that arrived
            if self.first_batch is None:
                self.first_batch = batch_seq
            self.batches_before_first += batch_seq
            self.samples_before_first = _plus(self.samples_before_first, before if batch_seq else 0)
        elif gap:
            self.batches_lost += gap
            missing = None if before is None or self._next_before is None else before - self._next_before
            self.samples_lost = _plus(self.samples_lost, missing)
        self.batches += 1
        self.samples += n_samples
        self.next_batch = (batch_seq + 1) & _SEQ
        self._next_before = None if before is None else before + n_samples
        return gap

    def tail(self, published_batches: int, published_samples: int) -> tuple[int, int | None]:
        """(batches, device samples) published after the last batch received, from the publisher's
        final counts (all of them when no batch arrived)."""
        if self.next_batch is None:
            return published_batches, published_samples
        batches = max(0, published_batches - self.next_batch)
        samples = None if self._next_before is None else max(0, published_samples - self._next_before)
        return batches, samples


def _plus(a: int | None, b: int | None) -> int | None:
    return None if a is None or b is None else a + b
