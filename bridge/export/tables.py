"""Archive to table: one row per sample, flat quantity columns, for pandas, R, spreadsheets.

Rows are in ``time_ns`` order across units, and each quantity a record holds is
flattened into columns (``accel_x``, ``m11`` .. ``m33``, ``roll``, ``q0``, ...). A
written file describes itself: a ``time_utc`` timestamp beside ``time_ns``, lower-case
identifiers as column names (SQL, pandas attribute access), nulls where a value is
missing and, in Parquet, each column's unit and frame and the file's provenance as
metadata. The columns one by one: ``docs/design/archive.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from bridge.archive.outputs import named_format
from bridge.archive.reader import ArchiveReader
from bridge.archive.samples import ArchivedSamples
from bridge.bus.codec import elements
from bridge.bus.gx3_pb2 import Event, Info
from bridge.export.describe import (
    ALIGNED_SEPARATOR,
    QUANTITY_ORDER,
    About,
    column_metadata,
    csv_header,
    flat_names,
    unit_labels,
)
from bridge.protocol.convert import (
    euler_to_quaternion,
    m_to_quaternion,
    quaternion_to_euler,
    quaternion_to_m,
)
from bridge.timing.offline import Estimate
from bridge.timing.realtime import RealtimeReads
from bridge.timing.stream import TRANSPORTS, Settings

#: Offline re-estimate of sample times: (unit, its columns ``ticks``, ``time_ns`` (live),
#: ``rx_ns``, ``rx_mono_raw_ns`` and the partial reads, in the order they were received)
#: -> time_ns and each one's uncertainty, int64 ns; None keeps that unit's live times.
ReEstimate = Callable[[str, Mapping[str, np.ndarray]], Estimate | None]

FORMATS = (".parquet", ".csv")


def _unit_times(unit: str, blocks: Sequence[ArchivedSamples],
                re_estimate: ReEstimate | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Best time_ns of each block of one unit and how sure each is.

    Live (uncertainty not known, 0), or re-estimated over the whole unit.
    """
    live = [(b.columns["time_ns"], np.zeros(len(b), np.int64)) for b in blocks]
    if re_estimate is None:
        return live
    columns = {name: np.concatenate([b.columns[name] for b in blocks])
               for name in ("ticks", "time_ns", "rx_ns", "rx_mono_raw_ns", "part_rx_mono_raw_ns",
                            "part_lead_ns")}
    raw = columns["rx_mono_raw_ns"]
    # the raw clock orders reads truly; the realtime clock may have been stepped back
    order = np.argsort(raw if (raw > 0).all() else columns["rx_ns"], kind="stable")
    found = re_estimate(unit, {name: col[order] for name, col in columns.items()})
    if found is None:
        return live
    cuts = np.cumsum([len(b) for b in blocks])[:-1]
    out = []
    for values in found:
        column = np.empty(len(raw), np.int64)
        column[order] = values
        out.append(np.split(column, cuts))
    return list(zip(*out, strict=True))


def last_info(archive: ArchiveReader, unit: str) -> Info | None:
    """The last Info a unit's bridge published into the archive."""
    topic = f"{archive_prefix(archive)}/{unit}/info"
    infos = archive.decoded(topic, Info) if topic in archive.topics("info") else []
    return infos[-1][1] if infos else None


def _unit_settings(archive: ArchiveReader, unit: str) -> Settings | None:
    """What decided a unit's timing, from the last Info its bridge published."""
    info = last_info(archive, unit)
    if info is None:
        return None
    if not (info.command and info.baud and info.decimation and info.filter_width):
        return None
    return Settings(record=info.command, decimation=info.decimation,
                    filter_width=info.filter_width, baud=info.baud,
                    transport=info.link if info.link in TRANSPORTS else "uart",
                    latency_timer_ms=info.latency_timer_ms or None)


def archive_prefix(archive: ArchiveReader) -> str:
    """The key prefix the archive was recorded under."""
    for m in archive.metadata:
        if m.name == "gx3.archive" and "prefix" in m.metadata:
            return m.metadata["prefix"]
    return "gx3"


