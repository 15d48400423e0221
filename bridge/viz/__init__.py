"""Rerun viewer output: the fleet in 3-D, its time series, status and events.

``RerunLogger`` writes samples, status and events into a Rerun recording column-wise,
with a blueprint that grows with the fleet, every sample or thinned for a recording of
any length; ``log_archive`` feeds it an archive or a window of one (``plan`` says which
window, at what rate, a viewer can hold), ``LiveFeed`` the live fleet on Zenoh,
``RrdWriter`` what a recording archives (``gx3 record --rrd``), ``IronedLogger``
shows magnetometers corrected for iron and ``MountedLogger`` units on one body in their
reference's axes and time; ``write_allan_plot`` draws a unit's Allan deviation (a PNG).
Names whose modules load Rerun or matplotlib are imported on first use. What the
recording holds, and why it is laid out so: ``docs/guides/rerun.md``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported
from bridge.viz.review import FULL_RATE_SAMPLES, Review, plan

if TYPE_CHECKING:
    from bridge.viz.allan import write_allan_plot
    from bridge.viz.logger import RerunLogger
    from bridge.viz.magcal import IronedLogger, write_fit
    from bridge.viz.mounted import MountedLogger
    from bridge.viz.sources import LiveFeed, RrdWriter, log_archive, log_messages

__all__ = ["FULL_RATE_SAMPLES", "IronedLogger", "LiveFeed", "MountedLogger", "RerunLogger",
           "Review", "RrdWriter", "log_archive", "log_messages", "plan", "write_allan_plot",
           "write_fit"]

#: Names whose modules import Rerun or matplotlib, imported on first use.
_ON_FIRST_USE = {
    "write_allan_plot": "bridge.viz.allan",
    "RerunLogger": "bridge.viz.logger",
    **dict.fromkeys(("IronedLogger", "write_fit"), "bridge.viz.magcal"),
    "MountedLogger": "bridge.viz.mounted",
    **dict.fromkeys(("LiveFeed", "RrdWriter", "log_archive", "log_messages"),
                    "bridge.viz.sources"),
}


def __getattr__(name: str) -> object:
    return imported(__name__, _ON_FIRST_USE, name)
