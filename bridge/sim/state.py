"""What a simulated unit keeps in non-volatile memory, and the file that stands in for it."""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from bridge.protocol.table import DEFAULT_BAUD, DEFAULT_FLAGS, Mode

# The manual names no factory decimation; 100 Hz is what the vendor's units ship with.
DEFAULT_DECIMATION = 10


@dataclass(frozen=True)
class Sampling:
    """The 0xDB settings; field names are the reply's, so a reply is ``asdict(sampling)``."""

    decimation: int = DEFAULT_DECIMATION
    flags: int = int(DEFAULT_FLAGS)
    filter_width: int = 15
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
        words = dict(self.eeprom)
        words[address] = value
        return replace(self, eeprom=tuple(sorted(words.items())))

    def word(self, address: int) -> int:
        return dict(self.eeprom).get(address, 0)


class StateFileError(ValueError):
    """A state file that cannot be read back; the message names the file and the fix."""


def load(path: Path | None, default: Stored) -> Stored:
    """The stored state of a unit: the file's if there is one, else ``default``."""
    if path is None or not path.exists():
        return default
    try:
        raw = json.loads(path.read_text())
        known = {f.name for f in fields(Stored)}
        values = {k: v for k, v in raw.items() if k in known}
        values["sampling"] = Sampling(**raw.get("sampling", {}))
        values["accel_bias"] = tuple(values.get("accel_bias", default.accel_bias))
        values["gyro_bias"] = tuple(values.get("gyro_bias", default.gyro_bias))
        values["eeprom"] = tuple((int(a), int(v)) for a, v in raw.get("eeprom", {}).items())
        return Stored(**values)
    except (OSError, ValueError, TypeError) as exc:
        raise StateFileError(f"{path}: not a unit state file ({exc}); give another path, "
                             "or remove this one to start from factory settings") from None


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
