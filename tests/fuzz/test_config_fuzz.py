"""Fuzzing the config loader (``rehab_hil.config.load_config``) with hypothesis.

A rig is configured by hand-edited TOML files: whatever the file holds (a typo, a wrong type, a
deleted line, random bytes, an added ``[[effects]]`` table), ``load_config`` either returns the
validated model or raises ``ConfigError`` naming the file, never another exception. For a scalar
given the wrong type, the error also names the dotted key (checked exhaustively over every key).
"""

from __future__ import annotations

import re
import tempfile
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from rehab_hil.config import ConfigError
from rehab_hil.loading import load_config

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
TEXTS = {p.name: p.read_bytes() for p in CONFIGS}
FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
KEY_LINE = re.compile(rb"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)(.*)$")
HEADER = re.compile(rb"^\s*\[([A-Za-z0-9_.]+)\]")


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="cfgfuzz-") as d:
        yield Path(d) / "rig.toml"


def load_or_config_error(path: Path, data: bytes) -> BaseModel | ConfigError:
    """Write ``data`` and load it; any exception other than ConfigError fails the test."""
    path.write_bytes(data)
    try:
        return load_config(path)
    except ConfigError as e:
        assert e.path == str(path)
        assert str(e).startswith(str(path))
        return e


toml_values = st.one_of(
    st.integers(-(2**63), 2**63 - 1).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),  # repr gives TOML's inf / nan spellings
    st.sampled_from(["true", "false", "nan", "-inf", "+inf", "0", "-0.0", "1e308", "1e-320", "[]", "{}",
                     '""', '"sim"', "[1, 2]", '["a", 1.5]', "{ a = 1 }", "1979-05-27T07:32:00Z", "07:32:00",
                     "0x1F", "0o17", "0b101", "1_000", "'''x'''", '"\\u0000"', "[[1], [2.5]]"]),
    st.text(max_size=12).map(lambda s: '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'),
)


@st.composite
def mutated_configs(draw: st.DrawFn) -> bytes:
    lines = TEXTS[draw(st.sampled_from(sorted(TEXTS)))].split(b"\n")
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["value", "value", "delete", "duplicate", "bytes", "rename", "effects"]))
        m = KEY_LINE.match(lines[i])
        if kind == "value" and m:
            lines[i] = m.group(1) + m.group(2) + m.group(3) + draw(toml_values).encode("utf-8", "surrogatepass")
        elif kind == "delete":
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "rename" and m:
            lines[i] = m.group(1) + m.group(2) + b"x" + m.group(3) + m.group(4)
        elif kind == "effects":
            name = draw(st.sampled_from(["coulomb_friction", "backlash", "dead_zone", "sensor_delay",
                                         "no_such_effect", ""]))
            params = ", ".join(f"{k} = {draw(toml_values)}" for k in
                               draw(st.lists(st.sampled_from(["level_nm", "width_deg", "delay_s", "x"]),
                                             unique=True, max_size=2)))
            lines.append(f'[[effects]]\nname = "{name}"\nparams = {{ {params} }}'.encode())
        else:
            line = bytearray(lines[i])
            if line:
                j = draw(st.integers(0, len(line) - 1))
                line[j] = draw(st.integers(0, 255))
            lines[i] = bytes(line)
        if not lines:
            break
    return b"\n".join(lines)


@pytest.mark.slow
@settings(FUZZ, max_examples=80)
@given(data=mutated_configs())
def test_mutated_configs_load_or_raise_a_config_error_naming_the_file(scratch, data):
    load_or_config_error(scratch, data)


@FUZZ
@given(data=st.binary(max_size=400))
def test_arbitrary_bytes_raise_a_config_error_naming_the_file(scratch, data):
    out = load_or_config_error(scratch, data)
    assert isinstance(out, ConfigError)  # random bytes are never a valid rig config


@FUZZ
@given(name=st.sampled_from(sorted(TEXTS)), cut=st.integers(0, 10_000))
def test_a_truncated_config_loads_or_raises_a_config_error_naming_the_file(scratch, name, cut):
    load_or_config_error(scratch, TEXTS[name][: cut % (len(TEXTS[name]) + 1)])


def scalar_keys(text: bytes) -> Iterator[tuple[int, str, object]]:
    """(line index, dotted key, parsed value) of every ``key = value`` line under a plain [table]."""
    table = ""
    parsed = tomllib.loads(text.decode())
    for i, line in enumerate(text.split(b"\n")):
        if h := HEADER.match(line):
            table = h.group(1).decode() + "."
            continue
        if line.lstrip().startswith(b"[["):
            table = None  # arrays of tables: skipped
            continue
        m = KEY_LINE.match(line)
        if m and table is not None:
            dotted = table + m.group(2).decode()
            value: object = parsed
            for part in dotted.split("."):
                value = value[part]  # type: ignore[index]
            yield i, dotted, value


@pytest.mark.parametrize("name", sorted(TEXTS))
def test_every_key_given_a_wrong_type_is_named_in_the_config_error(tmp_path, name):
    lines = TEXTS[name].split(b"\n")
    path = tmp_path / name
    wrong_named: list[str] = []
    for i, dotted, value in scalar_keys(TEXTS[name]):
        m = KEY_LINE.match(lines[i])
        assert m
        bad = b"1" if isinstance(value, str) else b'"not a number"'
        out = load_or_config_error(path, b"\n".join([*lines[:i], m.group(1) + m.group(2) + b" = " + bad,
                                                     *lines[i + 1:]]))
        if not (isinstance(out, ConfigError) and out.key == dotted):
            wrong_named.append(f"{dotted}: {out}")
    assert not wrong_named, wrong_named
