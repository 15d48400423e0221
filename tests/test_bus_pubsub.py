"""Publishing and subscribing over real Zenoh sessions on loopback, across processes.

The publishing process is examples/publisher.py (UnitPublisher with synthetic
records whose values are their index), so a subscriber can tell exactly which
samples arrived.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
import zenoh

import bridge
from bridge.bus.gx3_pb2 import Info
from bridge.bus.integrity import seal
from bridge.bus.publish import UnitPublisher
from bridge.bus.routes import PublisherKeys
from bridge.bus.session import ZenohOptions, open_session
from tests.helpers.records import indexed_payloads
from tests.helpers.waiting import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent


class Publisher:
    """examples/publisher.py in its own process."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(ROOT / "examples" / "publisher.py"), *args],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None and self.proc.stdin is not None
        self.stdin = self.proc.stdin
        self.stdout = self.proc.stdout
        assert self.stdout.readline().strip() == "READY"

    def start(self) -> None:
        self.stdin.write("go\n")
        self.stdin.flush()

    def wait_done(self) -> None:
        assert self.stdout.readline().strip() == "DONE"

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.stdin.close()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.stdout.close()


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def publisher(endpoint: str) -> Iterator[Callable[..., Publisher]]:
    started: list[Publisher] = []

    def start(*args: str) -> Publisher:
        pub = Publisher("--listen", endpoint, *args)
        started.append(pub)
        return pub

    yield start
    for pub in started:
        pub.stop()


def wait_alive(session: zenoh.Session, unit: str) -> None:
    """Until the unit's liveliness token (declared after its publishers) is seen."""
    def alive() -> bool:
        return any(r.ok is not None for r in session.liveliness().get(f"gx3/{unit}/alive",
                                                                       timeout=1.0))
    wait_for(alive, 20, f"{unit}'s liveliness token")


def test_samples_from_another_process_all_arrive_in_order(
        endpoint: str, publisher: Callable[..., Publisher]) -> None:
    n = 2000
    pub = publisher("--count", str(n), "--rate", "1000", "--code", "0xC8")
    misses: list[int] = []
    with bridge.subscribe("gx3/*/imu", connect=[endpoint], mode="peer", output="batches",
                          multicast_scouting=False,
                          on_miss=lambda source, nb: misses.append(nb)) as sub:
        with open_session(connect=[endpoint], multicast_scouting=False) as watcher:
            wait_alive(watcher, "imu0")
        pub.start()
        ticks: list[np.ndarray] = []
        got = 0
        while got < n:
            batch = sub.get(timeout=20)
            assert batch is not None, f"only {got} of {n} samples arrived"
            assert (batch.unit, batch.code) == ("imu0", 0xC8)
            index = batch["ticks"] // 62
            np.testing.assert_array_equal(batch["accel"][:, 0], index)  # values travel intact
            np.testing.assert_array_equal(batch["m"][:, 2, 2], index)
            ticks.append(batch["ticks"])
            got += len(batch)
        pub.wait_done()
        assert sub.get(timeout=0.5) is None, "no sample twice"
    all_ticks = np.concatenate(ticks)
    np.testing.assert_array_equal(all_ticks, np.arange(n) * 62)
    assert misses == [] and sub.misses == 0


class Proxy:
    """A TCP relay between a subscriber and a publisher whose link can be cut."""

    def __init__(self, target: int) -> None:
        self.target = target
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = int(self.server.getsockname()[1])
        self.cut = threading.Event()
        self.links: list[socket.socket] = []
        self.lock = threading.Lock()
        self.threads: list[threading.Thread] = []
        self._spawn(self._accept)

    def _spawn(self, target: Callable[..., None], *args: object) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        t.start()
        self.threads.append(t)

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.server.accept()
            except OSError:
                return
            if self.cut.is_set():
                client.close()
                continue
            upstream = socket.create_connection(("127.0.0.1", self.target))
            with self.lock:
                self.links += [client, upstream]
            self._spawn(self._pump, client, upstream)
            self._spawn(self._pump, upstream, client)

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def drop(self) -> None:
        """Cut every link and refuse new ones until ``restore``."""
        self.cut.set()
        with self.lock:
            for s in self.links:
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

    def restore(self) -> None:
        self.cut.clear()

    def close(self) -> None:
        self.drop()
        with contextlib.suppress(OSError):
            self.server.shutdown(socket.SHUT_RDWR)  # wakes the blocked accept()
        self.server.close()
        for t in self.threads:
            t.join(5)
        with self.lock:
            for s in self.links:
                s.close()