def offline_times(archive: ArchiveReader) -> ReEstimate:
    """Each unit's sample instants re-estimated over the whole recording.

    The live estimate only had the past. A unit is timed with the settings of its
    archived Info; units without one keep their live times. Each sample carries the read
    that ended inside its record, or right where it begins, where there was one
    (``part_rx_mono_raw_ns``): with it the records are bounded as live, to a byte time
    behind a USB-serial adapter.

    Where the samples carry their reads' raw-clock stamps, the unit's clock is fitted
    against the raw clock and each instant mapped onto the realtime clock as live
    (``bridge.timing.realtime``), by the offsets of the samples' reads (``rx_ns`` less
    ``rx_mono_raw_ns``); between two reads around a step the archive cannot tell which
    side an instant was on, and takes the side the live estimate took.

    Args:
        archive: The archive read.

    Returns:
        The re-estimate, for ``sample_table``'s ``re_estimate``.
    """
    def estimate(unit: str, columns: Mapping[str, np.ndarray]) -> Estimate | None:
        ticks, rx_ns, raw = columns["ticks"], columns["rx_ns"], columns["rx_mono_raw_ns"]
        settings = _unit_settings(archive, unit)
        if settings is None or len(ticks) < 2:
            return None
        on_raw = bool((raw > 0).all())
        order = np.argsort(ticks, kind="stable")
        rx = (raw if on_raw else rx_ns)[order]
        part, lead = columns["part_rx_mono_raw_ns"][order], columns["part_lead_ns"][order]
        has = (part > 0) & on_raw  # recorded, on the raw clock the rest is timed on
        instants, doubt = settings.offline_clock().estimate(
            ticks[order], rx, np.where(has, part, rx), np.where(has, lead, settings.floor_ns))
        if on_raw:
            reads, first = np.unique(raw, return_index=True)
            track = RealtimeReads(reads, rx_ns[first])
            live_offset = columns["time_ns"][order] - instants
            instants = track.map_array(instants, raw[order], sides=live_offset)
        out = Estimate(np.empty(len(ticks), np.int64), np.empty(len(ticks), np.int64))
        out.time_ns[order], out.uncertainty_ns[order] = instants, doubt
        return out

    return estimate


def sample_table(archive: ArchiveReader, units: Iterable[str] | None = None,
                 codes: Iterable[int] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None,
                 re_estimate: ReEstimate | None = None) -> dict[str, np.ndarray]:
    """Columns of the export: one row per sample, in time order.

    Args:
        archive: The archive read.
        units: Only these units; None: every unit.
        codes: Only these record types (command bytes); None: every type.
        start_ns: Only samples with ``time_ns`` at or after this (host ns).
        end_ns: Only samples with ``time_ns`` before this (host ns).
        re_estimate: Re-estimates each unit's sample times (``offline_times``); None
            keeps the live ones.

    Returns:
        Column name -> one value per row: ``unit``, ``command``, ``timer``, ``ticks``,
        ``time_ns`` (the best estimate of the sample instant: the live estimate unless a
        re-estimate is given), ``time_uncertainty_ns`` (the most ``time_ns`` can be off
        by, as the reads bound it; 0: not known), ``live_time_ns`` (as the bridge
        published it), ``rx_ns`` (host receive time), then each quantity any exported
        record holds, flattened (``accel_x``, ``m11`` .. ``m33``, ``roll``, ``q0``,
        ``temperature_0``, ...), NaN where a record lacks it. Temperatures are A/D codes
        stored as float32 (exact), so that they can be missing too. Orientation columns
        keep the manual's convention: M maps earth (NED) to sensor, the quaternion is
        scalar first.
    """
    blocks = archive.samples(units, codes)
    by_unit: dict[str, list[ArchivedSamples]] = {}
    for b in blocks:
        by_unit.setdefault(b.unit, []).append(b)
    times = {u: _unit_times(u, bs, re_estimate) for u, bs in by_unit.items()}
    unit_names = sorted(by_unit)
    ordered = [(b, t) for u in unit_names for b, t in zip(by_unit[u], times[u], strict=True)]
    time_ns, doubt = (np.concatenate([t[i] for _, t in ordered]) if ordered
                      else np.zeros(0, np.int64) for i in range(2))
    keep = np.ones(len(time_ns), bool)
    if start_ns is not None:
        keep &= time_ns >= start_ns
    if end_ns is not None:
        keep &= time_ns < end_ns
    present = [q for q in QUANTITY_ORDER if any(q in b.columns for b, _ in ordered)]
    columns: dict[str, np.ndarray] = {
        "unit": np.concatenate([np.full(len(b), unit_names.index(b.unit), np.int32)
                                for b, _ in ordered]) if ordered else np.zeros(0, np.int32),
        "command": _cat(ordered, "command", np.uint8),
        "timer": _cat(ordered, "timer", np.uint32),
        "ticks": _cat(ordered, "ticks", np.int64),
        "time_ns": time_ns,
        "time_uncertainty_ns": doubt,
        "live_time_ns": _cat(ordered, "time_ns", np.int64),
        "rx_ns": _cat(ordered, "rx_ns", np.int64),
    }
    for q in present:
        width = next(int(np.prod(b.columns[q].shape[1:])) for b, _ in ordered if q in b.columns)
        flat = np.full((len(time_ns), width), np.nan, np.float32)
        at = 0
        for b, _ in ordered:
            if q in b.columns:
                flat[at : at + len(b)] = b.columns[q].reshape(len(b), width)
            at += len(b)
        for i, name in enumerate(flat_names(q, width)):
            columns[name] = flat[:, i]
    order = np.flatnonzero(keep)
    order = order[np.lexsort((columns["unit"][order], time_ns[order]))]
    out = {k: v[order] for k, v in columns.items()}
    out["unit"] = np.asarray(unit_names, dtype=str)[out["unit"]] if unit_names \
        else np.zeros(0, str)
    return out


