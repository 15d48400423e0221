"""The host's clocks as a read sees them: a raw stamp, a realtime stamp, the sync state.

``CLOCK_MONOTONIC_RAW`` runs at the oscillator's own rate: chrony, ntpd and PTP never
step or slew it, so the unit's clock is fitted against it. The realtime clock is the
one they discipline and the one everything else on the host stamps with, so each sample
is mapped onto it at its own instant. Every read gets both, taken together (``stamp``).
Why two clocks: docs/design/time.md.

A script can move this process's realtime clock while its raw clock runs on, as a
disciplined host's clock moves: ``GX3_HOST_CLOCK_SCRIPT`` names a JSON file::

    {"changes": [{"at_ns": 1795000000000000000, "step_ns": 50000000},
                 {"at_ns": 1795000010000000000, "slew_ns": -10000000, "ppm": 500}],
     "sync": {"synchronised": false}}

``at_ns`` is an instant of the unmoved realtime clock; a step moves the clock at once, a
slew moves it by ``slew_ns`` at ``ppm`` of elapsed time (chrony at most 83,333 ppm,
ntpd 500). ``sync`` replaces what the kernel says (``HostSync``'s fields). The file is
read again when it changes, so a test can move a running process's clock. It is how a
fleet's behaviour under a disciplined clock is tested and rehearsed; nothing else uses it.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import json
import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

RAW = time.CLOCK_MONOTONIC_RAW
SCRIPT_ENV = "GX3_HOST_CLOCK_SCRIPT"
#: Raw readings this close around the realtime one make a pair taken together; a pair
#: further apart (the thread was preempted between them) is taken again.
PAIR_NS = 20_000
_PAIR_TRIES = 3
_RECHECK_S = 0.2  # how often a script file is looked at for changes


def raw_ns() -> int:
    """The raw monotonic clock, ns: moved by the oscillator alone."""
    return time.clock_gettime_ns(RAW)


class ClockScript:
    """Steps and slews applied to this process's realtime clock (see the module)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._mtime: int | None = None
        self._checked = -1.0
        self.steps: list[tuple[int, int]] = []
        self.slews: list[tuple[int, int, int]] = []  # at, amount, duration (ns)
        self.sync: dict[str, Any] = {}
        self._reload()

    def _reload(self) -> None:
        self._checked = time.monotonic()
        try:
            mtime = self.path.stat().st_mtime_ns
        except OSError:
            return
        if mtime == self._mtime:
            return
        try:
            spec = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return  # being written: the next look takes it
        self._mtime = mtime
        steps, slews = [], []
        for change in spec.get("changes", []):
            at = int(change["at_ns"])
            if "step_ns" in change:
                steps.append((at, int(change["step_ns"])))
            else:
                amount = int(change["slew_ns"])
                slews.append((at, amount, max(1, round(abs(amount) / (float(change["ppm"])
                                                                       * 1e-6)))))
        self.steps, self.slews = steps, slews
        self.sync = dict(spec.get("sync", {}))

    def shift(self, real: int) -> int:
        """How far the script has moved the realtime clock at unmoved instant ``real``."""
        if time.monotonic() - self._checked >= _RECHECK_S:
            self._reload()
        moved = sum(step for at, step in self.steps if real >= at)
        for at, amount, duration in self.slews:
            if real > at:
                moved += amount if real - at >= duration else round(amount * (real - at)
                                                                    / duration)
        return moved

    def now_ns(self) -> int:
        """The realtime clock as the script has moved it, ns since the Unix epoch."""
        real = time.time_ns()
        return real + self.shift(real)


def _load_script() -> ClockScript | None:
    path = os.environ.get(SCRIPT_ENV)
    return ClockScript(Path(path)) if path else None


#: The script moving this process's realtime clock, if one was given.
script: ClockScript | None = _load_script()
#: The host's realtime clock, ns since the Unix epoch (as ``time.time_ns``, moved by
#: ``script`` where there is one): what the host stamps everything else with.
realtime_ns: Callable[[], int] = time.time_ns if script is None else script.now_ns


def use_script(path: Path | None) -> None:
    """Move this process's realtime clock by a script from now on.

    For tests that run a bridge in-process.

    Args:
        path: The script (see the module); None: the host's own clock again.
    """
    global script, realtime_ns
    script = None if path is None else ClockScript(path)
    realtime_ns = time.time_ns if script is None else script.now_ns


