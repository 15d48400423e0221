"""`gx3 replay` on captures it must understand from their bytes, and on bad input.

Captures come from the emulator in virtual time through the USB delivery model
(bridge.sim.capture), written as another program would: raw reads, no metadata.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import psutil
import pytest

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.gx3_pb2 import Event
from bridge.export.tables import last_info, offline_times, sample_table
from bridge.ingest.replay import captures, replay
from bridge.protocol.codec import encode_reply
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig
from bridge.sim.state import Sampling
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, UsbDelivery
from tests.helpers.archives import sample_columns, write_capture
from tests.helpers.cli import gx3_here
from tests.helpers.mcap_order import order_problems
from tests.helpers.processes import GX3


@pytest.mark.parametrize("little_endian", [False, True])
def test_a_capture_without_metadata_is_understood_from_its_bytes(
        tmp_path: Path, little_endian: bool) -> None:
    config = streaming_config(UnitConfig(motion=MotionConfig(seed=4)), code=0xC8,
                              decimation=5)
    if little_endian:
        sampling = replace(config.stored.sampling, flags=config.stored.sampling.flags | 0x10)
        config = replace(config, stored=replace(config.stored,
                                                sampling=Sampling(**vars(sampling))))
    cap = synthesize(config, UsbDelivery(seed=2), seconds=20.0)
    path = write_capture(tmp_path / "raw.mcap", list(zip(cap.rx_ns.tolist(), cap.data,
                                                         strict=True)))
    results = replay([path], tmp_path / "out.mcap")
    assert results[0].settings is not None
    assert results[0].settings.record == 0xC8 and results[0].settings.decimation == 5
    assert ("little-endian floats" in results[0].inferred) == little_endian
    blocks = read_archive(tmp_path / "out.mcap").samples(["u1"])
    timer = np.concatenate([b.columns["timer"] for b in blocks])
    m = np.concatenate([b.columns["m"] for b in blocks])
    assert len(timer) == len(cap.truth["timer"])
    assert (np.sort(timer) == np.sort(cap.truth["timer"])).all()
    assert np.allclose(np.einsum("nij,nkj->nik", m, m), np.eye(3), atol=1e-5), \
        "orientation matrices decoded in the wrong byte order"


def test_garbage_and_empty_captures_are_clear_errors(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    garbage = write_capture(tmp_path / "garbage.mcap",
                            [(i, rng.bytes(64)) for i in range(500)])
    empty = write_capture(tmp_path / "empty.mcap", [])
    not_mcap = tmp_path / "text.mcap"
    not_mcap.write_text("hello\n")
    for path, message in ((garbage, "no record found"), (empty, "no raw reads"),
                          (not_mcap, "MCAP"), (tmp_path / "missing.mcap", "no such file")):
        done = gx3_here("replay", path, "-o", tmp_path / "o.mcap")
        assert done.exit_code != 0, path
        assert message in done.stderr and "Traceback" not in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_an_event_carries_the_receive_time_of_the_read_that_showed_it(tmp_path: Path) -> None:
    """As the live bridge tells a gap right after the read that held the record after it:
    not at the start of the stretch of records the replay times at once."""
    t0 = 1_763_000_000_000_000_000
    reads = [(t0 + i * 10_000_000, encode_reply(0xC2, accel=[0.0, 0.0, -1.0],
                                                ang_rate=[0.0, 0.0, 0.0], timer=1000 + i * 625))
             for i in range(300) if i not in (120, 121)]
    meta = {"unit": "u1", "record": "0xC2", "decimation": "10", "filter_width": "15",
            "baud": "115200", "transport": "uart"}
    path = write_capture(tmp_path / "raw.mcap", reads, meta)
    (result,) = replay([path], tmp_path / "out.mcap")
    assert result.samples == 298 and result.events["gap"] == 1
    ((unit, gap),) = read_archive(tmp_path / "out.mcap").events()
    assert (unit, gap.kind, gap.count) == ("u1", Event.GAP, 2)
    assert gap.time_ns == t0 + 122 * 10_000_000


def test_capture_reads_keep_their_receive_times(tmp_path: Path) -> None:
    reads = [(1_000 + i, bytes([i % 256]) * 3) for i in range(50)]
    (cap,) = captures(write_capture(tmp_path / "raw.mcap", reads))
    assert cap.unit == "u1"
    assert cap.rx_ns.tolist() == [rx for rx, _ in reads]
    assert cap.data == [d for _, d in reads]


def test_export_times_on_a_usb_unit_meet_the_targets(tmp_path: Path) -> None:
    """A 3-minute USB capture of a drifting unit (+40 ppm, wandering 3 ppm, stalls),
    replayed and exported: the best estimate within 0.25 ms of the instant the values
    describe (p99 after 30 s), the live one within 0.5 ms."""
    config = streaming_config(UnitConfig(motion=MotionConfig(seed=6), clock_ppm=40.0,
                                         clock_wander_ppm=3.0, clock_wander_period_s=120.0,
                                         clock_seed=2), code=0xC8, decimation=10)
    cap = synthesize(config, UsbDelivery(stall_every_s=10.0, seed=5), seconds=180.0)
    meta = {"unit": "u1", "record": "0xC8", "decimation": "10", "filter_width": "15",
            "baud": "115200", "transport": "usb"}
    path = write_capture(tmp_path / "raw.mcap", list(zip(cap.rx_ns.tolist(), cap.data,
                                                         strict=True)), meta)
    replay([path], tmp_path / "out.mcap")
    out = tmp_path / "out.parquet"
    done = gx3_here("export", tmp_path / "out.mcap", "-o", out)
    assert done.exit_code == 0, done.stderr
    import pyarrow.parquet as pq

    table = pq.read_table(out).to_pydict()
    truth = dict(zip(cap.truth["timer"].tolist(), cap.truth["value_ns"].tolist(), strict=True))
    instant = np.array([truth[t] for t in table["timer"]])
    settled = np.array(table["time_ns"]) - np.array(table["time_ns"])[0] > 30e9
    best = np.abs(np.array(table["time_ns"]) - instant)[settled]
    live = np.abs(np.array(table["live_time_ns"]) - instant)[settled]
    naive = np.abs(np.array(table["rx_ns"]) - instant)[settled]
    assert np.percentile(best, 99) < 250_000, np.percentile(best, 99)
    assert np.percentile(live, 99) < 500_000, np.percentile(live, 99)
    assert np.percentile(naive, 99) > 5_000_000, "the filter delay alone is 7 ms"


def usb_captures(tmp_path: Path, units: int) -> list[Path]:
    """One 20-second USB capture file per unit, each with its bridge's metadata."""
    paths = []
    for i in range(units):
        config = streaming_config(UnitConfig(motion=MotionConfig(seed=i), clock_ppm=30.0 * i),
                                  code=0xCC, decimation=5)
        cap = synthesize(config, UsbDelivery(seed=i), seconds=20.0)
        meta = {"unit": f"u{i}", "record": "0xCC", "decimation": "5", "filter_width": "15",
                "baud": "115200", "transport": "usb"}
        writer = RawCaptureWriter(tmp_path / f"u{i}.mcap", "gx3", f"u{i}", meta)
        for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
            writer.write(data, rx)
        writer.close()
        paths.append(tmp_path / f"u{i}.mcap")
    return paths


