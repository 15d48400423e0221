"""Rerun viewer output: the fleet in 3-D, its time series, status and events.

``RerunLogger`` writes samples, status and events into a Rerun recording column-wise,
with a blueprint that grows with the fleet; ``log_archive`` feeds it an archive,
``LiveFeed`` the live fleet on Zenoh, ``RrdWriter`` what a recording archives (``gx3
record --rrd``), ``IronedLogger`` shows magnetometers corrected for iron and
``MountedLogger`` units on one body in their reference's axes and time;
``write_allan_plot`` draws a unit's Allan deviation (a PNG).
What the recording holds, and why it is laid out so: ``docs/guides/rerun.md``.
"""

from bridge.viz.allan import write_allan_plot
from bridge.viz.logger import RerunLogger
from bridge.viz.magcal import IronedLogger, write_fit
from bridge.viz.mounted import MountedLogger
from bridge.viz.sources import LiveFeed, RrdWriter, log_archive, log_messages

__all__ = ["IronedLogger", "LiveFeed", "MountedLogger", "RerunLogger", "RrdWriter", "log_archive",
           "log_messages", "write_allan_plot", "write_fit"]