def stamp(clock: Callable[[int], int] = time.clock_gettime_ns,
          real: Callable[[], int] = time.time_ns) -> tuple[int, int]:
    """This instant on the raw and on the realtime clock, read together.

    The realtime clock is read between two raw readings, the raw stamp is their middle;
    a pair further apart than ``PAIR_NS`` (the thread was preempted) is taken again.

    Args:
        clock: ``time.clock_gettime_ns`` (the defaults bind the clocks once: this runs
            once a read).
        real: ``time.time_ns``.

    Returns:
        (raw, realtime) ns; the realtime one moved by the clock script, if any.
    """
    before = clock(RAW)
    now = real()
    after = clock(RAW)
    if after - before > PAIR_NS:  # preempted between them: the closest of a few more
        spread, before, now = min(_pair(clock, real) for _ in range(_PAIR_TRIES))
        after = before + spread
    return (before + after) >> 1, now if script is None else now + script.shift(now)


def _pair(clock: Callable[[int], int], real: Callable[[], int]) -> tuple[int, int, int]:
    """How far apart two raw readings around a realtime one were, the first, the realtime."""
    before = clock(RAW)
    now = real()
    return clock(RAW) - before, before, now


def moved(reals: list[int]) -> list[int]:
    """Realtime stamps read elsewhere (the compiled reader) as the script moves them."""
    if script is None:
        return reals
    shift = script.shift
    return [r + shift(r) for r in reals]


# --- the kernel's view of its own synchronisation (adjtimex) -----------------------------

TIME_ERROR = 5  # adjtimex's answer when the clock is not synchronised
STA_UNSYNC = 0x0040
_STATES = {0: "ok", 1: "leap second to insert", 2: "leap second to delete",
           3: "leap second in progress", 4: "leap second done", 5: "not synchronised"}


class _Timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class _Timex(ctypes.Structure):
    """``struct timex`` of <sys/timex.h> (Linux)."""

    _fields_ = [("modes", ctypes.c_uint), ("offset", ctypes.c_long), ("freq", ctypes.c_long),
                ("maxerror", ctypes.c_long), ("esterror", ctypes.c_long),
                ("status", ctypes.c_int), ("constant", ctypes.c_long),
                ("precision", ctypes.c_long), ("tolerance", ctypes.c_long),
                ("time", _Timeval), ("tick", ctypes.c_long), ("ppsfreq", ctypes.c_long),
                ("jitter", ctypes.c_long), ("shift", ctypes.c_int), ("stabil", ctypes.c_long),
                ("jitcnt", ctypes.c_long), ("calcnt", ctypes.c_long), ("errcnt", ctypes.c_long),
                ("stbcnt", ctypes.c_long), ("tai", ctypes.c_int), ("_pad", ctypes.c_int * 11)]


@dataclass(frozen=True)
class HostSync:
    """How well the host's realtime clock is disciplined, as its kernel says (adjtimex).

    ``known`` False: the kernel could not be asked (not Linux); the rest is then unset.
    The errors are the kernel's: ``estimated_error_ns`` what the sync daemon reckons,
    ``maximum_error_ns`` its bound (16 s when nothing disciplines the clock).
    """

    known: bool = False
    synchronised: bool = False
    state: str = ""
    estimated_error_ns: int = 0
    maximum_error_ns: int = 0
    tai_offset_s: int = 0
    host: str = ""

    def describe(self) -> str:
        """One line for people.

        Returns:
            Whether the clock is disciplined and, if it is, the kernel's estimated and
            maximum error.
        """
        if not self.known:
            return "host clock sync state unknown"
        if not self.synchronised:
            return "host clock not synchronised (no chrony, ntpd or PTP disciplines it)"
        return (f"host clock synchronised, estimated error {self.estimated_error_ns / 1e3:,.0f}"
                f" µs, at most {self.maximum_error_ns / 1e3:,.0f} µs")


_adjtimex: Any = None
with contextlib.suppress(OSError, AttributeError, TypeError):
    _adjtimex = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True).adjtimex


def host_sync() -> HostSync:
    """The kernel's sync state of the realtime clock now.

    Asks adjtimex, reading only; the clock script's ``sync``, where it has one, answers
    in its place.

    Returns:
        The state, ``known`` False where the kernel could not be asked.
    """
    host = socket.gethostname()
    if script is not None and script.sync:
        known = {f.name for f in fields(HostSync)}
        return HostSync(**{"known": True, "host": host,
                           **{k: v for k, v in script.sync.items() if k in known}})
    if _adjtimex is None:
        return HostSync(host=host)
    timex = _Timex()
    answer = int(_adjtimex(ctypes.byref(timex)))
    if answer < 0:
        return HostSync(host=host)
    synchronised = answer != TIME_ERROR and not timex.status & STA_UNSYNC
    return HostSync(known=True, synchronised=synchronised, state=_STATES.get(answer, str(answer)),
                    estimated_error_ns=int(timex.esterror) * 1000,
                    maximum_error_ns=int(timex.maxerror) * 1000, tai_offset_s=int(timex.tai),
                    host=host)
