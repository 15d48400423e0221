"""Rerun .rrd files read back with Rerun's own reader: rows, plot values, blueprint views."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader

from bridge.viz import layout


def table(store: Any, entity: str, index: str | None = "time") -> pa.Table:
    """The rows of ``entity`` in a recording ``store``, on the ``index`` timeline."""
    return store.reader(index=index, contents=entity).to_arrow_table()


def plot_values(store: Any, plot: str, unit: str) -> np.ndarray:
    """(rows, lines) of a unit's plot: one entity per line."""
    return np.column_stack([np.array(table(store, path).column(f"{path}:Scalars:scalars")
                                     .to_pylist())[:, 0] for path in layout.plot_paths(plot, unit)])


def scalar_lines(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every plotted line in a recording: its entity -> (time ns, value) of its rows, in time
    order; read chunk by chunk with Rerun's own reader (a 10-minute fleet's recording in a
    second, where a query per entity takes many)."""
    parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    with warnings.catch_warnings():  # a recorder's --rrd has no footer
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        chunks = list(RrdReader(path).stream())
    for chunk in chunks:
        if "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        if "Scalars:scalars" in batch.schema.names:
            parts.setdefault(chunk.entity_path, []).append((
                batch.column("time").cast(pa.int64()).to_numpy(),
                batch.column("Scalars:scalars").flatten().to_numpy()))
    out = {}
    for entity, pieces in parts.items():
        times = np.concatenate([t for t, _ in pieces])
        order = np.argsort(times, kind="stable")
        out[entity] = times[order], np.concatenate([v for _, v in pieces])[order]
    return out


def blueprint_views(path: Path) -> list[set[tuple[str, str]]]:
    """(view class, origin) of every view, one set per blueprint in the file."""
    reader = RrdReader(path)
    out = []
    for entry in reader.blueprints():
        views = set()
        for chunk in reader.stream(store=entry):
            batch = chunk.to_record_batch()
            names = batch.schema.names
            if "ViewBlueprint:space_origin" in names:
                kind = batch.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
                origin = batch.column("ViewBlueprint:space_origin").to_pylist()[0][0]
                views.add((kind, origin))
        out.append(views)
    return out


def rerun_rows(path: Path, entity: str) -> int:
    """Rows logged at ``entity`` on the ``time`` timeline, read with Rerun's own reader."""
    with warnings.catch_warnings():  # files still being written have no footer yet
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        return sum(c.num_rows for c in RrdReader(path).stream()
                   if c.entity_path == entity and "time" in c.timeline_names)


def rerun_rows_so_far(path: Path, entity: str) -> int:
    """``rerun_rows`` of a file another process is writing, 0 while Rerun's reader cannot
    read it yet (a frame cut at the end: RuntimeError; no recording in it yet, only its
    blueprint: ValueError); the finished file is checked in full."""
    try:
        return rerun_rows(path, entity) if path.exists() else 0
    except (RuntimeError, ValueError):
        return 0