def fleet_archive(path: Path, files: list[Path]) -> Path:
    """The reads of every unit in ``files`` in one archive, as `gx3 record --raw` keeps
    them (no capture metadata: replay finds the settings from the bytes)."""
    with ArchiveWriter(path) as writer:
        for cap in (c for f in files for c in captures(f)):
            writer.write_many(f"gx3/{cap.unit}/raw", cap.data, cap.rx_ns)
    return path


@pytest.mark.parametrize("layout", ["a file per unit", "one archive", "one archive cut short"])
def test_units_replayed_side_by_side_get_the_same_samples(tmp_path: Path, layout: str) -> None:
    paths = usb_captures(tmp_path, 3)
    units = ["u0", "u1", "u2"]
    if layout != "a file per unit":
        paths = [fleet_archive(tmp_path / "fleet.mcap", paths)]
    if layout == "one archive cut short":  # no summary: its units are found in its chunks
        data = paths[0].read_bytes()
        paths[0].write_bytes(data[: len(data) * 3 // 4])
        units = ["u0", "u1", "u2"][: len(read_archive(paths[0]).topics("raw"))]
        assert len(units) >= 2
    counted: list[int] = []  # the progress a terminal shows: samples as written
    alone = replay(paths, tmp_path / "alone.mcap", jobs=1, on_samples=counted.append)
    heard: list[str] = []
    together = replay(paths, tmp_path / "together.mcap", jobs=2,
                      on_unit=lambda r: heard.append(r.unit), on_samples=counted.append)
    assert [r.unit for r in together] == [r.unit for r in alone] == units
    assert sorted(heard) == units
    assert sum(counted) == 2 * sum(r.samples for r in alone) > 0
    assert [(r.samples, r.events, r.settings) for r in together] == \
        [(r.samples, r.events, r.settings) for r in alone]
    a, b = read_archive(tmp_path / "alone.mcap"), read_archive(tmp_path / "together.mcap")
    assert a.complete and b.complete and b.units() == a.units()
    for out in ("alone.mcap", "together.mcap"):  # units replayed one after another
        assert order_problems(tmp_path / out) == [], out
    for unit in a.units():
        cols_a = sample_columns(tmp_path / "alone.mcap", unit)
        cols_b = sample_columns(tmp_path / "together.mcap", unit)
        assert len(cols_a["ticks"]) == next(r.samples for r in alone if r.unit == unit)
        for k in cols_a:
            assert np.array_equal(cols_a[k], cols_b[k]), (unit, k)
        assert [e.kind for u, e in a.events() if u == unit] == \
            [e.kind for u, e in b.events() if u == unit]


def test_a_bad_capture_among_several_is_a_clear_error(tmp_path: Path) -> None:
    paths = usb_captures(tmp_path, 2)
    rng = np.random.default_rng(1)
    garbage = write_capture(tmp_path / "garbage.mcap", [(i, rng.bytes(64)) for i in range(500)])
    done = subprocess.run([GX3, "replay", *map(str, [paths[0], garbage, paths[1]]), "-j", "2",
                           "-o", str(tmp_path / "o.mcap")],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 2, done.stderr
    assert "no record found" in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.mcap", "u0.mcap",
                                                          "u1.mcap"], "a failed replay left a file"


def test_workers_end_when_the_replay_is_killed(tmp_path: Path) -> None:
    """kill -9 of `gx3 replay -j 2` leaves no worker behind. Its stderr is a full pipe
    nobody reads, so the replay waits in its first report with its workers started."""
    paths = usb_captures(tmp_path, 2)
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    with contextlib.suppress(BlockingIOError):
        while True:
            os.write(write_end, bytes(4096))
    os.set_blocking(write_end, True)
    proc = subprocess.Popen([GX3, "replay", *map(str, paths), "-j", "2", "-o",
                             str(tmp_path / "out.mcap")],
                            stdout=subprocess.DEVNULL, stderr=write_end)
    os.close(write_end)
    try:
        parent = psutil.Process(proc.pid)
        deadline = time.monotonic() + 60
        while len(workers := parent.children()) < 2:
            assert time.monotonic() < deadline and proc.poll() is None, "no workers started"
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        os.close(read_end)
    deadline = time.monotonic() + 30
    while running := [p.pid for p in workers if running_process(p)]:
        assert time.monotonic() < deadline, f"workers left running: {running}"
        time.sleep(0.1)


def running_process(process: psutil.Process) -> bool:
    """Still running: not ended, and not a zombie waiting for its new parent to reap it."""
    try:
        return process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_a_workers_error_reaches_the_caller_even_if_it_does_not_pickle() -> None:
    """What a worker sends goes through pickle; an error that does not pickle is sent as
    its words (the queue would drop it, and the replay would end short, saying nothing),
    in a ReplayError, which gx3 says in one line as it does every Gx3Error."""
    from bridge._workers import sendable
    from bridge.exceptions import Gx3Error, ReplayError

    class Unsendable(Exception):
        def __init__(self, what: str, where: int) -> None:
            super().__init__(f"{what} at {where}")

    said = sendable(Unsendable("odd bytes", 12), ReplayError)
    assert isinstance(said, ReplayError) and isinstance(said, Gx3Error)
    assert str(said) == "Unsendable: odd bytes at 12"
    plain = ReplayError("u1: no record found")
    assert sendable(plain, ReplayError) is plain


def test_a_raw_read_archived_late_keeps_its_receive_times(tmp_path: Path) -> None:
    """A recorder writes a read that came later than its reorder window at the log time
    of the message before it: both its stamps still come back exactly."""
    with ArchiveWriter(tmp_path / "late.mcap", reorder_s=0.0) as writer:
        writer.write_many("gx3/u1/raw", [b"a", b"b"], np.array([2_000, 3_000]),
                          np.array([20, 30]))
        writer.flush()  # written: what comes now at earlier log times is late
        writer.write_many("gx3/u1/raw", [b"c"], np.array([1_000]), np.array([40]))
    (capture,) = captures(tmp_path / "late.mcap")
    assert capture.data == [b"a", b"b", b"c"]
    assert capture.rx_ns.tolist() == [2_000, 3_000, 1_000]
    assert capture.raw_ns is not None and capture.raw_ns.tolist() == [20, 30, 40]
    assert read_archive(tmp_path / "late.mcap").messages("gx3/u1/raw").log_time.tolist() \
        == [2_000, 3_000, 3_000]


def test_a_captures_own_sampling_reply_sets_the_archives_info_and_export(
        tmp_path: Path) -> None:
    """A 500 Hz capture (filter width 32) that starts with the unit's own 0xDB reply and
    carries no metadata: replay times it by the reply, the archive's Info says what the
    reply said, and gx3 export re-times it with that, agreeing with the live time and
    the truth (not the factory width's 8.5 ms off)."""
    config = streaming_config(UnitConfig(motion=MotionConfig(seed=3), clock_ppm=-20.0),
                              code=0xC2, decimation=2, filter_width=32, baud=460_800)
    cap = synthesize(config, AdapterDelivery(frame_phase_s=0.0005, seed=4,
                                             latency_timer_s=0.001), seconds=30.0)
    sampling = vars(config.stored.sampling)
    reply = encode_reply(0xDB, **{k: sampling[k] for k in (
        "decimation", "flags", "filter_width", "mag_filter_width", "up_compensation",
        "north_compensation")})
    path = tmp_path / "raw.mcap"
    writer = RawCaptureWriter(path, "gx3", "u1")  # stamped as a bridge stamps: no metadata
    boot = int(cap.rx_ns[0]) - 3_600_000_000_000  # the raw clock counts from boot
    for rx, data in [(int(cap.rx_ns[0]) - 5_000_000, reply),
                     *zip(cap.rx_ns.tolist(), cap.data, strict=True)]:
        writer.write(data, rx, rx - boot)
    writer.close()
    replay([path], tmp_path / "out.mcap")
    archive = read_archive(tmp_path / "out.mcap")
    info = last_info(archive, "u1")
    assert info is not None
    assert (info.filter_width, info.decimation, info.command) == (32, 2, 0xC2)
    table = sample_table(archive, ["u1"], re_estimate=offline_times(archive))
    truth = dict(zip(cap.truth["timer"].tolist(), cap.truth["value_ns"].tolist(),
                     strict=True))
    settled = table["time_ns"] - table["time_ns"][0] > 5e9
    exported, live = table["time_ns"][settled], table["live_time_ns"][settled]
    true_ns = np.array([truth[t] for t in table["timer"][settled].tolist()])
    assert np.percentile(np.abs(exported - live), 99) < 100_000
    assert np.percentile(np.abs(exported - true_ns), 99) < 100_000
