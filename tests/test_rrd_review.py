"""`gx3 rrd` of a fleet's 10 minutes: full rate, windows and overviews, read back with Rerun's
own chunk reader against the archive's samples."""

from __future__ import annotations

import shlex
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bridge.archive.times import TimeSpan
from bridge.archive.walk import SampleSpan, read_archive, sample_span
from bridge.sim.archived import fleet_archive
from bridge.viz import layout
from bridge.viz.logger import RerunLogger
from bridge.viz.review import FULL_RATE_SAMPLES, plan
from bridge.viz.sources import log_archive
from tests.helpers.cli import gx3_here
from tests.helpers.rrd import blueprint_views, scalar_lines, table

UNITS = ("imu1", "imu2", "imu3")
SECONDS, RATE_HZ = 600, 100.0
WALL_NS = 1_763_000_000_000_000_000  # the archive's first samples
#: Every plotted line of a 0xCC unit
PLOTS = ("accel", "ang_rate", "mag", "euler")


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("review") / "fleet.mcap"
    fleet_archive(path, UNITS, SECONDS, RATE_HZ, wall_ns=WALL_NS)
    return path


def render(archive: Path, name: str, *args: str) -> tuple[Path, str]:
    """``gx3 rrd ARCHIVE -o NAME ARGS``: the recording and what was said."""
    out = archive.with_name(name)
    done = gx3_here("rrd", archive, "-o", out, *args)
    assert done.exit_code == 0, done.stderr
    return out, done.stderr


@pytest.fixture(scope="module")
def full(archive: Path) -> tuple[Path, str]:
    return render(archive, "full.rrd")


def read(path: Path) -> Any:
    return RrdReader(path).stream().collect()


