"""Serve emulated units on pseudo-terminals or TCP, paced in real time.

One thread drives every unit: it reads what hosts sent, runs each unit up to the
current time and writes the bytes that have crossed the line. A pty is opened by
pyserial like a real port (its baud setting is read back, and a host at the wrong rate
receives what a UART would make of it); TCP serves pyserial's ``socket://`` URLs.
How the transports follow a real line: ``docs/design/emulator.md``.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import selectors
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bridge.exceptions import LinkPathError
from bridge.sim.faults import FaultConfig, Faults, reframe
from bridge.sim.unit import LOOKAHEAD_S, SimUnit, UnitConfig
from bridge.sim.usb import HostDriver, UsbDelivery, link_for

_log = logging.getLogger(__name__)

_TICK_S = 0.0005
_SPEEDS = {getattr(termios, f"B{b}"): b for b in (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600) if hasattr(termios, f"B{b}")}


Notify = Callable[[str], None]


class Endpoint:
    """One unit's end of a host connection."""

    url: str

    def write(self, data: bytes) -> int:
        """Write what the host side can take now; return the bytes lost (host not reading)."""
        raise NotImplementedError

    def host_baud(self) -> int | None:
        """The baud rate the host opened its end at; None when there is none (TCP)."""
        return None

    def selectables(self) -> list[int | socket.socket]:
        """What to select on for the host's bytes and connections."""
        raise NotImplementedError

    def readable(self, obj: object) -> bytes:
        """What arrived on ``obj``, one of ``selectables``."""
        raise NotImplementedError

    def unplug(self) -> None:
        """Drop the host's connection, as a pulled cable does."""

    def plug(self) -> None:
        """Offer the connection again after an unplug."""

    def close(self) -> None:
        """Close the host connection for good."""
        raise NotImplementedError


