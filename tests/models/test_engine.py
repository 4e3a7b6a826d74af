"""The compiled engine: a part class compiled once for every diagram that uses it, an engine's
functions compiled once each, a new module when a kernel's source changes; and under Ctrl-C, an
interrupt that comes while a compiled simulation runs is raised as a plain KeyboardInterrupt once
the run returns, never a numba ``SystemError`` or a crash."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import numpy as np

from rehab_hil.models import engine
from rehab_hil.models.effect_parts import Backlash
from rehab_hil.models.mechanics import RotaryInertia, TorsionSpring, ViscousFriction
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Diagram


def _oscillator(*extra):
    return Diagram([RotaryInertia("mass", connect={"torque_nm": "torque_nm"}, x0=[1.0, 0.0], inertia_kg_m2=1.0),
                    TorsionSpring("spring", rename={"torque_nm": "torque_nm"}, stiffness_nm_per_rad=4.0,
                                  rest_angle_rad=0.0), *extra], inputs=(), sums=("torque_nm",))

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


def test_diagrams_of_different_structure_share_the_compiled_part_classes():
    damper = ViscousFriction("damper", rename={"torque_nm": "torque_nm"}, damping_nm_s_per_rad=0.1)
    bare, damped = _oscillator().compile(1e-3), _oscillator(damper).compile(1e-3)
    assert bare.engine is not damped.engine  # two structures, two engines
    # ... calling one module per part class: the inertia's and the spring's kernels compile once for both
    assert bare.engine._C0 is damped.engine._C0 and bare.engine._C1 is damped.engine._C1
    assert bare.engine._C0.__name__.startswith("rehab_hil_part_") and bare.engine._C0 is not bare.engine._C1
    # each still runs its own structure: x'' + b x' + 4 x = 0 from x = 1 at rest, b = 0 and 0.1
    t = np.arange(3000) * 1e-3
    wd = np.sqrt(4.0 - 0.05**2)
    damped_exact = np.exp(-0.05 * t) * (np.cos(wd * t) + 0.05 / wd * np.sin(wd * t))
    assert np.max(np.abs(bare.simulate(3000, outputs=["angle_rad"])["angle_rad"] - np.cos(2.0 * t))) < 1e-9
    assert np.max(np.abs(damped.simulate(3000, outputs=["angle_rad"])["angle_rad"] - damped_exact)) < 1e-9


def test_an_engine_compiles_its_output_pass_once_for_simulation_and_for_stepping(monkeypatch, tmp_path):
    # a literal True / False for the sample flag made numba compile the whole output pass twice
    monkeypatch.setenv("REHAB_HIL_CACHE_DIR", str(tmp_path))  # a clean cache: this engine compiles here
    play = Backlash("play", connect={"angle_rad": "angle_rad"}, rename={"angle_rad": "held_rad"}, width_rad=0.2)
    probe = Gain("probe", connect={"u": [("held_rad", 0.731)]}, rename={"y": "probe"}, gain=1.0)
    system = _oscillator(play, probe).compile(1e-3)
    res = system.simulate(2000, outputs=["held_rad", "angle_rad"])
    y = system.stepper(["held_rad"]).step(np.zeros(0))
    assert len(system.engine.eval_outputs.signatures) == 1
    held, angle = res["held_rad"], res["angle_rad"]
    assert y[0] == held[0] == 0.9  # at rest at 1 rad, the play's half width 0.1 rad from it
    assert np.all(held[:200] == 0.9) and angle[199] < 0.93  # held while the angle takes up the play
    assert np.max(np.abs(held - angle)) <= 0.1 + 1e-12


def test_an_edit_to_a_kernel_module_gives_new_part_modules_and_a_new_engine(monkeypatch):
    layout = _oscillator().layout
    before = engine.engine_for(layout)
    real = engine.inspect.getsource
    edited = "rehab_hil.models.mechanics"  # the module of both parts
    monkeypatch.setattr(engine.inspect, "getsource",
                        lambda m: real(m) + ("\n# edited" if m.__name__ == edited else ""))
    after = engine.engine_for(layout)  # generated and imported, not compiled: numba compiles on the first call
    assert after.__name__ != before.__name__
    assert after._C0.__name__ != before._C0.__name__ and after._C1.__name__ != before._C1.__name__


def test_an_engine_stepped_by_hand_is_compiled_before_its_first_step():
    # the rig's controller steps its engine by hand (service/controllers.py): on a clean cache its first
    # step compiled these for seconds inside the session's loop, a simulated device's its ``step``
    probe = Gain("probe", connect={"u": [("angle_rad", 0.377)]}, rename={"y": "probe"}, gain=1.0)
    system = _oscillator(probe).compile(1e-3)
    e = system.engine
    names = ("sample", "read_outputs", "integrate")
    assert [len(getattr(e, n).signatures) for n in names] == [1, 1, 1]
    stepper = system.stepper(["probe"])
    assert len(e.step.signatures) == 1
    sig, w, stage, xdn = system.workspace()
    x, xd, y = system.x0.copy(), system.xd0.copy(), np.zeros(1)
    e.sample(0.0, x, xd, np.zeros(0), system.params, sig, w, xdn)
    e.read_outputs(system.out_slots(["probe"]), sig, y)
    e.integrate(0.0, x, xd, np.zeros(0), system.params, 1e-3, 1, sig, w, stage)
    assert stepper.step(np.zeros(0))[0] == y[0] == 0.377 and x[0] < 1.0  # the spring pulls the mass back
    assert [len(getattr(e, n).signatures) for n in (*names, "step")] == [1, 1, 1, 1]  # nothing compiled anew


# Two processes that need the same new engine at the same moment (parallel test workers, a session and its
# simulated device): each builds the diagram, says so, and runs it once the test says go.
TWIN_CHILD = textwrap.dedent("""
    import os, sys, time
    from rehab_hil.models.mechanics import RotaryInertia, TorsionSpring
    from rehab_hil.models.sensors import Gain
    from rehab_hil.models.system import Diagram

    parts = [RotaryInertia("mass", connect={"torque_nm": "torque_nm"}, x0=[1.0, 0.0], inertia_kg_m2=1.0),
             TorsionSpring("spring", rename={"torque_nm": "torque_nm"}, stiffness_nm_per_rad=4.0,
                           rest_angle_rad=0.0),
             Gain("probe", connect={"u": [("angle_rad", 0.613)]}, rename={"y": "probe"}, gain=1.0)]
    system = Diagram(parts, inputs=(), sums=("torque_nm",)).compile(dt=1e-3)
    print("ready", flush=True)
    while not os.path.exists(sys.argv[1]):
        time.sleep(0.005)
    print(system.simulate(1000, outputs=["probe"])["probe"][-1], flush=True)
""")


def test_two_processes_that_need_a_new_engine_at_once_compile_it_once(tmp_path):
    import json
    import os

    env = {**os.environ, "REHAB_HIL_CACHE_DIR": str(tmp_path / "cache"),
           "REHAB_HIL_COMPILE_LOG": str(tmp_path / "compiles.jsonl")}
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", TWIN_CHILD, str(go)], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    assert [p.stdout.readline() for p in procs] == ["ready\n", "ready\n"]
    go.touch()  # both now reach the compilation together
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err[-2000:] for _, err in outs]
    assert outs[0][0] == outs[1][0]  # the same run: 0.613 cos(2 t) at t = 0.999 s
    assert abs(float(outs[0][0]) - 0.613 * np.cos(2 * 0.999)) < 1e-9
    rows = [json.loads(line) for line in (tmp_path / "compiles.jsonl").read_text().splitlines()]
    compiled_by = {r["pid"] for r in rows if r["module"].startswith("rehab_hil_")}
    assert rows and compiled_by <= {p.pid for p in procs}
    assert len(compiled_by) == 1, rows  # the other waited for it, then loaded it from the cache
