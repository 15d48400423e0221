"""gx3-bridge: MicroStrain 3DM-GX3 units onto Zenoh, into MCAP and Rerun.

``bridge.subscribe`` is the entry point for applications; it is imported on first
use so that the protocol layer never pulls in Zenoh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bridge.bus.subscribe import subscribe

__all__ = ["subscribe"]


def __getattr__(name: str) -> object:
    if name == "subscribe":
        from bridge.bus.subscribe import subscribe

        return subscribe
    raise AttributeError(f"module 'bridge' has no attribute {name!r}")
