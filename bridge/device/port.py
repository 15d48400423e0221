"""Open a unit's byte transport and read from it with honest receive times.

Any pyserial URL or device path works: a real tty, a pty, ``socket://``, ``rfc2217://``.
Reads are non-blocking behind ``select`` where the transport has a file descriptor,
so the receive time stamped on a read is the moment its bytes were handed over,
not the end of a read timeout (pyserial's socket ``read(n)`` otherwise waits for n
bytes or the timeout, which would smear every stamp by up to the timeout). Each read
is stamped on two clocks read together (``bridge.device.clock.stamp``): the raw
monotonic clock the unit's clock is fitted against, and the host's realtime clock.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import termios
from dataclasses import dataclass
from typing import Any

import serial

from bridge import _native as native
from bridge.device import clock
from bridge.exceptions import PortError

_READ_SIZE = 1 << 16
#: What a transport that went away raises. pyserial lets ``termios.error`` (not an
#: OSError) through where it drains or flushes the line: a pty whose unit closed it
#: between a write and its drain says EIO so.
_LINK_ERRORS = (serial.SerialException, OSError, termios.error)


def _error(url: str, exc: BaseException) -> PortError:
    text = str(exc)
    code = getattr(exc, "errno", None)
    if code is None and exc.args and isinstance(exc.args[0], int):  # termios.error
        code = exc.args[0]
    if code == errno.ENOENT or "No such file" in text:
        return PortError(f"{url}: no such port; check the cable and the device name "
                         "(ls /dev/tty*)", "port missing")
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
        return PortError(f"{url}: permission denied; add your user to the 'dialout' group "
                         "(then log in again) or use a udev rule", "permission denied")
    if code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in text:
        return PortError(f"{url}: port is busy: another program has it open (is a bridge "
                         "already running?)", "port busy")
    if "returned no data" in text or code == errno.EIO:
        return PortError(f"{url}: the device went away (cable pulled, or the unit lost "
                         "power)", "port gone")
    if code == errno.ECONNREFUSED or "Connection refused" in text:
        return PortError(f"{url}: connection refused; is the serial server (or gx3 sim) "
                         "running?", "connection refused")
    first = text.splitlines()[0] if text else type(exc).__name__
    return PortError(f"{url}: {first}")


@dataclass
class Port:
    """One open transport: ``url`` and pyserial's object for it (``raw``)."""

    url: str
    raw: Any

    @classmethod
    def open(cls, url: str, baud: int) -> Port:
        """Open a transport, exclusively, so a second bridge gets a clear 'busy'.

        Args:
            url: A device path or any pyserial URL (``socket://``, ``rfc2217://``).
            baud: The host side's baud rate.

        Returns:
            The open port.

        Raises:
            PortError: The port cannot be opened; the message says why and what to do.
        """
        kwargs: dict[str, Any] = {"baudrate": baud, "timeout": 0, "write_timeout": 2.0}
        if "://" not in url:
            kwargs["exclusive"] = True
        try:
            raw = serial.serial_for_url(url, **kwargs)
        except (*_LINK_ERRORS, ValueError) as exc:
            raise _error(url, exc) from None
        return cls(url, raw)

    @property
    def baud(self) -> int:
        """The baud rate the host side is set to; setting it raises PortError on failure."""
        return int(self.raw.baudrate)

    @baud.setter
    def baud(self, value: int) -> None:
        try:
            self.raw.baudrate = value
        except (*_LINK_ERRORS, ValueError) as exc:
            raise _error(self.url, exc) from None

    def _fileno(self) -> int | None:
        try:
            return int(self.raw.fileno())
        except (AttributeError, NotImplementedError, *_LINK_ERRORS):
            return None

    def read(self, wait_s: float) -> tuple[bytes, int, int]:
        """Bytes that arrived within ``wait_s``, and when they were read.

        Args:
            wait_s: How long to wait for the first byte.

        Returns:
            The bytes (none when nothing came), and their receive time in ns on the raw
            monotonic and on the realtime clock (``clock.stamp``).

        Raises:
            PortError: The transport is gone (cable pulled, server closed).
        """
        fd = self._fileno()
        try:
            if fd is not None:
                ready, _, _ = select.select([fd], [], [], wait_s)
                if not ready:
                    return (b"", *clock.stamp())
                data = os.read(fd, _READ_SIZE)  # pyserial's read would select again
                raw, real = clock.stamp()
                if not data:
                    raise PortError(f"{self.url}: the device went away (cable pulled?)",
                                    "port gone")
                return bytes(data), raw, real
            self.raw.timeout = wait_s
            data = self.raw.read(max(1, self.raw.in_waiting))
            if data and self.raw.in_waiting:
                data += self.raw.read(self.raw.in_waiting)
            return (bytes(data), *clock.stamp())
        except PortError:
            raise
        except _LINK_ERRORS as exc:
            raise _error(self.url, exc) from None

    def read_until(self, need: int, wait_s: float
                   ) -> tuple[list[bytes], list[int], list[int]]:
        """Reads as bytes come until ``need`` bytes have come or ``wait_s`` has passed.

        A live bridge waits so for the rest of a record in compiled code
        (``bridge/_gather.c``, the GIL released), and wakes in Python once a record rather
        than once a piece the link hands over. Without it, or without a file descriptor,
        this is one ``read``, and the caller reads again: the same reads either way.

        Args:
            need: Bytes to wait for.
            wait_s: How long to wait at most.

        Returns:
            Each read's bytes, and its receive times on the raw monotonic and on the
            realtime clock.

        Raises:
            PortError: The transport is gone (cable pulled, server closed).
        """
        fd = self._fileno()
        reader = native.reader
        if fd is None or reader is None or need <= 1:
            data, raw, real = self.read(wait_s)
            return ([data], [raw], [real]) if data else ([], [], [])
        try:
            reads, raws, reals, gone = reader.gather(fd, need, wait_s)
        except OSError as exc:
            raise _error(self.url, exc) from None
        if gone and not reads:  # the bytes before the end go out first, as reads would
            raise PortError(f"{self.url}: the device went away (cable pulled?)", "port gone")
        return reads, raws, clock.moved(reals)

    def write(self, data: bytes) -> None:
        """Write ``data`` and wait until it is sent.

        Args:
            data: The bytes.

        Raises:
            PortError: The transport is gone or the write timed out.
        """
        try:
            self.raw.write(data)
            self.raw.flush()
        except _LINK_ERRORS as exc:
            raise _error(self.url, exc) from None

    def close(self) -> None:
        """Close the transport; errors on the way are ignored."""
        with contextlib.suppress(*_LINK_ERRORS):
            self.raw.close()

