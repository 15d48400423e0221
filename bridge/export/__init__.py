"""Archives out to other formats: Parquet and CSV tables, ROS 2 and ROS 1 bags, gx3 export."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported
from bridge.archive.times import TimeSpan
from bridge.export.bags import BagWritten
from bridge.export.describe import About
from bridge.export.ros1_bag import write_ros1
from bridge.export.ros2_bag import Ros2Written, write_ros2

if TYPE_CHECKING:
    from bridge.export.mounted import shift_times, turn_units
    from bridge.export.run import Export, Exported
    from bridge.export.tables import (
        align_table,
        event_table,
        offline_times,
        sample_table,
        write_table,
    )

__all__ = [
    "About",
    "BagWritten",
    "Export",
    "Exported",
    "Ros2Written",
    "TimeSpan",
    "align_table",
    "event_table",
    "offline_times",
    "sample_table",
    "shift_times",
    "turn_units",
    "write_ros1",
    "write_ros2",
    "write_table",
]

#: Names whose modules import pyarrow, imported on first use.
_ON_FIRST_USE = {
    **dict.fromkeys(("Export", "Exported"), "bridge.export.run"),
    **dict.fromkeys(("shift_times", "turn_units"), "bridge.export.mounted"),
    **dict.fromkeys(("align_table", "event_table", "offline_times", "sample_table",
                     "write_table"), "bridge.export.tables"),
}


def __getattr__(name: str) -> object:
    return imported(__name__, _ON_FIRST_USE, name)
