"""A block of POSIX shared memory (``/dev/shm``) that a session's process creates and a loop process maps.

The creator uses ``multiprocessing.shared_memory`` (its resource tracker unlinks the block if the process
dies); a loop process maps the file directly, not through ``SharedMemory``, whose tracker would unlink the
block when the loop process ends while the session still reads it.
"""

from __future__ import annotations

import mmap
import os
from multiprocessing import shared_memory
from typing import Any

__all__ = ["SharedBlock"]


class SharedBlock:
    """``buf``: the block's bytes (a memoryview); ``close`` unmaps it and, from the creator, unlinks it."""

    def __init__(self, name: str, buf: Any, shm: shared_memory.SharedMemory | None = None,
                 mapped: mmap.mmap | None = None) -> None:
        self.name, self.buf, self._shm, self._mapped = name, buf, shm, mapped

    @property
    def owner(self) -> bool:
        return self._shm is not None

    @classmethod
    def create(cls, size: int) -> SharedBlock:
        shm = shared_memory.SharedMemory(create=True, size=size)
        return cls(shm.name, shm.buf, shm=shm)

    @classmethod
    def attach(cls, name: str) -> SharedBlock:
        fd = os.open(f"/dev/shm/{name.lstrip('/')}", os.O_RDWR)
        try:
            mapped = mmap.mmap(fd, os.fstat(fd).st_size)
        finally:
            os.close(fd)
        return cls(name, memoryview(mapped), mapped=mapped)

    def close(self) -> None:
        """Idempotent."""
        if self.buf is None:
            return
        if self._mapped is not None:
            self.buf.release()
            self._mapped.close()
        self.buf = None
        if self._shm is not None:
            try:
                self._shm.close()
            except BufferError:  # a view still exported: unlinked all the same
                pass
            try:
                self._shm.unlink()
            except FileNotFoundError:
                pass
