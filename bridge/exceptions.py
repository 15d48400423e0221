"""Every error gx3-bridge raises on purpose, in one tree.

Each carries a one-line message that says what was wrong and what to do, so a caller
can show it as it is; ``gx3`` catches ``Gx3Error`` once and prints it. Each also keeps
the standard parent that callers of the standard library expect (an unusable port is
an ``OSError``, a bad name a ``ValueError``)::

    Gx3Error
    ├── PortError (OSError)               a port that cannot be used; .why
    ├── DeviceError                       a unit that did not do what was asked; .why
    │   ├── CommandTimeout                no reply after every retry
    │   ├── CommandRejected               the error reply 21 00 21
    │   └── PersistRefused                would write non-volatile memory unasked
    ├── UnsupportedUnit                   not a 3DM-GX3 (a GX2, an Inertia-Link)
    ├── ProtocolError (ValueError)        a command or reply that does not fit the manual
    ├── BusError                          Zenoh
    │   ├── SessionError (RuntimeError)   a config or session that cannot be used
    │   ├── RemoteError (RuntimeError)    no bridge could be asked, or none answered
    │   ├── NameTaken (RuntimeError)      a running bridge holds the unit's name
    │   ├── BadName (ValueError)          a unit name or prefix that cannot be a key
    │   └── MetricsError (OSError)        a --metrics address that cannot be served
    ├── OutputRefused                     writing there would destroy data, or misname it
    ├── ArchiveError (OSError)            an archive that cannot be written
    ├── ArchiveReadError (ValueError)     a file that cannot be read as an archive
    ├── TimeSpanError (ValueError)        a --start/--end that is no time, or no span
    ├── CaptureError (OSError)            a raw capture that cannot be written
    ├── ReplayError (ValueError)          a replay that failed while working
    │   └── UnusableCapture               an input with nothing to replay
    ├── LogImportError (ValueError)       byte logs that cannot be imported as asked
    ├── CalibrationError (ValueError)     readings that cannot give a calibration
    ├── NoiseFileError (ValueError)       a noise file (imu.yaml) that cannot be used
    ├── AlignmentError (ValueError)       units whose motion cannot give their mounting
    ├── MountsFileError (ValueError)      a mounts file (mounts.yaml) that cannot be used
    ├── DemoError (RuntimeError)          a demo that cannot run as asked
    └── EmulatorError                     the emulator (gx3 sim)
        ├── OptionError (ValueError)      an option it cannot run with
        ├── StateFileError (ValueError)   a state file that cannot be read back
        └── LinkPathError                 a --link path that cannot be made
"""

from __future__ import annotations

__all__ = [
    "AlignmentError", "ArchiveError", "ArchiveReadError", "BadName", "BusError",
    "CalibrationError", "CaptureError", "CommandRejected", "CommandTimeout",
    "DemoError", "DeviceError", "EmulatorError", "Gx3Error", "LinkPathError",
    "LogImportError", "MetricsError", "MountsFileError", "NameTaken", "NoiseFileError",
    "OptionError", "OutputRefused", "PersistRefused", "PortError", "ProtocolError",
    "RemoteError", "ReplayError", "SessionError", "StateFileError", "TimeSpanError",
    "UnsupportedUnit", "UnusableCapture",
]


class Gx3Error(Exception):
    """The base of every error gx3-bridge raises on purpose.

    Its message is one line for a person, saying what was wrong and what to do.
    """


class PortError(Gx3Error, OSError):
    """The port cannot be used; the message says why and what to do, in one line.

    ``why`` names the cause in a few words (port missing, port busy, ...), so whoever
    waits for the port can tell one cause from another without parsing the message.
    """

    def __init__(self, message: str, why: str = "port error") -> None:
        super().__init__(message)
        self.why = why


class DeviceError(Gx3Error):
    """A unit did not do what was asked; the message says what and what to try.

    ``why`` names the cause in a few words, as ``PortError.why`` does.
    """

    why = "unit refused"


class CommandTimeout(DeviceError):
    """No reply within the timeout, after every retry."""

    why = "no answer"


class CommandRejected(DeviceError):
    """The unit answered 21 00 21: it did not accept the confirmation bytes."""


class PersistRefused(DeviceError):
    """The command would write non-volatile memory and the caller did not ask for that."""


class UnsupportedUnit(Gx3Error):
    """The unit is not a 3DM-GX3: retrying cannot help, so this is not a DeviceError."""


class ProtocolError(Gx3Error, ValueError):
    """A command or reply that does not fit the protocol; the message says what to change."""


class BusError(Gx3Error):
    """Zenoh could not do what was asked: the session, a remote bridge, a key."""


class SessionError(BusError, RuntimeError):
    """A Zenoh configuration or session that cannot be used; the message says why."""


class RemoteError(BusError, RuntimeError):
    """No bridge could be asked, or none answered; the message says why."""


class NameTaken(BusError, RuntimeError):
    """A running bridge holds the unit name; the message says what to do."""


class BadName(BusError, ValueError):
    """A unit name or prefix that cannot be a chunk of a Zenoh key."""


class MetricsError(BusError, OSError):
    """A ``--metrics`` address that cannot be served: not ADDR:PORT, or a busy port."""


class OutputRefused(Gx3Error):
    """Writing there would destroy data, or cannot start, or the name is another format's.

    The message says what to do.
    """


class ArchiveError(Gx3Error, OSError):
    """The archive cannot be written; the message names the file and the cause."""


class ArchiveReadError(Gx3Error, ValueError):
    """A file that cannot be read as an archive; the message says what it is instead."""


class TimeSpanError(Gx3Error, ValueError):
    """A --start or --end that is not a time, or an end that is not after the start.

    Said before anything is read where the two can be compared then, else as soon as
    the first sample's instant is known.
    """


class CaptureError(Gx3Error, OSError):
    """The capture file cannot be written; the message names it and the cause."""


class ReplayError(Gx3Error, ValueError):
    """A replay that failed while working; the message says why."""


class UnusableCapture(ReplayError):
    """An input that holds nothing to replay (no raw reads, no GX3 records).

    The user's input is wrong, not the replay.
    """


class LogImportError(Gx3Error, ValueError):
    """Byte logs that cannot be imported as asked (``gx3 import``).

    No record in them, no start given, or a reset whose time the logs cannot tell.
    """


class CalibrationError(Gx3Error, ValueError):
    """The readings cannot give a calibration; the message says what motion is missing."""


class NoiseFileError(Gx3Error, ValueError):
    """A noise file (Kalibr's imu.yaml) that cannot be used; the message says why."""


class AlignmentError(Gx3Error, ValueError):
    """Units whose motion cannot give their mounting (``gx3 align``).

    The message says what motion to record instead.
    """


class MountsFileError(Gx3Error, ValueError):
    """A mounts file (``gx3 align``'s mounts.yaml) that cannot be used; says why."""


class DemoError(Gx3Error, RuntimeError):
    """The demo cannot run as asked; the message says why."""


class EmulatorError(Gx3Error):
    """The emulator cannot run as asked."""


class OptionError(EmulatorError, ValueError):
    """An option the emulator cannot run with: the option's name and what is wrong."""

    def __init__(self, option: str, message: str) -> None:
        super().__init__(f"{option}: {message}")


class StateFileError(EmulatorError, ValueError):
    """A state file that cannot be read back; the message names the file and the fix."""


class LinkPathError(EmulatorError):
    """A --link path that cannot be made or would replace something that is not ours."""
