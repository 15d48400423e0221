"""UnitPublisher and bridge.subscribe on one real session (local delivery, no network)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

import bridge
from bridge.bus.codec import record_quantities
from bridge.bus.gx3_pb2 import Event, Status
from bridge.bus.integrity import intact, read_time
from bridge.bus.publish import UnitPublisher
from bridge.device.session import UnitInfo
from bridge.protocol.table import DATA_CODES
from bridge.unit.pipeline import Options, Pipeline
from bridge.unit.service import EARLY_READS, BusSink
from tests.helpers.records import wire_batch, wire_times
from tests.helpers.waiting import wait_for


def test_every_record_type_arrives_as_the_columns_it_left_as(session: zenoh.Session) -> None:
    with bridge.subscribe("gx3/*/imu", session=session, output="raw") as raw, \
            bridge.subscribe("gx3/imu0/imu", session=session, output="batches") as batches, \
            UnitPublisher(session, "imu0") as pub:
        for code in sorted(DATA_CODES):
            batch = wire_batch(code, 4, code)
            ticks, time_ns, rx_ns = wire_times(4)
            assert pub.publish_samples(batch, ticks, time_ns, rx_ns) == 4
            got: list[np.ndarray] = []
            while sum(len(g) for g in got) < 4:
                b = batches.get(timeout=10)
                assert b is not None and (b.unit, b.code) == ("imu0", code)
                done = sum(len(g) for g in got)
                got.append(b["ticks"])
                for q in ("timer", *record_quantities(code)):
                    np.testing.assert_array_equal(b[q], batch[q][done:done + len(b)],
                                                  err_msg=q)
            np.testing.assert_array_equal(np.concatenate(got), ticks)
        assert pub.published == 4 * len(DATA_CODES)
        first = raw.get(timeout=10)
        assert first is not None
        assert (first.key, first.encoding) == ("gx3/imu0/imu",
                                               "application/protobuf;gx3.v1.ImuSample")


def test_status_event_and_raw_carry_the_unit(session: zenoh.Session) -> None:
    with bridge.subscribe("gx3/imu0/*", session=session, output="raw") as sub, \
            UnitPublisher(session, "imu0", raw=True) as pub:
        pub.publish_status(Status(samples=10, state=Status.STREAMING))
        pub.publish_event(Event(kind=Event.GAP, count=3, detail="ticks 10 -> 50"))
        pub.publish_raw(b"\xc2\x00", raw_ns=7, real_ns=-5)
        got = {m.key: m for m in (sub.get(timeout=10) for _ in range(3)) if m is not None}
        status = Status.FromString(got["gx3/imu0/status"].payload)
        event = Event.FromString(got["gx3/imu0/event"].payload)
        assert (status.unit, status.samples, status.state) == ("imu0", 10, Status.STREAMING)
        assert (event.unit, event.kind, event.count) == ("imu0", Event.GAP, 3)
        assert got["gx3/imu0/raw"].payload == b"\xc2\x00"
        with pytest.raises(ValueError, match="a Status of unit 'imu9' cannot go out on the "
                                             "publisher of unit 'imu0'"):
            pub.publish_status(Status(unit="imu9"))


def test_a_subscription_closes_its_own_session_and_leaves_no_thread() -> None:
    before = set(threading.enumerate())
    sub = bridge.subscribe("gx3/*/imu", listen=["tcp/127.0.0.1:0"], multicast_scouting=False,
                           idle_timeout=0.2)
    assert list(sub) == []
    waiter = threading.Thread(target=sub.get)  # a reader blocked when close comes
    waiter.start()
    sub.close()
    waiter.join(5)
    assert not waiter.is_alive()
    # Zenoh's callback thread (pyo3) ends just after close; a loaded host may see it
    # for a moment, never for long
    wait_for(lambda: set(threading.enumerate()) == before, 30, "the subscription's threads to end")
    assert sub.get(timeout=0.1) is None


def test_bad_arguments_are_one_line_errors() -> None:
    with pytest.raises(ValueError, match="output 'numpy': use one of samples, batches, raw"):
        bridge.subscribe(output="numpy")  # type: ignore[call-overload]
    with pytest.raises(ValueError, match=r"key expression 'gx3//imu': "):
        bridge.subscribe("gx3//imu")


def test_a_late_subscriber_gets_the_history_it_asks_for(session: zenoh.Session) -> None:
    with UnitPublisher(session, "imu0", cache_samples=30) as pub:
        batch = wire_batch(0xC2, 50, 3)
        _, time_ns, rx_ns = wire_times(50)
        pub.publish_samples(batch, np.arange(50), time_ns, rx_ns)
        with bridge.subscribe("gx3/*/imu", session=session, history=20) as late:
            got = [late.get(timeout=10) for _ in range(20)]
            assert [s.ticks for s in got if s is not None] == list(range(30, 50))
            assert late.get(timeout=0.5) is None


def test_reads_from_before_the_first_bring_up_reach_the_capture_boundedly(
        session: zenoh.Session) -> None:
    """A unit that never comes up (a wrong baud rate) must not fill the memory with the
    reads kept for its capture; once it is up they follow, newest kept, in order."""
    sink = BusSink(session, "gx3", "late", "/dev/ttyUSB9", False, 1.0, quiet=True)
    sink.attach(Pipeline(Options(url="/dev/ttyUSB9"), sink))
    heard: list[int] = []
    sink.on_read(lambda data, raw_ns, real_ns: heard.append(real_ns))
    for rx_ns in range(EARLY_READS + 5):
        sink.read(b"\x00", rx_ns, rx_ns)
    assert heard == []
    sink.info(UnitInfo(firmware=1127, ids={"serial": "1"}, sampling={"decimation": 10},
                       baud=115_200, continuous_preset=0xCC, record=0xCC))
    try:
        assert heard == list(range(5, EARLY_READS + 5))
        sink.read(b"\x00", 1, 10**18)
        assert heard[-1] == 10**18
    finally:
        sink.close()


def test_one_put_in_sixteen_carries_when_it_was_put(session: zenoh.Session) -> None:
    """What the latency metrics are measured on: the last message of one imu put in 16
    carries the instant it was put after its CRC-32 (and its read's receipt and the
    put's return are heard); every other message carries its CRC alone."""
    got: list[tuple[bytes, bytes]] = []
    sub = session.declare_subscriber("gx3/imu0/imu", lambda s: got.append(
        (s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else b"")))
    stamped: list[tuple[int, int]] = []
    batch = wire_batch(0xC2, 4, 1)
    ticks, time_ns, rx_ns = wire_times(4)
    before = time.time_ns()
    with UnitPublisher(session, "imu0", on_stamped=lambda rx, put: stamped.append((rx, put))
                       ) as pub:
        for _ in range(40):  # four records a put
            pub.publish_samples(batch, ticks, time_ns, rx_ns)
        after = time.time_ns()
    wait_for(lambda: len(got) == 160, what="every sample")
    sub.undeclare()
    assert all(intact(payload, attachment) for payload, attachment in got)
    longer = [i for i, (_, attachment) in enumerate(got) if len(attachment) > 4]
    assert longer == [3, 67, 131]  # the last of puts 0, 16 and 32
    put_at = [read_time(got[i][1]) or 0 for i in longer]
    assert before <= put_at[0] <= put_at[1] <= put_at[2] <= after
    assert [rx for rx, _ in stamped] == [int(rx_ns[-1])] * 3
    assert all(p <= returned <= after
               for p, (_, returned) in zip(put_at, stamped, strict=True))
