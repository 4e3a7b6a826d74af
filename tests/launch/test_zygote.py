"""Children forked from the zygote behave as the ``python -c``/``-m`` processes they stand for: their
arguments, pipes, passed descriptors, exit codes, signals, process group and command line; an
environment the zygote was not started with, or another program, gets an ordinary process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from rehab_hil import launch

ECHO = "import sys; print(sys.argv[1:], flush=True); sys.stdout.write(sys.stdin.read()); sys.exit(int(sys.argv[1]))"


def test_a_forked_child_gets_its_arguments_pipes_and_exit_code() -> None:
    p = launch.popen([sys.executable, "-c", ECHO, "3", "x"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, bufsize=0)
    assert isinstance(p, launch.ForkedChild)
    p.stdin.write(b"through stdin\n")
    p.stdin.close()
    assert p.stdout.read() == b"['3', 'x']\nthrough stdin\n"
    assert p.wait(10) == 3 and p.poll() == 3


def test_a_module_run_with_m_sees_main_and_a_passed_descriptor_at_its_number(tmp_path: Path) -> None:
    (tmp_path / "probe_main.py").write_text(textwrap.dedent("""
        import os, sys
        if __name__ == "__main__":
            os.write(int(sys.argv[1]), f"{sys.argv[0].endswith('probe_main.py')} {os.getcwd()}".encode())
    """))
    r, w = os.pipe()
    old = sys.path[:]
    sys.path.insert(0, str(tmp_path))
    try:
        p = launch.popen([sys.executable, "-m", "probe_main", str(w)], pass_fds=(w,))
    finally:
        sys.path[:] = old
        os.close(w)
    assert p.wait(10) == 0
    assert os.read(r, 4096).decode() == f"True {os.getcwd()}"
    os.close(r)


def test_the_child_shows_its_own_command_line_and_group() -> None:
    argv = [sys.executable, "-c", "import time; time.sleep(30)", "marker-for-ps"]
    p = launch.popen(argv, process_group=0)
    try:
        deadline = time.monotonic() + 10
        while "marker-for-ps" not in (cmdline := Path(f"/proc/{p.pid}/cmdline").read_text()):
            assert time.monotonic() < deadline, cmdline
            time.sleep(0.02)
        assert cmdline.replace("\0", " ").split() == [*argv[:2], "import", "time;", "time.sleep(30)", "marker-for-ps"]
        assert os.getpgid(p.pid) == p.pid != os.getpgrp()
    finally:
        p.kill()
    assert p.wait(10) == -signal.SIGKILL


def test_an_exception_is_printed_and_exits_one() -> None:
    p = launch.popen([sys.executable, "-c", "raise ValueError('said')"], stderr=subprocess.PIPE)
    assert p.wait(10) == 1
    assert "ValueError: said" in p.stderr.read().decode()


def test_a_wait_that_runs_out_raises_timeout_expired_as_popen_does() -> None:
    p = launch.popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        try:
            p.wait(0.1)
        except subprocess.TimeoutExpired:
            pass
        else:
            raise AssertionError("no TimeoutExpired")
    finally:
        p.terminate()
    assert p.wait(10) == -signal.SIGTERM


def test_another_numba_setting_or_another_program_gets_an_ordinary_process() -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": "/tmp/elsewhere"}
    p = launch.popen([sys.executable, "-c", "pass"], env=env)
    q = launch.popen(["true"])
    assert type(p) is subprocess.Popen and type(q) is subprocess.Popen
    assert p.wait(30) == 0 and q.wait(10) == 0


def test_the_zygote_ends_with_the_process_it_serves_and_its_children_live_on() -> None:
    script = textwrap.dedent("""
        import sys, time
        from rehab_hil import launch
        child = launch.popen([sys.executable, "-c", "import time; time.sleep(30)"])
        print(launch.client._zygote.proc.pid, child.pid, flush=True)
        time.sleep(30)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    zygote, child = (int(x) for x in parent.stdout.readline().split())
    parent.kill()
    parent.wait(10)
    try:
        deadline = time.monotonic() + 10
        while _alive(zygote):
            assert time.monotonic() < deadline, "the zygote outlived its parent"
            time.sleep(0.05)
        assert _alive(child)
    finally:
        os.kill(child, signal.SIGKILL)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in "ZX"


def test_a_pythonpath_of_the_child_is_put_first_on_its_path_and_still_forks(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    p = launch.popen([sys.executable, "-c", "import sys; print(sys.path[0])"], env=env, stdout=subprocess.PIPE)
    assert isinstance(p, launch.ForkedChild)
    assert p.stdout.read().decode().strip() == str(tmp_path) and p.wait(10) == 0


def test_a_warm_up_runs_in_the_zygote_once_before_the_child_and_its_failure_is_ignored(tmp_path: Path) -> None:
    """What the warm-up loads, the child finds in memory: here a module nothing else imports."""
    code = "import sys; print('wsgiref.simple_server' in sys.modules)"
    plain = launch.popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert plain.stdout.read().decode().strip() == "False" and plain.wait(10) == 0
    warm = ("importlib:import_module", ("wsgiref.simple_server",))
    p = launch.popen([sys.executable, "-c", code], stdout=subprocess.PIPE, warm=warm)
    assert p.stdout.read().decode().strip() == "True" and p.wait(10) == 0
    broken = launch.popen([sys.executable, "-c", "print('ran')"], stdout=subprocess.PIPE,
                          warm=("no_such_module:f", ()))
    assert broken.stdout.read().decode().strip() == "ran" and broken.wait(10) == 0


def test_a_module_the_zygote_preloaded_runs_with_m_without_runpys_warning() -> None:
    """``rehab-hil run`` starts its loop process as ``-m rehab_hil.loop.process``, a module the zygote has
    imported: the child's stderr is the module's own, with no RuntimeWarning of runpy's about it."""
    p = launch.popen([sys.executable, "-m", "rehab_hil.loop.process", "99"], stdin=subprocess.DEVNULL,
                     stderr=subprocess.PIPE)
    assert isinstance(p, launch.ForkedChild)
    assert p.wait(20) == 1  # fd 99 is not open: the module's own error, raised from its __main__ block
    err = p.stderr.read().decode()
    assert "Bad file descriptor" in err and "RuntimeWarning" not in err
