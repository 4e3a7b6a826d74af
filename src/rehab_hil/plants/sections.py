"""The config tables every plant file shares (``PlantConfig``: plant, simulation, rig, effects,
changes, controllers, twin) and the sensor tables plants declare (encoder, force sensor).

A plant's own schema subclasses ``PlantConfig``; ``rehab_hil.loading`` picks it by the file's
``plant`` key. Names and bounds of ``[[effects]]`` are those of ``rehab_hil.effects``.
"""

from __future__ import annotations

from typing import Any, Literal

from rehab_hil.config import Field, RigSection, Section, SimulationSection, TwinSection, model_validator
from rehab_hil.control.cascade import RecordedControllerSection
from rehab_hil.effects import check_spec
from rehab_hil.importing import ImportMapping
from rehab_hil.models.schedule import Timing

__all__ = ["ChangeSpec", "EffectSpec", "EncoderSection", "ForceSensorSection", "PlantConfig"]


class EffectSpec(Section):
    """One added model effect (``[[effects]]`` tables): a library name and its parameters.

    Written by ``rehab-hil discrepancy`` into ``augmented.toml``; names and bounds are those of
    ``rehab_hil.effects`` (docs/discrepancy.md)."""

    name: str = Field(min_length=1, description="effect name in the library, e.g. coulomb_friction")
    params: dict[str, float] = Field(default_factory=dict, description="parameter values, SI units in the keys")
    start_s: float = Field(0.0, ge=0.0, description="on a simulated rig: seconds from the session's start before "
                           "the effect acts (docs/models.md, changes during a session) [s]")
    ramp_s: float = Field(0.0, ge=0.0, description="on a simulated rig: seconds from start_s over which its "
                          "magnitudes grow linearly from off to params (0: at once) [s]")

    @model_validator(mode="after")
    def _known(self) -> EffectSpec:
        check_spec(self.name, self.params)
        return self

    @property
    def timing(self) -> Timing:
        return Timing(self.start_s, self.ramp_s)


class ChangeSpec(Section):
    """A plant parameter that changes mid-session on a simulated rig (``[[changes]]`` tables): a
    dotted key of the plant's config, its new value (a factor, or a value in the key's unit), and
    when. A patient's stiffness doubling at 30 s, the supply sagging 8 % (docs/models.md)."""

    key: str = Field(min_length=1, description="dotted config key of this plant, e.g. contact.stiffness_n_per_m")
    scale: float | None = Field(None, description="the new value is the config value times this factor")
    value: float | None = Field(None, description="the new value, in the key's unit")
    start_s: float = Field(0.0, ge=0.0, description="seconds from the session's start before the change [s]")
    ramp_s: float = Field(0.0, ge=0.0, description="seconds from start_s over which the value moves linearly "
                          "from the config value to the new one (0: at once) [s]")

    @model_validator(mode="after")
    def _one_target(self) -> ChangeSpec:
        if (self.scale is None) == (self.value is None):
            raise ValueError("give exactly one of scale (a factor) or value (the new value, in the key's unit)")
        return self

    @property
    def timing(self) -> Timing:
        return Timing(self.start_s, self.ramp_s)


class PlantConfig(Section):
    """What every plant file has: its plant name, the integration step, the rig and added effects.

    ``rehab_hil.loading.load_config`` returns the plant's own subclass, validated: the type a
    config travels under (``cfg: PlantConfig``); a plant's own tables are its subclass's."""

    plant: str
    simulation: SimulationSection
    rig: RigSection
    effects: list[EffectSpec] = Field(default_factory=list, description="added model effects")
    changes: list[ChangeSpec] = Field(default_factory=list, description="plant parameters that change mid-session "
                                      "on a simulated rig (docs/models.md)")
    controllers: dict[str, Any] = Field(default_factory=dict, description="controller settings, one "
                                        "[controllers.<name>] table per controller (rehab_hil.controllers)")
    recorded_controller: RecordedControllerSection | None = Field(None, description="the controller that produced "
                                                                  "this plant's closed-loop records: the discrepancy "
                                                                  "workflow replays the loop from the reference")
    import_: ImportMapping | None = Field(None, alias="import", description="how a lab's logger files map onto "
                                          "the model's signals (rehab_hil.importing; rehab-hil import)")
    twin: TwinSection | None = Field(None, description="the live twin: the model beside the rig, its residual "
                                     "test and the online interaction estimate (docs/twin.md)")


class EncoderSection(Section):
    """The rig's quadrature encoder (x4 edges) and its homing (``rehab-hil run --home``)."""

    counts_per_rev: int = Field(ge=4, le=65_535, description="encoder edges per revolution of its axis (CONFIGURE "
                                "and HELLO carry it in 16 bits)")
    direction: Literal[1, -1] = Field(1, description="+1: counts rise with the angle; -1: an encoder wired (or "
                                      "mounted) the other way round, so counts fall as the angle rises")
    home_angle_deg: float = Field(0.0, ge=-360.0, le=360.0, description="joint angle at the pose `--home current` "
                                  "zeroes at [deg]")
    hard_stop_deg: float | None = Field(None, ge=-360.0, le=360.0, description="joint angle at the closed mechanical "
                                        "stop `--home hard-stop` drives to [deg]; unset: no hard-stop homing")
    homing_duty: float = Field(0.05, gt=0.0, le=0.3, description="duty of the hard-stop homing drive (slow, low "
                               "torque) [0..1]")


class ForceSensorSection(Section):
    """A Flexiforce (or load cell) on an ADC input: counts = offset_counts + counts_per_n * force."""

    counts_per_n: float = Field(gt=0.0, le=10000.0, description="ADC counts per newton")
    offset_counts: float = Field(ge=0.0, le=1023.0, description="ADC counts at zero force")