def _cat(ordered: list[tuple[ArchivedSamples, tuple[np.ndarray, np.ndarray]]], name: str,
         dtype: type) -> np.ndarray:
    if not ordered:
        return np.zeros(0, dtype)
    return np.concatenate([b.columns[name] for b, _ in ordered]).astype(dtype)


def event_table(archive: ArchiveReader, units: Iterable[str] | None = None,
                start_ns: int | None = None, end_ns: int | None = None) -> dict[str, np.ndarray]:
    """Every event (gap, reset, rollover, reconnect, ...) of every unit, with its time.

    Args:
        archive: The archive read.
        units: Only these units' events; None: every unit's.
        start_ns: Only events at or after this (host ns).
        end_ns: Only events before this (host ns).

    Returns:
        Columns ``unit``, ``time_ns``, ``ticks``, ``kind``, ``amount`` and ``detail``, a
        row per event; ``amount`` is the Event's ``count`` (``count`` is a method of a
        pandas DataFrame).
    """
    lo = -(1 << 63) if start_ns is None else start_ns
    hi = (1 << 63) - 1 if end_ns is None else end_ns
    rows = [(u, e) for u, e in archive.events(units) if lo <= e.time_ns < hi]
    return {
        "unit": np.array([u for u, _ in rows], str),
        "time_ns": np.array([e.time_ns for _, e in rows], np.int64),
        "ticks": np.array([e.ticks for _, e in rows], np.int64),
        "kind": np.array([Event.Kind.Name(e.kind) for _, e in rows], str),
        "amount": np.array([e.count for _, e in rows], np.uint64),
        "detail": np.array([e.detail for _, e in rows], str),
    }


def _arrow(col: np.ndarray) -> pa.Array:
    if col.dtype.kind in "OU":  # names: stored once per file, not once per row
        return pa.array(col.astype(str), pa.string()).dictionary_encode()
    if col.dtype.kind == "f":  # a missing value is null: SQL and polars count it as missing
        missing = np.isnan(col)
        return pa.array(col, mask=missing) if missing.any() else pa.array(col)
    return pa.array(col)


def _encoding(kind: pa.DataType) -> str | None:
    """How a Parquet column is stored best (None: a dictionary, for names and codes).

    Clocks and counters step by about a period: as deltas they take a few bits a row,
    where zstd of the plain values leaves six bytes. Noisy floats compress a fifth
    better, and faster, with their bytes split into streams of like significance.
    """
    if pa.types.is_timestamp(kind) or (pa.types.is_integer(kind) and kind.bit_width >= 32):
        return "DELTA_BINARY_PACKED"
    if pa.types.is_floating(kind):
        return "BYTE_STREAM_SPLIT"
    return None


def write_table(columns: dict[str, np.ndarray], path: Path, about: About | None = None) -> None:
    """Write columns as Parquet (zstd) or CSV, chosen by the file's extension.

    A ``time_utc`` timestamp goes beside ``time_ns``; in Parquet, each column's unit and
    frame and ``about`` go in as metadata, in CSV each column's unit into its header
    (``csv_header``: ``accel_x [g]``).

    Args:
        columns: The table (``sample_table``, ``event_table``, ``align_table``).
        path: The file to write, ``.parquet`` or ``.csv``.
        about: The file's provenance: archive, units, options.

    Raises:
        OutputRefused: The extension names no format this writes.
    """
    suffix = named_format(path, *FORMATS)
    labels = unit_labels(about.infos) if about else {}
    fields, arrays = [], []
    for name, col in columns.items():
        named = [(name, _arrow(col))]
        if name == "time_ns":
            named.append(("time_utc", named[0][1].view(pa.timestamp("ns", tz="UTC"))))
        for n, array in named:
            fields.append(pa.field(n, array.type, metadata=column_metadata(n, labels)))
            arrays.append(array)
    schema = pa.schema(fields, metadata=about.metadata() if about else None)
    table = pa.Table.from_arrays(arrays, schema=schema)
    if suffix == ".parquet":
        encodings = {f.name: e for f in fields if (e := _encoding(f.type))}
        pq.write_table(table, path, compression="zstd", column_encoding=encodings,
                       use_dictionary=[f.name for f in fields if f.name not in encodings])
    else:
        pa_csv.write_csv(table.rename_columns([csv_header(f.name, labels) for f in fields]),
                         path)


