"""`gx3 replay` tells the link of a capture without metadata from its receive times,
says so on the unit's line, times it accordingly, and takes --transport over both."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from bridge.archive.walk import read_archive
from bridge.bus.gx3_pb2 import Info
from bridge.ingest.replay import captures, replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery
from bridge.timing.links import infer_transport
from tests.helpers.archives import write_capture
from tests.helpers.processes import GX3, Sim
from tests.helpers.waiting import free_port
from tests.helpers.zenoh import zenoh_config

LINKS: dict[str, tuple[HostDelivery, int, str, int]] = {
    "usb": (UsbDelivery(frame_phase_s=0.0006, seed=3), 10_000_000, "usb", 0),
    "uart": (UartDelivery(seed=4), 115_200, "uart", 0),
    "adapter-16": (AdapterDelivery(latency_timer_s=0.016, frame_phase_s=0.0002, seed=5),
                   115_200, "usb-serial", 16),
}


def _capture(tmp_path: Path, link: str) -> Path:
    delivery, baud, _, _ = LINKS[link]
    config = streaming_config(UnitConfig(clock_ppm=-25.0), code=0xCC, baud=baud)
    cap = synthesize(config, delivery, 30.0)
    return write_capture(tmp_path / f"{link}.mcap",
                         list(zip(cap.rx_ns.tolist(), cap.data, strict=True)))


def _info(archive: Path) -> Info:
    (info,) = [m for _, m in read_archive(archive).decoded("gx3/u1/info", Info)]
    return info


@pytest.mark.parametrize("link", sorted(LINKS))
def test_the_link_of_a_capture_without_metadata_is_inferred(tmp_path: Path, link: str) -> None:
    _, _, transport, timer = LINKS[link]
    (result,) = replay([_capture(tmp_path, link)], tmp_path / "out.mcap")
    assert result.settings is not None
    assert (result.settings.transport, result.settings.latency_timer_ms or 0) == (
        transport, timer)
    (said,) = [text for text in result.inferred if text.startswith("transport ")]
    assert said.startswith(f"transport {transport}")
    info = _info(tmp_path / "out.mcap")
    assert (info.link, info.latency_timer_ms) == (transport, timer)


def test_gx3_replay_says_what_it_inferred_and_transport_overrides_it(tmp_path: Path) -> None:
    path = _capture(tmp_path, "adapter-16")
    done = subprocess.run([GX3, "replay", str(path), "-o", str(tmp_path / "a.mcap")],
                          capture_output=True, text=True, timeout=120, check=True)
    (line,) = [x for x in done.stderr.splitlines() if x.startswith("u1:")]
    assert "transport usb-serial, 16 ms latency timer (" in line, done.stderr
    done = subprocess.run([GX3, "replay", str(path), "-o", str(tmp_path / "b.mcap"),
                           "--transport", "uart"],
                          capture_output=True, text=True, timeout=120, check=True)
    (line,) = [x for x in done.stderr.splitlines() if x.startswith("u1:")]
    assert "transport" not in line, done.stderr
    assert (_info(tmp_path / "b.mcap").link, _info(tmp_path / "a.mcap").link) == (
        "uart", "usb-serial")
    bad = subprocess.run([GX3, "replay", str(path), "-o", str(tmp_path / "c.mcap"),
                          "--transport", "serial"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "--transport 'serial'" in bad.stderr and not (tmp_path / "c.mcap").exists()


@pytest.mark.parametrize("timer_ms", [1, 16])
def test_a_real_capture_behind_an_emulated_adapter_is_told_as_one(
        run_sim: Callable[..., Sim], tmp_path: Path, timer_ms: int) -> None:
    """`gx3 sim --usb-serial` read by `gx3 bridge --capture` on its pty: the bridge's
    metadata says uart (a pty is no ttyUSB), the receive times say adapter."""
    sim = run_sim("--pty", "--usb-serial", "--latency-timer", str(timer_ms),
                       "--continuous-preset", "0xCC", "--mode-preset", "2",
                       "--decimation", "10")
    (port,) = sim.endpoints(1)
    config = zenoh_config(tmp_path / "z.json5", listen=[f"tcp/127.0.0.1:{free_port()}"])
    raw = tmp_path / "raw.mcap"
    subprocess.run([GX3, "bridge", "--port", port, "--zenoh-config", str(config),
                    "--capture", str(raw), "--duration", "8"],
                   capture_output=True, timeout=60, check=True)
    (cap,) = captures(raw)
    assert cap.metadata["transport"] == "uart"
    found = infer_transport(cap.rx_ns, cap.data, 0xCC)
    assert (found.transport, found.latency_timer_ms) == ("usb-serial", timer_ms), \
        found.describe()
