"""What a simulated unit keeps in non-volatile memory, and the file that stands in for it."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from bridge.exceptions import StateFileError
from bridge.protocol.table import (
    BAUD_RATES,
    BY_NAME,
    DATA_CODES,
    DEFAULT_BAUD,
    DEFAULT_FILTER_WIDTH,
    DEFAULT_FLAGS,
    Mode,
)

# The manual names no factory decimation; 100 Hz is what the vendor's units ship with.
DEFAULT_DECIMATION = 10
USER_EEPROM = (range(0x0000, 0x00F0), range(0x0400, 0x0430))
MODE_PRESETS = (int(Mode.ACTIVE), int(Mode.CONTINUOUS), int(Mode.IDLE))


@dataclass(frozen=True)
class Sampling:
    """The 0xDB settings; field names are the reply's, so a reply is ``asdict(sampling)``."""

    decimation: int = DEFAULT_DECIMATION
    flags: int = int(DEFAULT_FLAGS)
    filter_width: int = DEFAULT_FILTER_WIDTH
    mag_filter_width: int = 17
    up_compensation: int = 10
    north_compensation: int = 10


@dataclass(frozen=True)
class Stored:
    """Everything that survives a 0xFE reset and a power cycle."""

    mode_preset: int = int(Mode.ACTIVE)
    continuous_preset: int = 0
    sampling: Sampling = field(default_factory=Sampling)
    baud: int = DEFAULT_BAUD
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    eeprom: tuple[tuple[int, int], ...] = ()

    def with_word(self, address: int, value: int) -> Stored:
        """This memory with one EEPROM word written.

        Args:
            address: The word's address.
            value: Its new value.

        Returns:
            The memory, changed.
        """
        words = dict(self.eeprom)
        words[address] = value
        return replace(self, eeprom=tuple(sorted(words.items())))

    def word(self, address: int) -> int:
        """An EEPROM word of this memory.

        Args:
            address: The word's address.

        Returns:
            Its value: 0 where none was written.
        """
        return dict(self.eeprom).get(address, 0)


def _sampling_range(name: str) -> tuple[int, int]:
    """The range 0xDB accepts for a setting, from the command table."""
    spec = next(f for f in BY_NAME["sampling_settings"].params if f.name == name)
    return int(spec.lo if spec.lo is not None else 0), int(spec.hi if spec.hi is not None
                                                          else 0xFFFF)


def problems(stored: Stored) -> Iterator[tuple[str, str]]:
    """(field, what is wrong) for every value a unit's memory could not hold."""
    if stored.mode_preset not in MODE_PRESETS:
        yield "mode_preset", f"{stored.mode_preset!r} is not 1 (active), 2 (continuous) or 3 (idle)"
    if stored.continuous_preset != 0 and stored.continuous_preset not in DATA_CODES:
        yield "continuous_preset", (f"{stored.continuous_preset!r} is neither 0 (none) nor a "
                                    "data command such as 0xC2")
    for name, value in asdict(stored.sampling).items():
        lo, hi = _sampling_range(name)
        if not _is_int(value) or not lo <= value <= hi:
            yield f"sampling.{name}", f"{value!r} is not a whole number from {lo} to {hi}"
    if stored.baud not in BAUD_RATES:
        yield "baud", f"{stored.baud!r} is not one of " + ", ".join(map(str, BAUD_RATES))
    for name in ("accel_bias", "gyro_bias"):
        vector = getattr(stored, name)
        if len(vector) != 3 or not all(_is_real(v) and math.isfinite(v) for v in vector):
            yield name, f"{list(vector)!r} is not three finite numbers"
    for address, value in stored.eeprom:
        if not _is_int(address) or not any(address in r for r in USER_EEPROM):
            yield "eeprom", (f"address {address!r} is not a user word "
                             "(0x0000-0x00EF or 0x0400-0x042F)")
        elif not _is_int(value) or not 0 <= value <= 0xFFFF:
            yield "eeprom", f"word 0x{address:04X} holds {value!r}, not a 16-bit value"


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def load(path: Path | None, default: Stored) -> Stored:
    """The stored state of a unit: the file's if there is one, else ``default``."""
    if path is None or not path.exists():
        return default
    try:
        stored = _parse(json.loads(path.read_text()), default)
        wrong = next(problems(stored), None)
    except (OSError, ValueError, TypeError) as exc:
        raise StateFileError(f"{path}: not a unit state file ({exc}); give another path, "
                             "or remove this one to start from factory settings") from None
    if wrong is not None:
        raise StateFileError(f"{path}: {wrong[0]}: {wrong[1]}; correct it, or remove the file "
                             "to start from factory settings")
    return stored


def _parse(raw: Any, default: Stored) -> Stored:
    """A Stored from a file's JSON, with its shape checked (the values by ``problems``)."""
    if not isinstance(raw, dict):
        raise ValueError("the top level is not an object")
    known = {f.name for f in fields(Stored)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ValueError(f"unknown field {unknown[0]!r}")
    values = dict(raw)
    sampling = raw.get("sampling", {})
    if not isinstance(sampling, dict):
        raise ValueError("sampling is not an object")
    values["sampling"] = Sampling(**sampling)
    for name in ("accel_bias", "gyro_bias"):
        vector = values.get(name, getattr(default, name))
        if not isinstance(vector, list | tuple):
            raise ValueError(f"{name} is not a list of three numbers")
        values[name] = tuple(vector)
    eeprom = raw.get("eeprom", {})
    if not isinstance(eeprom, dict):
        raise ValueError("eeprom is not an object of address: word")
    values["eeprom"] = tuple(sorted((int(a, 0), v) for a, v in eeprom.items()))
    return Stored(**values)


def check_writable(path: Path) -> None:
    """Fail at start, not on the first write to non-volatile memory, if ``path`` cannot be saved.

    Its folder must be creatable and writable, and it must not be a folder.
    """
    try:
        if path.is_dir():
            raise IsADirectoryError(21, "is a directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise StateFileError(f"{path} cannot be written ({exc.strerror or exc}); give a path "
                             "in a folder you can write") from None


def save(path: Path | None, stored: Stored) -> None:
    """Write atomically, so a crash never leaves half a state file behind."""
    if path is None:
        return
    data = asdict(stored)
    data["eeprom"] = {str(a): v for a, v in stored.eeprom}
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=1)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