class PtyEndpoint(Endpoint):
    """A pseudo-terminal; ``link`` is a stable symlink that names it across unplug/plug.

    The symlink only ever replaces a stale one to a pty (an earlier run's); it is
    removed while unplugged and on close.
    """

    def __init__(self, baud: int, link: Path | None = None) -> None:
        self.link = link
        self.baud = baud
        if link is not None and (link.exists() or link.is_symlink()) and not _ours(link):
            raise LinkPathError(f"{link} exists and is not a link to a pty; remove it or choose "
                            "another path")
        self._open()

    def _open(self) -> None:
        """A raw pty at the unit's baud rate, until a host opens it at its own."""
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        attrs = termios.tcgetattr(self.slave)
        speed = next(code for code, baud in _SPEEDS.items() if baud == self.baud)
        attrs[4] = attrs[5] = speed
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            try:
                tmp.unlink(missing_ok=True)
                tmp.symlink_to(self.path)
                os.replace(tmp, self.link)
            except OSError as exc:
                self._close_fds()
                raise LinkPathError(f"cannot make {self.link}: {exc.strerror or exc}") from None
        self.url = str(self.link or self.path)

    def selectables(self) -> list[int | socket.socket]:
        """The pty's master side."""
        return [self.master]

    def readable(self, obj: object) -> bytes:
        """What the host wrote to the pty."""
        try:
            return os.read(self.master, 4096)
        except OSError:
            return b""

    def write(self, data: bytes) -> int:
        """Write what the pty takes now; return the bytes lost (host not reading)."""
        try:
            written = os.write(self.master, data)
        except BlockingIOError:
            written = 0
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EAGAIN):
                raise
            written = 0
        return len(data) - written

    def host_baud(self) -> int | None:
        """The baud rate the host set on the pty (None: not one a UART runs at)."""
        try:
            return _SPEEDS.get(termios.tcgetattr(self.slave)[5])
        except termios.error:
            return None

    def unplug(self) -> None:
        """The pty goes, and so does the stable name, as udev removes a pulled device's link.

        A host retrying the name must not reach the next pty given that number.
        """
        self.close()

    def plug(self) -> None:
        """A new pty, under the same stable name."""
        self._open()

    def _close_fds(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.master = self.slave = -1

    def close(self) -> None:
        """Close the pty and remove the stable name."""
        self._close_fds()
        if self.link is not None and self.link.is_symlink() and _ours(self.link):
            self.link.unlink(missing_ok=True)


def _ours(link: Path) -> bool:
    """A symlink to a pty, as this emulator makes (maybe left by a run that was killed)."""
    return link.is_symlink() and os.readlink(link).startswith("/dev/pts/")


class _TcpEndpoint(Endpoint):
    """A TCP port serving one host at a time: a second client is closed at once."""

    def __init__(self, host: str, port: int, notify: Notify = _log.warning) -> None:
        self.notify = notify
        self.server = socket.create_server((host, port), reuse_port=False)
        self.server.setblocking(False)
        bound_host, bound_port = self.server.getsockname()[:2]
        self.url = f"socket://{bound_host}:{bound_port}"
        self.client: socket.socket | None = None
        self.unplugged = False

    def selectables(self) -> list[int | socket.socket]:
        return [self.server] if self.client is None else [self.server, self.client]

    def readable(self, obj: object) -> bytes:
        if obj is self.server:
            with contextlib.suppress(BlockingIOError):
                conn, peer = self.server.accept()
                if self.unplugged:
                    conn.close()
                    return b""
                if self.client is not None:
                    conn.close()
                    self.notify(f"{self.url}: refused a second client from "
                                f"{peer[0]}:{peer[1]}; one host at a time")
                    return b""
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.client = conn
            return b""
        if not isinstance(obj, socket.socket):
            return b""
        try:
            data = obj.recv(4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop_client()
        return data

    def write(self, data: bytes) -> int:
        if self.client is None:
            return len(data)
        try:
            return len(data) - self.client.send(data)
        except BlockingIOError:
            return len(data)
        except OSError:
            self._drop_client()
            return len(data)

    def _drop_client(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None

    def unplug(self) -> None:
        self.unplugged = True
        self._drop_client()

    def plug(self) -> None:
        self.unplugged = False

    def close(self) -> None:
        self._drop_client()
        self.server.close()


@dataclass
class _Slot:
    unit: SimUnit
    link: Endpoint
    faults: Faults
    held: bytearray
    lost: int = 0
    plugged: bool = True
    state_reported: bool = False
    pulled_until: float = 0.0  # a cable pulled on request (``Simulator.unplug``)
    power_cycle: bool = False
    usb: HostDriver | None = None  # USB (own port or an adapter's): bytes reach the host in frames


class Simulator:
    """N units, each on its own pty or TCP port, run by one background thread.

    Use as a context manager; ``endpoints`` are what a serial program opens (pyserial
    takes the socket:// URLs), ``units`` expose each unit's state and ground truth.
    ``notify`` gets one-line notices (a refused client, a state file that cannot be
    written) that must not stop the units.

    Args:
        configs: One config per unit (``unit_configs`` makes a fleet of them).
        transport: ``pty`` or ``tcp``.
        host: The address TCP ports listen on.
        port: The first unit's TCP port, the next unit's one more, ...; 0: free ports
            the OS picks.
        faults: Line faults: one for all units, or one per unit; None: none.
        links: Stable names (symlinks) for the units' ptys, one per unit.
        notify: Hears one-line notices; default: a warning on this module's logger.
        usb: How bytes reach the host (USB frames, an adapter); None: as they cross a
            UART.

    Raises:
        ValueError: ``transport`` is neither ``pty`` nor ``tcp``.
        LinkPathError: A link's path holds something that is not a link to a pty, or
            cannot be made.
        StateFileError: A unit's state file is there but not a unit's state.
    """

    def __init__(self, configs: list[UnitConfig], transport: str = "pty", host: str = "127.0.0.1",
                 port: int = 0, faults: FaultConfig | list[FaultConfig] | None = None,
                 links: list[Path] | None = None, notify: Notify = _log.warning,
                 usb: UsbDelivery | None = None) -> None:
        if transport not in ("pty", "tcp"):
            raise ValueError(f"transport must be 'pty' or 'tcp', not {transport!r}")
        per_unit = faults if isinstance(faults, list) else [faults or FaultConfig()] * len(configs)
        self.notify = notify
        now = time.monotonic()
        self.slots: list[_Slot] = []
        try:
            for i, config in enumerate(configs):
                if usb is not None and usb.transport == "usb":
                    config = replace(config, usb=True)
                unit = SimUnit(config, now)
                link: Endpoint
                if transport == "pty":
                    link = PtyEndpoint(unit.baud, links[i] if links else None)
                else:
                    link = _TcpEndpoint(host, port + i if port else 0, notify)
                self.slots.append(_Slot(
                    unit, link, Faults(per_unit[i], config.motion.seed, now), bytearray(),
                    usb=None if usb is None else link_for(replace(usb, seed=usb.seed + i), now)))
        except BaseException:
            self._close_links()
            raise
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gx3-sim", daemon=True)
        self.error: BaseException | None = None

    @property
    def units(self) -> list[SimUnit]:
        """Each unit's device model: its state, counters and ground truth."""
        return [s.unit for s in self.slots]

    @property
    def endpoints(self) -> list[str]:
        """What a serial program opens: each unit's pty (or its link), or socket:// URL."""
        return [s.link.url for s in self.slots]

    def start(self) -> Simulator:
        """Start the thread that runs the units.

        Returns:
            The simulator itself.
        """
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the units and close their ports."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self._close_links()

    def _close_links(self) -> None:
        for s in self.slots:
            s.link.close()

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            with selectors.DefaultSelector() as sel:
                while not self._stop.is_set():
                    self._register(sel)
                    for key, _ in sel.select(_TICK_S):
                        slot: _Slot = key.data
                        data = slot.link.readable(key.fileobj)
                        if data and slot.plugged:
                            slot.unit.receive(self._as_unit_hears(slot, data), time.monotonic())
                    now = time.monotonic()
                    self._plan_one(now)
                    for slot in self.slots:
                        self._pump(slot, now)
        except BaseException as exc:
            self.error = exc
            raise

    def _plan_one(self, now: float) -> None:
        """Compute ahead for the unit closest to running dry, one per tick.

        So that sixteen units never stall the line together.
        """
        slot = min(self.slots, key=lambda s: s.unit.planned_until)
        if slot.unit.planned_until < now + LOOKAHEAD_S / 2:
            slot.unit.plan(now)

    def _register(self, sel: selectors.BaseSelector) -> None:
        wanted = {(obj if isinstance(obj, int) else obj.fileno()): (obj, slot)
                  for slot in self.slots if slot.plugged for obj in slot.link.selectables()}
        for fd in [fd for fd in sel.get_map() if fd not in wanted]:
            sel.unregister(fd)
        for fd, (obj, slot) in wanted.items():
            key = sel.get_map().get(fd)
            if key is None or key.fileobj is not obj:
                if key is not None:
                    sel.unregister(fd)
                sel.register(obj, selectors.EVENT_READ, slot)

    def unplug(self, index: int, seconds: float, power_cycle: bool = False) -> None:
        """Pull a unit's cable for a while, as a test or a demo does on purpose.

        Args:
            index: The unit's place in ``units``.
            seconds: How long the cable stays out.
            power_cycle: The unit loses power too (USB-powered), and boots on replug.
        """
        slot = self.slots[index]
        slot.power_cycle = power_cycle
        slot.pulled_until = time.monotonic() + seconds

    @staticmethod
    def _as_unit_hears(slot: _Slot, data: bytes) -> bytes:
        host = slot.link.host_baud()
        return reframe(data, host, slot.unit.baud) if host else data

    def _pump(self, slot: _Slot, now: float) -> None:
        line = slot.unit.poll_line(now)
        if slot.unit.state_error is not None and not slot.state_reported:
            slot.state_reported = True
            self.notify(f"{slot.unit.config.serial}: cannot save non-volatile memory "
                        f"({slot.unit.state_error}); running on, changes kept until exit")
        if slot.faults.outage(now) or now < slot.pulled_until:
            if slot.plugged:
                slot.link.unplug()
                slot.plugged = False
                slot.held.clear()
            return
        if not slot.plugged:
            slot.link.plug()
            slot.plugged = True
            if slot.faults.config.disconnect_power_cycles or slot.power_cycle:
                slot.power_cycle = False
                slot.unit.power_cycle(now)
                line = []
        if slot.usb is None:
            host = slot.link.host_baud() if line else None  # a syscall: only for bytes
        else:  # bytes arrive in frames; behind an adapter the unit's UART meets the
            # adapter's, which runs at the baud rate the host set
            adapter = slot.link.host_baud() if line and not slot.unit.config.usb else None
            for baud, data in line:
                slot.usb.push(reframe(data, baud, adapter) if adapter else data, now, 10 / baud)
            line = [(0, data) for _, data in slot.usb.reads(now)]
            host = None
        for baud, data in line:
            slot.held += slot.faults.corrupt(reframe(data, baud, host) if host else data)
        if slot.held and not slot.faults.stalled(now):
            slot.lost += slot.link.write(bytes(slot.held))
            slot.held.clear()


def unit_configs(count: int, base: UnitConfig,
                 clock_ppm: list[float] | None = None) -> list[UnitConfig]:
    """Independent units from one config: own serial numbers, seeds and clock errors.

    Unit i gets serial ``<serial>-<i+1>``, motion seed ``seed + i`` and state file
    ``<stem>-<i+1><suffix>`` (one unit keeps them as they are).

    Args:
        count: How many units.
        base: What they share.
        clock_ppm: Each unit's clock error, ppm: unit i takes ``clock_ppm[i]`` (the last
            value repeats); None: each unit draws its own from its seed within the
            manual's ±0.01 % (±100 ppm).

    Returns:
        One config per unit.
    """
    out = []
    for i in range(count):
        seed = base.motion.seed + i
        if clock_ppm:
            ppm = clock_ppm[min(i, len(clock_ppm) - 1)]
        else:
            ppm = round(float(np.random.default_rng([seed, 0xC10C]).uniform(-100, 100)), 1)
        state = None
        if base.state_file is not None:
            state = base.state_file if count == 1 else base.state_file.with_name(
                f"{base.state_file.stem}-{i + 1}{base.state_file.suffix}")
        serial = base.serial if count == 1 else f"{base.serial}-{i + 1}"
        out.append(replace(base, serial=serial, clock_ppm=ppm, state_file=state,
                           motion=replace(base.motion, seed=seed)))
    return out
