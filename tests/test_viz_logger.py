"""The Rerun logger, checked by reading the .rrd back with Rerun's own reader."""

from __future__ import annotations

import colorsys
import math
import threading
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from bridge.bus.codec import record_quantities
from bridge.bus.gx3_pb2 import Event, HostClock, Status
from bridge.protocol import convert
from bridge.protocol.table import DATA_CODES
from bridge.viz import layout
from bridge.viz.demo import DEMO_EPOCH_NS, demo_columns
from bridge.viz.logger import RerunLogger
from tests.helpers.rrd import blueprint_views, plot_values, table

UNITS = {"imu0": (0xCC, 1), "imu1": (0xC8, 2), "imu2": (0xDF, 3)}
RATE_HZ = 100.0
SECONDS = 2.0
N = round(RATE_HZ * SECONDS)


def read(path: Path) -> Any:
    return RrdReader(path).stream().collect()


def ns(column: pa.ChunkedArray) -> np.ndarray:
    """A timestamp or duration column as int64 nanoseconds."""
    return np.array(column.cast(pa.int64()).to_pylist(), np.int64)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict[str, Any]]]:
    """Three units with different record types, status and a gap, in one recording."""
    path = tmp_path_factory.mktemp("viz") / "fleet.rrd"
    data = {u: demo_columns(u, code, seed, SECONDS, RATE_HZ) for u, (code, seed) in UNITS.items()}
    with RerunLogger(path, ["imu0", "imu1"]) as log:
        for unit, (code, _) in UNITS.items():
            half = N // 2  # two batches, as a live subscriber would see them
            for rows in (slice(0, half), slice(half, N)):
                log.log_samples(unit, code, {k: v[rows] for k, v in data[unit].items()})
        log.log_status("imu0", [
            Status(unit="imu0", time_ns=DEMO_EPOCH_NS + k * 10**9, samples_per_s=99.0 + k,
                   dropped=3 * k, clock_offset_ns=DEMO_EPOCH_NS + 1000 * k,
                   clock_drift_ppm=20.0) for k in range(3)])
        log.log_event("imu1", Event(unit="imu1", time_ns=DEMO_EPOCH_NS + 10**9, ticks=62_500,
                                    kind=Event.GAP, count=12, detail="ticks jumped by 7,500"))
        log.log_event("imu1", Event(unit="imu1", time_ns=DEMO_EPOCH_NS + 2 * 10**9,
                                    kind=Event.DISCONNECT, detail="port closed"))
    return path, data


def test_entities_timelines_and_row_counts(fleet: tuple[Path, dict[str, Any]]) -> None:
    path, data = fleet
    store = read(path)
    for unit, (_code, _) in UNITS.items():
        cols = data[unit]
        plots = {"imu0": ["accel", "ang_rate", "mag", "euler"],
                 "imu1": ["accel", "ang_rate", "euler"],
                 "imu2": ["quaternion", "euler"]}[unit]
        entities = [e for p in plots for e in layout.plot_paths(p, unit)] + [
            f"/world/{unit}/body"]
        if "accel" in plots:
            entities.append(f"/world/{unit}/body/accel")
        for entity in entities:
            t = table(store, entity)
            assert t.num_rows == N, entity
            assert np.array_equal(ns(t.column("time")), cols["time_ns"]), entity
            assert np.array_equal(ns(t.column("device_time")), cols["ticks"] * 16_000), entity
    # the record types decide what exists: no mag for 0xC8, no accel for 0xDF
    names = {c.entity_path for c in RrdReader(path).stream() if c.timeline_names}
    assert "/plots/mag/x/imu1" not in names and "/plots/accel/x/imu2" not in names
    assert "/world/imu1/body/mag" not in names and "/world/imu0/body/mag" in names


