"""gx3-bridge: MicroStrain 3DM-GX3 units onto Zenoh, into MCAP and Rerun.

``bridge.subscribe`` is the entry point for applications; it is imported on first
use so that the protocol layer never pulls in Zenoh. ``SCHEMAS_DIR`` holds the
installed ``gx3.proto`` (and ``replies.json``), for code generators in other
languages; ``__version__`` is the installed distribution's version. Library code logs
through ``logging`` (loggers under ``bridge``) and prints nothing.

The subpackages, in the order the data flows: ``protocol`` (the bytes: command table,
codec, framer), ``device`` (a unit over a port), ``timing`` (the unit's timer to host
time), ``bus`` (Zenoh), ``ros2`` (ROS 2 messages), ``unit`` (one unit from bytes to the
bus), ``recorder`` (the fleet recorded live), ``archive`` (the archive's file format),
``ingest`` (bytes into archives), ``export`` and ``analysis`` (archives out to tables
and bags, and what they tell of the units), ``viz`` (Rerun); ``sim`` is the emulator,
``fleet`` a fleet on one machine, and every error raised on purpose is in
``bridge.exceptions``. How they fit together, and which may import which:
docs/design/architecture.md.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bridge.bus.subscribe import subscribe

__all__ = ["SCHEMAS_DIR", "__version__", "subscribe"]

try:
    __version__ = version("gx3-bridge")
except PackageNotFoundError:  # a source tree on sys.path, never installed
    __version__ = "0+unknown"

SCHEMAS_DIR = Path(__file__).resolve().with_name("schemas")


def __getattr__(name: str) -> object:
    if name == "subscribe":
        from bridge.bus.subscribe import subscribe

        return subscribe
    raise AttributeError(f"module 'bridge' has no attribute {name!r}")
