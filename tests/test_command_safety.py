"""The table marks exactly the commands DESIGN.md forbids sending unasked."""

from __future__ import annotations

import pytest

from bridge.protocol.table import COMMANDS

ALWAYS = {0xD0, 0xD5, 0xD6, 0xE4, 0xFD, 0xFE}
WHEN_FUNCTION_2 = {0xD9, 0xDB}


@pytest.mark.parametrize("code", sorted(COMMANDS), ids=lambda c: f"0x{c:02X}")
def test_nonvolatile_commands_are_marked(code: int) -> None:
    cmd = COMMANDS[code]
    for function in range(4):
        expected = code in ALWAYS or (code in WHEN_FUNCTION_2 and function == 2)
        assert cmd.changes_nonvolatile({"function": function}) == expected
