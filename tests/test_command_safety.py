"""The table marks exactly the commands that write non-volatile memory, as the firmware does.

docs/design/protocol.md ("Commands that change what a unit stores") forbids sending those
unasked; the rules follow the manual's command pages and the 0xDB footnote (before
firmware 1.1.27, function 1 stores too).
"""

from __future__ import annotations

from typing import Any

import pytest

from bridge.protocol.table import COMMANDS, DATA_CODES

OLD, NEW = 1126, 1127  # 0xE9 version numbers: 1.1.26 and 1.1.27
ALWAYS = {0xE4, 0xFD, 0xFE}
FIRMWARES = [None, 414, OLD, NEW, 2000]


def writes(code: int, firmware: int | None = None, **params: Any) -> bool:
    return COMMANDS[code].changes_nonvolatile(params, firmware)


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_commands_that_always_write(firmware: int | None) -> None:
    for code in ALWAYS:
        assert writes(code, firmware)
    never = set(COMMANDS) - ALWAYS - {0xD0, 0xD5, 0xD6, 0xD9, 0xDB}
    for code in never:
        assert not any(writes(code, firmware, function=f) for f in range(4)), f"0x{code:02X}"


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_function_2_stores_comms_and_sampling_settings(firmware: int | None) -> None:
    for code in (0xD9, 0xDB):
        assert writes(code, firmware, function=2)
        assert not writes(code, firmware, function=0)
    assert not writes(0xD9, firmware, function=1)
    assert not writes(0xDB, firmware, function=3)


@pytest.mark.parametrize(("firmware", "stores"), [(None, True), (414, True), (OLD, True),
                                                  (NEW, False), (2000, False)])
def test_sampling_settings_function_1_stores_before_firmware_1_1_27(
    firmware: int | None, stores: bool
) -> None:
    """The manual's footnote; an unknown firmware is assumed old, the stricter rule."""
    assert writes(0xDB, firmware, function=1) == stores


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_preset_selector_0_is_a_read(firmware: int | None) -> None:
    assert not writes(0xD5, firmware, mode_preset=0)
    assert all(writes(0xD5, firmware, mode_preset=m) for m in (1, 2, 3))
    assert not writes(0xD6, firmware, continuous_preset=0)
    assert all(writes(0xD6, firmware, continuous_preset=c) for c in DATA_CODES)


@pytest.mark.parametrize("code", [0xC4, 0xD4, 0xFA, 0x21, 0xFF])
def test_continuous_preset_with_a_non_data_code_stores_nothing(code: int) -> None:
    assert not writes(0xD6, continuous_preset=code)


def test_transfer_to_nonvolatile_stores_only_the_two_biases() -> None:
    assert writes(0xD0, quantity=1)
    assert writes(0xD0, quantity=2)
    assert not writes(0xD0, quantity=3)