def test_values_are_those_logged(fleet: tuple[Path, dict[str, Any]]) -> None:
    path, data = fleet
    store = read(path)
    accel = plot_values(store, "accel", "imu0")
    assert np.array_equal(accel, data["imu0"]["accel"].astype(np.float64))
    euler = plot_values(store, "euler", "imu1")
    assert np.allclose(euler, np.degrees(convert.m_to_euler(data["imu1"]["m"])))
    arrows = np.array(table(store, "/world/imu0/body/mag").column(
        "/world/imu0/body/mag:Arrows3D:vectors").to_pylist())[:, 0, :]
    assert np.allclose(arrows / 0.9, data["imu0"]["mag"], atol=1e-6)


def test_series_named_once_static(fleet: tuple[Path, dict[str, Any]]) -> None:
    """Every line has its own entity, its name (unit and axis) and its unit's colour."""
    path, _ = fleet
    for label, entity in zip(("roll", "pitch", "yaw"), layout.plot_paths("euler", "imu1"),
                             strict=True):
        chunks = [c for c in RrdReader(path).stream() if c.entity_path == entity
                  and "SeriesLines:names" in c.to_record_batch().schema.names]
        assert len(chunks) == 1 and chunks[0].num_rows == 1, entity
        batch = chunks[0].to_record_batch()
        assert entity == f"/plots/euler/{label}/imu1"
        assert batch.column("SeriesLines:names").to_pylist() == [[f"imu1 {label}"]]
        assert batch.column("SeriesLines:colors").to_pylist() == [[_rgba(layout.unit_color(1))]]


