"""Nothing lost, nothing wrong: what the recorder archives is checked, and what it does
not archive is accounted for in the archive itself.

Real processes where the fault needs them (a `gx3 record` fed by the test's own Zenoh
session, a `gx3 router` stopped under a bridge and a recorder, two `gx3 bridge`es
under one name); the recorder's engine in this process where the test must hold its
writer still.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.gx3_pb2 import Event, Info
from bridge.bus.integrity import seal
from bridge.bus.publish import UnitPublisher
from bridge.bus.session import open_session
from bridge.recorder.live import Recorder
from bridge.sim.serve import Simulator
from tests.helpers.archives import archived_events, samples_in, topics_in
from tests.helpers.processes import GX3, bridge_process, published, recorder
from tests.helpers.records import CODE, indexed_batch, indexed_payloads
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import peer_sessions, zenoh_config


def archived_ticks(path: Path, unit: str) -> np.ndarray:
    blocks = read_archive(path).samples([unit])
    return np.sort(np.concatenate([b.columns["ticks"] for b in blocks])) if blocks \
        else np.zeros(0, np.int64)


def test_forged_and_damaged_samples_are_rejected_and_accounted_for(tmp_path: Path) -> None:
    """A sample naming another unit than its key, one whose payload does not match its
    CRC (a tail replaced, as Zenoh's splice does) and one with no CRC, put by another
    session into a running `gx3 record`: none is archived, each is in an event."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "checked.mcap"
    proc = recorder(out, zenoh_config(tmp_path / "rec.json5", listen=[endpoint]))
    try:
        with open_session(connect=[endpoint], mode="peer", multicast_scouting=False) as s, \
                UnitPublisher(s, "a") as pub:
            pub.set_info(Info(command=CODE))
            wait_for(lambda: "gx3/a/info" in topics_in(out),
                     what="the recorder to see unit a")
            records, ticks, times = indexed_batch(0, 10)
            pub.publish_samples(records, ticks, times)
            forged = indexed_payloads("b", 10, 1)[0]  # unit b's sample, a's key, a valid CRC
            damaged = bytearray(indexed_payloads("a", 11, 1)[0])
            damaged[-8:] = b"\xbf\x25\x07\xbd\x01\x09/a"  # the next batch's header
            s.put("gx3/a/imu", forged, attachment=seal(forged))
            s.put("gx3/a/imu", bytes(damaged), attachment=seal(indexed_payloads("a", 11, 1)[0]))
            s.put("gx3/a/imu", indexed_payloads("a", 12, 1)[0])  # no attachment, no CRC
            records, ticks, times = indexed_batch(13, 10)
            pub.publish_samples(records, ticks, times)
            wait_for(lambda: samples_in(out, "a") == 20, what="the genuine samples")
            wait_for(lambda: sum(e.count for e in archived_events(out, "a", Event.REJECTED)) == 3,
                     what="the rejections in the archive")
    finally:
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr.decode()
    np.testing.assert_array_equal(archived_ticks(out, "a"),
                                  np.r_[np.arange(10), np.arange(13, 23)] * 625)
    rejected = archived_events(out, "a", Event.REJECTED)
    by_reason = {"checksum": 0, "key": 0}
    for e in rejected:
        by_reason["checksum" if "CRC" in e.detail else "key"] += e.count
    assert by_reason == {"checksum": 2, "key": 1}
    assert all(e.leaf == "imu" and e.unit == "a" for e in rejected)
    assert read_archive(out).units() == ["a"], "the forged unit b got a channel"
    assert stderr.decode().count("warning:") == len(rejected)


def test_a_router_outage_leaves_a_loss_event_equal_to_what_is_missing(
        tmp_path: Path) -> None:
    """Bridge and recorder meet through a router that stops for seconds: what the
    bridge's cache cannot give back is missing from the archive, and the archive says
    exactly how many samples and where."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    client = tmp_path / "client.json5"
    client.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint]},
                                  "scouting": {"multicast": {"enabled": False}}}))

    def router() -> subprocess.Popen[bytes]:
        proc = subprocess.Popen([GX3, "router", "--listen", endpoint],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"READY"
        return proc

    def stop(proc: subprocess.Popen[bytes]) -> None:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)

    out = tmp_path / "outage.mcap"
    first = router()
    proc = recorder(out, client)
    try:
        with Simulator(TWO_UNITS[:1], "pty") as sim, \
                bridge_process(sim.endpoints[0], client, "--unit", "a", "--cache", "0.5") \
                as bridge:
            wait_for(lambda: samples_in(out, "a") >= 100, what="samples before the outage")
            stop(first)
            before = samples_in(out, "a")
            time.sleep(3.0)  # the outage: far longer than the bridge's 0.5 s cache
            second = router()
            try:
                wait_for(lambda: samples_in(out, "a") >= before + 200,
                         what="samples after the outage")
                bridge.send_signal(signal.SIGINT)
                _, bridge_err = bridge.communicate(timeout=30)
                time.sleep(1.0)
            finally:
                stop(second)
    finally:
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr.decode()
    ticks = archived_ticks(out, "a")
    holes = np.diff(ticks) // 625 - 1
    missing = int(holes.sum())
    lost = archived_events(out, "a", Event.LOST)
    imu = [e for e in lost if e.leaf == "imu"]
    assert missing > 100, "the outage lost nothing: the test proves nothing"
    assert sum(e.count for e in imu) == missing
    assert len(ticks) + missing == published(bridge_err, "a")
    for event in imu:  # each event's span is a hole in the archived ticks
        at = int(np.searchsorted(ticks, event.ticks))
        assert ticks[at - 1] + 625 == event.ticks and ticks[at] - 625 == event.end_ticks
        assert (event.end_ticks - event.ticks) // 625 + 1 == event.count


def test_a_second_bridge_under_a_held_name_is_refused(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    first_cfg = zenoh_config(tmp_path / "first.json5", listen=[endpoint])
    second_cfg = zenoh_config(tmp_path / "second.json5", connect=[endpoint])

    with Simulator(TWO_UNITS, "pty") as sim, \
            bridge_process(sim.endpoints[0], first_cfg, "--unit", "imu1"):
        with open_session(second_cfg) as watcher:
            wait_for(lambda: any(r.ok is not None for r in watcher.liveliness().get(
                "gx3/imu1/alive", timeout=1.0)), what="the first bridge's token")
        done = subprocess.run([GX3, "bridge", "--port", str(sim.endpoints[1]), "--unit",
                               "imu1", "--zenoh-config", str(second_cfg)],
                              capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "imu1" in lines[0] and "--unit" in lines[0], done.stderr


def test_one_unit_from_two_publishers_is_flagged(tmp_path: Path) -> None:
    out = tmp_path / "twice.mcap"
    rec_session, one, two = peer_sessions(3)
    warnings: list[str] = []
    writer = ArchiveWriter(out)
    rec = Recorder(rec_session, writer, on_event=lambda unit, e: warnings.append(e.detail))
    try:
        with UnitPublisher(one, "a"), UnitPublisher(two, "a"):
            def written() -> bool:
                rec.run_once(0.05)
                return bool(warnings)
            wait_for(written, what="the warning")
    finally:
        rec.close()
        writer.close()
        for s in (one, two, rec_session):
            s.close()
    flagged = archived_events(out, "a", Event.DUPLICATE_UNIT)
    assert len(flagged) == 1 and flagged[0].count == 2
    assert str(one.zid()) in flagged[0].detail and str(two.zid()) in flagged[0].detail
    assert len(warnings) == 1


def test_a_stalled_writer_sheds_into_the_archive_not_onto_zenoh(tmp_path: Path) -> None:
    """While the writer is held still, Zenoh keeps being emptied (publishers never
    wait on the recorder) into a capped buffer; what overflows it is shed, and the
    archive holds an event with exactly the samples that are not in it."""
    out = tmp_path / "shed.mcap"
    rec_session, pub_session = peer_sessions(2)
    writer = ArchiveWriter(out)
    n = 5000
    rec = Recorder(rec_session, writer, queue_size=100, buffer_bytes=100_000)
    try:
        with UnitPublisher(pub_session, "a") as pub:
            wait_for(lambda: bool(rec.snapshot()), what="unit a")
            rec.run_once(0.05)
            publishing = threading.Thread(target=lambda: [
                pub.publish_samples(*indexed_batch(start, 50)) for start in range(0, n, 50)])
            publishing.start()
            # the writer is held still: nobody calls run_once until all has come
            publishing.join(60)
            assert not publishing.is_alive(), "the publisher waited on the stalled writer"
            wait_for(lambda: rec.received >= n, what="every sample taken off Zenoh")
            rec.run_once(0.05)
    finally:
        rec.close()
        writer.close()
        pub_session.close()
        rec_session.close()
    ticks = archived_ticks(out, "a")
    shed = [e for e in archived_events(out, "a", Event.SHED) if e.leaf == "imu"]
    assert shed, "nothing was shed: the buffer cap did not bite"
    assert len(ticks) + sum(e.count for e in shed) == n
    kept = set((ticks // 625).tolist())
    for e in shed:
        span = set(range(e.ticks // 625, e.end_ticks // 625 + 1))
        assert not span & kept and len(span) == e.count, "the event spans its hole exactly"
    assert rec.losses[Event.SHED] == n - len(ticks)
