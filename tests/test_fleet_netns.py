"""A fleet across machines, for real: two Linux network namespaces joined by a veth pair.

The bridges live in one namespace, the recorder and a `gx3 router` in the other; the
only path between them is the veth link, multicast scouting is off, and everyone
names the router. Pulling the link for a few seconds (down, then up) must lose no
sample the bridges' caches still hold: the archive has every one.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from bridge.sim.serve import Simulator
from tests.helpers.archives import samples_in
from tests.helpers.processes import GX3, published
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import wait_for
from tests.helpers.zenoh import zenoh_config

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("ip") is None,
    reason="needs root and iproute2 to make network namespaces (CI has both)")

SUBNET = "10.231.{}.{}"


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=30)


@contextmanager
def two_hosts() -> Iterator[tuple[str, str, str, str]]:
    """Namespaces (bridges, recorder) and their addresses on a fresh veth pair."""
    tag = f"{os.getpid() % 10_000}"
    a, b = f"gx3a{tag}", f"gx3b{tag}"
    net = os.getpid() % 250 + 1
    addr_a, addr_b = SUBNET.format(net, 1), SUBNET.format(net, 2)
    ip("netns", "add", a)
    try:
        ip("netns", "add", b)
        ip("link", "add", f"va{tag}", "type", "veth", "peer", "name", f"vb{tag}")
        ip("link", "set", f"va{tag}", "netns", a)
        ip("link", "set", f"vb{tag}", "netns", b)
        for ns, dev, addr in ((a, f"va{tag}", addr_a), (b, f"vb{tag}", addr_b)):
            ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            ip("-n", ns, "link", "set", dev, "up")
            ip("-n", ns, "link", "set", "lo", "up")
        yield a, b, addr_a, addr_b
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True, timeout=30,
                           check=False)


def in_ns(ns: str, *args: str) -> list[str]:
    return ["ip", "netns", "exec", ns, GX3, *args]


def test_fleet_across_namespaces_through_a_router_survives_a_pulled_link(
        tmp_path: Path) -> None:
    with two_hosts() as (bridges_ns, recorder_ns, _, router_addr):
        endpoint = f"tcp/{router_addr}:7447"
        client = zenoh_config(tmp_path / "client.json5", connect=[endpoint])
        client.write_text(client.read_text().replace('"peer"', '"client"'))
        out = tmp_path / "fleet.mcap"
        router = subprocess.Popen(in_ns(recorder_ns, "router", "--listen", endpoint),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        procs: list[subprocess.Popen[bytes]] = [router]
        try:
            assert router.stdout is not None
            assert router.stdout.readline().strip() == b"READY"
            recorder = subprocess.Popen(
                in_ns(recorder_ns, "record", "-o", str(out), "--zenoh-config", str(client),
                      "--quiet", "--history", "10000"),
                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            procs.append(recorder)
            with Simulator(TWO_UNITS, "pty") as sim:
                bridges = [subprocess.Popen(
                    in_ns(bridges_ns, "bridge", "--port", port, "--unit", name,
                          "--zenoh-config", str(client)),
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                    for port, name in zip(sim.endpoints, ("a", "b"), strict=True)]
                procs += bridges
                wait_for(lambda: min(samples_in(out, "a"), samples_in(out, "b")) >= 100)
                link = f"va{os.getpid() % 10_000}"
                ip("-n", bridges_ns, "link", "set", link, "down")
                time.sleep(3.0)
                ip("-n", bridges_ns, "link", "set", link, "up")
                before = samples_in(out, "a")
                wait_for(lambda: samples_in(out, "a") >= before + 150, timeout=90)
                for bridge in bridges:
                    bridge.send_signal(signal.SIGINT)
                stderr = {name: bridge.communicate(timeout=30)[1]
                          for name, bridge in zip(("a", "b"), bridges, strict=True)}
            time.sleep(3.0)
            recorder.send_signal(signal.SIGINT)
            recorder.communicate(timeout=30)
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                proc.wait(timeout=30)
                for stream in (proc.stdout, proc.stderr):
                    if stream is not None:
                        stream.close()
    from bridge.archive.walk import read_archive

    archive = read_archive(out)
    assert archive.complete
    for unit in ("a", "b"):
        ticks = np.sort(np.concatenate([blk.columns["ticks"] for blk in archive.samples([unit])]))
        assert len(ticks) == published(stderr[unit], unit), f"{unit}: samples lost"
        assert (np.diff(ticks) == 625).all(), f"{unit}: a hole across the pulled link"
