"""The compiled engine under Ctrl-C: an interrupt that comes while a compiled simulation runs is
raised as a plain KeyboardInterrupt once the run returns, never a numba ``SystemError`` or a crash."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

# A child process: a crash must not take the test's worker with it, and SIGINT is at its default there
# (a pytest-xdist worker ignores it, and a child started so would keep ignoring it).
CHILD = textwrap.dedent("""
    import os, signal, threading, time
    from rehab_hil.models.mechanics import RotaryInertia, TorsionSpring
    from rehab_hil.models.system import Diagram

    parts = [RotaryInertia("mass", connect={"torque_nm": "torque_nm"}, x0=[1.0, 0.0], inertia_kg_m2=1.0),
             TorsionSpring("spring", rename={"torque_nm": "torque_nm"}, stiffness_nm_per_rad=4.0,
                           rest_angle_rad=0.0)]
    system = Diagram(parts, inputs=(), sums=("torque_nm",)).compile(dt=1e-3, substeps=400)
    system.simulate(10, outputs=["angle_rad"])  # compiles the engine on a clean cache
    t0 = time.monotonic(); system.simulate(10_000, outputs=["angle_rad"]); per_step = (time.monotonic() - t0) / 1e4
    n = int(1.5 / per_step)  # a run of about 1.5 s; the Ctrl-C comes 0.3 s into it
    for attempt in range(3):
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
        t0 = time.monotonic()
        try:
            system.simulate(n, outputs=["angle_rad"])
            print("not interrupted", flush=True)
        except KeyboardInterrupt:
            print(f"KeyboardInterrupt after {time.monotonic() - t0:.2f} s", flush=True)
""")


def test_ctrl_c_during_a_compiled_run_is_a_keyboard_interrupt_when_the_run_returns():
    proc = subprocess.run([sys.executable, "-X", "faulthandler", "-c", CHILD], capture_output=True, text=True,
                          timeout=300, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.returncode == 0, proc.stderr[-3000:]  # numba 0.68 without the hold: SystemError, or -11
    lines = proc.stdout.split("\n")[:-1]
    assert len(lines) == 3 and all(line.startswith("KeyboardInterrupt after") for line in lines), proc.stdout
    assert all(float(line.split()[2]) > 0.3 for line in lines), proc.stdout  # raised when the run returned


def test_a_model_recompiles_when_a_helper_its_kernels_import_from_another_module_changes():
    from rehab_hil.models.engine import kernel_modules
    from rehab_hil.models.system import Part
    from rehab_hil.patient.parts import TaskCue

    # the simulated patient's cue calls control.trajectories.open_close_reference inside its kernel: the
    # class's own modules alone (the key before) left the model compiled against the old reference
    assert "rehab_hil.control.trajectories" in kernel_modules([TaskCue], Part)


def test_an_edit_to_the_diagram_framework_does_not_recompile_every_model():
    from rehab_hil.models.engine import kernel_modules
    from rehab_hil.models.mechanics import RotaryInertia
    from rehab_hil.models.system import Part

    # the key held models/system.py, so any edit there recompiled every model (~400 on this machine, 7 min of
    # the next make test); its kernel of nothing lives in models/jit.py
    assert kernel_modules([RotaryInertia], Part) == ("rehab_hil.models.jit", "rehab_hil.models.mechanics")
