"""An export with a mounts file applied: units in the reference's axes and on its time.

``gx3 export --mounts mounts.yaml`` (a ``gx3 align`` file): each unit the file names has
its vectors and attitude turned into the reference's axes (``Mount.express``) and its
instants moved by its time shift. The shift goes in where each unit's instants are
estimated (``shift_times``), so that --start, --end and the rows' order see the shifted
times; the turn is made on the finished rows (``turn_units``), after any iron
correction, which belongs to the unit's own axes.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from bridge.analysis.mounts import TURNS, Mounts
from bridge.bus.codec import elements
from bridge.export.describe import flat_names
from bridge.export.tables import ReEstimate
from bridge.timing.offline import Estimate

__all__ = ["shift_times", "turn_units"]


def shift_times(re_estimate: ReEstimate, mounts: Mounts) -> ReEstimate:
    """``re_estimate`` with each mounted unit's instants moved by its time shift.

    Args:
        re_estimate: Each unit's instants (``offline_times``).
        mounts: The mounts file.

    Returns:
        The same, shifted: t_ref = t_unit + time_shift_s (a unit left with its live
        times gets them shifted too).
    """
    def estimate(unit: str, columns: Mapping[str, np.ndarray]) -> Estimate | None:
        found = re_estimate(unit, columns)
        mount = mounts.units.get(unit)
        if mount is None:
            return found
        if found is None:  # live times, whose uncertainty the archive does not hold
            return Estimate(columns["time_ns"] + mount.shift_ns,
                            np.zeros(len(columns["time_ns"]), np.int64))
        return Estimate(found.time_ns + mount.shift_ns, found.uncertainty_ns)

    return estimate


def turn_units(table: dict[str, np.ndarray], mounts: Mounts) -> None:
    """Turn, in place, each mounted unit's quantities into the reference's axes.

    Args:
        table: A sample table (``sample_table``).
        mounts: The mounts file.
    """
    for unit, mount in mounts.units.items():
        rows = table["unit"] == unit
        if not rows.any():
            continue
        for quantity in TURNS:
            names = flat_names(quantity, elements(quantity))
            if names[0] not in table:
                continue
            values = np.column_stack([table[name][rows] for name in names])
            turned = mount.express({quantity: values})[quantity]
            for name, column in zip(names, turned.T, strict=True):
                table[name][rows] = column
