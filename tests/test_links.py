"""The link a unit is on (UART, its own USB port, a USB-serial adapter), as found from
its device and carried through timing, bring-up, Info and raw-capture metadata."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bridge.archive.rawcapture import capture_metadata
from bridge.device.link import TIMER_RULE, Link, find_link, kernel_name
from bridge.protocol.table import REPLIES
from bridge.sim.serve import Simulator
from bridge.sim.usb import AdapterDelivery
from bridge.timing.stream import USB_FRAME_NS, Settings, StreamTiming
from bridge.unit.pipeline import Pipeline
from bridge.unit.service import info_message
from tests.helpers.pipeline import ListSink, running
from tests.helpers.units import STATIC_UNIT
from tests.helpers.waiting import wait_for

ROOT = Path(__file__).resolve().parent.parent


def _sysfs(root: Path, device: str, timer: str) -> Path:
    """A sysfs tree holding one adapter's latency timer, as the kernel lays it out."""
    folder = root / "bus" / "usb-serial" / "devices" / device
    folder.mkdir(parents=True)
    (folder / "latency_timer").write_text(timer)
    return root


def test_auto_finds_an_adapter_through_udev_links_with_its_latency_timer(
        tmp_path: Path) -> None:
    dev = tmp_path / "dev"
    (dev / "serial" / "by-id").mkdir(parents=True)
    (dev / "gx3").mkdir()
    for name in ("ttyUSB3", "ttyACM0", "ttyS0"):
        (dev / name).touch()
    by_id = dev / "serial" / "by-id" / "usb-FTDI_FT232R_USB_UART_A10K-if00-port0"
    by_id.symlink_to("../../ttyUSB3")
    (dev / "gx3" / "imu3").symlink_to("../serial/by-id/" + by_id.name)
    sysfs = _sysfs(tmp_path / "sys", "ttyUSB3", "16\n")

    for path in (dev / "ttyUSB3", by_id, dev / "gx3" / "imu3"):
        assert kernel_name(str(path)) == "ttyUSB3"
        assert find_link(str(path), sysfs=sysfs) == Link("usb-serial", 16, "ttyUSB3")
    assert find_link(str(dev / "ttyACM0"), sysfs=sysfs) == Link("usb", None, "ttyACM0")
    assert find_link(str(dev / "ttyS0"), sysfs=sysfs).transport == "uart"
    assert find_link("socket://127.0.0.1:9", sysfs=sysfs) == Link("uart")
    assert find_link(str(by_id), "uart", sysfs=sysfs) == Link("uart", None, "ttyUSB3")
    # no sysfs entry (another driver, or a container): the link without its timer
    assert find_link(str(by_id), sysfs=tmp_path / "none") == Link("usb-serial", None, "ttyUSB3")


