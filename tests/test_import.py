"""`gx3 import`: byte logs as a mooring's data logger writes them, against the emulator's truth.

A unit streams 0xCB for ten minutes, is switched to 0xCF and streams it ten more (both
at 10 Hz, its timer crossing the 32-bit rollover in the first); the logger keeps only
the bytes, in two files. The same reads with receive times make a raw capture, which
`gx3 replay` must also keep whole.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.walk import read_archive
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.ingest.bytelog import LogFile, import_logs
from bridge.protocol import Framer, checksum, encode_reply
from bridge.sim.capture import SyntheticCapture, streaming_config, synthesize
from bridge.sim.motion import MotionConfig, tumbling
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UartDelivery
from bridge.viz import layout
from tests.helpers.archives import write_two_units
from tests.helpers.cli import gx3_here
from tests.helpers.rrd import rerun_rows

SEGMENT_S = 600.0
SWITCH_S = 0.5  # the logger's commands between the two modes
TIMER_START = 2**32 - 300 * 62_500  # the rollover 5 minutes in
HARD_IRON = (0.12, -0.07, 0.2)  # gauss: what gx3 calibrate-mag must find


def _iso(time_ns: int) -> str:
    """An instant as a logger's operator writes it: ISO 8601, to the µs, in UTC."""
    return datetime.fromtimestamp(time_ns // 1000 / 1e6, UTC).isoformat()


def _unit(timer_start: int) -> UnitConfig:
    # tumbling, so that the magnetometer calibration has every side of the field
    motion = tumbling(MotionConfig(seed=4, hard_iron_gauss=HARD_IRON))
    return UnitConfig(serial="MOOR0001", clock_ppm=0.0, motion=motion, timer_start=timer_start)


@dataclass
class Logged:
    segments: list[SyntheticCapture]
    logs: list[Path]
    start: str  # the first record's instant, as the logger knows it

    def truth(self, key: str) -> np.ndarray:
        return np.concatenate([s.truth[key] for s in self.segments])


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> Logged:
    folder = tmp_path_factory.mktemp("logger")
    segments = []
    for i, code in enumerate((0xCB, 0xCF)):
        offset = i * (SEGMENT_S + SWITCH_S)
        unit = _unit((TIMER_START + round(offset * 62_500)) % 2**32)
        config = streaming_config(unit, code=code, decimation=100, baud=115_200)
        segments.append(synthesize(config, UartDelivery(), SEGMENT_S, start=offset))
    logs = []
    for i, segment in enumerate(segments):
        logs.append(folder / f"mooring_{i}.bin")
        logs[-1].write_bytes(b"".join(segment.data))
    return Logged(segments, logs, _iso(int(segments[0].truth["time_ns"][0])))


@dataclass
class Imported:
    path: Path
    stderr: str  # what gx3 import said


@pytest.fixture(scope="module")
def imported(logged: Logged, tmp_path_factory: pytest.TempPathFactory) -> Imported:
    """Both logs imported as unit moor, from the logger's start."""
    out = tmp_path_factory.mktemp("imported") / "mooring.mcap"
    done = gx3_here("import", *logged.logs, "--unit", "moor", "--start", logged.start,
                    "-o", out)
    assert done.exit_code == 0, done.stderr
    return Imported(out, done.stderr)


def test_every_record_comes_out_at_start_plus_device_time(logged: Logged,
                                                          imported: Imported) -> None:
    done, out = imported, imported.path
    # no 0xDB reply in the logs: the rate from the timer's steps, so no false gaps
    assert "at 10 Hz by the timer" in done.stderr and "1 rollover;" in done.stderr
    assert "gap" not in done.stderr
    assert "filter width 15 assumed" in done.stderr
    archive = read_archive(out)
    assert [e.kind for _, e in archive.events(["moor"])] == [Event.ROLLOVER]
    infos = [info for _, info in archive.decoded("gx3/moor/info", Info)]
    assert [(i.command, i.output_rate_hz, i.baud) for i in infos] == [(0xCB, 10, 0),
                                                                     (0xCF, 10, 0)]
    # the totals as a bridge's last Status, with no host clock and no clock model
    (status,) = [status for _, status in archive.decoded("gx3/moor/status", Status)]
    assert (status.samples, status.dropped, status.checksum_failures) == (
        len(logged.truth("code")), 0, 0)
    assert not status.HasField("host_clock") and status.clock_offset_ns == 0
    blocks = archive.samples(["moor"])
    codes = np.concatenate([np.full(len(b), b.code) for b in blocks])
    time_ns = np.concatenate([b.columns["time_ns"] for b in blocks])
    order = np.argsort(time_ns, kind="stable")
    codes, time_ns = codes[order], time_ns[order]
    # every record of both modes, in the order they were sent
    np.testing.assert_array_equal(codes, logged.truth("code"))
    # the instant its values describe: start + device time - filter delay, to a µs (the
    # start is given to the µs)
    error = time_ns - logged.truth("value_ns")
    assert np.abs(error).max() <= 1_000, np.abs(error).max()
    meta = {m.name: dict(m.metadata) for m in archive.metadata}
    assert meta["gx3.archive"]["host_clock"] == "none"
    assert meta["gx3.import"]["filter_width_from"] == "factory"


def test_imported_archives_work_with_every_archive_command(logged: Logged, imported: Imported,
                                                           tmp_path: Path) -> None:
    out = imported.path
    total = len(logged.truth("code"))
    table = gx3_here("export", out, "-o", tmp_path / "mooring.csv")
    assert table.exit_code == 0 and f"wrote {total:,} samples of 1 unit" in table.stderr, \
        table.stderr
    with (tmp_path / "mooring.csv").open() as f:
        rows = list(csv.DictReader(f))
    exported = np.array([int(r["time_ns"]) for r in rows])
    # export keeps the imported times: no host clock to re-estimate them against
    assert np.abs(np.sort(exported) - logged.truth("value_ns")).max() <= 1_000
    bag = gx3_here("export", out, "--format", "ros2", "-o", tmp_path / "bag.mcap")
    assert bag.exit_code == 0, bag.stderr
    # each Imu stamped with its sample's instant: the start plus device time
    with (tmp_path / "bag.mcap").open("rb") as f:
        imu = [m for _, c, _, m in make_reader(f, decoder_factories=[DecoderFactory()])
               .iter_decoded_messages() if c.topic.endswith("/imu")]
    assert f"wrote {total:,} Imu" in bag.stderr and len(imu) == total, bag.stderr
    stamps = np.sort([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu])
    truth = logged.truth("value_ns")
    nearest = truth[np.clip(np.searchsorted(truth, stamps), 0, len(truth) - 1)]
    assert np.abs(stamps - nearest).max() <= 1_000
    rrd = gx3_here("rrd", out, "-o", tmp_path / "mooring.rrd")
    assert rrd.exit_code == 0 and f"{total:,} samples" in rrd.stderr, rrd.stderr
    # every sample plotted; no host clock plot, since no host received them
    assert rerun_rows(tmp_path / "mooring.rrd", layout.plot_paths("ang_rate", "moor")[0]) == total
    host_clock = layout.plot_paths("host_clock", "moor")[0]
    assert rerun_rows(tmp_path / "mooring.rrd", host_clock) == 0
    iron = gx3_here("calibrate-mag", out, "-o", tmp_path / "iron.json")
    assert iron.exit_code == 0, iron.stderr
    # the iron the emulated magnetometer sits among, from the imported readings
    found = json.loads((tmp_path / "iron.json").read_text())
    np.testing.assert_allclose(found["hard_iron"], HARD_IRON, atol=1e-3)


def test_a_capture_that_switches_record_type_replays_whole(logged: Logged,
                                                           tmp_path: Path) -> None:
    """The same stream with receive times: a replay keeps the 0xCB records too."""
    capture = tmp_path / "raw.mcap"
    writer = RawCaptureWriter(capture, "gx3", "moor")
    for segment in logged.segments:
        for rx, data in zip(segment.rx_ns.tolist(), segment.data, strict=True):
            writer.write(data, rx)
    writer.close()
    done = gx3_here("replay", capture, "-o", tmp_path / "again.mcap")
    assert done.exit_code == 0, done.stderr
    blocks = read_archive(tmp_path / "again.mcap").samples(["moor"])
    by_code = {code: sum(len(b) for b in blocks if b.code == code) for code in (0xCB, 0xCF)}
    assert by_code == {code: int((logged.truth("code") == code).sum())
                       for code in (0xCB, 0xCF)}


def test_what_cannot_be_imported_is_said_in_one_line(logged: Logged, tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    garbage = tmp_path / "noise.bin"
    garbage.write_bytes(np.random.default_rng(1).integers(0, 256, 20_000, np.uint8).tobytes())
    little = tmp_path / "little.bin"  # a unit set to little-endian floats before the log
    little.write_bytes(b"".join(
        encode_reply(0xCB, little_endian=True, accel=(0.1, -0.2, 0.3), ang_rate=(1.1, 2.2, 3.3),
                     mag=(0.3, 0.1, -0.4), timer=6250 * k) for k in range(50)))
    cases: list[tuple[list[str | Path], str]] = [
        ([garbage, "-u", "x", "--start", "2026-01-01T00:00:00Z"],
         f"no record found in {garbage}: not a 3DM-GX3 byte log"),
        ([little, "-u", "x", "--start", "2026-01-01T00:00:00Z"],
         f"no record found in {little}, but 50 in its first 2,150 bytes with floats "
         "little-endian: try --little-endian"),
        ([logged.logs[0], "-u", "x"], "--start"),
        ([logged.logs[0], "-u", "x", "--start", "2026-01-01T00:00:00"], "has no zone"),
        ([logged.logs[0], "-u", "x", "--start-from-name", "log_%Y%m%d"],
         "does not match --start-from-name"),
        # a log whose unit was reset before it: its own start is needed
        ([logged.logs[1], logged.logs[1], "-u", "x", "--start", "2026-01-01T00:00:00Z"],
         "timer began again at its first record"),
    ]
    both = ["--start", logged.start, "--start-from-name", "log_%Y%m%d"]
    cases += [([logged.logs[0], "-u", "x", *both], "not both"),
              # one epoch, two starts: the second would be used for nothing
              ([logged.logs[0], "-u", "x", "--start", logged.start, "--start", logged.start],
               "one --start per epoch")]
    for args, says in cases:
        done = gx3_here("import", *args, "-o", out)
        assert done.exit_code == 2 and done.stderr.count("\n") == 1, (args, done.stderr)
        assert says in done.stderr and "Traceback" not in done.stderr, done.stderr
        assert not out.exists()
    done = gx3_here("import", little, "-u", "x", "--start", logged.start, "--little-endian",
               "-o", out)
    assert done.exit_code == 0 and "50 samples" in done.stderr, done.stderr
    out.unlink()
    out.write_text("mine\n")
    done = gx3_here("import", logged.logs[0], "-u", "x", "--start", logged.start, "-o", out)
    assert done.exit_code == 2 and "--force" in done.stderr and out.read_text() == "mine\n"
    # a log named as the output is refused, whatever --force says
    kept = logged.logs[0].read_bytes()
    done = gx3_here("import", logged.logs[0], "-u", "x", "--start", logged.start,
               "-o", logged.logs[0], "--force")
    assert done.exit_code == 2 and done.stderr.count("\n") == 1, done.stderr
    assert logged.logs[0].read_bytes() == kept


def test_an_archive_or_an_empty_file_is_said_for_what_it_is(tmp_path: Path) -> None:
    """Not "not a 3DM-GX3 byte log", which leaves the user guessing: what the file is,
    and what to do with it (in-process: refused before any reading)."""
    archive, empty, out = tmp_path / "run.mcap", tmp_path / "empty.bin", tmp_path / "x.mcap"
    write_two_units(archive)
    empty.write_bytes(b"")
    start = ["-u", "x", "--start", "2026-01-01T00:00:00Z", "-o", str(out)]
    for logs, says in (
            ([archive], f"{archive} is an MCAP archive, not a byte log: gx3 export, rrd "
                        "and allan read it as it is (a raw capture of a bridge's: gx3 "
                        "replay)"),
            ([empty, archive], f"{archive} is an MCAP archive"),
            ([empty], f"{empty} is empty: nothing to import"),
            ([empty, empty], f"{empty}, {empty} are all empty: nothing to import")):
        done = gx3_here("import", *logs, *start)
        assert done.exit_code == 2 and done.stderr.startswith(f"error: {says}"), done.stderr
        assert done.stderr.count("\n") == 1, done.stderr
        assert not out.exists()


def test_a_reset_inside_a_log_takes_the_next_start(tmp_path: Path) -> None:
    """A logger that power-cycled its unit mid-file: each epoch from its own --start."""
    off_s = 1000.0  # the unit was off for a while: the timer tells nothing of it
    segments = [synthesize(streaming_config(_unit(start), code=0xCB,
                                            decimation=100, baud=115_200),
                           UartDelivery(), 60.0, start=at)
                for start, at in ((3_000_000_000, 0.0), (0, 60.0 + off_s))]
    log = tmp_path / "cycled.bin"
    log.write_bytes(b"".join(b"".join(s.data) for s in segments))
    starts = [_iso(int(s.truth["time_ns"][0])) for s in segments]
    out = tmp_path / "cycled.mcap"
    done = gx3_here("import", log, "-u", "u", "--start", starts[0], "-o", out)
    assert done.exit_code == 2 and "reset 1, at timer" in done.stderr, done.stderr
    assert "further --start" in done.stderr and not out.exists()
    done = gx3_here("import", log, "-u", "u", "--start", starts[0], "--start", starts[1], "-o", out)
    assert done.exit_code == 0, done.stderr
    assert "1 reset; " in done.stderr and "gap" not in done.stderr
    blocks = read_archive(out).samples(["u"])
    time_ns = np.sort(np.concatenate([b.columns["time_ns"] for b in blocks]))
    truth = np.concatenate([s.truth["value_ns"] for s in segments])
    assert np.abs(time_ns - truth).max() <= 1_000


def test_a_reset_between_logs_named_by_time_starts_a_new_epoch(logged: Logged,
                                                                tmp_path: Path) -> None:
    """Two logs of a unit reset in between: each named by when it began, each epoch
    starts there (the filter delay taken out)."""
    names = [tmp_path / "log_20260101_000000.bin", tmp_path / "log_20260101_010000.bin"]
    for name in names:
        name.write_bytes(logged.logs[1].read_bytes())
    out = tmp_path / "reset.mcap"
    done = gx3_here("import", *names, "-u", "u", "--start-from-name", "log_%Y%m%d_%H%M%S",
               "-o", out)
    assert done.exit_code == 0, done.stderr
    assert "1 reset" in done.stderr
    blocks = read_archive(out).samples(["u"])
    time_ns = np.sort(np.concatenate([b.columns["time_ns"] for b in blocks]))
    half = len(time_ns) // 2
    hour = 3600 * 10**9
    first = int(datetime(2026, 1, 1, tzinfo=UTC).timestamp()) * 10**9 - 7_000_000
    assert (int(time_ns[0]), int(time_ns[half])) == (first, first + hour)


def test_a_record_with_a_corrupt_timer_is_dropped_as_live(tmp_path: Path) -> None:
    """Two records whose timers were corrupted with their checksums still right (one a
    little ahead, off the lattice; one far back, as a reset would be): each is a glitch,
    dropped and said, and every other record keeps its time."""
    segment = synthesize(streaming_config(_unit(5_000_000), code=0xCB, decimation=100,
                                          baud=115_200), UartDelivery(), 60.0)
    data = bytearray(b"".join(segment.data))
    framer = Framer({0xCB})
    offsets = np.concatenate([b.offsets for b in framer.feed(bytes(data)) + framer.flush()])
    for k, change in ((100, 1_000), (400, -3_000_000)):
        end = int(offsets[k]) + 43  # a 0xCB record: ..., timer (4 bytes), checksum (2)
        timer = int.from_bytes(data[end - 6:end - 2], "big") + change
        data[end - 6:end - 2] = timer.to_bytes(4, "big")
        data[end - 2:end] = checksum(data[end - 43:end - 2]).to_bytes(2, "big")
    log = tmp_path / "noisy.bin"
    log.write_bytes(bytes(data))
    out = tmp_path / "noisy.mcap"
    start = _iso(int(segment.truth["time_ns"][0]))
    done = gx3_here("import", log, "-u", "u", "--start", start, "-o", out)
    assert done.exit_code == 0, done.stderr
    assert "2 glitches" in done.stderr, done.stderr
    assert "gap" not in done.stderr and "reset" not in done.stderr, done.stderr
    archive = read_archive(out)
    assert [e.kind for _, e in archive.events(["u"])] == [Event.GLITCH, Event.GLITCH]
    time_ns = np.concatenate([b.columns["time_ns"] for b in archive.samples(["u"])])
    truth = np.delete(segment.truth["value_ns"], [100, 400])
    assert np.abs(np.sort(time_ns) - truth).max() <= 1_000


def test_delta_records_are_timed_at_the_middle_of_their_period(tmp_path: Path) -> None:
    """0xC3 integrates over the output period (here 50 ms): an imported record's time_ns
    is the period's middle, as live, not its end."""
    config = streaming_config(_unit(0), code=0xC3, decimation=50, baud=115_200)
    capture = synthesize(config, UartDelivery(), 20.0)
    log = tmp_path / "delta.bin"
    log.write_bytes(b"".join(capture.data))
    import_logs([LogFile(log, int(capture.truth["time_ns"][0]))], tmp_path / "delta.mcap",
                "d1")
    (block,) = read_archive(tmp_path / "delta.mcap").samples(["d1"])
    error = block.columns["time_ns"] - capture.truth["value_ns"]
    assert np.abs(error).max() <= 1_000, np.abs(error).max()
