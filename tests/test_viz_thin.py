"""Thinning for a recording of any length: each bin's extremes, read back with Rerun's reader."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

from bridge.bus.gx3_pb2 import Event, Status
from bridge.viz import layout
from bridge.viz.demo import DEMO_EPOCH_NS, demo_columns
from bridge.viz.logger import RerunLogger
from bridge.viz.thin import Bins, bin_width_ns
from tests.helpers.rrd import table

SECONDS = 6.0
RATE_HZ = 100.0


def brute_extremes(time_ns: np.ndarray, values: np.ndarray, width_ns: int) -> np.ndarray:
    """Each bin's first least and first greatest row, one bin at a time."""
    picked: set[int] = set()
    for b in np.unique(time_ns // width_ns):
        rows = np.flatnonzero(time_ns // width_ns == b)
        finite = rows[np.isfinite(values[rows])]
        if len(finite):
            picked.add(int(finite[np.argmin(values[finite])]))
            picked.add(int(finite[np.argmax(values[finite])]))
    return np.array(sorted(picked), np.int64)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.one_of(
    st.floats(-5, 5, allow_nan=False), st.just(float("nan")), st.sampled_from([1.0, -1.0]))),
    max_size=60), st.integers(1, 15))
def test_extremes_are_each_bins_first_least_and_greatest(rows: list[tuple[int, float]],
                                                         width: int) -> None:
    """NaN passed over, ties to the first row, a bin of NaN alone keeps nothing."""
    time_ns = np.sort(np.array([t for t, _ in rows], np.int64))
    values = np.array([v for _, v in rows], np.float64)
    bins = Bins.of(time_ns, width, hold_last=False)
    assert np.array_equal(bins.extremes(values), brute_extremes(time_ns, values, width))


def test_bin_widths() -> None:
    assert bin_width_ns(10) == 100_000_000 and bin_width_ns(1 / 60) == 60_000_000_000
    assert bin_width_ns(3e9) == 1
    for bad in (0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="above 0"):
            bin_width_ns(bad)