def line_rows(lines: dict[str, tuple[np.ndarray, np.ndarray]], unit: str
              ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every line of a unit's sample plots, of ``scalar_lines``."""
    return {entity: lines[entity] for plot in PLOTS for entity in layout.plot_paths(plot, unit)}


def test_the_default_renders_ten_minutes_of_three_units_in_full(
        archive: Path, full: tuple[Path, str]) -> None:
    path, said = full
    assert said.startswith(f"wrote {path}: 180,000 samples of 3 units; open it with")
    store, lines = read(path), scalar_lines(path)
    samples = {b.unit: b for b in read_archive(archive).samples()}
    for unit in UNITS:
        for entity, (t, _) in line_rows(lines, unit).items():
            assert np.array_equal(t, samples[unit].columns["time_ns"]), entity
        assert table(store, f"/plots/samples_per_s/{unit}").num_rows == SECONDS
        assert table(store, f"/events/{unit}").num_rows == 1  # its bring-up


def test_an_overview_keeps_every_minutes_extremes_in_a_quarter_of_the_rows(
        archive: Path, full: tuple[Path, str]) -> None:
    """--max-rate 10: every line's least and greatest value of each minute (of each
    tenth of a second, at their own instants) in a quarter of the rows at most and under
    a third of the bytes; attitude ten times a second; status and events whole; and the
    command for full rate on a window."""
    overview, said = render(archive, "overview.rrd", "--max-rate", "10")
    assert "an overview of 180,000 samples of 3 units (--max-rate 10)" in said, said
    assert overview.stat().st_size < full[0].stat().st_size / 3
    whole, thin, store = scalar_lines(full[0]), scalar_lines(overview), read(overview)
    rows = kept = 0
    for unit in UNITS:
        every, some = line_rows(whole, unit), line_rows(thin, unit)
        for entity, (t, v) in every.items():
            st, sv = some[entity]
            rows, kept = rows + len(t), kept + len(st)
            assert np.isin(st, t).all(), entity  # samples, at their own instants
            for period in (60 * 10**9, 10**8):  # each minute, each bin
                bins = np.unique(t // period)
                lo, hi = _by_bin(t // period, v, bins)
                slo, shi = _by_bin(st // period, sv, bins)
                assert np.array_equal(lo, slo) and np.array_equal(hi, shi), (entity, period)
        attitude = table(store, f"/world/{unit}/body").column("time").cast("int64").to_pylist()
        assert len(attitude) == SECONDS * 10 and np.all(np.diff(attitude) > 0)
        assert len(thin[f"/plots/samples_per_s/{unit}"][0]) == SECONDS
        assert table(store, f"/events/{unit}").num_rows == 1
    assert kept <= rows / 4, (kept, rows)
    # the live view's layout and timelines: a window and an overview read the same
    assert max(blueprint_views(overview), key=len) == max(blueprint_views(full[0]), key=len)
    assert {tuple(c.timeline_names) for c in RrdReader(overview).stream()
            if c.entity_path.startswith("/plots/accel/") and c.timeline_names
            } == {("device_time", "time")}
    command = said.splitlines()[-1].removeprefix("full rate on a window: ")
    assert shlex.split(command) == ["gx3", "rrd", str(archive), "-o",
                                    str(overview.with_name("overview-window.rrd")),
                                    "--start", "0", "--end", "600"]


def _by_bin(index: np.ndarray, values: np.ndarray, bins: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest value in each of ``bins``."""
    where = np.searchsorted(bins, index)
    lo, hi = np.full(len(bins), np.inf), np.full(len(bins), -np.inf)
    np.minimum.at(lo, where, values)
    np.maximum.at(hi, where, values)
    return lo, hi


@pytest.mark.parametrize("how", ["seconds", "iso"])
def test_a_window_holds_exactly_its_samples(archive: Path, how: str) -> None:
    """--start/--end as gx3 export takes them (seconds from the first sample, or ISO
    times): the window's samples of the units asked for, at full rate, each with its
    archived values, and the status within it; nothing of the other units."""
    start, end = WALL_NS + 120 * 10**9, WALL_NS + 180_500_000_000
    bounds = ["120", "180.5"] if how == "seconds" else [
        datetime.fromtimestamp(t / 1e9, UTC).isoformat() for t in (start, end)]
    path, said = render(archive, f"window-{how}.rrd", "--start", bounds[0], "--end",
                        bounds[1], "-u", "imu2")
    assert said.startswith(f"wrote {path}: 6,050 samples of 1 unit"), said
    samples = read_archive(archive).samples(["imu2"])[0]
    inside = (samples.columns["time_ns"] >= start) & (samples.columns["time_ns"] < end)
    store = read(path)
    got = line_rows(scalar_lines(path), "imu2")
    for axis, entity in enumerate(layout.plot_paths("accel", "imu2")):
        t, v = got[entity]
        assert np.array_equal(t, samples.columns["time_ns"][inside])
        assert np.array_equal(v, samples.columns["accel"][inside, axis].astype(np.float64))
    assert table(store, "/world/imu2/body").num_rows == inside.sum()
    assert table(store, "/plots/samples_per_s/imu2").num_rows == 61  # statuses 120..180 s
    names = {c.entity_path for c in RrdReader(path).stream()}
    assert not any("imu1" in n or "imu3" in n for n in names), names


def test_what_cannot_be_rendered_is_one_line(archive: Path, tmp_path: Path) -> None:
    for args, words in ((["-u", "imu9"], "no samples of unit imu9 in it (units: imu1, imu2, "
                         "imu3); check --unit"),
                        (["--start", "700"], "no samples from --start to --end"),
                        (["--start", "yesterday"], "'yesterday' is neither an ISO time"),
                        (["--max-rate", "0"], "--max-rate: a rate of 0.0 Hz: give one "
                         "above 0")):
        done = gx3_here("rrd", archive, "-o", tmp_path / "x.rrd", *args)
        assert done.exit_code == 2 and words in done.stderr, (args, done.stderr)
        assert done.stderr.count("\n") == 1 and not (tmp_path / "x.rrd").exists()


def test_the_default_bound_picks_full_rate_or_the_rate_that_fits() -> None:
    """A window of at most FULL_RATE_SAMPLES samples in full; a longer one at the highest
    rate whose two rows a bin keep each line within the bound: a fleet's day at 1 Hz."""
    hour = 3600 * 10**9

    def span(units: int, hours: float, rate: float) -> SampleSpan:
        n = round(hours * 3600 * rate)
        return SampleSpan({f"u{i}": n for i in range(units)}, WALL_NS,
                          WALL_NS + round(hours * hour))

    assert plan(span(3, 1 / 6, 100)).max_rate_hz is None
    assert plan(span(16, 8, 100)).max_rate_hz == 1.0
    assert plan(span(16, 8, 500)).max_rate_hz == 1.0
    assert plan(span(1, 24 * 365, 1000)).max_rate_hz == 1 / 60  # the lowest there is
    day = span(16, 8, 100)
    assert plan(day, ["u3"]).max_rate_hz == 10.0  # one unit's day
    tenth = plan(day, None, TimeSpan("3600", "4200"))
    assert tenth.max_rate_hz is None and tenth.samples == 16 * 600 * 100
    assert plan(day, max_rate_hz=5).max_rate_hz == 5.0
    overview = plan(day)
    assert overview.samples > FULL_RATE_SAMPLES and overview.full_rate_seconds() == 600.0


def test_a_long_window_becomes_the_overview_that_fits(archive: Path, tmp_path: Path) -> None:
    """Over the bound (here 50,000 samples, for speed) with no rate asked: the highest
    overview rate that keeps each line within it, rendered from the archive."""
    review = plan(sample_span(archive), bound=50_000)
    assert review.max_rate_hz == 10.0 and not review.asked  # 2 x 10 x 600 x 3 <= 50,000
    path = tmp_path / "fits.rrd"
    with RerunLogger(path, review.units, max_rate_hz=review.max_rate_hz) as logger:
        assert log_archive(archive, logger, units=review.units) == 180_000
    lines = scalar_lines(path)
    for unit in UNITS:
        assert all(len(t) <= 2 * 10 * SECONDS for t, _ in line_rows(lines, unit).values())