@pytest.mark.parametrize("cache", [5000, 100])
def test_a_subscriber_that_loses_its_link_recovers_or_counts_every_sample(
        endpoint: str, publisher: Callable[..., Publisher], cache: int) -> None:
    n = 3000
    pub = publisher("--count", str(n), "--rate", "1000", "--code", "0xC2", "--cache", str(cache))
    proxy = Proxy(int(endpoint.rsplit(":", 1)[1]))
    via = f"tcp/127.0.0.1:{proxy.port}"
    seen: list[int] = []
    config = ZenohOptions(connect=[via], multicast_scouting=False).config()
    config.insert_json5("scouting/gossip/enabled", "false")  # the proxy is the only path
    try:
        with zenoh.open(config) as session, \
                bridge.subscribe("gx3/imu0/imu", session=session, output="samples") as sub:
            watcher = open_session(connect=[endpoint], multicast_scouting=False)
            with watcher:
                wait_alive(watcher, "imu0")
            pub.start()

            def received(count: int) -> Callable[[], bool]:
                def check() -> bool:
                    while len(seen) + sub.misses < count:
                        if (sample := sub.get(timeout=0.05)) is None:
                            return False
                        seen.append(sample.ticks // 62)
                    return True
                return check

            wait_for(received(300), 20, "the first samples")
            proxy.drop()
            time.sleep(1.0)  # the outage itself: a second without a link
            proxy.restore()
            pub.wait_done()
            wait_for(received(n), 30, "recovery or a miss report")
            assert sub.get(timeout=1.0) is None
    finally:
        proxy.close()
    assert seen == sorted(seen) and len(set(seen)) == len(seen), "in order, none twice"
    if cache >= n:
        assert sub.misses == 0, "the cache held every sample of the outage"
    else:
        assert sub.misses > 0, "a one-second outage at 1 kHz outlasts a 100-sample cache"
    assert set(seen) <= set(range(n))
    assert len(seen) + sub.misses == n, f"{len(seen)} received + {sub.misses} missed != {n}"


def test_liveliness_token_disappears_when_the_publisher_is_killed(
        endpoint: str, publisher: Callable[..., Publisher]) -> None:
    pub = publisher()
    events: list[zenoh.SampleKind] = []
    with open_session(connect=[endpoint], multicast_scouting=False) as session:
        token_watch = session.liveliness().declare_subscriber(
            "gx3/*/alive", lambda s: events.append(s.kind), history=True)
        wait_for(lambda: zenoh.SampleKind.PUT in events, 20, "the token")
        os.kill(pub.proc.pid, signal.SIGKILL)
        pub.proc.wait()
        wait_for(lambda: zenoh.SampleKind.DELETE in events, 15, "the token to go")
        assert not [r for r in session.liveliness().get("gx3/imu0/alive", timeout=1.0)
                    if r.ok is not None]
        token_watch.undeclare()


def test_a_receiving_session_declares_each_publishers_key_as_it_appears(endpoint: str) -> None:
    """Declared keys keep Zenoh from searching every unit's tokens per sample (routes.py)."""
    with open_session(listen=[endpoint], multicast_scouting=False) as there, \
            open_session(connect=[endpoint], multicast_scouting=False) as here:
        early = UnitPublisher(there, "early")
        keys = PublisherKeys(here, "gx3/*/imu")
        gone: list[str] = []
        watch = here.liveliness().declare_subscriber(
            "gx3/*/imu/@adv/pub/**",
            lambda s: gone.append(str(s.key_expr)) if s.kind == zenoh.SampleKind.DELETE
            else None)
        try:
            wait_for(lambda: keys.keys == ["gx3/early/imu"], 20, "the early unit's key")
            late = UnitPublisher(there, "late")
            wait_for(lambda: keys.keys == ["gx3/early/imu", "gx3/late/imu"], 20,
                     "the late unit's key")
            late.close()
            early.close()
            wait_for(lambda: len(gone) == 2, 20, "both publishers' tokens to go")
            assert keys.keys == ["gx3/early/imu", "gx3/late/imu"]  # a unit may come back
        finally:
            watch.undeclare()
            keys.close()
            early.close()
        assert keys.keys == []


def _reply_texts(session: zenoh.Session, key: str, payload: str | None = None) -> list[str]:
    out = []
    for r in session.get(key, payload=payload, timeout=5.0):
        if r.ok is not None:
            out.append(r.ok.payload.to_string())
        else:
            assert r.err is not None
            out.append("ERR " + r.err.payload.to_string())
    return out


def test_info_and_command_queryables(endpoint: str) -> None:
    carried_out: list[str] = []

    def handler(text: str) -> str:
        if text != "capture_gyro_bias":
            raise ValueError(f"unknown command {text!r}")
        carried_out.append(text)
        return "done"

    with open_session(listen=[endpoint], multicast_scouting=False) as a, \
            open_session(connect=[endpoint], multicast_scouting=False) as b, \
            UnitPublisher(a, "imu0", on_command=handler) as refusing, \
            UnitPublisher(a, "imu1", on_command=handler, allow_commands=True):
        wait_alive(b, "imu1")
        assert _reply_texts(b, "gx3/imu0/info") == [
            "ERR imu0: no Info yet, the unit is still being brought up"]
        refusing.set_info(Info(serial="6234.1234", firmware=1127, firmware_text="1.1.27"))
        (reply,) = list(b.get("gx3/imu0/info", timeout=5.0))
        assert reply.ok is not None
        assert str(reply.ok.encoding) == "application/protobuf;gx3.v1.Info"
        info = Info.FromString(reply.ok.payload.to_bytes())
        assert (info.unit, info.serial, info.firmware_text) == ("imu0", "6234.1234", "1.1.27")
        (refusal,) = _reply_texts(b, "gx3/imu0/command", "capture_gyro_bias")
        assert refusal.startswith("ERR imu0: commands are disabled") and \
            "--allow-commands" in refusal
        assert _reply_texts(b, "gx3/imu1/command", "capture_gyro_bias") == ["done"]
        assert _reply_texts(b, "gx3/imu1/command", "reset") == [
            "ERR imu1: unknown command 'reset'"]
    assert carried_out == ["capture_gyro_bias"]


def test_example_subscriber_decodes_from_the_schema_alone(
        endpoint: str, publisher: Callable[..., Publisher]) -> None:
    script = ROOT / "examples" / "subscriber.py"
    source = script.read_text()
    assert "import bridge" not in source and "from bridge" not in source
    pub = publisher("--count", "4000", "--rate", "1000", "--code", "0xC2")
    pub.start()
    forging = threading.Event()

    def forge() -> None:
        """A damaged sample now and then: unit imu0's, its CRC not its payload's."""
        good = indexed_payloads("imu0", 0, 1)[0]
        bad = good[:-4] + b"\x00\x00\x80\x7f"
        with open_session(connect=[endpoint], multicast_scouting=False) as s:
            while not forging.wait(0.1):
                s.put("gx3/imu0/imu", bad, attachment=seal(good))

    forger = threading.Thread(target=forge)
    forger.start()
    try:
        done = subprocess.run([sys.executable, str(script), "--connect", endpoint,
                               "--lines", "3"], capture_output=True, text=True, timeout=60)
    finally:
        forging.set()
        forger.join()
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 3, done.stdout
    assert not lines[-1].endswith("rejected 0)"), "damaged samples were not rejected"
    for line in lines:
        match = re.fullmatch(r"imu0 0xC2 ticks=(\d+) time=\S+ accel=\[(.*)\] ang_rate=\[(.*)\] "
                             r"\((\d+)/s, missed 0, rejected \d+\)", line)
        assert match, line
        index = int(match[1]) // 62
        assert match[2] == match[3] == ", ".join([f"{float(index)}"] * 3)
        # a second's count: a loaded machine may print late, so only bound it loosely
        assert 0 < int(match[4]) <= 4000, "the samples that arrived in that second"


def test_an_app_gets_only_intact_samples_of_their_key(endpoint: str) -> None:
    """Damaged (CRC), unchecked (no CRC) and forged (another unit's sample on this key)
    messages never reach the app; each is counted and reported."""
    rejects: list[tuple[str, str, int]] = []
    with open_session(listen=[endpoint], multicast_scouting=False) as a, \
            open_session(connect=[endpoint], multicast_scouting=False) as b, \
            bridge.subscribe("gx3/*/imu", session=a, output="samples",
                             on_reject=lambda *r: rejects.append(r)) as sub:
        good = indexed_payloads("u", 0, 4)
        forged = indexed_payloads("v", 9, 1)[0]
        pub = b.declare_publisher("gx3/u/imu")
        # the stub says bool; it is a MatchingStatus (stack-facts)
        wait_for(lambda: bool(cast(Any, pub.matching_status).matching), what="the subscriber")
        pub.put(good[0], attachment=seal(good[0]))
        pub.put(good[1][:-1] + b"\x01", attachment=seal(good[1]))
        pub.put(good[2])
        pub.put(forged, attachment=seal(forged))
        pub.put(good[3], attachment=seal(good[3]))
        got = [sub.get(timeout=20), sub.get(timeout=20)]
        assert sub.get(timeout=0.5) is None
    assert [(s.unit, s.ticks) for s in got if s is not None] == [("u", 0), ("u", 3 * 625)]
    assert sub.rejected == 3
    by_reason = {reason: sum(n for _, r, n in rejects if r == reason) for _, reason, _ in rejects}
    assert by_reason == {"checksum": 2, "key": 1}
    assert {key for key, _, _ in rejects} == {"gx3/u/imu"}