# -- aligning units on one time grid ---------------------------------------------------------

#: Neighbouring samples further apart than this many typical periods are a gap: no value
#: is made up between them.
GAP_PERIODS = 1.5
_TO_QUATERNION: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "m": lambda v: m_to_quaternion(v.reshape(-1, 3, 3)),
    "quaternion": lambda v: v,
    "euler": euler_to_quaternion,
}
_FROM_QUATERNION: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "m": lambda q: quaternion_to_m(q).reshape(-1, 9),
    "quaternion": lambda q: q,
    "euler": quaternion_to_euler,
}


def _slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical interpolation of (n, 4) unit quaternions, the short way round."""
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    dot = np.sum(q0 * q1, axis=1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-9
    safe = np.where(small, 1.0, sin)
    a = np.where(small, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    b = np.where(small, w, np.sin(w * theta) / safe)
    out: np.ndarray = a[:, None] * q0 + b[:, None] * q1
    return out


def _resample(t: np.ndarray, values: np.ndarray, grid: np.ndarray, quantity: str) -> np.ndarray:
    """``values`` (n, k) at sample times ``t`` on ``grid``.

    Linear for vectors, slerp for orientation (m, quaternion, euler); NaN outside the
    samples and inside gaps.
    """
    out = np.full((len(grid), values.shape[1]), np.nan)
    if len(t) < 2:
        exact = np.isin(grid, t)
        out[exact] = values[:1]
        return out
    period = float(np.median(np.diff(t)))
    i = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 2)
    span = (t[i + 1] - t[i]).astype(np.float64)
    w = (grid - t[i]) / np.where(span > 0, span, 1.0)
    ok = (grid >= t[0]) & (grid <= t[-1]) & (span <= GAP_PERIODS * period)
    ok |= grid == t[i]  # a sample exactly on the grid is always kept
    lo, hi, w = values[i[ok]].astype(np.float64), values[i[ok] + 1].astype(np.float64), w[ok]
    if quantity in _TO_QUATERNION:
        to_q, from_q = _TO_QUATERNION[quantity], _FROM_QUATERNION[quantity]
        out[ok] = from_q(_slerp(to_q(lo), to_q(hi), w))
    else:
        out[ok] = lo + w[:, None] * (hi - lo)
    return out


def align_table(table: dict[str, np.ndarray], rate_hz: float) -> dict[str, np.ndarray]:
    """The units' samples on one time grid: a row per instant, a column per unit and quantity.

    The grid's instants are multiples of the period since the epoch. A column is named
    ``<unit label>__<column>`` (``unit_labels``: a name SQL and pandas take as it is);
    values are interpolated linearly (orientation by slerp), and are NaN outside a
    unit's samples and inside its gaps.

    Args:
        table: A sample table (``sample_table``).
        rate_hz: The grid's rate.

    Returns:
        ``time_ns`` and the aligned columns.

    Raises:
        ValueError: The rate is not positive.
    """
    if not rate_hz > 0:
        raise ValueError(f"--align {rate_hz}: give a positive rate in Hz, e.g. 100")
    step = round(1e9 / rate_hz)
    times = table["time_ns"]
    grid = np.arange(-(-int(times.min()) // step) * step, int(times.max()) + 1, step,
                     dtype=np.int64)
    out: dict[str, np.ndarray] = {"time_ns": grid}
    groups = [(q, flat_names(q, elements(q))) for q in QUANTITY_ORDER]
    labels = unit_labels(table["unit"].tolist())
    for unit, label in labels.items():
        rows = table["unit"] == unit
        for q, names in groups:
            if names[0] not in table:
                continue
            values = np.stack([table[n][rows] for n in names], axis=1)
            have = np.isfinite(values).all(axis=1)
            if not have.any():
                continue
            aligned = _resample(times[rows][have], values[have], grid, q)
            for k, name in enumerate(names):
                out[f"{label}{ALIGNED_SEPARATOR}{name}"] = aligned[:, k].astype(np.float32)
    return out
