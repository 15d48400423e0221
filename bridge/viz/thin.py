"""Long series in few rows: each time bin's least and greatest value, at their own instants.

A viewer holds every row it is given, and a fleet's day at full rate is tens of
gigabytes. Rows in time order are cut into bins of a fixed width, aligned to the Unix
epoch (every unit, every run and every window bins alike, and a width that divides a
minute never straddles one); a line keeps, of each bin, the row of its least and the row
of its greatest value, so every spike and every extreme survives at the instant it
happened, in two rows a bin at most. An average would hide the very spike one looks for.
What the rest of a recording does (attitude, status, events): ``docs/guides/rerun.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Bins", "bin_width_ns"]


def bin_width_ns(max_rate_hz: float) -> int:
    """The width of the bins of a rate, in whole nanoseconds.

    Args:
        max_rate_hz: Bins a second.

    Returns:
        1 s / ``max_rate_hz``, at least 1 ns.

    Raises:
        ValueError: The rate is not above 0.
    """
    if not max_rate_hz > 0:
        raise ValueError(f"a rate of {max_rate_hz} Hz: give one above 0")
    return max(1, round(1e9 / max_rate_hz))


@dataclass(frozen=True)
class Bins:
    """Rows in time order, cut into bins; the last one may be held open.

    A batch of a stream that goes on ends in a bin that the next batch may add to: it is
    held open (``cut``), and only the rows that can still be its extremes are carried
    over (``carried``), so the work stays in proportion to the rows, whatever the width.

    Attributes:
        starts: The first row of each bin.
        cut: The first row of the open bin (``rows`` when none is open).
        rows: How many rows there are.
    """

    starts: np.ndarray
    cut: int
    rows: int

    @classmethod
    def of(cls, time_ns: np.ndarray, width_ns: int, hold_last: bool) -> Bins:
        """The bins of rows.

        Args:
            time_ns: Each row's instant, ascending.
            width_ns: The bins' width.
            hold_last: Hold the last bin open: more rows of it may come.

        Returns:
            The bins.
        """
        index = np.asarray(time_ns, np.int64) // width_ns
        starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]]) if len(index) \
            else np.zeros(0, np.int64)
        cut = int(starts[-1]) if hold_last and len(starts) else len(index)
        return cls(starts, cut, len(index))

    @property
    def firsts(self) -> np.ndarray:
        """The first row of each closed bin (attitude is shown at those)."""
        return self.starts[self.starts < self.cut]

    def extremes(self, values: np.ndarray) -> np.ndarray:
        """The rows of each bin's least and greatest value, ascending.

        Of equal values, the first; NaN is passed over, and a bin of NaN alone keeps no
        row.

        Args:
            values: One value per row.

        Returns:
            Row indexes, of every bin (the open one too).
        """
        values = np.asarray(values, np.float64)
        if not len(values):
            return np.zeros(0, np.int64)
        counts = np.diff(np.r_[self.starts, len(values)])
        group = np.repeat(np.arange(len(self.starts)), counts)
        picked = []
        for reduce in (np.fmin, np.fmax):  # fmin and fmax pass NaN over
            extreme = reduce.reduceat(values, self.starts)
            rows = np.flatnonzero(values == extreme[group])
            if len(rows):  # the first row of each bin that holds its extreme
                rows = rows[np.r_[True, group[rows[1:]] != group[rows[:-1]]]]
            picked.append(rows)
        return np.union1d(*picked)

    def carried(self, extremes: list[np.ndarray]) -> np.ndarray:
        """The rows of the open bin that the next batch needs: its first, and its extremes.

        Together with the next batch's rows they give the bin exactly the first row and
        the extremes it would have had in one batch.

        Args:
            extremes: ``extremes`` of each line.

        Returns:
            Row indexes, ascending (none when no bin is open).
        """
        if self.cut >= self.rows:
            return np.zeros(0, np.int64)
        held = [self.cut, *(int(i) for rows in extremes for i in rows[rows >= self.cut])]
        return np.unique(np.asarray(held, np.int64))
