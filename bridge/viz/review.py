"""What ``gx3 rrd`` renders of an archive: a window of some units, whole if a viewer holds it.

Rerun's viewer holds every row of a recording in memory, and an archive of a fleet's day
at full rate would need tens of gigabytes. A window of up to ``FULL_RATE_SAMPLES``
samples is rendered at full rate; a longer one becomes an overview at the highest rate of
``OVERVIEW_RATES_HZ`` that keeps it within the same bound (``bridge.viz.thin``: each
line's least and greatest value of each bin, so no spike is lost), unless a rate is
asked for. What the bound costs the viewer: ``docs/guides/rerun.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # gx3's command line reads this module's numbers: it stays light
    from bridge.archive.times import TimeSpan
    from bridge.archive.walk import SampleSpan

__all__ = ["FULL_RATE_SAMPLES", "OVERVIEW_RATES_HZ", "Review", "plan"]

#: The most samples rendered at full rate unless a rate is asked for: a recording of
#: about 430 MB, which Rerun's viewer holds in about 0.3 GiB (docs/guides/rerun.md).
FULL_RATE_SAMPLES = 1_000_000
#: Overview rates, bins a second, from the highest: each bin width divides a minute, so
#: every minute's extremes are among its bins'.
OVERVIEW_RATES_HZ = (100.0, 50.0, 20.0, 10.0, 5.0, 2.0, 1.0, 0.5, 0.2, 0.1, 1 / 30, 1 / 60)
#: Rows an overview bin gives each plotted line at most: its least and its greatest value.
ROWS_PER_BIN = 2


@dataclass(frozen=True)
class Review:
    """What an archive is rendered as: which units, from when to when, at what rate.

    Attributes:
        units: The units shown.
        start_ns: The window's first instant (host ns); None: from the start, status and
            events from before the first sample included.
        end_ns: The instant after its last (host ns); None: to the end.
        offset_s: Seconds from the archive's first sample to the window's first.
        seconds: Seconds the window's samples span.
        samples: About how many samples of ``units`` lie in the window.
        max_rate_hz: Bins a second of an overview; None: every sample.
        asked: Whether the rate was asked for (else chosen to fit ``FULL_RATE_SAMPLES``).
    """

    units: tuple[str, ...]
    start_ns: int | None
    end_ns: int | None
    offset_s: float
    seconds: float
    samples: int
    max_rate_hz: float | None
    asked: bool

    def full_rate_seconds(self, bound: int = FULL_RATE_SAMPLES) -> float:
        """The longest window of these units that ``bound`` samples cover at full rate.

        Whole minutes when it is a minute or more.

        Args:
            bound: The samples.

        Returns:
            Seconds.
        """
        if not self.samples:
            return self.seconds
        fits = bound * self.seconds / self.samples
        return float(math.floor(fits / 60) * 60) if fits >= 60 else fits


def plan(span: SampleSpan, units: Sequence[str] | None = None,
         window: TimeSpan | None = None, max_rate_hz: float | None = None,
         bound: int = FULL_RATE_SAMPLES) -> Review:
    """What to render of an archive, from what its summary says of its samples.

    Args:
        span: The archive's samples (``bridge.archive.walk.sample_span``).
        units: The units asked for; None: every unit with samples.
        window: The --start and --end asked for; None: every sample.
        max_rate_hz: The overview's rate asked for (``RerunLogger`` checks it); None:
            full rate if the window holds at most ``bound`` samples, else the highest of
            ``OVERVIEW_RATES_HZ`` that keeps each line within it.
        bound: The most samples rendered at full rate (and rows a line gets) by default.

    Returns:
        The plan.

    Raises:
        ValueError: The archive has no samples, a unit has none, or the window holds none
            (TimeSpanError: its end is not after its start).
    """
    if not span.counts or span.first_ns is None or span.last_ns is None:
        raise ValueError("no samples in it; give an archive gx3 recorded units into")
    chosen = tuple(dict.fromkeys(units)) if units else tuple(sorted(span.counts))
    if missing := [u for u in chosen if u not in span.counts]:
        raise ValueError(f"no samples of unit {missing[0]} in it (units: "
                         f"{', '.join(sorted(span.counts))}); check --unit")
    first, last = span.first_ns, span.last_ns + 1
    lo, hi = (None, None) if window is None else window.resolve(first)
    since = first if lo is None else max(first, lo)
    until = last if hi is None else min(last, hi)
    if since >= until:
        raise ValueError(f"no samples from --start to --end (the samples span "
                         f"{span.seconds():,.1f} s from the first); check them")
    seconds = (until - since) / 1e9
    samples = round(sum(span.counts[u] for u in chosen) * (until - since) / (last - first))
    rate, asked = max_rate_hz, max_rate_hz is not None
    if rate is None and samples > bound:
        fits = [r for r in OVERVIEW_RATES_HZ
                if ROWS_PER_BIN * r * seconds * len(chosen) <= bound]
        rate = fits[0] if fits else OVERVIEW_RATES_HZ[-1]
    return Review(chosen, lo, hi, (since - first) / 1e9, seconds, samples, rate, asked)
