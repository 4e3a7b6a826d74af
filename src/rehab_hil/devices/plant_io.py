"""A plant model behind the rig's I/O: PWM duty in, encoder and ADC counts out (one 1 kHz tick at a time).

Built from a plant's ``DeviceBinding``; shared by the Python simulated device and the simavr
harness driver so both close the loop with the same model. A binding with a schedule (changes that
start mid-session, ``models/schedule.py``) has its values moved here, on device time: ticks since
the session's start (``start_session``: the device's accepted CONFIGURE; until then, power-on).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.models.system import Diagram
from rehab_hil.protocol import BASE_RATE_HZ, DUTY_FULL

__all__ = ["PlantIO"]

ADC_MAX = 1023


class PlantIO:
    """Steps the plant by one base tick with the applied duties; reads counts at the tick instant.

    ``tick(duty, direction)`` returns the readings at the start of the tick (the plant's state
    then) and advances the plant over the tick with those duties held (zero-order hold), with the
    scheduled values of the tick's start instant (session time, in ticks of 1 / BASE_RATE_HZ)."""

    def __init__(self, binding: DeviceBinding, adc_noise_counts: float = 0.0, seed: int = 0,
                 truth_signals: Sequence[str] = (), truth_sink: Callable[[float, np.ndarray], None] | None = None
                 ) -> None:
        if adc_noise_counts < 0 or not math.isfinite(adc_noise_counts):
            raise ValueError(f"adc_noise_counts must be a finite number >= 0, got {adc_noise_counts!r}")
        per_tick = 1.0 / BASE_RATE_HZ / binding.step_s
        self.steps_per_tick = round(per_tick)
        if self.steps_per_tick < 1 or abs(per_tick - self.steps_per_tick) > 1e-9:
            raise ValueError(f"plant step {binding.step_s} s must divide the device tick {1 / BASE_RATE_HZ} s")
        if len(binding.adc) > 2:
            raise ValueError(f"the device has 2 ADC inputs, the binding asks for {len(binding.adc)}")
        self.binding = binding
        inputs = (*binding.duty_inputs, *binding.constant_inputs)
        self.system = Diagram(binding.parts, inputs=inputs, sums=binding.sums).compile(binding.step_s,
                                                                                       binding.substeps)
        names = self.system.input_names
        known = set(binding.duty_inputs) | set(binding.constant_inputs)
        missing = [n for n in names if n not in known]
        if missing:
            raise ValueError(f"plant inputs {missing} are neither duty inputs nor constant inputs")
        self._index = {n: i for i, n in enumerate(names)}
        # a plant without an encoder port reads count 0 (the protocol always carries one)
        self._enc = 1 if binding.encoder_source else 0
        enc = [binding.encoder_source] if binding.encoder_source else []
        # an ADC sensor may measure a plant input (the Finger Extensor's patient torque): read it there
        self._adc_input = [self._index.get(a.source, -1) if a.source not in self.system.diagram.producers else -1
                           for a in binding.adc]
        read = [*enc, *(a.source for a, i in zip(binding.adc, self._adc_input, strict=True) if i < 0)]
        # a simulated patient's true state (``patient/``): read beside the sensors, handed to ``truth_sink``
        self._n_truth = len(truth_signals)
        self.truth_sink = truth_sink
        self.stepper = self.system.stepper([*read, *truth_signals])
        self._clock = self._index.get("session_time_s", -1)  # a part that runs on the session's clock
        self._u = np.zeros(len(names))
        for name, value in binding.constant_inputs.items():
            self.set_input(name, value)
        self._scale = {name: d.scale for name, d in binding.duty_inputs.items()}  # full-duty values
        self.schedule = binding.schedule
        self.session_ticks = 0  # device ticks since the session's start
        self._alpha = [0.0] * len(self.schedule.items) if self.schedule else []
        self._next_change = self._first_change()
        self.noise = adc_noise_counts
        self._rng = np.random.default_rng(seed)
        self.sensor_load = [0.0, 0.0]  # a known load on each ADC sensor (its unit), on top of the plant's
        # a rig with direction -1 has its encoder wired the other way: its counts fall as the angle rises
        self._counts_per_rad = binding.encoder_direction * binding.encoder_counts_per_rev / (2.0 * math.pi)
        # what each tick reads, resolved once (the tick is the in-process session's hottest Python)
        self._duty = [(self._index[name], d.channel, d.signed, name) for name, d in binding.duty_inputs.items()]
        outs = iter(range(self._enc, self._enc + len(binding.adc)))  # the outputs after the encoder, in order
        self._adc = [(k, i, -1 if i >= 0 else next(outs), ch.offset_counts, ch.counts_per_unit)
                     for k, (ch, i) in enumerate(zip(binding.adc, self._adc_input, strict=True))]

    def set_input(self, name: str, value: float) -> None:
        """Set a constant plant input (e.g. the patient's torque); unknown names raise KeyError."""
        if name not in self._index:
            raise KeyError(f"unknown plant input {name!r}; inputs: {sorted(self._index)}")
        if not math.isfinite(value):
            raise ValueError(f"input {name} must be finite, got {value!r}")
        self._u[self._index[name]] = value

    def reset(self) -> None:
        """Back to the power-on state: the plant's initial state and the session clock at 0."""
        self.stepper.reset()
        self.start_session()

    def start_session(self) -> None:
        """The session starts now (a device calls it on an accepted CONFIGURE): scheduled changes
        count their start_s from here, and every scheduled value goes back to its start value."""
        self.session_ticks = 0
        if self.schedule is not None:
            s = self.schedule
            for k, item in enumerate(s.items):
                self._alpha[k] = 0.0
                self.stepper.params[item.param_index] = s.params[item.param_index]
                for name in item.input_delta:
                    self._u[self._index[name]] = s.inputs[name]
                for name in item.scale_delta:
                    self._scale[name] = s.scales[name]
        self._next_change = self._first_change()

    def _first_change(self) -> float:
        """The first session tick at which a scheduled value may move (inf: none)."""
        if not self.schedule:
            return math.inf
        return min(math.ceil(item.timing.start_s * BASE_RATE_HZ - 1e-9) for item in self.schedule.items)

    def _apply_schedule(self) -> None:
        """Move every scheduled value to session time ``session_ticks``; note when to look again."""
        assert self.schedule is not None
        s, t = self.schedule, self.session_ticks / BASE_RATE_HZ
        nxt = math.inf
        for k, item in enumerate(s.items):
            a = item.timing.alpha(t)
            if a != self._alpha[k]:
                self._alpha[k] = a
                self.stepper.params[item.param_index] = s.params[item.param_index] + a * item.param_delta
                for name, d in item.input_delta.items():
                    self._u[self._index[name]] = s.inputs[name] + a * d
                for name, d in item.scale_delta.items():
                    self._scale[name] = s.scales[name] + a * d
            if a < 1.0:  # still to move: at its start, or (ramping) at the next tick
                start = math.ceil(item.timing.start_s * BASE_RATE_HZ - 1e-9)
                nxt = min(nxt, max(start, self.session_ticks + 1))
        self._next_change = nxt

    def set_sensor_load(self, channel: int, value: float) -> None:
        """Put a known load on ADC ``channel``'s sensor (in its unit, e.g. N for a calibration weight),
        added to what the plant puts there; 0 takes it off."""
        if channel not in range(len(self.binding.adc)):
            raise ValueError(f"ADC channel {channel}: this rig has {len(self.binding.adc)} ADC sensor(s)")
        if not math.isfinite(value):
            raise ValueError(f"load must be finite, got {value!r}")
        self.sensor_load[channel] = value

    def tick(self, duty: tuple[int, int] | list[int], direction: int) -> tuple[int, int, int]:
        """Readings (encoder count, adc0, adc1) at this instant, then advance one tick."""
        ticks = self.session_ticks
        if ticks >= self._next_change:
            self._apply_schedule()
        u = self._u
        if self._clock >= 0:
            u[self._clock] = ticks / BASE_RATE_HZ
        self.session_ticks = ticks + 1
        scale = self._scale
        for index, channel, signed, name in self._duty:
            # the input's own sign (DutyInput.direction_sign); its full-duty value may move mid-session (a sagging
            # supply)
            sign = -1.0 if signed and direction >> channel & 1 else 1.0
            u[index] = sign * scale[name] * duty[channel] / DUTY_FULL
        stepper = self.stepper
        y = stepper.advance(u)  # the stepper's own buffer: read before the next step
        if self.steps_per_tick > 1:
            y = y.copy()
            for _ in range(self.steps_per_tick - 1):
                stepper.advance(u)
        if self.truth_sink is not None and self._n_truth:
            self.truth_sink(ticks / BASE_RATE_HZ, y[-self._n_truth:])
        return self._counts(y.tolist())

    def _counts(self, y: list[float]) -> tuple[int, int, int]:
        enc = math.floor(y[0] * self._counts_per_rad) if self._enc else 0
        adc = [0, 0]
        u, load, noise = self._u, self.sensor_load, self.noise
        for k, i_input, i_out, offset, per_unit in self._adc:
            value = float(u[i_input]) if i_input >= 0 else y[i_out]
            v = offset + per_unit * (value + load[k])
            if noise:
                v += self._rng.normal(0.0, noise)
            adc[k] = int(min(max(round(v), 0), ADC_MAX)) if math.isfinite(v) else ADC_MAX
        return enc, adc[0], adc[1]