def test_a_sysfs_timer_that_is_garbage_or_unreadable_is_unknown_not_a_crash(
        tmp_path: Path) -> None:
    dev = tmp_path / "ttyUSB0"
    dev.touch()
    for k, text in enumerate(("-3\n", "0\n", "4294967296\n", "sixteen\n", "")):
        sysfs = _sysfs(tmp_path / f"sys{k}", "ttyUSB0", text)
        assert find_link(str(dev), sysfs=sysfs) == Link("usb-serial", None, "ttyUSB0"), text
    unreadable = _sysfs(tmp_path / "locked", "ttyUSB0", "16\n")
    (unreadable / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer").unlink()
    (unreadable / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer").mkdir()
    assert find_link(str(dev), sysfs=unreadable).latency_timer_ms is None
    assert find_link(str(dev), sysfs=_sysfs(tmp_path / "max", "ttyUSB0", "255\n")) == \
        Link("usb-serial", 255, "ttyUSB0")


def test_a_path_that_cannot_be_looked_at_leaves_the_error_to_opening_the_port(
        tmp_path: Path) -> None:
    bad = tmp_path / ("x" * 300)  # lstat fails (a name too long), as a vanishing link can
    assert kernel_name(str(bad)) == bad.name
    assert find_link(str(bad)) == Link("uart")


def test_a_long_latency_timer_is_warned_about_with_the_fix() -> None:
    slow = Link("usb-serial", 16, "ttyUSB3")
    assert slow.describe() == "usb-serial, latency timer 16 ms"
    warning = slow.warning()
    assert warning is not None and TIMER_RULE in warning
    assert "/sys/bus/usb-serial/devices/ttyUSB3/latency_timer" in warning
    assert Link("usb-serial", 1).warning() is None and Link("usb-serial").warning() is None
    assert Link("usb-serial").describe() == "usb-serial, latency timer unknown"
    rules = (ROOT / TIMER_RULE).read_text()  # the rule named is shipped and sets 1 ms
    assert re.search(r'^ACTION=="add", SUBSYSTEM=="usb-serial".*ATTR\{latency_timer\}="1"$',
                     rules, re.M)


def test_an_adapter_is_timed_as_its_serial_line_behind_usb_frames() -> None:
    adapter = Settings(record=0xCC, decimation=10, filter_width=15, baud=115_200,
                       transport="usb-serial", latency_timer_ms=16)
    uart = Settings(record=0xCC, decimation=10, filter_width=15, baud=115_200)
    usb = Settings(record=0xCC, decimation=10, filter_width=15, baud=115_200, transport="usb")
    assert adapter.floor_ns == uart.floor_ns == round(REPLIES[0xCC].length * 10 / 115_200 * 1e9)
    assert (adapter.frame_ns, usb.frame_ns, uart.frame_ns) == (USB_FRAME_NS, USB_FRAME_NS, 0)
    timing = StreamTiming()
    timing.configure(adapter, restarted=True)
    assert timing.timeline is not None and timing.timeline.clock.floor_ns == adapter.floor_ns


@contextmanager
def _adapter_unit(tmp_path: Path, timer_ms: int) -> Iterator[tuple[Simulator, Pipeline, ListSink]]:
    """An emulated unit behind an adapter, on a pty named as the kernel names one, with
    the adapter's sysfs entry; the pipeline on it with transport auto."""
    sysfs = _sysfs(tmp_path / "sys", "ttyUSB5", f"{timer_ms}\n")
    delivery = AdapterDelivery(latency_timer_s=timer_ms / 1000, stall_every_s=0.0, seed=2)
    with running(STATIC_UNIT, tmp_path / "ttyUSB5", delivery, sysfs=sysfs) as unit:
        yield unit


def test_bring_up_names_the_adapter_warns_once_and_info_carries_it(tmp_path: Path) -> None:
    with _adapter_unit(tmp_path, 16) as (sim, pipeline, sink):
        wait_for(lambda: len(sink.column("ticks")) >= 100, timeout=30)
        sim.unplug(0, 1.5)
        wait_for(lambda: sink.kinds().count("bring_up") >= 2
                 and len(sink.column("ticks")) >= 200, timeout=30)
        info = info_message("imu", str(tmp_path / "ttyUSB5"), sink.infos[-1], False,
                            pipeline.link)
    first, again = [e.detail for e in sink.events if e.kind == "bring_up"][:2]
    assert "over usb-serial, latency timer 16 ms" in first and TIMER_RULE in first
    assert "over usb-serial, latency timer 16 ms" in again and TIMER_RULE not in again
    assert (info.link, info.latency_timer_ms) == ("usb-serial", 16)
    meta = capture_metadata(info)
    assert (meta["transport"], meta["latency_timer_ms"]) == ("usb-serial", "16")


def test_a_one_ms_adapter_streams_without_a_warning(tmp_path: Path) -> None:
    timer_ms = 1
    with _adapter_unit(tmp_path, timer_ms) as (_, pipeline, sink):
        wait_for(lambda: len(sink.column("ticks")) >= 100, timeout=30)
        assert pipeline.timing.settings is not None
        assert pipeline.timing.settings.latency_timer_ms == timer_ms
    (detail,) = [e.detail for e in sink.events if e.kind == "bring_up"]
    said, *warnings = detail.split("; ")
    assert said.endswith(f"over usb-serial, latency timer {timer_ms} ms")
    assert not [w for w in warnings if "latency" in w], warnings