def _rgba(rgb: tuple[int, int, int]) -> int:
    """An RGB as Rerun stores it: 0xRRGGBBAA, opaque."""
    return (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | 0xFF


def test_sixteen_units_one_colour_each_everywhere(tmp_path: Path) -> None:
    """A unit's colour is its box's and its every line's, and no two of 16 units share a
    hue: the nearest two are 20 degrees or more apart, or differ in lightness."""
    path = tmp_path / "sixteen.rrd"
    units = [f"imu{i}" for i in range(1, 17)]
    with RerunLogger(path, units) as log:
        for i, unit in enumerate(units):
            log.log_samples(unit, 0xC8, demo_columns(unit, 0xC8, i, 0.1))
    boxes: dict[str, int] = {}
    lines: dict[str, set[int]] = {}
    for chunk in RrdReader(path).stream():
        names = chunk.to_record_batch().schema.names
        parts = chunk.entity_path.split("/")  # /world/<unit>/body/box, /plots/<p>/<l>/<unit>
        if "Boxes3D:colors" in names:
            (color,) = chunk.to_record_batch().column("Boxes3D:colors").to_pylist()[0]
            boxes[parts[2]] = color >> 8
        elif "SeriesLines:colors" in names:
            (color,) = chunk.to_record_batch().column("SeriesLines:colors").to_pylist()[0]
            lines.setdefault(parts[-1], set()).add(color >> 8)
    assert set(boxes) == set(units)
    for unit in units:
        assert lines[unit] == {boxes[unit]}, unit  # 3 accel + 3 rate + 3 euler lines
    hls = [colorsys.rgb_to_hls(*(((c >> s) & 255) / 255 for s in (16, 8, 0)))
           for c in boxes.values()]
    for a in range(16):
        for b in range(a + 1, 16):
            hue = abs(hls[a][0] - hls[b][0]) * 360
            assert min(hue, 360 - hue) >= 20 or abs(hls[a][1] - hls[b][1]) >= 0.1, (a, b)
    assert len({round(h[0] * 16) % 16 for h in hls}) == 16  # 16 distinct hues


def test_units_side_by_side(fleet: tuple[Path, dict[str, Any]]) -> None:
    path, _ = fleet
    store = read(path)
    east = []
    for unit in UNITS:
        t = table(store, f"/world/{unit}", index=None)
        east.append(t.column(f"/world/{unit}:Transform3D:translation").to_pylist()[0][0])
    positions = np.array(east)
    # units declared first keep their order; the rest follow in order of appearance
    assert np.all(np.diff(positions[:, 1]) >= 0.9) and np.all(positions[:, [0, 2]] == 0)


def test_status_figures(fleet: tuple[Path, dict[str, Any]]) -> None:
    path, _ = fleet
    store = read(path)
    offset = table(store, "/plots/clock_offset/imu0")  # one line: no line part in the path
    assert np.allclose(np.array(offset.column(
        "/plots/clock_offset/imu0:Scalars:scalars").to_pylist())[:, 0], [0, 0.001, 0.002])
    # device time is the clock model's inverse: (time - offset) * (1 + drift)
    expected = np.round((np.arange(3) * 10**9 - 1000 * np.arange(3)) * (1 + 20e-6))
    assert np.array_equal(ns(offset.column("device_time")), expected.astype(np.int64))
    dropped = table(store, "/plots/dropped/imu0").column("/plots/dropped/imu0:Scalars:scalars")
    assert np.array(dropped.to_pylist())[:, 0].tolist() == [0, 3, 6]


def test_gap_is_an_event_at_its_time(fleet: tuple[Path, dict[str, Any]]) -> None:
    path, _ = fleet
    store = read(path)
    log = table(store, "/events/imu1")
    # led by the time of day (the viewer's time column is too narrow to show it), the
    # records lost counted and their span at the unit's rate (from its 100 Hz samples)
    assert log.column("/events/imu1:TextLog:text").to_pylist() == [
        ["00:00:01.000  imu1 GAP (12 records, 0.12 s): ticks jumped by 7,500"],
        ["00:00:02.000  imu1 DISCONNECT: port closed"]]
    assert log.column("/events/imu1:TextLog:level").to_pylist() == [["WARN"], ["ERROR"]]
    assert ns(log.column("time")).tolist() == [DEMO_EPOCH_NS + 10**9, DEMO_EPOCH_NS + 2 * 10**9]
    # every event on the time timeline only (the gap has device ticks, the disconnect has
    # none): Rerun shows some rows with another row's level when they are on both
    assert {tuple(c.timeline_names) for c in RrdReader(path).stream()
            if c.entity_path == "/events/imu1"} == {("time",)}


def test_blueprint_has_the_scene_and_a_view_per_quantity(
        fleet: tuple[Path, dict[str, Any]]) -> None:
    """A view per axis of each quantity (accel x of every unit), a view per status figure."""
    path, _ = fleet
    views = blueprint_views(path)
    assert views, "no blueprint in the recording"
    latest = max(views, key=len)
    lines = {"accel": "xyz", "ang_rate": "xyz", "mag": "xyz", "euler": ("roll", "pitch", "yaw"),
             "quaternion": ("q0", "q1", "q2", "q3")}
    expected = {("3D", "/world"), ("TextLog", "/events")} | {
        ("TimeSeries", f"/plots/{p}/{label}") for p, labels in lines.items()
        for label in labels} | {("TimeSeries", f"/plots/{p}") for p in (
            "samples_per_s", "dropped", "clock_offset", "clock_drift")}
    assert latest == expected


def test_events_before_any_rate_still_count_records(tmp_path: Path) -> None:
    path = tmp_path / "early.rrd"
    with RerunLogger(path) as log:
        log.log_event("u", Event(unit="u", time_ns=DEMO_EPOCH_NS + 3_600_123_456_789,
                                 kind=Event.GAP, count=180))
    text = table(read(path), "/events/u").column("/events/u:TextLog:text").to_pylist()
    assert text == [["01:00:00.123  u GAP (180 records)"]]


def test_rate_from_status_gives_the_span(tmp_path: Path) -> None:
    path = tmp_path / "status.rrd"
    with RerunLogger(path) as log:
        log.log_status("u", Status(unit="u", time_ns=DEMO_EPOCH_NS, output_rate_hz=50.0))
        log.log_event("u", Event(unit="u", time_ns=DEMO_EPOCH_NS, kind=Event.GAP, count=90))
    text = table(read(path), "/events/u").column("/events/u:TextLog:text").to_pylist()
    assert text == [["00:00:00.000  u GAP (90 records, 1.8 s)"]]


def test_host_clock_sync_is_told_when_it_changes(tmp_path: Path) -> None:
    """The bridge host's clock in the unit's event log: when first seen and whenever it
    changes (synchronised or not), remembered from one batch of statuses to the next;
    a status like the last, or one without a host clock (an older bridge), adds nothing."""
    path = tmp_path / "host.rrd"
    synced = HostClock(host="robot1", known=True, synchronised=True, state="ok",
                       estimated_error_ns=250_000, maximum_error_ns=1_500_000)
    worse = HostClock(host="robot1", known=True, synchronised=True, state="ok",
                      estimated_error_ns=400_000, maximum_error_ns=1_600_000)
    adrift = HostClock(host="robot1", known=True, synchronised=False)

    def status(k: int, host_clock: HostClock | None) -> Status:
        return Status(unit="u", time_ns=DEMO_EPOCH_NS + k * 10**9, host_clock=host_clock)

    with RerunLogger(path) as log:
        log.log_status("u", [status(0, synced), status(1, worse), status(2, adrift),
                             status(3, None)])
        log.log_status("u", status(4, adrift))
        log.log_status("u", status(5, synced))
    log_table = table(read(path), "/events/u")
    texts = [t[0] for t in log_table.column("/events/u:TextLog:text").to_pylist()]
    assert [t[:27] for t in texts] == ["00:00:00.000  u on robot1: ", "00:00:02.000  u on robot1: ",
                                       "00:00:05.000  u on robot1: "]
    assert "synchronised" in texts[0] and "250 µs" in texts[0] and "1,500 µs" in texts[0]
    assert "not synchronised" in texts[1]
    assert log_table.column("/events/u:TextLog:level").to_pylist() == [
        ["INFO"], ["WARN"], ["INFO"]]


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # read while still written
def test_unit_appearing_later_extends_the_blueprint(tmp_path: Path) -> None:
    path = tmp_path / "late.rrd"
    with RerunLogger(path) as log:
        log.log_samples("a", 0xC2, demo_columns("a", 0xC2, 1, 0.5))
        first = len(blueprint_views_now(log, path))
        log.log_samples("a", 0xC2, demo_columns("a", 0xC2, 1, 0.5, start_s=0.5))
        assert len(blueprint_views_now(log, path)) == first  # nothing new: not sent again
        log.log_samples("b", 0xC2, demo_columns("b", 0xC2, 2, 0.5))
        assert len(blueprint_views_now(log, path)) == first + 1  # the camera frames b too
        temps = demo_columns("c", 0xD1, 3, 0.5)
        log.log_samples("c", 0xD1, temps)
    latest = max(blueprint_views(path), key=len)
    assert {("TimeSeries", "/plots/mag_temperature"),
            ("TimeSeries", layout.line_origin("gyro_temperature", "gyro Z"))} <= latest
    store = read(path)
    celsius = np.array(table(store, "/plots/mag_temperature/c").column(
        "/plots/mag_temperature/c:Scalars:scalars").to_pylist())
    # Equation 15 of the first code (the magnetometer's); the model runs at about 25 C
    assert np.allclose(celsius[:, 0], convert.mag_temperature_celsius(temps["temperature"][:, 0]))
    assert np.allclose(celsius, 25.0, atol=1.0)


def blueprint_views_now(log: RerunLogger, path: Path) -> list[set[tuple[str, str]]]:
    log.flush()
    return blueprint_views(path)


def _hamilton_matrix(xyzw: np.ndarray) -> np.ndarray:
    """The rotation matrix of a Hamilton x, y, z, w quaternion (textbook formula)."""
    x, y, z, w = xyzw / np.linalg.norm(xyzw)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


@pytest.mark.parametrize("code", [0xC5, 0xDF, 0xCE])
def test_rotation_is_sensor_to_earth(tmp_path: Path, code: int) -> None:
    """Known attitudes: 30 degrees of roll, pitch and yaw, each alone, then all three.
    The logged rotation must be M^T and move the sensor axes where physics says."""
    a = math.radians(30.0)
    euler = np.array([[a, 0, 0], [0, a, 0], [0, 0, a], [a, -a, 2 * a]])
    m = convert.euler_to_m(euler)
    quantity = {0xC5: ("m", m), 0xDF: ("quaternion", convert.m_to_quaternion(m)),
                0xCE: ("euler", euler)}[code]
    columns: dict[str, np.ndarray] = {
        "ticks": np.arange(4, dtype=np.int64), "time_ns": DEMO_EPOCH_NS + np.arange(4),
        quantity[0]: quantity[1].astype(np.float32)}
    path = tmp_path / "rot.rrd"
    with RerunLogger(path) as log:
        log.log_samples("u", code, columns)
    q = np.array(table(read(path), "/world/u/body").column(
        "/world/u/body:Transform3D:quaternion").to_pylist())[:, 0, :]
    rotations = np.array([_hamilton_matrix(x) for x in q])
    assert np.allclose(rotations, m.transpose(0, 2, 1), atol=1e-6)
    c, s = math.cos(a), math.sin(a)
    # roll right: the sensor's y (right) axis dips below the horizon (+down)
    assert np.allclose(rotations[0] @ [0, 1, 0], [0, c, s], atol=1e-6)
    # pitch up: the sensor's x (forward) axis rises (-down)
    assert np.allclose(rotations[1] @ [1, 0, 0], [c, 0, -s], atol=1e-6)
    # yaw right: the sensor's x axis turns from north towards east
    assert np.allclose(rotations[2] @ [1, 0, 0], [c, s, 0], atol=1e-6)


def test_nan_attitudes_are_left_out_of_the_scene(tmp_path: Path) -> None:
    cols = demo_columns("u", 0xC8, 1, 0.1)
    cols["m"][3] = np.nan
    path = tmp_path / "nan.rrd"
    with RerunLogger(path) as log:
        log.log_samples("u", 0xC8, cols)
    store = read(path)
    assert table(store, "/world/u/body").num_rows == len(cols["ticks"]) - 1
    assert table(store, "/plots/accel/x/u").num_rows == len(cols["ticks"])


def test_bad_input_is_one_clear_line(tmp_path: Path) -> None:
    cols = demo_columns("u", 0xC2, 1, 0.1)
    with RerunLogger(tmp_path / "bad.rrd") as log:
        with pytest.raises(ValueError, match=r"lack column\(s\) ang_rate"):
            log.log_samples("u", 0xC2, {k: v for k, v in cols.items() if k != "ang_rate"})
        with pytest.raises(ValueError, match="do not have the 10 rows"):
            log.log_samples("u", 0xC2, {**cols, "accel": cols["accel"][:5]})
        with pytest.raises(ValueError, match="0x10 is not a data record"):
            log.log_samples("u", 0x10, cols)


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # read while still written
def test_batches_are_gathered_then_sent_in_chunks_of_max_rows(tmp_path: Path) -> None:
    path = tmp_path / "gather.rrd"
    cols = demo_columns("u", 0xC2, 1, 1.2)
    half = {k: v[:60] for k, v in cols.items()}
    rest = {k: v[60:] for k, v in cols.items()}

    def accel_chunks() -> list[int]:
        return [c.num_rows for c in RrdReader(path).stream()
                if c.entity_path == "/plots/accel/x/u" and c.timeline_names]

    with RerunLogger(path, latency_s=3600.0, max_rows=100) as log:
        log.log_samples("u", 0xC2, half)
        log.recording.flush()
        assert accel_chunks() == []  # gathered, not sent
        log.log_samples("u", 0xC2, rest)  # 120 rows: due
        log.recording.flush()
        assert accel_chunks() == [100, 20]
        log.log_samples("u", 0xC2, half)
        log.flush()
        assert accel_chunks() == [100, 20, 60]


def test_live_window_limits_every_plot(tmp_path: Path) -> None:
    path = tmp_path / "live.rrd"
    with RerunLogger(path, window_s=10.0) as log:
        log.log_samples("a", 0xC2, demo_columns("a", 0xC2, 1, 0.5))
    reader = RrdReader(path)
    ranges = [c.to_record_batch().column("VisibleTimeRanges:ranges").to_pylist()[0]
              for entry in reader.blueprints() for c in reader.stream(store=entry)
              if c.entity_path.endswith("/VisibleTimeRanges")]
    assert len(ranges) == 6  # accel and ang_rate, a view per axis
    for view in ranges:
        assert {r["timeline"]: r["range"]["start"] for r in view} == {
            "time": -10 * 10**9, "device_time": -10 * 10**9}


def test_units_logging_from_several_threads(tmp_path: Path) -> None:
    """A live subscriber's callbacks run on several threads; nothing is lost or mixed up."""
    path = tmp_path / "threads.rrd"
    data = {f"u{i}": demo_columns(f"u{i}", 0xC8, i, 1.0) for i in range(4)}
    with RerunLogger(path, latency_s=0.0) as log:
        def feed(unit: str) -> None:
            for start in range(0, 100, 10):
                log.log_samples(unit, 0xC8, {k: v[start:start + 10]
                                             for k, v in data[unit].items()})
        threads = [threading.Thread(target=feed, args=(u,)) for u in data]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    store = read(path)
    for unit, cols in data.items():
        got = plot_values(store, "accel", unit)
        assert np.array_equal(got, cols["accel"].astype(np.float64))
    east = sorted(table(store, f"/world/{u}", index=None).column(
        f"/world/{u}:Transform3D:translation").to_pylist()[0][0][1] for u in data)
    assert east == [0.0, 1.0, 2.0, 3.0]  # each unit its own place


def test_a_stream_the_caller_owns_stays_open(tmp_path: Path) -> None:
    """gx3 view hands in a stream connected to a viewer: the logger flushes it, never
    closes it."""
    path = tmp_path / "own.rrd"
    rec = rr.RecordingStream("gx3", recording_id="caller")
    rec.save(path)
    with RerunLogger(rec) as log:
        log.log_samples("a", 0xC2, demo_columns("a", 0xC2, 1, 0.2))
    rec.log("/after", rr.TextLog("still open"), static=True)
    rec.flush()
    rec.disconnect()
    names = {c.entity_path for c in RrdReader(path).stream()}
    assert {"/plots/accel/x/a", "/after"} <= names
    assert RrdReader(path).recordings()[0].recording_id == "caller"


@pytest.mark.parametrize("footer", [True, False])
def test_footer_is_the_callers_choice(tmp_path: Path, footer: bool) -> None:
    path = tmp_path / "footer.rrd"
    with RerunLogger(path, write_footer=footer) as log:
        log.log_samples("a", 0xC2, demo_columns("a", 0xC2, 1, 0.2))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert table(read(path), "/plots/accel/x/a").num_rows == 20
    assert any("no footer" in str(w.message) for w in caught) is not footer


@pytest.mark.parametrize("code", sorted(DATA_CODES))
def test_every_record_type_shows_its_quantities(tmp_path: Path, code: int) -> None:
    path = tmp_path / "rec.rrd"
    with RerunLogger(path) as log:
        log.log_samples("u", code, demo_columns("u", code, 1, 0.1))
    logged = {c.entity_path for c in RrdReader(path).stream() if c.timeline_names}
    held = set(record_quantities(code))
    plotted = {q for q in held if q not in ("m", "temperature")}
    if "temperature" in held:
        plotted |= {"mag_temperature", "gyro_temperature"}
    attitude = bool(held & {"m", "quaternion", "euler"})
    if attitude:
        plotted.add("euler")
    arrows = {layout.ARROWS[q][0] for q in held if q in layout.ARROWS}
    assert logged == ({e for p in plotted for e in layout.plot_paths(p, "u")}
                      | ({"/world/u/body"} if attitude else set())
                      | {f"/world/u/body/{a}" for a in arrows})


def _last_blueprint(path: Path) -> dict[str, dict[str, Any]]:
    """Blueprint entity -> {column: last value} of the fullest blueprint in the file (the
    one sent once every unit had appeared)."""
    reader = RrdReader(path)
    found = []
    for entry in reader.blueprints():
        out: dict[str, dict[str, Any]] = {}
        for chunk in reader.stream(store=entry):
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                out.setdefault(chunk.entity_path, {})[name] = batch.column(name).to_pylist()[-1]
        found.append(out)
    return max(found, key=lambda b: sum(len(v.get("ViewContents:query", ())) for v in b.values()))


@pytest.mark.parametrize("count", [3, 16])
def test_scene_frames_every_unit_and_views_hold_eight(tmp_path: Path, count: int) -> None:
    """Units stand on a grid 4 wide; the camera looks at its middle with every unit
    within 25 degrees of its line of sight; no plot view holds more than 8 units, and
    every unit's accel x is in a view."""
    path = tmp_path / "grid.rrd"
    units = [f"imu{i}" for i in range(1, count + 1)]
    with RerunLogger(path, units) as log:
        for i, unit in enumerate(units):
            log.log_samples(unit, 0xC2, demo_columns(unit, 0xC2, i, 0.1))
    store = read(path)
    where = np.array([table(store, f"/world/{u}", index=None).column(
        f"/world/{u}:Transform3D:translation").to_pylist()[0][0] for u in units])
    assert len({tuple(p) for p in where}) == count
    assert np.ptp(where[:, 1]) == min(count, 4) - 1 and np.all(where[:, 2] == 0)
    blueprint = _last_blueprint(path)
    (eye,) = [v for v in blueprint.values() if "EyeControls3D:position" in v]
    position = np.array(eye["EyeControls3D:position"][0])
    sight = np.array(eye["EyeControls3D:look_target"][0]) - position
    to_units = where - position
    cos = to_units @ sight / np.linalg.norm(to_units, axis=1) / np.linalg.norm(sight)
    assert np.degrees(np.arccos(cos)).max() < 25
    queries = [v["ViewContents:query"] for v in blueprint.values() if "ViewContents:query" in v]
    listed = [q for q in queries if not any("**" in e for e in q)]
    assert all(len(q) <= 8 for q in listed)
    if count > 8:
        assert {f"/plots/accel/x/{u}" for u in units} <= {e for q in listed for e in q}


def test_the_least_lag_of_each_second_of_arrival_is_plotted(tmp_path: Path) -> None:
    """A host whose samples arrive 2-5 ms after they were taken, then one whose clock runs
    3 ms ahead: per whole second of arrival, the least arrival - time_ns, in ms; a second
    is plotted once the next begins, however the arrivals are cut into calls."""
    path = tmp_path / "lag.rrd"
    second = 10**9
    arrival = DEMO_EPOCH_NS + np.arange(0, 4 * second, second // 100)
    lag = np.where(arrival < DEMO_EPOCH_NS + 2 * second, 2_000_000, -3_000_000) \
        + (np.arange(len(arrival)) % 7) * 500_000
    with RerunLogger(path) as log:
        for part in np.array_split(np.arange(len(arrival)), 9):
            log.log_arrivals("u", arrival[part], arrival[part] - lag[part])
    store = read(path)
    path_ = layout.plot_paths("host_clock", "u")[0]
    times = ns(table(store, path_).column("time")) - DEMO_EPOCH_NS
    assert times.tolist() == [0, second, 2 * second]  # the fourth second is not over
    np.testing.assert_allclose(plot_values(store, "host_clock", "u")[:, 0], [2.0, 2.0, -3.0])