def lines(path: Path, plot: str, unit: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each line of a unit's plot: (time ns, value) of its rows."""
    store = RrdReader(path).stream().collect()
    out = {}
    for entity in layout.plot_paths(plot, unit):
        rows = table(store, entity)
        out[entity] = (np.array(rows.column("time").cast("int64").to_pylist(), np.int64),
                       np.array(rows.column(f"{entity}:Scalars:scalars").to_pylist())[:, 0])
    return out


@pytest.fixture(scope="module")
def fleet() -> dict[str, dict[str, np.ndarray]]:
    """Two units' samples, one with a NaN attitude and a spike."""
    data = {"u1": demo_columns("u1", 0xCC, 1, SECONDS, RATE_HZ),
            "u2": demo_columns("u2", 0xC8, 2, SECONDS, RATE_HZ)}
    data["u1"]["accel"][123] = [9.0, -9.0, 0.5]  # a knock: one sample
    data["u2"]["m"][40] = np.nan
    return data


def render(path: Path, data: dict[str, dict[str, np.ndarray]], splits: list[int],
           rate_hz: float, latency_s: float = 0.0) -> None:
    """The samples logged in pieces cut at ``splits``, thinned, with status and events."""
    codes = {"u1": 0xCC, "u2": 0xC8}
    with RerunLogger(path, ["u1", "u2"], max_rate_hz=rate_hz, latency_s=latency_s,
                     max_rows=50) as log:
        for unit, columns in data.items():
            for rows in np.split(np.arange(len(columns["ticks"])), splits):
                log.log_samples(unit, codes[unit], {k: v[rows] for k, v in columns.items()})
            log.log_status(unit, [Status(unit=unit, time_ns=DEMO_EPOCH_NS + k * 10**9,
                                         samples_per_s=100.0) for k in range(6)])
            log.log_event(unit, Event(unit=unit, time_ns=DEMO_EPOCH_NS + 2 * 10**9,
                                      kind=Event.GAP, count=3))


@pytest.mark.parametrize("rate_hz", [2.0, 0.4])
def test_every_bins_extremes_at_their_instants_however_the_batches_fall(
        tmp_path: Path, fleet: dict[str, dict[str, np.ndarray]], rate_hz: float) -> None:
    """Batches of any length, sent as they come (a bin held open across sends): each line
    keeps exactly each bin's least and greatest sample, at its own time; the attitude
    is each bin's first; status and events are whole."""
    width = bin_width_ns(rate_hz)
    whole, pieces = tmp_path / "whole.rrd", tmp_path / "pieces.rrd"
    render(whole, fleet, [], rate_hz)
    render(pieces, fleet, [7, 8, 101, 250, 251, 333, 590], rate_hz)
    for path in (whole, pieces):
        for unit, plot in (("u1", "accel"), ("u1", "euler"), ("u2", "ang_rate"),
                           ("u2", "euler")):
            time_ns = fleet[unit]["time_ns"]
            expected = {"accel": fleet[unit]["accel"], "ang_rate": fleet[unit]["ang_rate"]}
            for (entity, (t, v)), axis in zip(lines(path, plot, unit).items(), range(3),
                                              strict=True):
                if plot in expected:
                    values = np.asarray(expected[plot][:, axis], np.float64)
                    rows = brute_extremes(time_ns, values, width)
                    assert np.array_equal(t, time_ns[rows]), entity
                    assert np.array_equal(v, values[rows]), entity
                else:  # derived: every bin once, 2 rows at most, NaN never kept
                    bins = time_ns // width
                    assert set(t // width) == set(bins), entity
                    assert np.bincount(t // width - bins[0]).max() <= 2 and np.isfinite(v).all()
        store = RrdReader(path).stream().collect()
        for unit in ("u1", "u2"):
            attitude = table(store, f"/world/{unit}/body")
            starts = np.flatnonzero(np.r_[True, np.diff(fleet[unit]["time_ns"] // width) != 0])
            firsts = fleet[unit]["time_ns"][starts]
            if unit == "u2":  # the NaN attitude is the first of no bin here
                assert 40 not in starts
            assert attitude.column("time").cast("int64").to_pylist() == firsts.tolist()
            assert table(store, f"/plots/samples_per_s/{unit}").num_rows == 6
            assert table(store, f"/events/{unit}").num_rows == 1
    assert 123 in brute_extremes(fleet["u1"]["time_ns"], fleet["u1"]["accel"][:, 0], width)


def test_a_bin_is_sent_once_a_later_sample_closes_it(
        tmp_path: Path, fleet: dict[str, dict[str, np.ndarray]]) -> None:
    """A live tee: what is sent before the end holds closed bins only, and the open one
    comes with ``flush``."""
    path = tmp_path / "live.rrd"
    cols = fleet["u1"]
    with RerunLogger(path, max_rate_hz=1.0, latency_s=0.0) as log:
        log.log_samples("u1", 0xCC, {k: v[:250] for k, v in cols.items()})  # 2.5 s
        log.recording.flush()
        sent = rows_on_file(path, "/plots/accel/x/u1")
        log.log_samples("u1", 0xCC, {k: v[250:] for k, v in cols.items()})
    assert sent and max(sent) < DEMO_EPOCH_NS + 2 * 10**9  # the bin from 2 s is open
    assert max(rows_on_file(path, "/plots/accel/x/u1")) >= DEMO_EPOCH_NS + 5 * 10**9


def rows_on_file(path: Path, entity: str) -> list[int]:
    """The times of an entity's rows in a file being written (no footer yet)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        return [t for c in RrdReader(path).stream()
                if c.entity_path == entity and c.timeline_names
                for t in c.to_record_batch().column("time").cast("int64").to_pylist()]


def test_a_rate_above_the_units_keeps_every_sample(
        tmp_path: Path, fleet: dict[str, dict[str, np.ndarray]]) -> None:
    path = tmp_path / "fast.rrd"
    render(path, fleet, [100], 1000.0)
    store = RrdReader(path).stream().collect()
    assert table(store, "/plots/accel/x/u1").num_rows == len(fleet["u1"]["ticks"])
    assert table(store, "/world/u1/body").num_rows == len(fleet["u1"]["ticks"])


def test_a_thinning_logger_refuses_a_rate_of_zero(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="above 0"):
        RerunLogger(tmp_path / "x.rrd", max_rate_hz=0.0)
