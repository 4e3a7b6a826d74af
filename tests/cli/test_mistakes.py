"""Every subcommand against the mistakes people make: a missing file, a directory where a file
goes, a closed standard input, a typo'd key, Ctrl-C in a terminal. Each is one line naming the
file or key, exit 2 (Ctrl-C: the session's own clean stop), never a traceback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.testing import CONFIGS

FE = CONFIGS / "finger_extensor.toml"
ROOT = CONFIGS.parent

# a subcommand and its arguments around the config path; {cfg} is replaced by the path under test
WITH_CONFIG = {
    "simulate": ["simulate", "--config", "{cfg}", "--scenario", "step", "--duration", "0.2"],
    "run": ["run", "--config", "{cfg}", "--device", "inprocess", "--duration", "0.2", "--no-display"],
    "tune": ["tune", "--config", "{cfg}", "--out", "{tmp}/tuned.toml"],
    "sensitivity": ["sensitivity", "--config", "{cfg}"],
    "discrepancy": ["discrepancy", "--config", "{cfg}", "--data", "{tmp}/data.csv", "--out", "{tmp}/rep"],
    "replay": ["replay", "--config", "{cfg}", "--data", "{tmp}/data.csv"],
    "twin": ["twin", "{tmp}/data.csv", "--config", "{cfg}"],
    "doctor": ["doctor", "--config", "{cfg}", "--device", "inprocess", "--yes"],
    "calibrate": ["calibrate", "force", "--config", "{cfg}", "--device", "inprocess", "--weights-g", "50,100",
                  "--sensor-id", "s1", "--yes"],
}


def _argv(name: str, cfg, tmp_path) -> list[str]:
    return [a.replace("{cfg}", str(cfg)).replace("{tmp}", str(tmp_path)) for a in WITH_CONFIG[name]]


def _one_line(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and "\n" not in err, err
    assert err.startswith(f"rehab-hil {command}: error: "), err
    return err


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "data.csv"
    assert main(["simulate", "--config", str(FE), "--scenario", "step", "--duration", "0.3", "--out", str(out)]) == 0
    return out


@pytest.fixture
def data_csv(recorded, tmp_path):
    (tmp_path / "data.csv").write_bytes(recorded.read_bytes())
    return tmp_path / "data.csv"


@pytest.mark.parametrize("name", sorted(WITH_CONFIG))
def test_a_missing_config_is_one_line_naming_it(name, tmp_path, capsys, data_csv):
    capsys.readouterr()
    missing = tmp_path / "nope.toml"
    assert main(_argv(name, missing, tmp_path)) == 2
    assert f"{missing}: file not found" in _one_line(capsys, name)


@pytest.mark.parametrize("name", sorted(WITH_CONFIG))
def test_a_directory_given_as_the_config_is_one_line_naming_it(name, tmp_path, capsys, data_csv):
    capsys.readouterr()
    assert main(_argv(name, tmp_path, tmp_path)) == 2
    assert str(tmp_path) in _one_line(capsys, name)


@pytest.mark.parametrize("name", sorted(WITH_CONFIG))
def test_a_typod_key_is_reported_as_the_typo(name, tmp_path, capsys, data_csv):
    capsys.readouterr()
    bad = tmp_path / "typo.toml"
    bad.write_text(FE.read_text().replace("kp_per_deg = 0.30   ", "kp_per_dge = 0.30   "))
    assert main(_argv(name, bad, tmp_path)) == 2
    err = _one_line(capsys, name)
    assert f"{bad}: " in err and "kp_per_dge: unknown key (did you mean 'kp_per_deg'?)" in err


@pytest.mark.parametrize("argv", [
    ["simulate", "--config", str(FE), "--scenario", "step", "--out", "{tmp}"],
    ["run", "--config", str(FE), "--device", "inprocess", "--duration", "0.2", "--record", "{tmp}/file"],
    ["discrepancy", "--config", str(FE), "--data", "{tmp}/data.csv", "--out", "{tmp}/file"],
    ["discrepancy", "--config", str(FE), "--data", "{tmp}/nothing.csv", "--out", "{tmp}/rep"],
    ["replay", "--config", str(FE), "--data", "{tmp}"],
    ["report", "{tmp}/file"],
    ["simulate", "--config", str(FE), "--scenario", "step", "--duration", "0.2", "--out", "{tmp}/file/sub/x.csv"],
    ["replay", "--config", str(FE), "--data", "{tmp}/data.csv", "--out", "{tmp}/file/r.csv"],
    ["run", "--config", str(FE), "--device", "simm", "--duration", "0.2"],
    ["doctor", "--config", str(FE), "--device", "inproces", "--yes"],
    ["calibrate", "force", "--config", str(FE), "--device", "inprocess", "--weights-g", "200,100", "--sensor-id", "s1"],
], ids=lambda a: " ".join(a[:1] + [x for x in a if x.startswith("--")][-1:]))
def test_a_bad_path_or_argument_is_one_line(argv, tmp_path, capsys, data_csv):
    (tmp_path / "file").write_text("not a folder")
    capsys.readouterr()
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    _one_line(capsys, argv[0])
    assert (tmp_path / "file").read_text() == "not a folder"  # nothing overwritten


@pytest.mark.slow
@pytest.mark.parametrize("argv", [
    ["doctor", "--config", str(FE), "--device", "sim"],
    ["calibrate", "force", "--config", str(FE), "--device", "sim", "--weights-g", "50,100",
     "--sensor-id", "s1", "--out-dir", "{tmp}"],
])
def test_a_closed_standard_input_at_a_prompt_is_one_line(argv, tmp_path):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    proc = subprocess.run([sys.executable, "-m", "rehab_hil.cli", *argv], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, cwd=ROOT, timeout=240)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip().splitlines()
    assert "Traceback" not in proc.stderr
    assert err[-1] == f"rehab-hil {argv[0]}: error: standard input closed while waiting for an answer: answer on a " \
                      "terminal, or pass --yes (doctor, calibrate) or --home none (run)"


class Terminal:
    """``rehab-hil ARGS`` in a real terminal (a pty whose line discipline sends SIGINT to its whole
    foreground process group), its output collected; killed and closed on exit."""

    def __init__(self, *args: str) -> None:
        import pty

        self.pid, self.fd = pty.fork()
        if self.pid == 0:  # the child: its own session, the pty its controlling terminal
            os.chdir(ROOT)
            os.execv(sys.executable, [sys.executable, "-m", "rehab_hil.cli", *args])
        self.out = bytearray()

    def pump(self, seconds: float) -> bool:
        """Collect output for ``seconds``; False once the child closed the terminal."""
        import select

        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if select.select([self.fd], [], [], 0.1)[0]:
                try:
                    data = os.read(self.fd, 65536)
                except OSError:
                    return False
                if not data:
                    return False
                self.out.extend(data)
        return True

    def type(self, key: bytes) -> int:
        """Type ``key``, collect the rest of the output (up to 120 s) and return the exit code."""
        os.write(self.fd, key)
        deadline = time.monotonic() + 120
        while self.pump(0.5) and time.monotonic() < deadline:
            pass
        return os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])

    @property
    def text(self) -> str:
        return self.out.decode(errors="replace")

    def __enter__(self) -> Terminal:
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            os.kill(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.close(self.fd)


@pytest.mark.slow
@pytest.mark.parametrize("device", ["sim", "avr"])
def test_ctrl_c_in_a_terminal_stops_a_simulated_rig_cleanly(tmp_path, device):
    """Ctrl-C typed in a real terminal: the host's process group gets SIGINT, and the simulated
    device's (for the firmware: its driver and simavr) unless the device runs in a process group of
    its own. The live display is on, as in a terminal."""
    with Terminal("run", "--config", str(FE), "--device", device, "--lockstep", "--duration", "600", "--record",
                  str(tmp_path), "--home", "none") as term:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            term.pump(0.2)
            found = list(tmp_path.glob("*/run.csv"))
            if found and found[0].stat().st_size > 20000:
                break
        assert found, term.text[-2000:]
        code = term.type(b"\x03")  # Ctrl-C
    text = term.text
    assert code == 130, text[-3000:]  # 128 + SIGINT, as every command ends on Ctrl-C
    assert "Traceback" not in text and "link_loss" not in text
    assert "stop_request" in text and "SIGINT" in text
    assert "yes" in text.split("device PWM off at end")[1].splitlines()[0]
    csv = found[0]
    meta = json.loads((csv.parent / "metadata.json").read_text())
    assert meta["pwm_off_at_end"] and meta["safety_events"][0]["reason"] == "stop_request"
    assert meta["rows"] == read_csv(csv).t.size  # metadata says what was written


def test_monitor_with_no_hub_is_one_line_with_a_hint(capsys):
    from rehab_hil.testing import free_port

    port = free_port()
    assert main(["monitor", "rig1", "--port", str(port), "--duration", "1", "--no-live"]) == 2
    err = _one_line(capsys, "monitor")
    assert f"cannot connect to tcp/127.0.0.1:{port}" in err and "no hub there" in err and "--telemetry RIG" in err
    assert ".rs:" not in err


def test_ctrl_d_at_the_homing_prompt_is_one_line(tmp_path):
    """On a terminal ``run`` asks before it zeroes the encoder; Ctrl-D there ends it in one line."""
    with Terminal("run", "--config", str(FE), "--device", "inprocess", "--duration", "5", "--no-display",
                  "--record", str(tmp_path)) as term:
        deadline = time.monotonic() + 120
        while b"press Enter" not in term.out and time.monotonic() < deadline:
            term.pump(0.2)
        assert b"press Enter" in term.out, term.text
        code = term.type(b"\x04")  # Ctrl-D
    assert code == 2 and "Traceback" not in term.text
    assert "rehab-hil run: error: standard input closed while waiting for an answer" in term.text
    assert not list(tmp_path.glob("*/run.csv"))  # nothing recorded: the session never started
