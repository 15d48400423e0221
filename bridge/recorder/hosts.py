"""Each bridge host's clock against the recorder's, judged by when its samples arrive.

A sample's ``time_ns`` is on its bridge host's realtime clock and its arrival on the
recorder's, so the least (arrival - time_ns) over a host's samples bounds how far behind
the recorder its clock can be, and a negative least proves it ahead (``HostView``). A
host that disagrees is told as a HOST_CLOCK_OFFSET event of each of its units
(``ClockChecks``), and each host's bound over the whole recording goes into the
archive (``gx3.hosts``). Why: ``docs/design/time.md``.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from bridge.archive.writer import stamps
from bridge.bus.gx3_pb2 import Event, HostClock, Info, Status
from bridge.device import clock

#: Seconds of arrival over which a host's clock bound is taken: long enough that some
#: sample meets the least latency, short enough to follow a clock being corrected.
HOST_WINDOW_S = 10
#: A host counts as ahead only beyond the bridges' own timing error (~0.06 ms), and a
#: condition clears only once the bound is back by this much (no event per wobble).
HOST_MARGIN_NS = 100_000
HOSTS_METADATA = "gx3.hosts"
_SECOND_NS = 1_000_000_000


class Lags:
    """The least (arrival - time_ns) of one unit's samples (see ``HostView``).

    Kept per second of arrival over the last ``HOST_WINDOW_S`` seconds, and over the
    whole recording.

    Samples are gathered and read about once a second of arrivals (their time_ns from
    their headers in bulk, ``stamps``): a read costs mostly a fixed amount, so a second
    of a 1 kHz unit costs little more than the 50 samples a pass writes.
    """

    def __init__(self, unit: str) -> None:
        self.unit = unit
        self.least: int | None = None  # over the samples read so far
        self._seconds: deque[list[int]] = deque(maxlen=HOST_WINDOW_S)  # [second, least]
        self._payloads: list[bytes] = []
        self._arrivals: list[np.ndarray] = []

    @property
    def seen(self) -> bool:
        """Whether any sample came (read or still gathered)."""
        return self.least is not None or bool(self._payloads)

    def add(self, payloads: list[bytes], arrival: np.ndarray) -> None:
        """Samples that arrived at ``arrival`` (the recorder's clock, in arrival order)."""
        if payloads:
            self._payloads += payloads
            self._arrivals.append(arrival)
            self._read_due(int(arrival[-1]))

    def _read_due(self, now_ns: int) -> None:
        if self._arrivals and now_ns - int(self._arrivals[0][0]) >= _SECOND_NS:
            self.read()

    def read(self) -> None:
        """Fold the samples gathered into the least per second and overall."""
        if not self._payloads:
            return
        payloads, self._payloads = self._payloads, []
        arrival = np.concatenate(self._arrivals)
        self._arrivals = []
        try:
            _, _, time_ns = stamps(self.unit, payloads)
        except ValueError:  # not a sample after all (the writer has left it out): none
            return
        lag = arrival - time_ns
        first, last = int(arrival[0]) // _SECOND_NS, int(arrival[-1]) // _SECOND_NS
        if first == last:
            seconds = [(first, int(lag.min()))]
        else:
            second = arrival // _SECOND_NS
            starts = np.concatenate(([0], np.flatnonzero(np.diff(second)) + 1))
            seconds = list(zip(second[starts].tolist(),
                               np.minimum.reduceat(lag, starts).tolist(), strict=True))
        for at, least in seconds:
            if self._seconds and self._seconds[-1][0] == at:
                self._seconds[-1][1] = min(self._seconds[-1][1], least)
            else:  # a step back of the recorder's clock is a new second too
                self._seconds.append([at, least])
            self.least = least if self.least is None else min(self.least, least)

    def bound(self, now_ns: int) -> int | None:
        """The least over the seconds of arrival within ``HOST_WINDOW_S`` of ``now_ns``.

        None: no sample arrived in them. Samples gathered for less than a second are not
        in it yet.
        """
        self._read_due(now_ns)
        since = now_ns // _SECOND_NS - HOST_WINDOW_S
        return min((least for at, least in self._seconds if at > since), default=None)


class UnitHost:
    """What one unit shows of its bridge host's clock: its sync state, and its samples' lags.

    Args:
        unit: The unit's name.
    """

    def __init__(self, unit: str) -> None:
        self.unit = unit
        #: the host's clock, from the latest Status or Info that carried one, and that
        #: message's own time
        self.clock: HostClock | None = None
        self.clock_ns = 0
        self.lags = Lags(unit)

    def learn(self, message: Status | Info, at_ns: int) -> None:
        """Keep the host clock ``message`` carries if it is newer than the one known.

        An Info answered late is older than the Status before it. A unit whose bridge now
        runs on another host starts its clock bound afresh.

        Args:
            message: A Status or Info of the unit.
            at_ns: The message's own time.
        """
        if not message.HasField("host_clock") or at_ns < self.clock_ns:
            return
        host = message.host_clock.host
        if self.clock is not None and self.clock.host not in ("", host):
            self.lags = Lags(self.unit)
        self.clock, self.clock_ns = message.host_clock, at_ns


@dataclass(frozen=True)
class HostView:
    """The clock of one host that bridges run on, as the recorder sees it.

    A sample's ``time_ns`` is on its bridge host's realtime clock, its arrival on the
    recorder's, and arrival - time_ns = (recorder's clock - host's) + latency, with
    latency > 0: so the least of it over a host's samples bounds how far behind the
    recorder the host's clock can be, and a negative least proves it ahead.

    ``bound_ns``: the least (arrival on the recorder's clock - time_ns) of its units'
    samples over the last ``HOST_WINDOW_S`` s, the most its clock can be behind the
    recorder's (negative: it is ahead by at least that much); ``whole_ns`` the same over
    the recording so far (samples are read about once a second); None: no sample yet.
    ``clock``: its latest sync state.
    ``host`` is empty for a bridge that names no host (an older one): such a unit is a
    host of its own.
    """

    host: str
    units: tuple[str, ...]
    bound_ns: int | None
    whole_ns: int | None
    clock: HostClock | None

    @property
    def name(self) -> str:
        """How events and the terminal name it."""
        return f"host {self.host}" if self.host else f"the unnamed host of {self.units[0]}"


def ahead(bound_ns: int | None) -> bool:
    """Whether a host is provably ahead of the recorder by more than the bridges' timing error.

    ``bound_ns`` is the host's least (arrival - time_ns).
    """
    return bound_ns is not None and bound_ns < -HOST_MARGIN_NS


def host_tolerance_ns(ms: float | None) -> int | None:
    """A host clock tolerance given in ms, in ns (None: none).

    ValueError unless above 0: every sample arrives some time after it was taken, so 0
    would always be exceeded.
    """
    if ms is None:
        return None
    if not (math.isfinite(ms) and ms > 0):
        raise ValueError(f"{ms:g}: give a tolerance above 0 ms, such as 5")
    return round(ms * 1e6)


def recorder_metadata(sync: clock.HostSync) -> dict[str, str]:
    """The recorder's own host and its clock's sync state, for the archive's metadata.

    Every arrival time (publish time) in the archive is on this clock.
    """
    return {"recorder_host": sync.host, "recorder_clock": json.dumps(asdict(sync))}


def host_views(units: Iterable[UnitHost], now_ns: int) -> list[HostView]:
    """Every bridge host's clock against the recorder's, from what its units showed.

    Units with neither samples nor a named host are left out (nothing is known of
    their host).

    Args:
        units: Each unit's host, as the recorder saw it, by unit name.
        now_ns: The end of the last ``HOST_WINDOW_S`` s that ``bound_ns`` covers, on the
            recorder's realtime clock.

    Returns:
        One row per host, by name, unnamed ones last.
    """
    groups: dict[tuple[bool, str], list[UnitHost]] = {}  # (unnamed, host or unit)
    for unit in units:
        host = unit.clock.host if unit.clock is not None else ""
        if host or unit.lags.seen:
            groups.setdefault((not host, host or unit.unit), []).append(unit)
    rows = []
    for (unnamed, host), members in sorted(groups.items()):
        bounds = [b for u in members if (b := u.lags.bound(now_ns)) is not None]
        wholes = [u.lags.least for u in members if u.lags.least is not None]
        latest = max(members, key=lambda u: u.clock_ns)
        rows.append(HostView("" if unnamed else host, tuple(u.unit for u in members),
                             min(bounds, default=None), min(wholes, default=None),
                             latest.clock))
    return rows


class ClockChecks:
    """Which hosts' clocks disagree with the recorder's: HOST_CLOCK_OFFSET events, told once.

    Args:
        tolerance_ns: How far behind the recorder's clock a host's may be
            (``host_tolerance_ns``); None: no such check (a host ahead of the recorder
            is always told).
    """

    def __init__(self, tolerance_ns: int | None) -> None:
        self.tolerance_ns = tolerance_ns
        # (host name, condition) -> the units told of it since it started
        self._told: dict[tuple[str, str], set[str]] = {}

    def events(self, hosts: Iterable[HostView], now: int) -> list[tuple[str, Event]]:
        """HOST_CLOCK_OFFSET events, one for each unit of a host whose clock disagrees.

        A host disagrees with the recorder when it is provably ahead by more than
        ``HOST_MARGIN_NS`` (cleared once it is not provably ahead at all), or, with a
        tolerance, when its bound is beyond it (cleared once back under it by
        ``HOST_MARGIN_NS``). Each is told once when it starts (and to a unit that joins
        the host while it holds), again only after it cleared: a host that stays off
        fills no archive.

        Args:
            hosts: Every host, as it is now (``host_views``).
            now: Now, on the recorder's realtime clock: the events' time.

        Returns:
            (unit, event) of each event to archive.
        """
        notes = []
        tolerance = self.tolerance_ns
        for host in hosts:
            bound = host.bound_ns
            if bound is None:
                continue
            checks = [("ahead", ahead(bound), bound >= 0)]
            if tolerance is not None:
                checks.append(("behind", bound > tolerance,
                               bound <= tolerance - HOST_MARGIN_NS))
            for condition, holds, cleared in checks:
                key = (host.name, condition)
                if cleared:
                    self._told.pop(key, None)
                    continue
                if not holds:
                    continue
                told = self._told.setdefault(key, set())
                detail = self._detail(host, condition, bound)
                for unit in host.units:
                    if unit not in told:
                        told.add(unit)
                        notes.append((unit, Event(
                            unit=unit, time_ns=now, kind=Event.HOST_CLOCK_OFFSET, count=1,
                            clock_change_ns=bound, detail=detail)))
        return notes

    def _detail(self, host: HostView, condition: str, bound: int) -> str:
        """The event's one line: what the bound proves, or allows, and what to look at."""
        if condition == "ahead":
            return (f"the clock of {host.name} is ahead of the recorder's by at least "
                    f"{-bound / 1e6:,.2f} ms: its samples arrived before the instants they "
                    "were stamped with (check chrony, ntpd or PTP on both hosts)")
        assert self.tolerance_ns is not None
        return (f"the clock of {host.name} may be behind the recorder's by up to "
                f"{bound / 1e6:,.2f} ms, or its samples take that long to arrive (tolerance "
                f"{self.tolerance_ns / 1e6:g} ms)")


def hosts_metadata(hosts: list[HostView]) -> dict[str, str]:
    """The ``gx3.hosts`` metadata record.

    Each host's units, the least (arrival - time_ns) over the whole recording and its
    latest sync state; and the recorder's own.

    Args:
        hosts: Every host, over the whole recording (``host_views``).

    Returns:
        The record's key-value pairs.
    """
    meta = {"note": "least_lag_ns: the least (arrival on the recorder's clock - "
                    "time_ns) of the host's samples over the recording: the most its "
                    "clock was behind the recorder's; negative: ahead by at least that",
            "recorder": json.dumps(asdict(clock.host_sync()))}
    for host in hosts:
        meta[f"host/{host.host or host.units[0] + ' (unnamed)'}"] = json.dumps({
            "units": list(host.units), "least_lag_ns": host.whole_ns,
            "ahead": ahead(host.whole_ns),
            "clock": None if host.clock is None else {
                f.name: getattr(host.clock, f.name) for f in HostClock.DESCRIPTOR.fields}})
    return meta
