"""A lab's own controller, declared here and tested in the lab's CI on the simulated rig (docs/sessions.md)."""

from types import SimpleNamespace

from rehab_hil.controllers import Controller, ControllerSpec
from rehab_hil.controllers.pid import feedback_parts, limit_part
from rehab_hil.service.session import open_session


class GentlePD(ControllerSpec):
    """PD on the encoder angle with the lab's own gains, no integral action."""

    name = "gentle_pd"

    @classmethod
    def build(cls, ctx, settings, reference):
        gains = SimpleNamespace(kp_per_deg=0.2, ki_per_deg_s=0.0, kd_s_per_deg=0.004, derivative_filter_s=0.004)
        demand = f"{ctx.effort}_demand"
        parts = [reference.part(ctx.reference), *feedback_parts(ctx, gains, demand, ctx.effort_bounds),
                 limit_part(ctx, demand)]
        return Controller(cls.name, ctx, reference, parts, sums=(demand,))


def test_gentle_pd_follows_the_session_on_the_finger_extensor():
    with open_session("configs/finger_extensor.toml", "inprocess", controller="gentle_pd") as session:
        result = session.run(12.0)  # one open-close cycle of the config's session
    assert result.events == [] and result.pwm_off_at_end
    assert result.tracking["rmse"] < 5.0  # [deg]
