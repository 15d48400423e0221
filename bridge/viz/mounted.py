"""Units on one body drawn in the reference's axes and on its time (``gx3 rrd --mounts``).

A mounts file (``gx3 align``) turns each unit it names into the reference's axes and
moves its samples by its time shift before they are logged: one small transform on each
batch, after any iron correction (which belongs to the unit's own axes). The file, its
SHA-256 and what it holds go into the recording as its ``gx3_mounts`` property.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import rerun as rr

from bridge.analysis.magcal import UnitIron
from bridge.analysis.mounts import Mounts
from bridge.viz.logger import RerunLogger
from bridge.viz.magcal import IronedLogger

__all__ = ["PROPERTY", "MountedLogger"]

#: The recording property that holds the mounts file applied.
PROPERTY = "gx3_mounts"


class MountedLogger(IronedLogger):
    """An IronedLogger that also draws mounted units in their reference's axes and time.

    Args:
        mounts: The mounts file; None: none.
        irons: The iron calibrations, one per unit at most.
        *args: As ``RerunLogger``'s.
        **kwargs: As ``RerunLogger``'s.
    """

    def __init__(self, mounts: Mounts | None, irons: Sequence[UnitIron], *args: Any,
                 **kwargs: Any) -> None:
        self.mounts = mounts
        super().__init__(irons, *args, **kwargs)
        if mounts is not None:
            about = mounts.provenance()
            self.recording.send_property(PROPERTY, rr.AnyValues(
                file=str(about["file"]), sha256=str(about["sha256"]),
                reference=mounts.reference, mounts=json.dumps(about)))

    def log_samples(self, unit: str, code: int, columns: Mapping[str, np.ndarray]) -> None:
        """Log a batch as ``IronedLogger`` does, a mounted unit's in its reference's frame.

        Its vectors and attitude are turned into the reference's axes, and its
        ``time_ns`` moved by its time shift.

        Args:
            unit: The unit.
            code: The record type (command byte).
            columns: As ``RerunLogger.log_samples`` takes them.

        Raises:
            ValueError: A column is missing, or the columns differ in length.
        """
        ironed = self.ironed(unit, columns)
        mount = None if self.mounts is None else self.mounts.units.get(unit)
        if mount is not None:
            turned = mount.express(ironed)
            turned["time_ns"] = np.asarray(turned["time_ns"], np.int64) + mount.shift_ns
            ironed = turned
        # the iron is corrected above, in the unit's own axes: not again
        RerunLogger.log_samples(self, unit, code, ironed)
