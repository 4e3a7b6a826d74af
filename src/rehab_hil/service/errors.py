"""The one-line error a session raises for what its user can fix (the CLI prints it as it is)."""

from __future__ import annotations

__all__ = ["SessionError"]


class SessionError(ValueError):
    """A session cannot be built or run as asked: one line naming what to change. ``option`` is the
    ``SessionOptions`` field (or "device", "duration") it is about, None for the config itself."""

    def __init__(self, option: str | None, message: str) -> None:
        super().__init__(f"{option}: {message}" if option else message)
        self.option, self.message = option, message
