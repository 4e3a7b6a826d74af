"""The parent's side of the zygote (``launch/zygote.py``): ``popen`` sends it a request and returns a
``ForkedChild``, which answers ``poll``/``wait``/``kill`` as a ``subprocess.Popen`` does."""

from __future__ import annotations

import contextlib
import itertools
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
from typing import IO, Any

FIXED_ENV_PREFIXES = ("NUMBA_", "OPENBLAS_", "OMP_", "MKL_", "PYTHON")  # read once, when a module is imported
START_TIMEOUT_S = 120.0  # importing numba and the package on a busy machine
WARM_TIMEOUT_S = 600.0  # a warm on a clean cache compiles the kernels: minutes on a busy machine
MAX_WARM_BYTES = 100_000  # a unix datagram's default send buffer is about 200 kB
UNKNOWN_EXIT = -1  # the zygote ended before the child did: its exit code cannot be known here


class ZygoteUnavailable(RuntimeError):
    """The zygote could not start or fork; the caller starts the child the ordinary way."""


def fixed_env(env: Any) -> dict[str, str]:
    """The settings read at import that a forked child cannot change (``PYTHONPATH`` it can: ``child_path``)."""
    return {k: v for k, v in env.items() if k.startswith(FIXED_ENV_PREFIXES) and k != "PYTHONPATH"}


def child_path(env: dict[str, str]) -> list[str]:
    """The child's ``sys.path``: this process's, after the entries of the child's ``PYTHONPATH`` it lacks
    (a fresh interpreter puts ``PYTHONPATH`` first)."""
    extra = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p not in sys.path]
    return [*extra, *sys.path]


