"""The typed rig contract, in the spirit of ros2_control's state and command interfaces.

A plant's rig binding declares what the device measures (state interfaces: a model signal, its
physical kind and SI unit, and the hardware source that carries it) and what the host commands
(command interfaces: a model input driven by a PWM channel). Controllers claim the interfaces
they use; ``on_configure`` checks the claims against the binding and the device's HELLO. The
interface types themselves live in ``rehab_hil.interfaces`` (no rig imports, so plants can use
them) and are re-exported here.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import Protocol

from rehab_hil.hardware.interface import HardwareError
from rehab_hil.interfaces import Claims, CommandInterface, StateInterface
from rehab_hil.interfaces import Source as Source  # the Literal aliases stay importable from here
from rehab_hil.interfaces import StateKind as StateKind
from rehab_hil.protocol import PROTOCOL_VERSION, Hello

__all__ = ["Binding", "Claims", "CommandInterface", "ContractError", "StateInterface", "on_configure"]


class ContractError(HardwareError):
    """The device, the plant's binding and the controllers' claims do not fit together."""


class Binding(Protocol):
    """What ``on_configure`` reads of a plant's rig binding (``rehab_hil.interfaces.DeviceBinding``)."""

    @property
    def state_interfaces(self) -> tuple[StateInterface, ...]: ...

    @property
    def command_interfaces(self) -> tuple[CommandInterface, ...]: ...

    @property
    def encoder_counts_per_rev(self) -> int: ...


def on_configure(binding: Binding, hello: Hello | None, claims: Claims | Iterable[Claims] = ()) -> None:
    """Check the device's HELLO and the controllers' claims against the binding before anything
    moves; raises ``ContractError`` with one line naming what differs.

    The HELLO must speak this host's protocol version and have a PWM channel for every command
    interface and an ADC input for every ADC state interface; the binding's encoder resolution must
    fit CONFIGURE (the device adopts it there, whatever its HELLO said before; a build pinned to
    another encoder refuses that CONFIGURE). Each claimed interface must exist, and no command
    interface may be claimed twice."""
    if hello is None:
        raise ContractError("contract: no HELLO from the device (connect first)")
    if hello.protocol_version != PROTOCOL_VERSION:
        raise ContractError(f"contract: the device speaks protocol v{hello.protocol_version}, "
                            f"this host v{PROTOCOL_VERSION} (firmware {hello.fw_major}.{hello.fw_minor}."
                            f"{hello.fw_patch})")
    commands, states = binding.command_interfaces, binding.state_interfaces
    for ci in commands:
        if ci.channel >= hello.n_pwm:
            raise ContractError(f"contract: command interface {ci.name} needs PWM channel {ci.channel}, "
                                f"the device has {hello.n_pwm} PWM channel(s)")
    for si in states:
        if si.source.startswith("adc") and int(si.source[3:]) >= hello.n_adc:
            raise ContractError(f"contract: state interface {si.name} needs ADC input {si.source[3:]}, "
                                f"the device has {hello.n_adc} ADC input(s)")
    if any(si.source == "encoder" for si in states):
        _check_encoder(binding.encoder_counts_per_rev)
    command_names = [ci.name for ci in commands]
    state_names = [si.name for si in states]
    owner: dict[str, int] = {}
    for i, c in enumerate([claims] if isinstance(claims, Claims) else list(claims)):
        for name in c.command:
            if name not in command_names:
                raise ContractError(f"contract: a controller claims command interface {name!r}, which the "
                                    f"binding does not provide{_closest(name, command_names)}")
            if owner.setdefault(name, i) != i:
                raise ContractError(f"contract: command interface {name!r} is claimed by two controllers")
        for name in c.state:
            if name not in state_names:
                raise ContractError(f"contract: a controller claims state interface {name!r}, which the "
                                    f"binding does not provide{_closest(name, state_names)}")


def _check_encoder(binding_cpr: int) -> None:
    """The encoder is the rig's, not the firmware build's: CONFIGURE carries the binding's counts per
    revolution and the device adopts it (HELLO reports it from then on), so a different value in
    HELLO (0 before the first CONFIGURE, or an earlier session's) is no mismatch. Only a resolution
    CONFIGURE's 16-bit field cannot carry is refused."""
    if not 0 < binding_cpr <= 0xFFFF:
        raise ContractError(f"contract: the binding's {binding_cpr} encoder counts/rev do not fit CONFIGURE's "
                            "16-bit field (1..65535)")


def _closest(name: str, known: list[str]) -> str:
    near = difflib.get_close_matches(name, known, n=1)
    return f" (did you mean {near[0]!r}?); provided: {known}" if near else f"; provided: {known}"
