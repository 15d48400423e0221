"""`gx3 bridge` through host trouble: a stalled process, and a line too slow for its rate.

A real bridge process on an emulated unit over a pty, with a real recorder: what
the archive holds afterwards is compared with the emulator's ground truth. A host
that stops the bridge for a second or two (SIGSTOP, as a suspended or starved host
does) loses what the pty could not buffer; the timer runs on, so that is a gap of
exactly the records lost, with ticks and time_ns running on, not a reset. A line
too slow for its record and rate is named at bring-up and on configure, with the
fix, and its gaps are summed on the terminal rather than printed one by one.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from bridge.archive.walk import read_archive
from bridge.bus.gx3_pb2 import Event
from bridge.export.tables import offline_times, sample_table
from bridge.protocol.framer import Framer
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Stored
from bridge.sim.unit import UnitConfig
from bridge.unit.pipeline import Options, Pipeline
from bridge.unit.service import GAP_LINE_S
from tests.helpers.archives import events_in, samples_in
from tests.helpers.pipeline import ListSink
from tests.helpers.processes import GX3, bridge_process, recorder
from tests.helpers.units import FIVE_HUNDRED_HZ, STATIC_UNIT
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config

SLOW_LINE = UnitConfig(serial="SLOWLINE", motion=MotionConfig(seed=8),
                       stored=Stored(mode_preset=2, continuous_preset=0xCC))


def _finish(proc: subprocess.Popen[bytes]) -> str:
    """Stop a bridge or recorder with Ctrl-C; its stderr."""
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err.decode()
    return err.decode()


def _gx3(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([GX3, *args], capture_output=True, text=True, timeout=60,
                          check=False, stdin=subprocess.DEVNULL)


def _network(tmp_path: Path) -> tuple[Path, Path, Path]:
    """Configs for the recorder (listening), the bridge (connecting to it, listening for
    the operator) and the operator's commands (connecting to the bridge)."""
    recording, commands = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    return (zenoh_config(tmp_path / "rec.json5", listen=[recording]),
            zenoh_config(tmp_path / "bridge.json5", listen=[commands], connect=[recording]),
            zenoh_config(tmp_path / "cli.json5", connect=[commands]))


def test_a_stalled_bridge_reports_the_records_lost_as_a_gap(tmp_path: Path) -> None:
    rec_cfg, bridge_cfg, cli_cfg = _network(tmp_path)
    out = tmp_path / "stall.mcap"
    rec = recorder(out, rec_cfg, "--history", "100000")
    with Simulator([FIVE_HUNDRED_HZ], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--baud", "921600", "--unit", "a",
                           "--allow-commands") as bridge:
        wait_for(lambda: samples_in(out, "a") >= 1500, what="3 s of samples")
        os.kill(bridge.pid, signal.SIGSTOP)
        time.sleep(1.5)  # the fault itself; nothing below depends on its length
        os.kill(bridge.pid, signal.SIGCONT)
        resumed = samples_in(out, "a")
        wait_for(lambda: samples_in(out, "a") >= resumed + 1000, what="2 s after the stall")
        done = _gx3("set-timer", "--value", "0", "--unit", "a", "--zenoh-config", str(cli_cfg))
        assert done.returncode == 0, done.stderr
        wait_for(lambda: any(e.kind == Event.RESET for e in events_in(out, "a")),
                 what="the timer set to be reported")
        _finish(bridge)
        truth = sim.units[0].truth.arrays()
    _finish(rec)

    archive = read_archive(out)
    events = events_in(out, "a")
    resets = [e for e in events if e.kind == Event.RESET]
    assert len(resets) == 1, "only the timer set is a reset"
    table = sample_table(archive, ["a"], re_estimate=offline_times(archive))
    first = table["ticks"] < resets[0].ticks  # the epoch the stall was in
    ticks, timer = table["ticks"][first], table["timer"][first]
    exported, live = table["time_ns"][first], table["live_time_ns"][first]
    # every record the unit sent, by its timer: where each archived one stands in truth
    at = np.searchsorted(truth["timer"][: np.argmax(truth["timer"] == timer[-1]) + 1], timer)
    assert (truth["timer"][at] == timer).all(), "an archived record the unit never sent"
    missing = np.diff(at) - 1
    holes = np.flatnonzero(missing)
    assert missing.max() >= 200, "the stall lost no records: nothing was tested"
    gaps = {e.ticks: e.count for e in events if e.kind == Event.GAP}
    assert gaps == {int(ticks[h + 1]): int(missing[h]) for h in holes}, \
        "each gap counts exactly the records lost"
    device_ticks = truth["device_s"][at] * 62_500
    assert np.abs((ticks - ticks[0]) - (device_ticks - device_ticks[0])).max() <= 1, \
        "ticks ran on through the stall"
    value_ns = truth["value_ns"][at]
    settled = ticks >= ticks[0] + 2 * 62_500
    for name, times in (("live", live), ("exported", exported)):
        error = np.abs(times - value_ns)[settled].max()
        assert error < 20_000_000, f"{name} time_ns off by {error / 1e6:.1f} ms"


