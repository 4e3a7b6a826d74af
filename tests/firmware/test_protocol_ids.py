"""The firmware's frame types and payload lengths (firmware/rehab_fw/protocol_ids.h, which the simavr
harness includes too) are the host's (rehab_hil.protocol): the header, compiled as C, agrees with
``MESSAGE_TYPES`` on every type and length, and accepts a host frame only at its host length."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from rehab_hil.protocol import MESSAGE_TYPES, PROTOCOL_VERSION

from .conftest import ROOT

HEADER = ROOT / "firmware" / "rehab_fw" / "protocol_ids.h"
PROBE = r"""
#include <stdio.h>
#include "protocol_ids.h"
int main(void) {
    printf("version %d\n", PROTO_VERSION);
    for (int t = 0; t < 256; t++) printf("%d %d\n", t, proto_host_payload_len((uint8_t)t));
    return 0;
}
"""


def _defines() -> dict[str, int]:
    text = HEADER.read_text()
    return {k: int(v, 0) for k, v in re.findall(r"^#define (PROTO_\w+) (\w+)$", text, re.M)}


def test_every_type_and_payload_length_in_the_header_is_the_hosts() -> None:
    d = _defines()
    types = {k[len("PROTO_T_"):]: v for k, v in d.items() if k.startswith("PROTO_T_")}
    lengths = {k[len("PROTO_LEN_"):]: v for k, v in d.items() if k.startswith("PROTO_LEN_")}
    assert sorted(types.values()) == sorted(MESSAGE_TYPES)  # the same set of types, none missing
    for name, length in lengths.items():
        assert name in types, f"PROTO_LEN_{name} has no PROTO_T_{name}"
        assert MESSAGE_TYPES[types[name]].FMT.size == length, name
    assert d["PROTO_VERSION"] == PROTOCOL_VERSION


def test_the_firmware_accepts_a_host_frame_only_at_the_hosts_payload_length(tmp_path: Path) -> None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (the harness needs one too: scripts/install_toolchain.sh)")
    (tmp_path / "probe.c").write_text(PROBE)
    exe = tmp_path / "probe"
    subprocess.run([cc, "-Wall", "-Werror", f"-I{HEADER.parent}", "-o", str(exe), str(tmp_path / "probe.c")],
                   check=True, capture_output=True, timeout=60)
    lines = subprocess.run([str(exe)], check=True, capture_output=True, text=True, timeout=10).stdout.splitlines()
    assert lines[0] == f"version {PROTOCOL_VERSION}"
    accepted = {int(t): int(n) for t, n in (line.split() for line in lines[1:]) if int(n) >= 0}
    host = {t: cls.FMT.size for t, cls in MESSAGE_TYPES.items() if t < 0x80}  # host -> device types
    assert accepted == host
