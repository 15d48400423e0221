"""Samples, status and events of a fleet of units into a Rerun recording, column-wise.

One ``RerunLogger`` serves every caller: a live subscriber hands it each batch as it
arrives (units may appear at any time), an archive reader hands it whole columns, a
recorder writes an .rrd beside its MCAP. Each batch costs a few ``send_columns`` calls,
whatever its length, so kHz streams of many units stay cheap. The unit's M maps earth
(NED) to sensor; the scene shows the sensor-to-earth rotation M^T, as a Rerun
(x, y, z, w) quaternion. What the recording holds, and where: ``docs/guides/rerun.md``.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from datetime import UTC, datetime
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt
import rerun as rr

from bridge.bus.codec import record_quantities
from bridge.bus.events import LEVEL, event_text
from bridge.bus.gx3_pb2 import Event, HostClock, Status
from bridge.device.clock import HostSync
from bridge.protocol import convert
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.viz import layout, thin
from bridge.viz.layout import DEVICE_TIME, PLOT, TIME

NS_PER_TICK = 1_000_000_000 // TICKS_PER_SECOND  # 16,000 exactly



def _indexes(time_ns: npt.ArrayLike, device_ns: npt.ArrayLike | None) -> list[rr.TimeColumn]:
    """The timelines of rows: nanoseconds as datetime64/timedelta64.

    Rerun takes those as such; plain numbers would be read as seconds.
    """
    cols = [rr.TimeColumn(TIME, timestamp=np.asarray(time_ns, np.int64).astype("datetime64[ns]"))]
    if device_ns is not None:
        cols.append(rr.TimeColumn(
            DEVICE_TIME, duration=np.asarray(device_ns, np.int64).astype("timedelta64[ns]")))
    return cols


def _time_of_day(time_ns: int) -> str:
    """HH:MM:SS.mmm, UTC, as the viewer's time panel shows it."""
    when = datetime.fromtimestamp(time_ns // 1_000_000 / 1000, UTC)
    return when.strftime("%H:%M:%S.%f")[:-3]


def _host_clock_text(unit: str, state: HostClock) -> tuple[str, str]:
    """(text, level) of a unit's bridge host clock's sync state, as the events read.

    A clock nothing disciplines warns: its units' times drift from the rest of the fleet.
    """
    sync = HostSync(**{f.name: getattr(state, f.name) for f in fields(HostSync)})
    where = f" on {state.host}" if state.host else ""
    level = "WARN" if state.known and not state.synchronised else "INFO"
    return f"{unit}{where}: {sync.describe()}", level


def _sensor_to_earth(columns: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """(n, 4) x, y, z, w quaternions of the rotation M^T.

    From whichever attitude the record holds (M, else Q, else Euler angles); None for
    records without one.
    """
    if "m" in columns:
        q = convert.m_to_quaternion(columns["m"])
    elif "quaternion" in columns:
        q = np.asarray(columns["quaternion"], np.float64)
    elif "euler" in columns:
        q = convert.euler_to_quaternion(columns["euler"])
    else:
        return None
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN records stay NaN
        return convert.sensor_to_earth_xyzw(q)


def _euler_degrees(columns: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """(n, 3) roll, pitch, yaw in degrees, as sent or derived from M or Q."""
    if "euler" in columns:
        euler = np.asarray(columns["euler"], np.float64)
    elif "m" in columns:
        euler = convert.m_to_euler(columns["m"])
    elif "quaternion" in columns:
        with np.errstate(invalid="ignore", divide="ignore"):
            euler = convert.quaternion_to_euler(columns["quaternion"])
    else:
        return None
    return np.degrees(euler)


def _sample_series(columns: Mapping[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """Plot name -> (n, lines) float64 values of a batch of samples."""
    series = {name: np.asarray(columns[name], np.float64).reshape(n, -1)
              for name in columns if name in PLOT}
    euler = _euler_degrees(columns)
    if euler is not None:
        series["euler"] = euler
    if "temperature" in columns:
        codes = np.asarray(columns["temperature"], np.float64).reshape(n, 4)
        series["mag_temperature"] = np.asarray(convert.mag_temperature_celsius(codes[:, :1]))
        series["gyro_temperature"] = codes[:, 1:]
    return series


def _parts(rows: np.ndarray, size: int) -> list[np.ndarray]:
    """``rows`` in pieces of ``size`` at most (none when there are none)."""
    return [rows[at:at + size] for at in range(0, len(rows), size)]


@dataclass
class _Pending:
    """Batches of one unit and record type gathered since ``since`` (monotonic seconds)."""

    since: float
    parts: list[dict[str, np.ndarray]] = field(default_factory=list)
    rows: int = 0


@dataclass
class _Kept:
    """What thinning kept of one unit and record type since ``since``, not sent yet.

    Gathered into sends of up to ``max_rows`` rows, as full-rate samples are: a send per
    batch of a few bins would make chunks of a few rows, mostly overhead.
    """

    since: float
    #: each line's entity -> pieces of (time_ns, device_ns, value) of its rows
    lines: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = field(
        default_factory=dict)
    scene: list[dict[str, np.ndarray]] = field(default_factory=list)  # the bins' first rows
    rows: int = 0  # of the line with the most


class RerunLogger:
    """Writes a fleet's samples, status and events to one Rerun recording.

    The blueprint is (re)sent, as active and default, whenever a plot or a unit appears,
    so it is in every recording and grows with the fleet. Samples reach the recording
    at most ``latency_s`` after they were logged, provided the caller logs or flushes at
    least that often (a live caller with no data flowing calls ``flush``). A recorder
    writing hours of data to a file is better served by latency_s of a few seconds
    (bigger chunks: a smaller file) and ``write_footer=False`` (Rerun otherwise keeps an
    index entry per chunk in memory until the file is closed).

    With ``max_rate_hz``, samples are thinned for a recording of any length
    (``bridge.viz.thin``): each plotted line keeps the least and the greatest value of
    each 1/max_rate_hz s bin, at the instants they happened, and the scene each bin's
    first attitude and arrows; status and events are kept whole. A bin is kept once a
    later sample closes it (or on ``flush``), and what is kept is sent as samples are:
    ``max_rows`` rows or ``latency_s`` after the first, at most.

    Args:
        target: A RecordingStream the caller set up (spawned viewer, gRPC connection,
            file), or a path, for which the logger opens an .rrd file of its own and
            closes it in ``close``.
        units: Units to place in the scene first, in natural order (imu2 before imu10);
            others join as they appear.
        application_id: The application id of a recording the logger opens.
        recording_id: The recording id of a recording the logger opens.
        window_s: Limit the plots to the last so many seconds, for live viewing; None:
            no limit.
        latency_s: The longest a sample waits before it is sent.
        max_rows: Rows of one unit and record type sent at once, at most.
        write_footer: Whether a file the logger opens gets Rerun's footer.
        max_rate_hz: Thin samples to bins this many a second; None: every sample.

    Raises:
        ValueError: ``max_rate_hz`` is not above 0.
    """

    def __init__(self, target: rr.RecordingStream | str | os.PathLike[str],
                 units: Iterable[str] = (), *, application_id: str = "gx3",
                 recording_id: str | None = None, window_s: float | None = None,
                 latency_s: float = 0.25, max_rows: int = 4096,
                 write_footer: bool = True, max_rate_hz: float | None = None) -> None:
        self.bin_ns = None if max_rate_hz is None else thin.bin_width_ns(max_rate_hz)
        if isinstance(target, rr.RecordingStream):
            self.recording, self._owned = target, False
        else:
            self.recording = rr.RecordingStream(application_id, recording_id=recording_id)
            self.recording.save(os.fspath(target), write_footer=write_footer)
            self._owned = True
        self.window_s = window_s
        self.latency_s = latency_s
        self.max_rows = max_rows
        self._pending: dict[tuple[str, int], _Pending] = {}
        self._kept: dict[tuple[str, int], _Kept] = {}
        self._lock = threading.Lock()
        self._blueprint_lock = threading.Lock()
        self._units: dict[str, int] = {}
        self._styled: set[tuple[str, str]] = set()
        self._plots: set[str] = set()
        self._first_offset: dict[str, int] = {}
        self._sent: tuple[frozenset[str], tuple[str, ...]] | None = None
        self._rate_hz: dict[str, float] = {}
        self._host_clock: dict[str, tuple[str, bool, bool]] = {}  # unit: host, known, synced
        self._lag: dict[str, tuple[int, int]] = {}  # unit: second of arrival, least lag
        self.recording.log(layout.WORLD, rr.ViewCoordinates.FRD, static=True)
        self.recording.log(f"{layout.WORLD}/ned", rr.Arrows3D(
            origins=[layout.NED_ORIGIN_M] * 3, vectors=np.eye(3) * layout.AXIS_LENGTH_M,
            colors=[layout.NED_COLOR], radii=0.005, labels=["N", "E", "D"]), static=True)
        for unit in sorted(units, key=layout.natural_key):
            self._unit(unit)
        self._send_blueprint()

    # --- public API --------------------------------------------------------------------
    @property
    def units(self) -> tuple[str, ...]:
        """The units in the scene, in the order they were placed."""
        return tuple(self._units)

    def log_samples(self, unit: str, code: int, columns: Mapping[str, np.ndarray]) -> None:
        """Log a batch of one unit's records of one type.

        Batches are gathered per unit and record type and sent once ``max_rows`` rows or
        ``latency_s`` seconds have built up (checked at each call), or on ``flush``: a
        send costs about the same for 10 rows as for 4,000.

        Args:
            unit: The unit.
            code: The record type (command byte).
            columns: Every quantity the record holds plus ``ticks`` (unwrapped device
                timer) and ``time_ns`` (aligned host time), as
                ``bridge.bus.codec.decode_batch`` returns them; copied.

        Raises:
            ValueError: A column is missing, or the columns differ in length.
        """
        quantities = record_quantities(code)
        missing = [c for c in ("ticks", "time_ns", *quantities) if c not in columns]
        if missing:
            raise ValueError(f"0x{code:02X} samples of {unit!r} lack column(s) "
                             f"{', '.join(missing)}: pass every quantity of the record "
                             "and ticks, time_ns")
        n = len(columns["ticks"])
        if n > 1 and unit not in self._rate_hz:
            step = float(np.median(np.diff(np.asarray(columns["ticks"], np.int64))))
            if step > 0:
                self._rate_hz[unit] = TICKS_PER_SECOND / step
        bad = [c for c in ("time_ns", *quantities) if len(columns[c]) != n]
        if bad:
            raise ValueError(f"0x{code:02X} samples of {unit!r}: column(s) {', '.join(bad)} "
                             f"do not have the {n} rows of ticks")
        if n == 0:
            return
        self._unit(unit)
        now = time.monotonic()
        with self._lock:
            pending = self._pending.setdefault((unit, code), _Pending(now))
            # copies: the caller may reuse its buffers before the batch is sent
            pending.parts.append({c: np.array(columns[c]) for c in
                                  ("ticks", "time_ns", *quantities)})
            pending.rows += n
        self._send_pending(now)

    def log_status(self, unit: str, statuses: Status | Sequence[Status]) -> None:
        """Log status messages of one unit.

        Plotted: samples/s, dropped total, clock offset (relative to the first status
        with a clock model) and drift. Device time is the clock model's inverse, for
        statuses that have a model (clock_offset_ns != 0). Its bridge host clock's sync
        state goes into the unit's event log when it is first seen and whenever it
        changes (synchronised or not, another host), with the kernel's estimated and
        maximum error at that moment.

        Args:
            unit: The unit.
            statuses: One Status, or several in time order.
        """
        items = [statuses] if isinstance(statuses, Status) else list(statuses)
        if not items:
            return
        index = self._unit(unit)
        time_ns = np.array([s.time_ns for s in items], np.int64)
        offset = np.array([s.clock_offset_ns for s in items], np.int64)
        drift = np.array([s.clock_drift_ppm for s in items], np.float64)
        modelled = offset != 0
        if items[-1].output_rate_hz > 0:
            self._rate_hz[unit] = items[-1].output_rate_hz
        if modelled.any():
            self._first_offset.setdefault(unit, int(offset[modelled][0]))
        first = self._first_offset.get(unit, 0)
        series = {
            "samples_per_s": np.array([s.samples_per_s for s in items], np.float64),
            "dropped": np.array([s.dropped for s in items], np.float64),
            "clock_offset": np.where(modelled, (offset - first) / 1e6, np.nan),
            "clock_drift": np.where(modelled, drift, np.nan),
        }
        device_ns = np.round((time_ns - offset) * (1.0 + drift * 1e-6)).astype(np.int64)
        for plot, values in series.items():
            self._style(plot, unit, index)
            (path,) = layout.plot_paths(plot, unit)
            self._send_split(path, time_ns, device_ns, modelled, rr.Scalars.columns,
                             scalars=values)
        self._log_host_clock(unit, items)
        self._send_blueprint()

    def log_arrivals(self, unit: str, arrival_ns: npt.ArrayLike, time_ns: npt.ArrayLike) -> None:
        """Log when a unit's samples arrived against when they were taken.

        The least arrival - time_ns of each second of arrival is plotted
        (``host_clock``). The latency in it is never negative, so it is the most the
        bridge host's clock can be behind this one's, and below zero the host is provably
        ahead. A second is plotted once the next one begins.

        Args:
            unit: The unit.
            arrival_ns: When the samples reached this process, on its clock (for an
                archive, the recorder's receive times), in arrival order.
            time_ns: When they were taken, on the bridge host's clock.
        """
        arrival = np.asarray(arrival_ns, np.int64)
        if not len(arrival):
            return
        index = self._unit(unit)
        lag = arrival - np.asarray(time_ns, np.int64)
        second = arrival // 1_000_000_000
        pending = self._lag.get(unit)
        if pending is not None:
            second, lag = np.append(pending[0], second), np.append(pending[1], lag)
        starts = np.concatenate(([0], np.flatnonzero(np.diff(second)) + 1))
        seconds, least = second[starts], np.minimum.reduceat(lag, starts)
        self._lag[unit] = (int(seconds[-1]), int(least[-1]))
        if len(seconds) > 1:
            self._style("host_clock", unit, index)
            (path,) = layout.plot_paths("host_clock", unit)
            done = seconds[:-1] * 1_000_000_000
            self._send_split(path, done, done, np.zeros(len(done), bool), rr.Scalars.columns,
                             scalars=least[:-1] / 1e6)
            self._send_blueprint()

    def log_event(self, unit: str, events: Event | Sequence[Event]) -> None:
        """Log events of one unit as text log entries at the time they happened.

        Each text is led by that time of day (UTC). Records lost are told with the time
        they span at the unit's output rate, from its status or, before one came, from
        its samples.

        Events are on the ``time`` timeline only: Rerun 0.41's text log view shows some rows
        with another row's level when the rows of one entity lie on different sets of
        timelines (events with device ticks on both, those without on ``time`` only).

        Args:
            unit: The unit.
            events: One Event, or several.
        """
        items = [events] if isinstance(events, Event) else list(events)
        if not items:
            return
        self._unit(unit)
        rate_hz = self._rate_hz.get(unit, 0.0)
        self._send_texts(unit, [(e.time_ns, event_text(unit, e, rate_hz),
                                 LEVEL.get(e.kind, "INFO")) for e in items])
        self._send_blueprint()

    def flush(self) -> None:
        """Send every gathered sample and wait until the recording has them."""
        self._send_pending(None)
        self.recording.flush()

    def close(self) -> None:
        """Flush; for a logger that opened its own file, also finish and close that file."""
        self.flush()
        if self._owned:
            self.recording.disconnect()

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # --- internals ---------------------------------------------------------------------
    def _unit(self, unit: str) -> int:
        """The unit's place in the scene; the first sight of a unit logs its static parts."""
        with self._lock:
            if unit in self._units:
                return self._units[unit]
            index = self._units[unit] = len(self._units)
        rec, body, color = self.recording, layout.body_path(unit), layout.unit_color(index)
        rec.log(f"{layout.WORLD}/{layout.entity_part(unit)}",
                rr.Transform3D(translation=layout.unit_position(index)), static=True)
        half = np.array(layout.BOX_SIZE_M) * layout.BOX_SCALE / 2
        rec.log(f"{body}/box", rr.Boxes3D(half_sizes=[half], colors=[(*color, 200)],
                                          fill_mode=rr.components.FillMode.Solid,
                                          labels=[unit]), static=True)
        rec.log(f"{body}/axes", rr.Arrows3D(
            vectors=np.eye(3) * layout.AXIS_LENGTH_M, radii=0.008,
            colors=np.array(layout.AXIS_COLORS, np.uint8)), static=True)
        for arrow, arrow_color in (("accel", layout.ACCEL_COLOR), ("mag", layout.MAG_COLOR)):
            rec.log(f"{body}/{arrow}", rr.Arrows3D.from_fields(
                colors=np.array([arrow_color], np.uint8), radii=0.01), static=True)
        return index

    def _send_pending(self, now: float | None) -> None:
        """Send the gathered batches that are due at ``now`` (all of them for None)."""
        with self._lock:
            due = [key for key, p in self._pending.items() if now is None
                   or p.rows >= self.max_rows or now - p.since >= self.latency_s]
            taken = [(key, self._pending.pop(key)) for key in due]
        width_ns = self.bin_ns
        for key, pending in taken:
            parts = pending.parts
            record = parts[0] if len(parts) == 1 else {
                c: np.concatenate([p[c] for p in parts]) for c in parts[0]}
            if width_ns is None:
                for start in range(0, pending.rows, self.max_rows):
                    self._send_samples(key[0], {c: v[start:start + self.max_rows]
                                                for c, v in record.items()})
                continue
            carried = self._thin(key, record, width_ns, now)
            if now is not None and len(carried["ticks"]):
                with self._lock:  # first among what came since: the bin it ends is open
                    pending = self._pending.setdefault(key, _Pending(now))
                    pending.parts.insert(0, carried)
                    pending.rows += len(carried["ticks"])
        if width_ns is not None:
            self._send_kept(now)
        if taken:
            self._send_blueprint()

    def _send_samples(self, unit: str, record: dict[str, np.ndarray]) -> None:
        """One send per plot and scene entity, for all rows at once."""
        index, rec, n = self._units[unit], self.recording, len(record["ticks"])
        time_ns = np.asarray(record.pop("time_ns"), np.int64)
        device_ns = np.asarray(record.pop("ticks"), np.int64) * NS_PER_TICK
        indexes = _indexes(time_ns, device_ns)
        for plot, values in _sample_series(record, n).items():
            self._style(plot, unit, index)
            for path, line in zip(layout.plot_paths(plot, unit), values.T, strict=True):
                rec.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=line))
        self._send_scene(unit, record, time_ns, device_ns, indexes)

    def _send_scene(self, unit: str, record: Mapping[str, np.ndarray], time_ns: np.ndarray,
                    device_ns: np.ndarray, indexes: list[rr.TimeColumn]) -> None:
        """The attitude and the arrows of rows (``indexes``: their timelines)."""
        rec, body = self.recording, layout.body_path(unit)
        xyzw = _sensor_to_earth(record)
        if xyzw is not None:
            ok = np.isfinite(xyzw).all(axis=1)
            rec.send_columns(body, indexes=indexes if ok.all() else
                             _indexes(time_ns[ok], device_ns[ok]),
                             columns=rr.Transform3D.columns(quaternion=xyzw[ok]))
        for name, (arrow, scale) in layout.ARROWS.items():
            if name in record:
                vectors = np.asarray(record[name], np.float32) * np.float32(scale)
                rec.send_columns(f"{body}/{arrow}", indexes=indexes,
                                 columns=rr.Arrows3D.columns(vectors=vectors))

    def _thin(self, key: tuple[str, int], record: dict[str, np.ndarray], width_ns: int,
              now: float | None) -> dict[str, np.ndarray]:
        """Keep each ``width_ns`` bin's extremes of every line, and its first row.

        Unless ``now`` is None (a flush), the last bin stays open: the rows it still needs
        are returned, to go first in the next batch; else nothing is.
        """
        unit = key[0]
        index = self._units[unit]
        if (np.diff(record["time_ns"]) < 0).any():  # a late batch: bins need time order
            order = np.argsort(record["time_ns"], kind="stable")
            record = {c: v[order] for c, v in record.items()}
        time_ns = np.asarray(record["time_ns"], np.int64)
        device_ns = np.asarray(record["ticks"], np.int64) * NS_PER_TICK
        bins = thin.Bins.of(time_ns, width_ns, hold_last=now is not None)
        extremes, lines = [], {}
        for plot, values in _sample_series(record, len(time_ns)).items():
            self._style(plot, unit, index)
            for path, line in zip(layout.plot_paths(plot, unit), values.T, strict=True):
                rows = bins.extremes(line)
                extremes.append(rows)
                rows = rows[rows < bins.cut]
                lines[path] = (time_ns[rows], device_ns[rows], line[rows])
        firsts = bins.firsts
        with self._lock:
            kept = self._kept.setdefault(key, _Kept(time.monotonic() if now is None else now))
            for path, piece in lines.items():
                kept.lines.setdefault(path, []).append(piece)
            kept.scene.append({c: v[firsts] for c, v in record.items()})
            kept.rows += max((len(t) for t, _, _ in lines.values()), default=len(firsts))
        carried = bins.carried(extremes)
        return {c: v[carried] for c, v in record.items()}

    def _send_kept(self, now: float | None) -> None:
        """Send what thinning kept that is due at ``now`` (all of it for None)."""
        with self._lock:
            due = [key for key, k in self._kept.items() if now is None
                   or k.rows >= self.max_rows or now - k.since >= self.latency_s]
            taken = [(key, self._kept.pop(key)) for key in due]
        rec = self.recording
        for (unit, _), kept in taken:
            for path, pieces in kept.lines.items():
                time_ns, device_ns, values = (np.concatenate([p[i] for p in pieces])
                                              for i in range(3))
                for part in _parts(np.arange(len(time_ns)), self.max_rows):
                    rec.send_columns(path, indexes=_indexes(time_ns[part], device_ns[part]),
                                     columns=rr.Scalars.columns(scalars=values[part]))
            scene = {c: np.concatenate([p[c] for p in kept.scene]) for c in kept.scene[0]}
            time_ns = np.asarray(scene["time_ns"], np.int64)
            device_ns = np.asarray(scene["ticks"], np.int64) * NS_PER_TICK
            for part in _parts(np.arange(len(time_ns)), self.max_rows):
                self._send_scene(unit, {c: v[part] for c, v in scene.items()}, time_ns[part],
                                 device_ns[part], _indexes(time_ns[part], device_ns[part]))

    def _log_host_clock(self, unit: str, items: Sequence[Status]) -> None:
        """The statuses where the unit's host clock state changed, as text log entries."""
        changes = []
        for status in items:
            if not status.HasField("host_clock"):
                continue
            state = status.host_clock
            seen = (state.host, state.known, state.synchronised)
            if self._host_clock.get(unit) != seen:
                self._host_clock[unit] = seen
                changes.append((status.time_ns, *_host_clock_text(unit, state)))
        if changes:
            self._send_texts(unit, changes)

    def _send_texts(self, unit: str, rows: Sequence[tuple[int, str, str]]) -> None:
        """(time_ns, text, level) rows into the unit's event log.

        Each text is led by its time of day (UTC), on the ``time`` timeline only (see
        ``log_event``).
        """
        time_ns = np.array([t for t, _, _ in rows], np.int64)
        texts = np.array([f"{_time_of_day(t)}  {text}" for t, text, _ in rows], dtype=str)
        levels = np.array([level for _, _, level in rows], dtype=str)
        self.recording.send_columns(layout.event_path(unit), indexes=_indexes(time_ns, None),
                                    columns=rr.TextLog.columns(text=texts, level=levels))

    def _style(self, plot: str, unit: str, index: int) -> None:
        """Names and colours of a unit's lines in a plot, logged once, static."""
        with self._lock:
            if (plot, unit) in self._styled:
                return
            self._styled.add((plot, unit))
            self._plots.add(plot)
        color = layout.unit_color(index)
        for path, label in zip(layout.plot_paths(plot, unit), PLOT[plot].labels, strict=True):
            self.recording.log(path, rr.SeriesLines(names=[f"{unit} {label}"], colors=[color]),
                               static=True)

    def _send_blueprint(self) -> None:
        """Send the blueprint when the plots or the number of units changed since it was sent.

        One sender at a time, so the last one sent is the newest.
        """
        with self._blueprint_lock:
            with self._lock:
                sent = (frozenset(self._plots), tuple(self._units))
            if sent == self._sent:
                return
            self._sent = sent
            self.recording.send_blueprint(layout.blueprint(*sent, window_s=self.window_s),
                                          make_active=True, make_default=True)

    def _send_split(self, path: str, time_ns: np.ndarray, device_ns: np.ndarray,
                    has_device: np.ndarray, columns: Callable[..., Any],
                    **values: np.ndarray) -> None:
        """``columns(**values)`` of rows with a device time on both timelines.

        The other rows go on ``time`` only.
        """
        for rows, dev in ((has_device, device_ns), (~has_device, None)):
            if rows.any():
                self.recording.send_columns(
                    path, indexes=_indexes(time_ns[rows], None if dev is None else dev[rows]),
                    columns=columns(**{k: v[rows] for k, v in values.items()}))