def test_a_line_too_slow_for_its_rate_is_named_and_its_gaps_summed(tmp_path: Path) -> None:
    """0xCC (79 bytes) at 250 Hz needs 19,750 bytes/s; 115,200 baud carries 11,520."""
    rec_cfg, bridge_cfg, cli_cfg = _network(tmp_path)
    out = tmp_path / "slow.mcap"
    fix = "--new-baud 230400 or --decimation 7 or more"
    with Simulator([SLOW_LINE], "pty") as sim:
        local = _gx3("configure", "--port", sim.endpoints[0], "--decimation", "4", "--json")
        assert local.returncode == 0, local.stderr
        assert fix in json.loads(local.stdout)["warning"]
        rec = recorder(out, rec_cfg)
        try:  # the recorder is stopped whatever fails: no process is left behind
            with bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a",
                                "--allow-commands") as bridge:
                started = time.monotonic()
                wait_for(lambda: sum(e.kind == Event.GAP for e in events_in(out, "a")) >= 300,
                         what="the gaps of a line too slow")
                remote = _gx3("configure", "--unit", "a", "--decimation", "5", "--json",
                              "--zenoh-config", str(cli_cfg))
                assert remote.returncode == 0, remote.stderr
                assert "--new-baud 230400 or --decimation 7" in \
                    json.loads(remote.stdout)["warning"]
                stderr = _finish(bridge)
                ran = time.monotonic() - started
        finally:
            _finish(rec)
    events = events_in(out, "a")
    bring_up = [e for e in events if e.kind == Event.BRING_UP]
    assert fix in bring_up[0].detail and fix in stderr
    gaps = [e for e in events if e.kind == Event.GAP]
    assert len(gaps) >= 300 and all(e.count >= 1 for e in gaps), "one event per gap"
    lines = re.findall(r"^\S+ gap\b.*$", stderr, re.M)
    assert 1 <= len(lines) <= 2 + ran / GAP_LINE_S, f"{len(lines)} gap lines in {ran:.0f} s"
    counts = [re.search(r" gap(?: \(([\d,]+))?", line) for line in lines]
    summed = sum(int((m.group(1) or "1").replace(",", "")) for m in counts if m)
    assert summed == sum(e.count for e in gaps), "the lines count every missing sample"


def test_a_host_stall_after_a_read_with_no_whole_record_is_not_a_silent_unit() -> None:
    """The pipeline's thread stops for 1.5 s just after a read that held only part of a
    record (what a stopped or starved host does at any moment): the unit kept talking,
    the port kept its bytes, so there is nothing to report and nothing is lost."""
    sink, framer, stalled = ListSink(), Framer(expect=[0xC2]), threading.Event()

    def on_read(data: bytes, raw_ns: int, real_ns: int) -> None:
        whole = framer.feed(data, raw_ns)  # the same bytes the session frames
        if not whole and not stalled.is_set() and len(sink.column("ticks")) >= 50:
            stalled.set()
            time.sleep(1.5)

    with Simulator([STATIC_UNIT], "pty") as sim:
        pipeline = Pipeline(Options(url=sim.endpoints[0]), sink, on_read=on_read)
        stop = threading.Event()
        worker = threading.Thread(target=pipeline.run, args=(stop,))
        worker.start()
        try:
            wait_for(stalled.is_set, what="a read with no whole record")
            wait_for(lambda: len(sink.column("ticks")) >= 300, what="samples after the stall")
        finally:
            stop.set()
            worker.join(timeout=30)
    assert sink.kinds() == ["bring_up"], "the unit was never silent"
    assert (np.diff(sink.column("ticks")) == 625).all(), "a record was lost"
