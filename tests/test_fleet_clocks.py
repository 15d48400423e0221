"""A fleet's clocks in the open: the recorder bounds each bridge host's clock against its own.

A sample cannot arrive before the instant it was stamped with, so the least of
(arrival on the recorder's clock - time_ns) over a host's samples is the most that
host's clock can be behind the recorder's, and a negative one proves it ahead. Units
publish from a real Zenoh session on loopback (multicast scouting off) as bridges on
named hosts would, some with their samples stamped later (a host ahead) or earlier (a
host behind) than the instant they are put; a real recorder archives them, and the
archive afterwards must hold one HOST_CLOCK_OFFSET event per unit of a host that is
off, none for an honest host, and the hosts' bounds in its metadata. Every margin is
wide: only the physics (arrival after publication, on one machine's clock) is relied on.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.gx3_pb2 import Event, HostClock, Info, Status
from bridge.bus.publish import UnitPublisher
from bridge.bus.session import open_session
from bridge.cli.record import _hosts_table
from bridge.device import clock
from bridge.protocol.codec import Batch
from bridge.protocol.table import REPLIES
from bridge.recorder import hosts as host_clocks
from bridge.recorder.hosts import HOST_MARGIN_NS, HOSTS_METADATA, HostView
from bridge.recorder.live import Recorder
from tests.helpers.archives import archived_events
from tests.helpers.cli import gx3_here
from tests.helpers.processes import GX3
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import peer_sessions, zenoh_config

CODE = 0xC2
MS = 1_000_000
AHEAD_NS = 5 * MS
PERIOD_S = 0.005  # 200 samples/s per unit


@dataclass
class Unit:
    """A unit as its bridge host stamps it: ``ahead_ns`` is added to every sample's
    time_ns (a host whose clock is that much ahead); ``status_names_host`` False: its
    Status carries no host clock (its Info alone names the host)."""

    host: str
    ahead_ns: int = 0
    status_names_host: bool = True


def host_clock(host: str) -> HostClock:
    return HostClock(host=host, known=True, synchronised=True, estimated_error_ns=40_000,
                     maximum_error_ns=900_000, state="ok")


def publish(pubs: dict[str, UnitPublisher], units: dict[str, Unit],
            stop: threading.Event) -> None:
    """Each unit's samples every ``PERIOD_S``, stamped now + its ``ahead_ns`` (read at each
    sample, so a test can move a host's clock), and a Status every half second."""
    columns = {f.name: np.zeros((1, *f.shape), np.float32) for f in REPLIES[CODE].fields}
    tick, next_status = 0, 0.0
    while not stop.is_set():
        ticks = np.array([tick * 625], np.int64)
        columns["timer"] = ticks.astype(np.uint32)
        for name, pub in pubs.items():
            times = np.array([clock.realtime_ns() + units[name].ahead_ns], np.int64)
            pub.publish_samples(Batch(CODE, columns, np.arange(1), times, False), ticks,
                                times)
        if time.monotonic() >= next_status:
            next_status = time.monotonic() + 0.5
            for name, pub in pubs.items():
                status = Status(time_ns=clock.realtime_ns(), connected=True)
                if units[name].status_names_host:
                    status.host_clock.CopyFrom(host_clock(units[name].host))
                pub.publish_status(status)
        tick += 1
        stop.wait(PERIOD_S)


class Fleet:
    """Units publishing from one session as if from bridges on their hosts, a Recorder in
    this process writing ``out`` from another; everything closed on exit."""

    def __init__(self, out: Path, units: dict[str, Unit], **options: Any) -> None:
        self.out, self.units = out, units
        self.heard: list[tuple[str, Event]] = []
        self._rec_session, self._pub_session = peer_sessions(2)
        self.writer = ArchiveWriter(out)
        self.recorder = Recorder(self._rec_session, self.writer,
                                 on_event=lambda unit, e: self.heard.append((unit, e)),
                                 **options)
        self._pubs = {name: UnitPublisher(self._pub_session, name) for name in units}
        for name, pub in self._pubs.items():
            pub.set_info(Info(bring_up_time_ns=clock.realtime_ns(),
                              host_clock=host_clock(units[name].host)))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=publish, args=(self._pubs, units, self._stop))

    def __enter__(self) -> Fleet:
        self.run_until(lambda: len(self.recorder.snapshot()) == len(self.units),
                       "every unit's liveliness")
        self._thread.start()
        return self

    def run_until(self, condition: Callable[[], bool], what: str) -> None:
        def written() -> bool:
            self.recorder.run_once(0.05)
            return condition()
        wait_for(written, what=what)

    def run_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.recorder.run_once(0.1)

    def told(self, unit: str) -> list[Event]:
        return [e for u, e in self.heard if u == unit and e.kind == Event.HOST_CLOCK_OFFSET]

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        for pub in self._pubs.values():
            pub.close()
        self.recorder.close()
        self.writer.close()
        self._pub_session.close()
        self._rec_session.close()


