"""Which link a unit's device is on, found from the kernel's name for it.

The timing model differs by link: a plain UART (bytes as they cross the line), the
GX3's own USB port (``/dev/ttyACM*``, CDC-ACM: 1 ms frames), or its serial port
through a USB-serial adapter (``/dev/ttyUSB*``: the line, then 1 ms frames, then
the adapter's latency timer). udev's stable names (``/dev/serial/by-id/...``,
``/dev/gx3/...``) are symlinks, so the device is followed link by link to its
kernel name. Linux's FTDI driver sets the latency timer to 16 ms, which holds each
read back up to 16 ms; sysfs tells, and 1 ms is the fix.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

SYSFS = Path("/sys")
#: Payload of one full-speed bulk packet from an FTDI-like adapter: 64 less 2 status bytes.
ADAPTER_PACKET_BYTES = 62
#: What Linux's FTDI driver sets; 1 ms is the fix for timing (configs/udev).
DEFAULT_LATENCY_TIMER_MS = 16
TIMER_RULE = "configs/udev/99-gx3.rules"
_KERNEL_TTY = re.compile(r"tty(ACM|USB)\d+")
_MAX_HOPS = 40  # the kernel's own limit on nested symlinks
_MAX_LATENCY_TIMER_MS = 255  # the FTDI driver's range is 1-255 ms


@dataclass(frozen=True)
class Link:
    """How a unit reaches the host.

    ``transport`` is "uart", "usb" or "usb-serial"; ``latency_timer_ms`` an adapter's
    latency timer (None where sysfs does not say).
    """

    transport: str
    latency_timer_ms: int | None = None
    device: str = ""  # kernel name (ttyUSB0, ...), where one was found

    def describe(self) -> str:
        """One line for people.

        Returns:
            The transport, and an adapter's latency timer ("usb-serial, latency timer
            16 ms").
        """
        if self.transport != "usb-serial":
            return self.transport
        timer = "unknown" if self.latency_timer_ms is None else f"{self.latency_timer_ms} ms"
        return f"usb-serial, latency timer {timer}"

    def warning(self) -> str | None:
        """What to change when the adapter holds reads back longer than a frame.

        Returns:
            One line naming the fix (the udev rule, or the sysfs file now), or None
            where the timer is 1 ms or not known.
        """
        if self.latency_timer_ms is None or self.latency_timer_ms <= 1:
            return None
        return (f"the USB-serial adapter's latency timer is {self.latency_timer_ms} ms, so "
                f"reads wait up to {self.latency_timer_ms} ms: set it to 1 ms with the udev "
                f"rule in {TIMER_RULE} (now: echo 1 | sudo tee "
                f"/sys/bus/usb-serial/devices/{self.device}/latency_timer)")


def kernel_name(url: str) -> str:
    """The device's kernel name, followed through udev's symlinks.

    A link udev removes meanwhile (an unplug) or one it may not read ends the walk where
    it is: opening the port then says what is wrong.

    Args:
        url: A device path or a pyserial URL.

    Returns:
        The first ttyACM*/ttyUSB* on its chain of symlinks, else the name it finally
        resolves to ("" for a URL such as socket://).
    """
    if "://" in url:
        return ""
    path = Path(url)
    try:
        for _ in range(_MAX_HOPS):
            if _KERNEL_TTY.fullmatch(path.name) or not path.is_symlink():
                break
            path = path.parent / path.readlink()
    except OSError:
        pass
    return path.name


def _latency_timer_ms(device: str, sysfs: Path = SYSFS) -> int | None:
    """A USB-serial adapter's latency timer as the kernel reports it.

    None if it does not: no such file, unreadable, or not a timer the kernel allows
    (1 to 255 ms).
    """
    try:
        text = (sysfs / "bus" / "usb-serial" / "devices" / device / "latency_timer").read_text()
        value = int(text.strip())
    except (OSError, ValueError):
        return None
    return value if 1 <= value <= _MAX_LATENCY_TIMER_MS else None


def find_link(url: str, transport: str = "auto", sysfs: Path = SYSFS) -> Link:
    """The link to a unit at ``url``.

    Args:
        url: The unit's device path (udev's stable names are followed) or pyserial URL.
        transport: "uart", "usb" or "usb-serial" as given, or "auto": by the kernel's
            device name (ttyACM: usb, ttyUSB: usb-serial, anything else: uart).
        sysfs: Where sysfs is mounted, for an adapter's latency timer.

    Returns:
        The transport, an adapter's latency timer where sysfs tells it, the kernel name.
    """
    name = kernel_name(url)
    device = name if _KERNEL_TTY.fullmatch(name) else ""
    if transport == "auto":
        transport = ("usb" if device.startswith("ttyACM") else
                     "usb-serial" if device.startswith("ttyUSB") else "uart")
    timer = _latency_timer_ms(device, sysfs) if transport == "usb-serial" and device else None
    return Link(transport, timer, device)
