"""`gx3 bridge` as users run it: an OS process between an emulated unit and Zenoh.

The unit is the emulator on a real pty; the bridge is the installed console script;
the subscriber is the public ``bridge.subscribe`` API in this process, on loopback
with multicast scouting off. What is checked is what a fleet user relies on:
every sample of a 1 kHz unit arrives in order and equals the unit's ground truth,
status and info are published, commands are refused unless allowed, and a killed
bridge's liveliness token goes away while a restarted one picks up again.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import zenoh
from typer.testing import Result

from bridge.bus.gx3_pb2 import Info, Status
from bridge.bus.subscribe import SampleBatch, subscribe
from bridge.sim.serve import Simulator
from tests.helpers.cli import gx3_here
from tests.helpers.processes import Stderr, bridge_process
from tests.helpers.units import FAST, SLOW
from tests.helpers.waiting import wait_for


@pytest.mark.parametrize(("budget_ms", "pure"), [(None, False), (5, False), (None, True)],
                         ids=["default", "max-latency-5ms", "pure-python"])
def test_every_sample_of_a_1khz_unit_arrives_equal_to_the_truth(
        network: tuple[Path, Path], budget_ms: int | None, pure: bool) -> None:
    """With a latency budget too: then reads gather a few records each; and without the
    compiled core (``GX3_NATIVE=0``, as on a machine without a compiler)."""
    bridge_cfg, client_cfg = network
    seconds = 5.0
    budget = [] if budget_ms is None else ["--max-latency-ms", str(budget_ms)]
    with Simulator([FAST], "pty") as sim, \
            subscribe("gx3/fast/imu", output="batches", zenoh_config=client_cfg,
                      history=20_000) as sub, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--baud", "921600", "--unit", "fast",
                           *budget, env={"GX3_NATIVE": "0"} if pure else None):
        batches: list[SampleBatch] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            batch = sub.get(timeout=1.0)
            if batch is not None:
                batches.append(batch)
                ticks = batches[-1]["ticks"]
                if ticks[-1] - batches[0]["ticks"][0] >= seconds * 62_500:
                    break
        unit = sim.units[0]
        truth = unit.truth.arrays()
        delay, period = unit.filter_delays()[0], unit.period
        misses = sub.misses
    ticks = np.concatenate([b["ticks"] for b in batches])
    timer = np.concatenate([b["timer"] for b in batches])
    per_read = len(ticks) / len(np.unique(np.concatenate([b["rx_ns"] for b in batches])))
    if budget_ms is not None:  # a read every 4 ms: 4 records a read (by default about 1,
        # more only when a loaded host reads late)
        assert per_read >= 3, f"{per_read:.1f} records a read: reads did not gather"
    accel = np.concatenate([b["accel"] for b in batches])
    assert ticks[-1] - ticks[0] >= seconds * 62_500, f"not {seconds:g} s of samples"
    steps = np.diff(ticks)
    assert set(steps.tolist()) <= {62, 63}, f"missing or repeated samples: {np.unique(steps)}"
    assert misses == 0
    # the published records are exactly the records the unit sent, in order
    start = int(np.flatnonzero(truth["timer"] == timer[0])[0])
    assert (truth["timer"][start : start + len(timer)] == timer).all()
    # and their values are what the unit measured: the motion at each record's
    # instant, as its moving-average filter delays it
    device_s = truth["device_s"][start : start + len(timer)]
    expected = unit.motion.sample(device_s - delay, period)["accel"].astype(np.float32)
    assert np.unique(accel[:, 0]).size > 0.9 * len(accel), "a moving unit's records differ"
    np.testing.assert_array_equal(accel, expected)


def test_status_info_and_refused_commands(network: tuple[Path, Path]) -> None:
    bridge_cfg, client_cfg = network
    with Simulator([SLOW], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "slow"), \
            zenoh.open(zenoh.Config.from_file(str(client_cfg))) as session:
        statuses: list[Status] = []

        def on_status(sample: zenoh.Sample) -> None:
            msg = Status()
            msg.ParseFromString(sample.payload.to_bytes())
            statuses.append(msg)

        sub = session.declare_subscriber("gx3/slow/status", on_status)
        wait_for(lambda: len(statuses) >= 3 and statuses[-1].samples > 100)
        sub.undeclare()
        infos = [r.ok for r in session.get("gx3/slow/info", timeout=5.0) if r.ok is not None]
        refused = [r.err for r in session.get("gx3/slow/command", timeout=5.0,
                                              payload='{"action": "set_timer"}')
                   if r.err is not None]
    status = statuses[-1]
    assert status.state == Status.STREAMING and status.connected
    assert status.command == 0xC8 and status.output_rate_hz == 100.0
    assert 80 <= status.samples_per_s <= 120
    assert status.dropped == 0 and status.checksum_failures == 0
    info = Info()
    info.ParseFromString(infos[0].payload.to_bytes())
    assert info.serial == "SLOW0001" and info.firmware_text == "1.1.27"
    assert info.decimation == 10 and not info.allow_commands
    assert refused and "--allow-commands" in refused[0].payload.to_string()


def test_operator_commands_over_zenoh(network: tuple[Path, Path]) -> None:
    bridge_cfg, client_cfg = network
    with Simulator([SLOW], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "slow",
                           "--allow-commands"):
        def gx3(*args: str) -> Result:  # the operator's commands, in this process
            return gx3_here(*args, "--unit", "slow", "--zenoh-config", client_cfg, "--json")

        wait_for(lambda: gx3("info").exit_code == 0)
        info = json.loads(gx3("info").stdout)
        timer = gx3("set-timer", "--value", "1000")
        test = gx3("stationary-test")
        reset = gx3_here("reset", "--unit", "slow", "--zenoh-config", client_cfg)
    assert info["serial"] == "SLOW0001"
    assert timer.exit_code == 0 and json.loads(timer.stdout)["timer"] >= 1000
    assert test.exit_code == 0 and json.loads(test.stdout)["flags"]["system_tick"]
    assert reset.exit_code != 0 and "--yes" in reset.stderr, "a reset must be confirmed"


def test_killed_bridge_goes_away_and_a_new_one_picks_up(network: tuple[Path, Path]) -> None:
    bridge_cfg, client_cfg = network
    with Simulator([SLOW], "pty") as sim, \
            zenoh.open(zenoh.Config.from_file(str(client_cfg))) as session:
        events: list[str] = []
        token = session.liveliness().declare_subscriber(
            "gx3/*/alive", lambda s: events.append(str(s.kind)), history=True)
        with bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "slow") as first:
            wait_for(lambda: events.count("SampleKind.PUT") == 1)
            os.kill(first.pid, signal.SIGKILL)
            first.wait(timeout=10)
            wait_for(lambda: "SampleKind.DELETE" in events)
        with subscribe("gx3/slow/imu", output="batches", zenoh_config=client_cfg) as sub, \
                bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "slow"):
            wait_for(lambda: events.count("SampleKind.PUT") == 2)
            got = sub.get(timeout=20.0)
        token.undeclare()
    assert got is not None and len(got) > 0


def test_sigint_stops_continuous_mode_and_capture_holds_every_read(
        network: tuple[Path, Path], tmp_path: Path) -> None:
    from mcap.reader import make_reader

    bridge_cfg, client_cfg = network
    capture = tmp_path / "raw.mcap"
    with Simulator([SLOW], "pty") as sim, \
            subscribe("gx3/slow/imu", output="batches", zenoh_config=client_cfg) as sub:
        with bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "slow", "--capture",
                            str(capture)) as proc:
            got = 0
            while got < 150:
                batch = sub.get(timeout=20.0)
                assert batch is not None, "no samples"
                got += len(batch)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=20) == 0
        assert sim.units[0].mode == 1, "the unit was left streaming"
    with capture.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
        reads = [(m.log_time, m.data) for _, _, m in reader.iter_messages()]
    assert topics == {"gx3/slow/raw"}
    data = b"".join(d for _, d in reads)
    assert data.count(bytes((0xC8,))) >= 150, "the capture lacks the streamed records"
    assert all(b[0] <= a[0] for a, b in zip(reads[1:], reads, strict=False))


def test_a_missing_port_is_said_once_and_given_up_with_exit_1(
        network: tuple[Path, Path], tmp_path: Path) -> None:
    bridge_cfg, _ = network
    port = tmp_path / "imu1"
    with bridge_process(str(port), bridge_cfg, "--give-up-after", "3") as proc:
        assert proc.wait(timeout=60) == 1
        out = Stderr(proc)
        (waiting,) = out.waiting()
        lines = out.read().splitlines()
    assert f"{port}: no such port" in waiting and "retrying" in waiting
    assert "disconnect" not in out.text
    assert lines[-1].startswith(f"error: no unit came up on {port}; ")
    assert lines[-1].endswith("(gave up after 3 s)")
    assert "Traceback" not in out.text


def test_a_silent_unit_is_said_once_never_a_disconnect_and_exits_1(
        network: tuple[Path, Path]) -> None:
    bridge_cfg, _ = network
    master, slave = os.openpty()
    asked = bytearray()

    def tries() -> int:
        """Bring-up attempts seen on the line: each asks 0xE9 three times."""
        with contextlib.suppress(BlockingIOError):
            asked.extend(os.read(master, 1 << 16))
        return asked.count(0xE9) // 3

    os.set_blocking(master, False)
    try:
        with bridge_process(os.ttyname(slave), bridge_cfg) as proc:
            out = Stderr(proc)
            wait_for(lambda: tries() >= 3, what="three bring-up attempts")
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=60) == 1
            (waiting,) = out.waiting()
            text = out.read()
    finally:
        os.close(master)
        os.close(slave)
    assert "no reply to 0xE9" in waiting and "retrying" in waiting
    assert "disconnect" not in text
    assert text.splitlines()[-1].startswith("error: no unit came up on ")


def test_a_busy_port_is_told_apart_and_a_new_reason_said_again(
        network: tuple[Path, Path]) -> None:
    import serial

    bridge_cfg, _ = network
    master, slave = os.openpty()
    holder = serial.Serial(os.ttyname(slave), exclusive=True)  # another program has it
    try:
        with bridge_process(os.ttyname(slave), bridge_cfg) as proc:
            out = Stderr(proc)
            wait_for(lambda: len(out.waiting()) == 1, what="the busy port reported")
            holder.close()  # free, but nobody answers on it
            wait_for(lambda: len(out.waiting()) == 2, what="the silent unit reported")
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=60) == 1
            busy, silent = out.waiting()
            text = out.read()
    finally:
        holder.close()
        os.close(master)
        os.close(slave)
    assert "port is busy: another program has it open" in busy
    assert "no reply to 0xE9" in silent
    assert "disconnect" not in text


@pytest.mark.parametrize("model", ["3DM-GX2", "Inertia-Link"])
def test_a_gx2_family_unit_is_refused_at_bring_up_not_mistimed(
        network: tuple[Path, Path], model: str) -> None:
    bridge_cfg, _ = network
    with Simulator([replace(FAST, model_name=model)], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--baud", "921600") as proc:
        assert proc.wait(timeout=60) == 2
        text = Stderr(proc).read()
    last = text.splitlines()[-1]
    assert last.startswith(f"error: the unit says it is a {model}, not a 3DM-GX3: ")
    assert "19,660,800 ticks/s" in last and "Traceback" not in text
    assert "retrying" not in text
