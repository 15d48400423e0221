"""The emulator: 3DM-GX3 units in software, answering as the manual says a unit does.

``Simulator`` serves units on pseudo-terminals or TCP ports in real time, for a bridge
or any serial program to open. ``SimUnit`` is one unit's device model alone, with no
I/O, driven by whatever clock the caller passes, so that a test can cross the timer
rollover or stream for an hour in a second. ``synthesize`` runs a unit in virtual time
through a model of its link to the host (``UsbDelivery``, ``AdapterDelivery``,
``UartDelivery``) and returns what a bridge would have read, beside the truth of every
record. A ``Mounting`` fixes units to one body (``handheld``: turned by hand), for
``gx3 align``. How it follows the manual, and where it had to choose:
``docs/design/emulator.md``.

Importing it needs neither Zenoh nor Rerun.
"""

from bridge.sim.archived import archive_samples, fleet_archive
from bridge.sim.capture import SyntheticCapture, streaming_config, synthesize
from bridge.sim.faults import FaultConfig
from bridge.sim.motion import Motion, MotionConfig, Mounting, handheld, tumbling
from bridge.sim.serve import Simulator, unit_configs
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import SimUnit, TruthLog, UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery

__all__ = [
    "AdapterDelivery",
    "FaultConfig",
    "HostDelivery",
    "Motion",
    "MotionConfig",
    "Mounting",
    "Sampling",
    "SimUnit",
    "Simulator",
    "Stored",
    "SyntheticCapture",
    "TruthLog",
    "UartDelivery",
    "UnitConfig",
    "UsbDelivery",
    "archive_samples",
    "fleet_archive",
    "handheld",
    "streaming_config",
    "synthesize",
    "tumbling",
    "unit_configs",
]
