"""A new controller is one module plus config keys (docs/controllers.md): a thermostat on the angle,
declared here without touching any other module, runs offline with the plant model and on the rig."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.config import Field, Section
from rehab_hil.controllers import ControlContext, Controller, ControllerSpec, Reference, build_controller, closed_loop
from rehab_hil.controllers.pid import limit_part
from rehab_hil.interfaces import Claims
from rehab_hil.loading import load_config
from rehab_hil.models.system import Part, njit
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS

from .conftest import with_text


class Thermostat(Part):
    """Full effort while the angle is more than ``band_deg`` below the reference, none once it is
    above it; in between the last decision holds (a discrete state: hysteresis)."""

    inputs = ("reference", "measurement")
    discrete_states = ("on",)
    outputs = ("effort",)
    params = ("effort_on", "band_deg")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        e = u[0] - u[1]
        on = 1.0 if e > p[1] else (0.0 if e < -p[1] else xd[0])
        y[0] = p[0] * on

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        e = u[0] - u[1]
        xd_next[0] = 1.0 if e > p[1] else (0.0 if e < -p[1] else xd[0])


class ThermostatSettings(Section):
    effort_on: float = Field(gt=0.0, le=1000.0, description="effort while on [actuator unit]")
    band_deg: float = Field(gt=0.0, le=30.0, description="half the hysteresis band [deg]")


class ThermostatController(ControllerSpec):
    name = "thermostat"
    summary = "on-off on the encoder angle with a hysteresis band"
    settings = ThermostatSettings

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        return "it only heats: the actuator must be one-sided" if ctx.signed else None

    @classmethod
    def build(cls, ctx: ControlContext, settings: ThermostatSettings, reference: Reference) -> Controller:
        demand = f"{ctx.effort}_demand"
        parts = [reference.part(ctx.reference),
                 Thermostat("thermostat", connect={"reference": ctx.reference, "measurement": ctx.angle},
                            rename={"effort": demand}, effort_on=settings.effort_on, band_deg=settings.band_deg),
                 limit_part(ctx, demand)]
        return Controller(cls.name, ctx, reference, parts, sums=(demand,))


TABLE = "\n[controllers.thermostat]\neffort_on = 0.5\nband_deg = 1.0\n"


@pytest.fixture
def config(tmp_path):
    return with_text(CONFIGS / "sma_exoskeleton.toml", tmp_path / "sma.toml", TABLE)


def test_a_declared_controller_is_found_by_its_name_and_its_table_is_checked(config, tmp_path):
    cfg = load_config(config)
    assert cfg.controllers["thermostat"].effort_on == 0.5
    bad = with_text(CONFIGS / "sma_exoskeleton.toml", tmp_path / "bad.toml", TABLE.replace("1.0", "-1.0"))
    with pytest.raises(ValueError, match=r"bad\.toml: controllers\.thermostat\.band_deg: input should be greater"):
        load_config(bad)
    with pytest.raises(ValueError, match="only heats"):
        build_controller(load_config(CONFIGS / "finger_extensor.toml").model_copy(
            update={"controllers": {"thermostat": ThermostatSettings(effort_on=1.0, band_deg=1.0)}}), "thermostat")


def test_it_runs_offline_with_the_plant_model_and_holds_the_bend_inside_its_band(config):
    cfg = load_config(config)
    ctl = build_controller(cfg, "thermostat")
    assert ctl.claims == Claims(command=("pwm_duty",), state=("theta_mcp_rad",))
    ref = ctl.reference
    res = closed_loop(ctl, ref.first_open_s + ref.period_s)
    hold = (res.t > ref.first_open_s + ref.move_s + 1.0) & (res.t < ref.first_open_s + ref.move_s + ref.hold_open_s)
    err = res[ctl.ctx.reference][hold] - res[ctl.ctx.angle][hold]
    assert np.abs(err).max() < 3.0  # the wire's lag adds a little to the 1 deg band
    assert set(np.unique(np.round(res[ctl.ctx.effort], 6))) <= {0.0, 0.5}


def test_it_runs_on_the_rig_through_the_loop(config):
    with open_session(config, "inprocess", controller="thermostat") as session:
        res = session.run(8.0)
    assert res.events == [] and res.pwm_off_at_end
    assert res.tracking["max_abs_error"] < 40.0 and res.final_sample is not None