def hosts_record(path: Path) -> dict[str, Any]:
    """The archive's gx3.hosts metadata, its JSON values decoded."""
    (record,) = [m for m in read_archive(path).metadata if m.name == HOSTS_METADATA]
    return {k: v if k == "note" else json.loads(v) for k, v in record.metadata.items()}


def offsets(path: Path, unit: str) -> list[Event]:
    return archived_events(path, unit, Event.HOST_CLOCK_OFFSET)


def test_a_host_ahead_is_told_once_per_unit_and_an_honest_host_never(tmp_path: Path) -> None:
    out = tmp_path / "ahead.mcap"
    units = {"a1": Unit("robot-ahead", AHEAD_NS), "a2": Unit("robot-ahead", AHEAD_NS),
             "h1": Unit("robot-honest", status_names_host=False)}
    with Fleet(out, units) as fleet:
        fleet.run_until(lambda: bool(fleet.told("a1") and fleet.told("a2")),
                        "the ahead host's events")
        fleet.run_for(3.0)  # the host stays ahead: nothing more is said
        shown = {h.host: h for h in fleet.recorder.hosts()}
    for unit in ("a1", "a2"):
        (event,) = offsets(out, unit)
        # arrival is after publication, on this machine's one clock: never below -5 ms
        assert -AHEAD_NS <= event.clock_change_ns < -HOST_MARGIN_NS, event
        assert event.unit == unit and event.count == 1
        assert "the clock of host robot-ahead is ahead of the recorder's by" in event.detail
    assert offsets(out, "h1") == []
    assert sorted((u, e.detail) for u, e in fleet.heard) == sorted(
        (u, offsets(out, u)[0].detail) for u in ("a1", "a2"))  # on_event heard just those
    # the live view: each host with its units, bound and sync state (the honest host
    # named by its unit's Info alone)
    assert shown["robot-ahead"].units == ("a1", "a2")
    assert host_clocks.ahead(shown["robot-ahead"].bound_ns)
    assert shown["robot-honest"].units == ("h1",)
    honest = shown["robot-honest"].bound_ns
    assert honest is not None and honest >= 0 and not host_clocks.ahead(honest)
    assert shown["robot-ahead"].clock is not None and shown["robot-ahead"].clock.synchronised
    # the archive's record of the whole recording
    hosts = hosts_record(out)
    ahead, straight = hosts["host/robot-ahead"], hosts["host/robot-honest"]
    assert ahead["units"] == ["a1", "a2"] and ahead["ahead"] is True
    assert -AHEAD_NS <= ahead["least_lag_ns"] <= -2 * MS  # hundreds of samples: one was quick
    assert ahead["clock"]["synchronised"] is True and ahead["clock"]["host"] == "robot-ahead"
    assert straight["units"] == ["h1"] and straight["ahead"] is False
    assert 0 <= straight["least_lag_ns"] < 1000 * MS
    assert hosts["recorder"]["host"] == socket.gethostname()


def test_a_tolerance_tells_a_host_that_may_be_behind(tmp_path: Path) -> None:
    out = tmp_path / "behind.mcap"
    units = {"b1": Unit("robot-late", -1000 * MS), "h1": Unit("robot-honest")}
    with Fleet(out, units, max_host_offset_ms=100.0) as fleet:
        fleet.run_until(lambda: bool(fleet.told("b1")), "the late host's event")
        fleet.run_for(3.0)
    (event,) = offsets(out, "b1")
    assert 1000 * MS <= event.clock_change_ns < 5000 * MS
    assert re.search(r"the clock of host robot-late may be behind the recorder's by up to "
                     r"[\d,.]+ ms, or its samples take that long to arrive \(tolerance "
                     r"100 ms\)", event.detail), event.detail
    assert offsets(out, "h1") == []


