"""`gx3 record` as users run it: real bridges on emulated units, a real recorder process.

The recorder listens on a loopback port; each bridge connects to it (multicast
scouting off). The archive must hold every sample each bridge published while it
ran, with no hole in any unit's ticks, and each unit's info and status.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from bridge.archive.walk import read_archive
from bridge.sim.serve import Simulator
from bridge.viz.thin import Bins
from tests.helpers.archives import sample_columns, samples_in
from tests.helpers.cli import gx3_here
from tests.helpers.mcap_order import order_problems
from tests.helpers.processes import GX3, bridge_process, published, recorder
from tests.helpers.rrd import rerun_rows, rerun_rows_so_far, scalar_lines
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config


def stop_bridges(**bridges: subprocess.Popen[bytes]) -> dict[str, bytes]:
    """Ctrl-C each bridge and wait for it to end, then give the recorder two seconds to
    take in what was still on its way: each bridge's stderr."""
    for bridge in bridges.values():
        bridge.send_signal(signal.SIGINT)
    stderr = {unit: bridge.communicate(timeout=30)[1] for unit, bridge in bridges.items()}
    time.sleep(2.0)
    return stderr


def test_every_published_sample_is_archived(tmp_path: Path) -> None:
    """Two bridges, one recorder asking their caches for what it missed: every sample
    each published is archived, and drawn in its --rrd; the --capture file of a's reads,
    replayed, gives what a published live, each read at the time the bridge received it,
    timed with the unit's settings."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    out = tmp_path / "fleet.mcap"
    rrd = tmp_path / "fleet.rrd"
    capture = tmp_path / "raw.mcap"
    proc = recorder(out, rec_cfg, "--history", "10000", "--rrd", str(rrd))
    with Simulator(TWO_UNITS, "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a", "--capture",
                           str(capture)) as a, \
            bridge_process(sim.endpoints[1], bridge_cfg, "--unit", "b") as b:
        wait_for(lambda: min(samples_in(out, "a"), samples_in(out, "b")) >= 300)
        stderr = stop_bridges(a=a, b=b)
    proc.send_signal(signal.SIGINT)
    _, rec_err = proc.communicate(timeout=30)
    assert proc.returncode == 0, rec_err.decode()
    archive = read_archive(out)
    assert archive.complete and archive.units() == ["a", "b"]
    assert order_problems(out) == []  # frames, status, info and samples in log-time order
    for unit in ("a", "b"):
        ticks = np.sort(np.concatenate([blk.columns["ticks"]
                                        for blk in archive.samples([unit])]))
        assert len(ticks) == published(stderr[unit], unit), f"{unit}: samples missing"
        assert (np.diff(ticks) == 625).all(), f"{unit}: a hole in the archived samples"
        topics = set(archive.topics())
        assert {f"gx3/{unit}/info", f"gx3/{unit}/status", f"gx3/{unit}/frame"} <= topics
        assert rerun_rows(rrd, f"/plots/accel/x/{unit}") == len(ticks), "--rrd lost samples"
    rendered = tmp_path / "rendered.rrd"
    done = gx3_here("rrd", out, "-o", rendered)
    assert done.exit_code == 0, done.stderr
    for unit in ("a", "b"):
        entity = f"/plots/accel/x/{unit}"
        assert rerun_rows(rendered, entity) == rerun_rows(rrd, entity)
    assert_replay_gives_live(capture, out, tmp_path / "re.mcap")


def assert_replay_gives_live(source: Path, live: Path, replayed: Path) -> None:
    """``source``'s raw reads of unit a, replayed, give a's samples in ``live``."""
    assert read_archive(source).topics("raw") == ["gx3/a/raw"]
    done = gx3_here("replay", source, "-o", replayed)
    assert done.exit_code == 0, done.stderr
    assert "inferred" not in done.stdout + done.stderr
    a, b = sample_columns(live, "a"), sample_columns(replayed, "a")
    assert len(a["ticks"]) >= 300
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_the_recorders_summary_is_for_people_at_80_columns(tmp_path: Path) -> None:
    """What a person sees at the end of `gx3 record --rrd` in an 80-column terminal:
    every line fits, no header is cut, the offset is how far the unit's clock moved
    (a few ms at most here, not the epoch-sized offset itself), and no third-party
    log line (Rerun's file sink warnings, raw ANSI codes) reaches the terminal. With
    --rrd-max-rate, the Rerun recording holds each line's least and greatest value of
    each bin, at their instants, of every sample archived."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    out = tmp_path / "fleet.mcap"
    proc = subprocess.Popen([GX3, "record", "-o", out.name, "--zenoh-config", str(rec_cfg),
                             "--rrd", "fleet.rrd", "--rrd-max-rate", "5"],
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=tmp_path,
                            env={**os.environ, "COLUMNS": "80"})
    with Simulator(TWO_UNITS[:1], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "imu-with-a-long-name"):
        wait_for(lambda: samples_in(out, "imu-with-a-long-name") >= 300)
        proc.send_signal(signal.SIGINT)
        _, raw = proc.communicate(timeout=30)
    assert proc.returncode == 0, raw.decode()
    text = raw.decode()
    assert "\x1b" not in text and "WARN" not in text and "FileSink" not in text, text
    lines = text.splitlines()
    assert max(map(len, lines)) <= 80, text
    header = next(line for line in lines if line.startswith("unit "))
    assert header.split() == ["unit", "state", "rate/s", "samples", "drops", "crc", "ms",
                              "ppm", "time", "MB"], text
    (row,) = [line for line in lines if line.startswith("imu-with-a-long-name ")]
    offset_ms = float(row.split()[6])
    assert abs(offset_ms) < 5.0, text
    archived = sample_columns(out, "imu-with-a-long-name")
    time_ns, accel = archived["time_ns"], archived["accel"][:, 1].astype(np.float64)
    bins = Bins.of(time_ns, 200_000_000, hold_last=False)
    thinned = scalar_lines(tmp_path / "fleet.rrd")["/plots/accel/y/imu-with-a-long-name"]
    kept = bins.extremes(accel)
    assert np.array_equal(thinned[0], time_ns[kept]) and np.array_equal(thinned[1], accel[kept])
    assert len(kept) < len(time_ns) / 4


def test_killed_recorder_leaves_a_readable_archive(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    out = tmp_path / "killed.mcap"
    proc = recorder(out, rec_cfg)
    with Simulator(TWO_UNITS[:1], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a"):
        wait_for(lambda: samples_in(out, "a") >= 200)
        first = samples_in(out, "a")
        wait_for(lambda: samples_in(out, "a") > first, what="a later flush")  # mid-run
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        killed = time.time_ns()
    for stream in (proc.stdout, proc.stderr):
        assert stream is not None
        stream.close()
    archive = read_archive(out)
    assert not archive.complete
    blocks = archive.samples(["a"])
    ticks = np.sort(np.concatenate([b.columns["ticks"] for b in blocks]))
    assert (np.diff(ticks) == 625).all()
    last = max(int(b.receive_ns.max()) for b in blocks)
    assert killed - last < 2.5e9, "more than the last second or so was lost"
    repaired = tmp_path / "repaired.mcap"
    done = gx3_here("repair", out, "-o", repaired)
    assert done.exit_code == 0, done.stderr
    fixed = read_archive(repaired)
    assert fixed.complete and sum(len(b) for b in fixed.samples(["a"])) == len(ticks)


def test_replay_of_the_raw_reads_published_gives_the_live_samples(tmp_path: Path) -> None:
    """The bridge's reads published raw (--publish-raw) into the recorder's archive
    (--raw): replayed, they give what the bridge published live (the --capture file does
    too: test_every_published_sample_is_archived)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    live = tmp_path / "live.mcap"
    proc = recorder(live, rec_cfg, "--raw")
    with Simulator(TWO_UNITS[:1], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a",
                           "--publish-raw") as bridge:
        wait_for(lambda: samples_in(live, "a") >= 300)
        stop_bridges(a=bridge)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=30)
    assert_replay_gives_live(live, live, tmp_path / "re.mcap")


def test_view_saves_the_live_fleet(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view_cfg = zenoh_config(tmp_path / "view.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    rrd = tmp_path / "live.rrd"
    viewer = subprocess.Popen([GX3, "view", "--save", str(rrd), "--zenoh-config",
                               str(view_cfg)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    with Simulator(TWO_UNITS[:1], "pty") as sim, \
            bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a"):
        wait_for(lambda: rerun_rows_so_far(rrd, "/plots/accel/x/a") >= 100)
    viewer.send_signal(signal.SIGINT)
    _, stderr = viewer.communicate(timeout=30)
    assert viewer.returncode == 0, stderr.decode()
    assert rerun_rows(rrd, "/plots/accel/x/a") >= 100
    assert "samples shown" in stderr.decode()


def test_view_without_a_display_or_sink_says_what_to_do(
        monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    done = gx3_here("view")
    assert done.exit_code == 2 and "--serve" in done.stderr and "--save" in done.stderr


def test_bridge_and_recorder_meet_through_a_router(tmp_path: Path) -> None:
    """Clients that only know the router: a bridge and a recorder, no peer links."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    client = tmp_path / "client.json5"
    client.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint]},
                                  "scouting": {"multicast": {"enabled": False}}}))
    router = subprocess.Popen([GX3, "router", "--listen", endpoint],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert router.stdout is not None and router.stdout.readline().strip() == b"READY"
        out = tmp_path / "routed.mcap"
        proc = recorder(out, client)
        with Simulator(TWO_UNITS[:1], "pty") as sim, \
                bridge_process(sim.endpoints[0], client, "--unit", "a"):
            wait_for(lambda: samples_in(out, "a") >= 100)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    finally:
        router.send_signal(signal.SIGINT)
        router.communicate(timeout=30)
    assert router.returncode == 0
    assert samples_in(out, "a") >= 100


def test_rrd_renders_an_archive_cut_short(tmp_path: Path) -> None:
    """A killed recorder's file: `gx3 rrd` renders what is readable and says so."""
    from bridge.archive.writer import ArchiveWriter
    from bridge.bus.codec import encode_batch
    from bridge.protocol.codec import Batch
    from bridge.protocol.table import REPLIES

    path = tmp_path / "cut.mcap"
    with ArchiveWriter(path, chunk_size=4096) as writer:
        n = 2000
        columns = {f.name: np.zeros((n, *f.shape), np.float32) for f in REPLIES[0xC2].fields}
        columns["timer"] = (np.arange(n) * 625).astype(np.uint32)
        t = 1_763_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
        batch = Batch(0xC2, columns, np.arange(n), t, False)
        for i, payload in enumerate(encode_batch("a", batch, np.arange(n) * 625, t, t)):
            writer.write("gx3/a/imu", payload, int(t[i]))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / "cut.rrd"
    done = gx3_here("rrd", path, "-o", out)
    assert done.exit_code == 0, done.stderr
    rows = rerun_rows(out, "/plots/accel/x/a")
    assert 0 < rows < 2000, rows
    assert f"{rows:,} samples" in done.stderr and "Traceback" not in done.stderr
