"""``rehab-hil monitor`` (every rig): a live rig's angle and analog value are shown even when its
last record of a batch is a command record, which carries no estimate (a real hub on loopback)."""

from __future__ import annotations

from collections.abc import Callable

import zenoh
from rich.console import Console

from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import CommandRecord, SampleRecord
from rehab_hil.protocol import Sample
from rehab_hil.telemetry.codec import encode_state
from rehab_hil.telemetry.lab_view import LabView, render_lab


def test_every_live_rig_shows_its_angle_when_a_batch_ends_in_a_command_record(
        client: Callable[..., zenoh.Session], wait: Callable[..., bool]) -> None:
    sample = SampleRecord(3.5, 0.002, Sample(9, 8, -7, 6, 5, 4, 3, 1, 2, 1, 0, 1),
                          State(0.002, 0.5, 0.0, {"torque_nm": 0.125}), Command((0.25, 0.0), 0, True, 30.0), 4, 40.5)
    command = CommandRecord(3.6, 0.003, Command((0.25, 0.0), 0, True, 30.0), 5, 40.5)
    view = LabView(client())
    publisher = client()
    try:
        publisher.put("rehab/rig7/state", encode_state([sample, command]))
        assert wait(lambda: view.snapshot() and view.snapshot()[0].records == 2)
        console = Console(width=200, record=True)
        console.print(render_lab(view.snapshot()))
        row = next(line for line in console.export_text().splitlines() if line.strip().startswith("rig7"))
        assert "28.6" in row  # 0.5 rad in degrees
        assert "0.125" in row and "30.0" in row  # the analog value and the reference
    finally:
        view.close()