def test_a_host_is_told_again_only_after_it_cleared(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Ahead, told; set right, cleared once the window has none of its ahead samples
    left; ahead again, told again. A shorter window keeps the test short."""
    monkeypatch.setattr(host_clocks, "HOST_WINDOW_S", 2)
    out = tmp_path / "again.mcap"
    units = {"a1": Unit("robot-wobbly", AHEAD_NS)}
    with Fleet(out, units) as fleet:
        fleet.run_until(lambda: len(fleet.told("a1")) == 1, "the first event")
        fleet.run_for(1.0)
        units["a1"].ahead_ns = 0  # its clock set right

        def cleared() -> bool:
            (host,) = fleet.recorder.hosts()
            return host.bound_ns is not None and host.bound_ns >= 0
        fleet.run_until(cleared, "the window to forget the host's ahead samples")
        fleet.run_for(1.0)
        assert len(fleet.told("a1")) == 1
        units["a1"].ahead_ns = AHEAD_NS
        fleet.run_until(lambda: len(fleet.told("a1")) == 2, "the second event")
        fleet.run_for(3.0)
    told = offsets(out, "a1")
    assert len(told) == 2 and all(e.clock_change_ns < -HOST_MARGIN_NS for e in told)
    assert told[0].time_ns < told[1].time_ns


def test_a_tolerance_must_be_above_zero() -> None:
    for bad in (-1.0, 0.0, float("nan")):
        with pytest.raises(ValueError, match="give a tolerance above 0 ms"):
            Recorder(None, None, max_host_offset_ms=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", ["-1", "0", "nan"])
def test_gx3_record_refuses_a_bad_tolerance_in_one_line(tmp_path: Path, value: str) -> None:
    done = gx3_here("record", "-o", tmp_path / "x.mcap", "--max-host-offset-ms", value,
                    "--connect", "tcp/127.0.0.1:9", "--mode", "client", "--duration", "0")
    assert done.exit_code == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "--max-host-offset-ms" in lines[0], done.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_gx3_record_shows_and_archives_the_hosts_clocks(tmp_path: Path) -> None:
    """The command as run: its own clock in gx3.archive, the host ahead warned of, in its
    final table (80 columns) and in gx3.hosts."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "fleet.mcap"
    cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    proc = subprocess.Popen([GX3, "record", "-o", str(out), "--zenoh-config", str(cfg),
                             "--max-host-offset-ms", "500"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "COLUMNS": "80"})
    try:
        session = open_session(connect=[endpoint], mode="peer", multicast_scouting=False)
        units = {"a1": Unit("robot-ahead", AHEAD_NS)}
        stop = threading.Event()
        try:
            with UnitPublisher(session, "a1") as pub:
                thread = threading.Thread(target=publish, args=({"a1": pub}, units, stop))
                thread.start()
                try:
                    wait_for(lambda: out.exists() and out.stat().st_size > 0
                             and bool(offsets(out, "a1")), what="the event in the archive")
                finally:
                    stop.set()
                    thread.join()
        finally:
            session.close()
    finally:
        proc.send_signal(signal.SIGINT)
        _, stderr_bytes = proc.communicate(timeout=60)
    stderr = stderr_bytes.decode()
    assert proc.returncode == 0, stderr
    assert re.search(r"warning: the clock of host robot-ahead is ahead of the recorder's", stderr)
    final = stderr[stderr.rindex("bridge hosts' clocks"):].splitlines()
    assert re.search(r"robot-ahead\s+a1\s+ahead by ≥ [\d.]+ ms\s+synced ±0\.04 ms",
                     final[2]), final
    table = final[:final.index(next(line for line in final if line.startswith("wrote ")))]
    assert all(len(line) <= 80 for line in table), stderr
    archive = read_archive(out)
    (meta,) = [m.metadata for m in archive.metadata if m.name == "gx3.archive"]
    assert meta["recorder_host"] == socket.gethostname()
    assert set(json.loads(meta["recorder_clock"])) >= {"known", "synchronised",
                                                        "estimated_error_ns"}
    hosts = hosts_record(out)
    assert hosts["host/robot-ahead"]["ahead"] is True
    assert len(offsets(out, "a1")) == 1


def test_the_hosts_table_fits_80_columns() -> None:
    """However long host and unit names are, the table keeps within 80 columns at its
    natural width (a wider terminal gives it no more)."""
    hosts = [HostView("a-very-long-host-name.lab.example.org", tuple(f"imu{i}" for i in range(40)),
                      -123_456_789, -123_456_789, host_clock("x")),
             HostView("robot1", ("imu1",), 800_000, 600_000,
                      HostClock(host="robot1", known=True, synchronised=False)),
             HostView("", ("old",), None, None, None)]
    console = Console(width=200, record=True)
    console.print(_hosts_table(hosts, 5 * MS, whole=False))
    text = console.export_text()
    assert max(map(len, text.splitlines())) <= 80, text
    assert "ahead by ≥ 123 ms" in text and "0.80 ms behind at most" in text
    assert "not synchronised" in text and "no samples yet" in text
