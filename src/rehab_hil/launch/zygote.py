"""The zygote (``python -m rehab_hil.launch.zygote SOCKET_FD``): imports the children's modules once,
then forks one child per request on its socket and reports each child's exit back.

A request is a pickled dict (``id``, ``mode`` "-c"/"-m", ``target``, ``args``, ``env``, ``cwd``, ``path``,
``targets``: the child's fd number for each fd passed with it, ``pgid``) with the fds attached. The
zygote stays single-threaded, so forking it is safe; it ends when its parent's end of the socket closes
(its children live on, as children of a dead parent do)."""

from __future__ import annotations

import fcntl
import importlib
import os
import pickle
import select
import signal
import socket
import sys
import traceback
from typing import Any

PRELOAD = ("rehab_hil.loop.process", "rehab_hil.devices.sim_device", "rehab_hil.devices.avr_device",
           "rehab_hil.devices.usb_bridge")
MAX_FDS = 16
MAX_MESSAGE = 1 << 20


def preload() -> None:
    """Import the children's modules and build numba's CPU target (its registries and BLAS check: about
    0.6 s that each process would otherwise spend before loading its first cached kernel)."""
    import setproctitle

    setproctitle.getproctitle()  # takes hold of the argv area now: a forked child can retitle itself
    for name in PRELOAD:
        importlib.import_module(name)
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()


def serve(sock: socket.socket) -> None:
    """Fork a child per request, report its pid and later its exit code, until the parent goes."""
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    sock.send(pickle.dumps(("ready", os.getpid())))
    try:
        while True:
            ready, _, _ = select.select([sock, wake_r], [], [])
            if wake_r in ready:
                os.read(wake_r, 4096)
            _reap(sock)
            if sock in ready and not _answer(sock, wake_r, wake_w):
                return
    except (BrokenPipeError, ConnectionResetError):
        return


def _answer(sock: socket.socket, wake_r: int, wake_w: int) -> bool:
    msg, fds, _, _ = socket.recv_fds(sock, MAX_MESSAGE, MAX_FDS)
    if not msg:
        return False
    req: dict[str, Any] = {}
    try:
        req = pickle.loads(msg)
        _warm(req.get("warm"))
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _child(req, fds, (sock.fileno(), wake_r, wake_w))
        sock.send(pickle.dumps(("started", req["id"], pid)))
    except Exception as e:
        sock.send(pickle.dumps(("failed", req.get("id"), f"{type(e).__name__}: {e}")))
    finally:
        for fd in fds:
            os.close(fd)
    return True


_WARMED: set[bytes] = set()


def _warm(data: bytes | None) -> None:
    """Call a request's warm-up ("module:function", args) once per distinct call; its failure is the
    child's to meet and report."""
    if not data or data in _WARMED:
        return
    _WARMED.add(data)
    try:
        target, args = pickle.loads(data)
        module, function = target.split(":")
        getattr(importlib.import_module(module), function)(*args)
    except Exception:
        pass


def _reap(sock: socket.socket) -> None:
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        sock.send(pickle.dumps(("exit", pid, os.waitstatus_to_exitcode(status))))


def _child(req: dict[str, Any], fds: list[int], zygote_fds: tuple[int, ...]) -> None:
    """In the forked child: become the process the request describes, run it, never return."""
    code = 1
    try:
        signal.set_wakeup_fd(-1)
        for fd in zygote_fds:
            os.close(fd)
        _set_up(req, fds)
        code = _run(req)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else _said(e.code))
    except BaseException:
        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(code & 0xFF if code >= 0 else 1)


def _said(message: object) -> int:
    print(message, file=sys.stderr)
    return 1


def _set_up(req: dict[str, Any], fds: list[int]) -> None:
    """Process group, signals, fds at the numbers asked for (all others closed), cwd, environment, path."""
    pgid = req["pgid"]
    os.setpgid(0, 0 if pgid is None else pgid)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    floor = max([256, *req["targets"]]) + 1  # above every target: no dup2 below overwrites a source
    high = [fcntl.fcntl(fd, fcntl.F_DUPFD, floor) for fd in fds]
    for fd, target in zip(high, req["targets"], strict=True):
        os.dup2(fd, target)
    keep = set(req["targets"]) | {0, 1, 2}
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        if fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass
    os.chdir(req["cwd"])
    os.environ.clear()
    os.environ.update(req["env"])
    sys.path[:] = req["path"]


def _run(req: dict[str, Any]) -> int:
    """``python -c CODE ARGS`` or ``python -m MODULE ARGS``, as the interpreter would run them, under that
    command line (``ps``, ``/proc/PID/cmdline``) rather than the zygote's."""
    from setproctitle import setproctitle

    setproctitle(" ".join(req["argv"]))
    if req["mode"] == "-c":
        sys.argv = ["-c", *req["args"]]
        exec(compile(req["target"], "<string>", "exec"), {"__name__": "__main__", "__builtins__": __builtins__})
    else:
        import runpy
        import warnings

        sys.argv = [req["target"], *req["args"]]
        with warnings.catch_warnings():  # a preloaded module: runpy runs its code again as __main__, as -m would
            warnings.filterwarnings("ignore", "'.*' found in sys.modules after import", RuntimeWarning)
            runpy.run_module(req["target"], run_name="__main__", alter_sys=True)
    return 0


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C is the session's to handle
    sock = socket.socket(fileno=int(sys.argv[1]))
    try:
        preload()
    except Exception as e:
        sock.send(pickle.dumps(("broken", f"{type(e).__name__}: {e}")))
        return 1
    os.chdir("/")
    serve(sock)
    return 0


if __name__ == "__main__":
    sys.exit(main())