class Zygote:
    """One per parent process, started on first use; a thread reads its reports (ready, started, exit)."""

    def __init__(self) -> None:
        self.owner, self.env, self.ids = os.getpid(), fixed_env(os.environ), itertools.count()
        self.sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        path = os.pathsep.join(p for p in sys.path if p)
        self.proc = subprocess.Popen([sys.executable, "-m", "rehab_hil.launch.zygote", str(theirs.fileno())],
                                     pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, process_group=0,
                                     env={**os.environ, "PYTHONPATH": path})
        theirs.close()
        self.state, self.replies, self.exits = "starting", {}, {}
        self.cond, self.send_lock = threading.Condition(), threading.Lock()
        threading.Thread(target=self._read, name="zygote-reader", daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                msg = self.sock.recv(1 << 16)
            except OSError:
                msg = b""
            if not msg:
                break
            kind, *rest = pickle.loads(msg)
            with self.cond:
                if kind in ("ready", "broken"):
                    self.state = kind if kind == "ready" else f"broken: {rest[0]}"
                elif kind in ("started", "failed"):
                    self.replies[rest[0]] = (kind, rest[1])
                elif kind == "exit":
                    self.exits[rest[0]] = rest[1]
                self.cond.notify_all()
        with self.cond:
            self.state = "gone"
            self.cond.notify_all()
        self.proc.wait()

    def usable(self) -> bool:
        return self.owner == os.getpid() and self.state in ("starting", "ready")

    def start(self, req: dict[str, Any], fds: list[int]) -> int:
        """Fork the child ``req`` describes with ``fds`` at ``req['targets']``; its pid."""
        with self.cond:
            if not self.cond.wait_for(lambda: self.state != "starting", START_TIMEOUT_S) or self.state != "ready":
                raise ZygoteUnavailable(f"zygote {self.state}")
        with self.send_lock:
            req["id"] = next(self.ids)
            socket.send_fds(self.sock, [pickle.dumps(req)], fds)
        with self.cond:
            self.cond.wait_for(lambda: req["id"] in self.replies or self.state != "ready",
                               WARM_TIMEOUT_S if req.get("warm") else START_TIMEOUT_S)
            kind, got = self.replies.pop(req["id"], ("failed", f"zygote {self.state}"))
        if kind != "started":
            raise ZygoteUnavailable(got)
        return int(got)

    def exit_code(self, pid: int, timeout: float | None) -> int | None:
        """The child's exit code (negative: the signal), waiting up to ``timeout`` (None: for ever)."""
        with self.cond:
            self.cond.wait_for(lambda: pid in self.exits or self.state == "gone", timeout)
            if pid in self.exits:
                return self.exits[pid]
        if self.state == "gone" and not _exists(pid):
            return UNKNOWN_EXIT
        return None


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class ForkedChild:
    """A child forked by the zygote: ``pid``, ``stdin``, ``stdout``, ``stderr``, ``returncode`` and the
    ``subprocess.Popen`` methods the package uses."""

    def __init__(self, zygote: Zygote, pid: int, args: list[str], streams: list[IO[bytes] | None]) -> None:
        self.zygote, self.pid, self.args = zygote, pid, args
        self.stdin, self.stdout, self.stderr = streams
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self.zygote.exit_code(self.pid, 0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            self.returncode = self.zygote.exit_code(self.pid, timeout)
            if self.returncode is None:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def __enter__(self) -> ForkedChild:
        return self

    def __exit__(self, *exc: object) -> None:
        for f in (self.stdin, self.stdout, self.stderr):
            if f is not None:
                with contextlib.suppress(OSError):
                    f.close()
        self.wait()


_zygote: Zygote | None = None
_lock = threading.Lock()


def _zygote_for(env: Any) -> Zygote | None:
    global _zygote
    if os.environ.get("REHAB_HIL_ZYGOTE", "1") == "0":
        return None
    with _lock:
        if _zygote is None or not _zygote.usable():
            _zygote = Zygote()
    return _zygote if fixed_env(env) == _zygote.env else None


def warm() -> None:
    """Start this process's zygote now, so that it imports while the caller goes on (no-op if it runs)."""
    _zygote_for(os.environ)


def _plan(argv: list[str]) -> tuple[str, str, list[str]] | None:
    """("-c", code, args) or ("-m", module, args) for ``[sys.executable, -c|-m, ...]``, else None."""
    if len(argv) >= 3 and argv[0] == sys.executable and argv[1] in ("-c", "-m"):
        return argv[1], argv[2], list(argv[3:])
    return None


def popen(argv: list[str], *, stdin: Any = None, stdout: Any = None, stderr: Any = None,
          pass_fds: tuple[int, ...] = (), env: dict[str, str] | None = None, process_group: int | None = None,
          bufsize: int = -1, warm: tuple[str, tuple[Any, ...]] | None = None) -> subprocess.Popen[bytes] | ForkedChild:
    """``subprocess.Popen(argv, ...)``, forked from the zygote when ``argv`` runs this interpreter's
    ``-c``/``-m`` (``process_group``: None keeps this process's group, 0 a group of its own).

    ``warm`` ("module:function", args): the zygote calls it before forking, once per distinct call, to
    load what the child will load (its compiled kernels); the child and every later one find it in
    memory. Its failure is ignored there: the child meets the same error and reports it."""
    env = dict(os.environ if env is None else env)
    plan, zygote = _plan(argv), _zygote_for(env)
    if plan is not None and zygote is not None:
        try:
            return _forked(zygote, argv, plan, (stdin, stdout, stderr), pass_fds, env, process_group, bufsize,
                           _warm_bytes(warm))
        except ZygoteUnavailable:
            pass
    return subprocess.Popen(argv, stdin=stdin, stdout=stdout, stderr=stderr, pass_fds=pass_fds, env=env,
                            process_group=process_group, bufsize=bufsize)


def _forked(zygote: Zygote, argv: list[str], plan: tuple[str, str, list[str]], std: tuple[Any, Any, Any],
            pass_fds: tuple[int, ...], env: dict[str, str], process_group: int | None,
            bufsize: int, warm: bytes | None) -> ForkedChild:
    theirs: list[int] = []
    ours: list[int | None] = []
    opened: list[int] = []  # the child's ends made here, closed here once it has them
    for n, how in enumerate(std):
        child_fd, mine = (theirs[1], None) if how == subprocess.STDOUT else _std_fd(n, how)
        theirs.append(child_fd)
        ours.append(mine)
        if how in (subprocess.PIPE, subprocess.DEVNULL):
            opened.append(child_fd)
    mode, target, args = plan
    req = {"argv": list(argv), "mode": mode, "target": target, "args": args, "env": env, "cwd": os.getcwd(),
           "path": child_path(env), "warm": warm, "targets": [0, 1, 2, *pass_fds],
           "pgid": 0 if process_group == 0 else os.getpgrp()}
    try:
        pid = zygote.start(req, [*theirs, *pass_fds])
    except ZygoteUnavailable:
        for fd in [*opened, *(m for m in ours if m is not None)]:
            os.close(fd)
        raise
    for fd in opened:
        os.close(fd)
    streams = [None if mine is None else open(mine, "wb" if n == 0 else "rb", buffering=bufsize)
               for n, mine in enumerate(ours)]
    return ForkedChild(zygote, pid, argv, streams)


def _warm_bytes(warm: tuple[str, tuple[Any, ...]] | None) -> bytes | None:
    """``warm`` pickled on its own (the zygote may not import all it names: then it skips it), or None
    when it cannot be pickled or would not fit a socket message beside the request."""
    if warm is None:
        return None
    try:
        data = pickle.dumps(warm, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:
        return None
    return data if len(data) <= MAX_WARM_BYTES else None


def _std_fd(n: int, how: Any) -> tuple[int, int | None]:
    """The child's fd ``n`` (0, 1, 2) for a Popen-style argument, and this process's end of a pipe."""
    if how is None or how == subprocess.STDOUT:
        return n, None
    if how == subprocess.PIPE:
        r, w = os.pipe()
        return (r, w) if n == 0 else (w, r)
    if how == subprocess.DEVNULL:
        return os.open(os.devnull, os.O_RDWR), None
    return (how if isinstance(how, int) else how.fileno()), None
