"""Load and validate ``configs/*.toml``: every error names the file and the dotted key.

Each plant declares its schema as pydantic models on these sections (strict types, no unknown
keys, no NaN or infinity, ranges as field constraints); ``rehab_hil.loading.load_config`` picks
the schema by the file's top-level ``plant`` key. Units are in the key names (``radius_m``).
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = [
    "ConfigError",
    "Field",
    "HostLimits",
    "MonitorSettings",
    "RigEstopSection",
    "RigHostSection",
    "RigLimitsSection",
    "RigLinkSection",
    "RigSection",
    "RigSessionSection",
    "RigThermalSection",
    "Section",
    "SimulationSection",
    "TwinSection",
    "load_toml",
    "model_validator",
    "validate",
]


class ConfigError(ValueError):
    """A configuration file is unreadable or invalid; the message names file and key."""

    def __init__(self, path: str | Path, key: str, message: str) -> None:
        self.path, self.key, self.message = str(path), key, message
        where = f"{self.path}: {key}: " if key else f"{self.path}: "
        super().__init__(where + message)


class Section(BaseModel):
    """Base of every config table: strict types, unknown keys refused, finite numbers only."""

    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False, frozen=True)


class SimulationSection(Section):
    """Fixed-step integration: the step is the one the real-time loop uses."""

    step_s: float = Field(gt=0.0, le=0.1, description="sample step of the simulation and loop [s]")
    substeps: int = Field(ge=1, le=100, description="RK4 substeps per sample step")


class RigLimitsSection(Section):
    """Host-side safety limits (the firmware enforces its own copy; see docs/configs.md)."""

    max_duty: float = Field(ge=0.0, le=1.0, description="largest PWM duty the host will command [0..1]")
    min_angle_deg: float = Field(ge=-360.0, le=360.0)
    max_angle_deg: float = Field(ge=-360.0, le=360.0)
    max_force_n: float = Field(gt=0.0, le=1000.0, description="contact-force trip level [N]")
    max_heating_s: float = Field(gt=0.0, le=600.0, description="longest continuous PWM-on time [s]")
    max_temperature_c: float = Field(gt=-50.0, le=300.0, description="estimated actuator temperature trip [C]")
    link_loss_periods: int = Field(ge=1, le=10000, description="missing samples before link loss")
    stuck_sensor_s: float = Field(ge=0.0, le=60.0, description="driving hard, far from the reference, and "
                                  "the encoder has not moved for this long: a stuck sensor [s] (0 = off)")
    stuck_min_duty: float = Field(ge=0.0, le=1.0, description="duty at or above which the rig counts as driving")
    stuck_min_error_deg: float = Field(gt=0.0, le=360.0, description="tracking error that counts as far")
    stuck_min_motion_deg: float = Field(gt=0.0, le=360.0, description="encoder motion that counts as moving")
    force_debounce_ms: int = Field(default=3, ge=1, le=255, description="the force limit trips after this many "
                                   "consecutive 1 kHz ticks (firmware) / this long (host) above it [ms]")

    @model_validator(mode="after")
    def _range(self) -> RigLimitsSection:
        if self.min_angle_deg >= self.max_angle_deg:
            raise ValueError("min_angle_deg must be below max_angle_deg")
        return self


class RigHostSection(Section):
    """The host loop's own settings: estimation and how far inside the firmware's limits it trips."""

    velocity_filter_hz: float = Field(gt=0.0, le=500.0, description="cutoff of the encoder velocity filter [Hz]")
    angle_margin_deg: float = Field(ge=0.0, le=90.0, description="host trips this far inside the range of motion")
    force_margin_n: float = Field(ge=0.0, le=100.0, description="host trips this far below max_force_n")
    heating_margin_s: float = Field(ge=0.0, le=60.0, description="host trips this long before max_heating_s")


class RigThermalSection(Section):
    """The host's own actuator temperature estimate, for a plant whose model has no heated actuator (the
    Finger Extensor's winding): first order from the PWM history, tau dT/dt = T0 + rise*duty - T, or two
    modes. A plant that models its actuator's heat (the SMA wire, the TCP coil) has one thermal model, its
    own (``plants/thermal.py``): the safety uses it, and a model here is refused (``loading.py``).

    Where a thermistor is wired (an ADC channel whose signal ends in ``_c``), the supervisor trips
    on the measured temperature too and on a disagreement with the estimate (broken sensor or
    wrong model): ``max_disagreement_c`` and ``disagreement_s`` hold for either estimate."""

    ambient_c: float | None = Field(default=None, ge=-50.0, le=100.0, description="the room [C]")
    rise_at_full_duty_c: float | None = Field(default=None, ge=0.0, le=10000.0, description="equilibrium rise at "
                                              "duty 1 [C] (may exceed any real temperature: a coil that would melt "
                                              "long before)")
    time_constant_s: float | None = Field(default=None, gt=0.0, le=3600.0)
    second_rise_at_full_duty_c: float = Field(default=0.0, ge=-10000.0, le=10000.0, description="a second mode's "
                                              "equilibrium rise at duty 1 (an identified second-order transfer "
                                              "function; may be negative) [C]")
    second_time_constant_s: float | None = Field(default=None, gt=0.0, le=3600.0, description="its time constant "
                                                 "[s]; unset: one mode")
    max_disagreement_c: float = Field(default=25.0, gt=0.0, le=500.0, description="measured vs estimated "
                                      "temperature beyond this is a fault (sensor or model) [C]")
    disagreement_s: float = Field(default=1.0, gt=0.0, le=600.0, description="for this long [s]")

    @model_validator(mode="after")
    def _whole_model(self) -> RigThermalSection:
        given = [k for k in MODEL_KEYS if getattr(self, k) is not None]
        if given and len(given) < len(MODEL_KEYS):
            missing = next(k for k in MODEL_KEYS if getattr(self, k) is None)
            raise ValueError(f"{missing} is missing: a first-order estimate needs {', '.join(MODEL_KEYS)} "
                             f"(given: {', '.join(given)})")
        return self

    @property
    def has_model(self) -> bool:
        """Whether the table holds an estimate (else only the thermistor's disagreement settings)."""
        return self.rise_at_full_duty_c is not None


MODEL_KEYS = ("ambient_c", "rise_at_full_duty_c", "time_constant_s")  # [rig.thermal]'s first-order estimate


class RigEstopSection(Section):
    """The e-stop input (D4, INPUT_PULLUP). A normally-closed loop holds D4 low through the switch, so
    a pressed button and a broken wire both read high, both a stop (IEC 60204-1 / ISO 13850:
    emergency-stop circuits fail to the stopped state); a normally-open button cannot tell a
    broken wire from "released"."""

    enabled: bool = Field(description="the firmware trips ESTOP_INPUT and the host trips estop_input")
    normally_closed: bool = Field(default=True, description="loop wiring: true = pin high is a stop")


class RigLinkSection(Section):
    """The simulated link between host and a simulated device (docs/loop.md, "The link"): an Uno's
    ATmega16U2 running Arduino-usbserial forwards UART bytes to USB when its 4.096 ms Timer0 flush
    fires or more than 96 bytes wait (Arduino-usbserial.c: BUFFER_NEARLY_FULL, TOV0 at 16 MHz/256/256);
    USB bulk OUT reaches the 16U2 once per 1 ms full-speed frame; opening the port pulses DTR, which
    resets the 328P into optiboot (silent, PWM pins floating) before the sketch says HELLO."""

    usb_bridge: bool = Field(description="model the 16U2 bridge (false: bytes pass at once)")
    to_host_flush_ms: float = Field(default=4.096, gt=0.0, le=100.0, description="16U2 UART->USB flush period [ms]")
    to_host_flush_bytes: int = Field(default=96, ge=1, le=4096, description="16U2 flushes early above this [B]")
    to_device_frame_ms: float = Field(default=1.0, gt=0.0, le=100.0, description="USB OUT delivery period [ms]")
    jitter_ms: float = Field(default=0.0, ge=0.0, le=100.0, description="extra uniform 0..jitter delay per "
                             "flush (host USB stack scheduling) [ms]")
    auto_reset: bool = Field(default=True, description="opening the port resets the device (DTR, Uno auto-reset)")
    bootloader_ms: float = Field(default=1000.0, ge=0.0, le=10_000.0, description="optiboot's wait after an "
                                 "external reset before the sketch runs (WATCHDOG_1S in optiboot.c) [ms]")


class RigSessionSection(Section):
    """What ``rehab-hil run`` does: open-close cycles (seed 000: 5 per minute) and the controller
    that follows them (a module of ``rehab_hil.controllers``, its settings in ``[controllers.<name>]``)."""

    controller: str = Field(min_length=1, description="the session's controller: model_based, pid, "
                            "open_loop_map, pulsed (rehab_hil.controllers)")
    cycles_per_minute: float = Field(gt=0.0, le=120.0)
    closed_deg: float = Field(ge=-360.0, le=360.0)
    open_deg: float = Field(ge=-360.0, le=360.0)
    move_fraction: float = Field(gt=0.0, lt=0.5, description="share of a cycle spent on each move")
    step_deg: float = Field(ge=-360.0, le=360.0, description="target of --reference step")


@dataclass(frozen=True)
class HostLimits:
    """What the host trips at: ``[rig.limits]`` less the ``[rig.host]`` margins, so the host acts
    before the firmware (which keeps the limits as written). ``RigSection.host_limits`` makes it."""

    min_angle_deg: float
    max_angle_deg: float
    max_force_n: float
    max_heating_s: float  # at least one loop period: a margin never leaves no heating at all


class RigSection(Section):
    """How the host reaches the device and how fast the loop runs."""

    port: str = Field(min_length=1, description='serial device path, or "sim" / "avr" for simulated devices')
    baud: int = Field(ge=9600, le=4_000_000, description="serial baud rate [bit/s]")
    sample_rate_hz: float = Field(gt=0.0, le=2000.0, description="device sample and loop rate [Hz]")
    watchdog_ms: int = Field(ge=5, le=10_000, description="firmware watchdog: PWM off without a command [ms]")
    write_timeout_ms: int = Field(default=200, ge=1, le=60_000, description="a serial write blocked this long "
                                  "(the device is not reading) is a lost link [ms]")
    limits: RigLimitsSection
    host: RigHostSection | None = None
    thermal: RigThermalSection | None = None
    session: RigSessionSection | None = None
    estop: RigEstopSection | None = None
    link: RigLinkSection | None = None
    force_calibration: str | None = Field(default=None, min_length=1,
                                          description="the force sensor's calibration file (rehab-hil calibrate "
                                                      "force), relative to this config file's directory")

    def host_limits(self) -> HostLimits:
        """The limits less the host's margins (none without ``[rig.host]``); the one place they are taken."""
        lim, host = self.limits, self.host
        am = host.angle_margin_deg if host else 0.0
        fm = host.force_margin_n if host else 0.0
        hm = host.heating_margin_s if host else 0.0
        return HostLimits(min_angle_deg=lim.min_angle_deg + am, max_angle_deg=lim.max_angle_deg - am,
                          max_force_n=max(lim.max_force_n - fm, 0.0),
                          max_heating_s=max(lim.max_heating_s - hm, 1.0 / self.sample_rate_hz))

    def unreachable_temperature(self) -> str | None:
        """Why ``limits.max_temperature_c`` can never fire (the estimate levels off below it), or None."""
        th = self.thermal
        if th is None or not th.has_model:
            return None
        rise = th.rise_at_full_duty_c + (th.second_rise_at_full_duty_c if th.second_time_constant_s else 0.0)
        ceiling = th.ambient_c + rise * self.limits.max_duty
        if self.limits.max_temperature_c < ceiling:
            return None
        return (f"{self.limits.max_temperature_c} C is unreachable: the thermal estimate levels off at "
                f"rig.thermal.ambient_c + rise_at_full_duty_c x rig.limits.max_duty = {ceiling:.1f} C, so the "
                "temperature trip could never fire; set it below that")


@dataclass(frozen=True)
class MonitorSettings:
    """The knobs of the twin's residual test (``rehab_hil.twin.monitor``), as ``TwinSection.monitor``
    hands them over; defined beside the table that sets them, so the schema imports no twin."""

    learn_s: float = 10.0  # the normal residual level is learned over this long
    settle_s: float = 1.0  # ... after this much of the session (the first anchoring, homing)
    drift_sigma: float = 4.0  # allowed excess over the normal level, in its spreads
    min_excess_counts: float = 0.4  # ... and at least this many counts (a noiseless simulation has no spread)
    threshold_counts: float = 1.5  # the CUSUM's alarm level, in counts x segments


class TwinSection(Section):
    """The live twin (docs/twin.md): the plant model beside the rig, its residual test and the
    online estimate of the patient's interaction parameters."""

    enabled: bool = Field(False, description="run the twin in every `rehab-hil run` (also: run --twin)")
    segment_s: float = Field(0.25, gt=0.0, le=5.0, description="re-anchoring period: each residual is what the "
                             "model got wrong in this long from a measured start [s]")
    channels: list[str] = Field(default_factory=list, description="measured outputs whose residual is tested "
                                "(default: every output the rig measures)")
    learn_s: float = Field(10.0, gt=0.0, description="the normal residual level is learned over this long [s]")
    settle_s: float = Field(1.0, ge=0.0, description="... starting this long into the session [s]")
    drift_sigma: float = Field(4.0, gt=0.0, description="allowed excess over the normal level, in its spreads")
    min_excess_counts: float = Field(0.4, ge=0.0, description="... and at least this many sensor counts")
    threshold_counts: float = Field(1.5, gt=0.0, description="CUSUM alarm level [counts x segments]")
    stop_on_mismatch: bool = Field(False, description="a model mismatch trips the rig into its safe state "
                                   "(default: an event only)")
    diagnose: bool = Field(True, description="name the likeliest cause of a mismatch on the recent window")
    diagnose_window_s: float = Field(5.0, gt=0.5, le=30.0, description="data after the change the diagnosis "
                                     "fits on [s]")
    estimate: list[str] = Field(default_factory=list, description="interaction parameters estimated online, as "
                                "diagram parameters (part.param) or effect parameters (effect.param); default: "
                                "the contact's stiffness and damping when the model has a contact")
    estimate_segment_s: float | None = Field(None, gt=0.0, le=5.0, description="re-anchoring period of the online "
                                             "estimate's own model [s] (default: segment_s); a slow plant's "
                                             "monitor may look over longer segments than its estimate needs")
    forgetting_s: float = Field(2.0, gt=0.0, description="memory of the online estimate (RLS forgetting) [s]")
    patient_torque: bool = Field(True, description="estimate the patient's torque on the joint from the model and "
                                 "the rig's angle and force sensors, per move (twin/patient_torque.py)")
    thermal: list[str] | None = Field(None, description="thermal quantities estimated online, as config keys "
                                      "(sma.ambient_c, sma.h1_w_per_m2_c, drive.supply_voltage_v; the TCP's "
                                      "muscle.max_power_w ...); default: every one the plant's model has "
                                      "(twin/thermal.py); [] turns the thermal estimate off")
    thermal_window_s: float | None = Field(None, gt=0.0, le=600.0, description="the thermal estimate fits its "
                                           "model over windows this long [s] (default: the session's open-close "
                                           "cycle, else 12 s)")
    thermal_memory_s: float = Field(60.0, gt=0.0, description="memory of the thermal estimate across windows "
                                    "(forgetting exp(-window / memory)) [s]")
    min_realtime_factor: float = Field(5.0, gt=0.0, description="the model must run this many times faster than "
                                       "real time here, per model run a segment needs (the twin, the estimate and "
                                       "one per estimated parameter), or the twin is refused at start")

    def monitor(self) -> MonitorSettings:
        return MonitorSettings(learn_s=self.learn_s, settle_s=self.settle_s, drift_sigma=self.drift_sigma,
                               min_excess_counts=self.min_excess_counts, threshold_counts=self.threshold_counts)


T = TypeVar("T", bound=BaseModel)


def _dotted(loc: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in loc)


def _message(err: dict[str, Any]) -> str:
    kind = err["type"]
    if kind == "missing":
        return "missing key"
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "finite_number":
        return "must be a finite number (no nan or inf)"
    got = err.get("input")
    msg = err["msg"]
    if kind.endswith("_type"):
        return f"wrong type: {msg.lower()}, got {type(got).__name__} {got!r}"
    return f"{msg.lower()} (got {got!r})" if not isinstance(got, dict) else msg.lower()


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; unreadable or malformed files raise ``ConfigError``."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(path, "", "file not found") from None
    except OSError as e:
        raise ConfigError(path, "", f"cannot read: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, "", f"not valid TOML: {e}") from None
    except UnicodeDecodeError as e:  # TOML is UTF-8; found by tests/fuzz/test_config_fuzz.py
        raise ConfigError(path, "", f"not valid TOML: not UTF-8 at byte {e.start}") from None


def validate(path: str | Path, data: dict[str, Any], schema: type[T], prefix: str = "") -> T:
    """Validate ``data`` against ``schema``; the first error becomes a ``ConfigError`` (its key
    after ``prefix``, the table ``data`` sits in). An unknown key is reported before the missing
    one it was probably meant to be (a typo), with the closest known key."""
    _reject_non_finite(path, data, ())
    try:
        model = schema.model_validate(data)
    except ValidationError as e:
        errs = sorted(e.errors(), key=lambda err: err["type"] != "extra_forbidden")
        first = errs[0]
        key = _dotted(first["loc"])
        hint = _typo_hint(first, errs)
        raise ConfigError(path, prefix + key, _message(first) + hint + _also(errs[1:], prefix, hint)) from None
    rig = getattr(model, "rig", None)
    if isinstance(rig, RigSection) and (why := rig.unreachable_temperature()):
        raise ConfigError(path, "rig.limits.max_temperature_c", why)
    return model


def _also(rest: list[dict[str, Any]], prefix: str, hint: str) -> str:
    """Every further error on the same line, each with its key (none hidden behind a count); a
    missing key the typo hint already names is not repeated."""
    parts = [f"{prefix}{_dotted(err['loc'])}: {_message(err)}" for err in rest
             if not (err["type"] == "missing" and repr(str(err["loc"][-1])) in hint)]
    return f"; also {'; '.join(parts)}" if parts else ""


def _typo_hint(first: dict[str, Any], errs: list[dict[str, Any]]) -> str:
    """For an unknown key: the missing key of the same table it most resembles."""
    if first["type"] != "extra_forbidden":
        return ""
    table, name = first["loc"][:-1], str(first["loc"][-1])
    missing = [str(e["loc"][-1]) for e in errs if e["type"] == "missing" and e["loc"][:-1] == table]
    close = difflib.get_close_matches(name, missing, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _reject_non_finite(path: str | Path, data: Any, loc: tuple[Any, ...]) -> None:
    # pydantic accepts nan for a float field that is only range-checked in some modes: refuse early.
    if isinstance(data, dict):
        for k, v in data.items():
            _reject_non_finite(path, v, (*loc, k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            _reject_non_finite(path, v, (*loc, i))
    elif isinstance(data, float) and not math.isfinite(data):
        raise ConfigError(path, _dotted(loc), f"must be a finite number, got {data!r}")
