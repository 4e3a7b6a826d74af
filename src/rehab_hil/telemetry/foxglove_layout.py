"""The Foxglove layout for rig telemetry: angle vs reference, force/torque, duty, temperature, state,
and the live twin's prediction, residual and residual test (``rehab-hil run --twin``).

Built with the SDK's layout types (``foxglove.layouts``) on the plant-independent fields of the
``<prefix>/sample`` channel, so one layout fits every plant, the live server and MCAP recordings.
``python -m rehab_hil.telemetry.foxglove_layout > docs/foxglove_layout.json`` regenerates the shipped file;
``rehab-hil foxglove --layout-out FILE`` writes one for the rigs it bridges.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Sequence
from typing import Any

import foxglove.layouts as fl

from rehab_hil.telemetry.foxglove import topics
from rehab_hil.twin.outputs import prediction_topic

__all__ = ["layout", "layout_json", "message_paths"]


def _plot(title: str, series: list[tuple[str, str]], y_label: str) -> fl.PlotPanel:
    return fl.PlotPanel(title=title, config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=v, label=lab, timestamp_method="receiveTime") for v, lab in series],
        show_legend=True, y_axis_label=y_label, time_window_mode="automatic"))


def _rig_view(prefix: str, name: str) -> fl.SplitContainer:
    t = topics(prefix)
    s, e = t["sample"], t["event"]
    p = prediction_topic(prefix)
    tag = f"{name}: " if name else ""
    plots = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=_plot(f"{tag}angle vs reference", [(f"{s}.angle_deg", "angle"),
                                                                (f"{s}.reference_deg", "reference")], "deg")),
        fl.SplitItem(content=_plot(f"{tag}force / torque (first calibrated ADC signal)",
                                   [(f"{s}.analog0", "analog0")], "N or N m")),
        fl.SplitItem(content=_plot(f"{tag}duty", [(f"{s}.command_duty0_ratio", "commanded"),
                                                  (f"{s}.applied_duty0_ratio", "applied")], "ratio")),
        fl.SplitItem(content=_plot(f"{tag}estimated temperature",
                                   [(f"{s}.estimated_temperature_c", "temperature")], "C")),
    ])
    transitions = fl.StateTransitionsConfig(paths=[
        fl.StateTransitionsSeries(value=f"{s}.command_enable_bool", label="command enable"),
        fl.StateTransitionsSeries(value=f"{s}.status_bits", label="device status bits"),
        fl.StateTransitionsSeries(value=f"{s}.fault_bits", label="device fault bits"),
        fl.StateTransitionsSeries(value=f"{e}.kind", label="safety / link events")])
    state = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=fl.StateTransitionsPanel(title=f"{tag}state", config=transitions)),
        fl.SplitItem(proportion=1, content=fl.RawMessagesPanel(title=f"{tag}latest event",
                                                               config=fl.RawMessagesConfig(topic_path=e))),
    ])
    twin = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=_plot(f"{tag}twin: measured vs predicted angle",
                                   [(f"{p}.angle_measured_deg", "measured"), (f"{p}.angle_predicted_deg", "twin")],
                                   "deg")),
        fl.SplitItem(content=_plot(f"{tag}twin: angle residual", [(f"{p}.angle_residual_deg", "residual")], "deg")),
        fl.SplitItem(content=_plot(f"{tag}twin: residual test (CUSUM; an event above its threshold)",
                                   [(f"{p}.cusum_max_counts", "CUSUM")], "counts")),
    ])
    return fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=3, content=plots),
                                                     fl.SplitItem(proportion=2, content=twin),
                                                     fl.SplitItem(proportion=1, content=state)])


def layout(rigs: Sequence[tuple[str, str]] = (("/rig", ""),)) -> fl.Layout:
    """A layout for ``(prefix, name)`` rigs: one tab per rig when there are several."""
    if len(rigs) == 1:
        return fl.Layout(content=_rig_view(*rigs[0]))
    return fl.Layout(content=fl.TabContainer(tabs=[fl.TabItem(title=name, content=_rig_view(prefix, name))
                                                   for prefix, name in rigs]))


def layout_json(rigs: Sequence[tuple[str, str]] = (("/rig", ""),)) -> str:
    """The layout as indented JSON text (what Foxglove's "Import layout" reads)."""
    return json.dumps(json.loads(layout(rigs).to_json()), indent=2) + "\n"


_PATH = re.compile(r"^(/[A-Za-z0-9_./-]*?)(?:\.([A-Za-z0-9_]+))?$")


def message_paths(doc: Any) -> set[tuple[str, str | None]]:
    """Every (topic, field) a layout document names (values that look like ``/topic.field`` or ``/topic``)."""
    out: set[tuple[str, str | None]] = set()

    def walk(x: Any, key: str = "") -> None:
        if isinstance(x, dict):
            for k, v in x.items():
                walk(v, k)
        elif isinstance(x, list):
            for v in x:
                walk(v, key)
        elif isinstance(x, str) and x.startswith("/") and key in ("value", "topicPath", "xValuePath", "timestampPath"):
            m = _PATH.match(x)
            if m is None:
                raise ValueError(f"unreadable message path {x!r}")
            out.add((m.group(1), m.group(2)))

    walk(doc)
    return out


if __name__ == "__main__":  # pragma: no cover
    sys.stdout.write(layout_json())
