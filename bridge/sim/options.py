"""The options of ``gx3 sim``, checked and turned into the emulator's configs.

``SimOptions`` holds the options as a person gives them (numbers as text where people
write them so: ``--flags 0x0003``, ``--hard-iron 0.1,0,0``); ``setup`` checks them all
before anything opens and gives a ``SimSetup`` (the units' configs, their faults, their
link to the host), whose ``open`` starts the ``Simulator``. Every refusal is an
``OptionError`` naming the option, so a command line can show it as it is::

    from bridge.sim.options import SimOptions

    setup = SimOptions(pty=True, units=2, tumble=True).setup()
    with setup.open() as simulator:
        print(simulator.endpoints)
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from bridge.exceptions import EmulatorError, LinkPathError, OptionError, StateFileError
from bridge.sim.faults import FaultConfig
from bridge.sim.serve import Simulator
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery

if TYPE_CHECKING:
    from bridge.sim.motion import Mounting

__all__ = ["SimOptions", "SimSetup"]

_log = logging.getLogger("bridge.sim.serve")  # the emulator's own log
#: The most characters of the unit's ID strings (16 ASCII bytes on the wire).
ID_LENGTH = 16
#: The largest clock error ``--clock-ppm`` takes, either way.
MAX_CLOCK_PPM = 10_000.0
#: The longest extra latency ``--link-latency`` takes, ms.
MAX_LINK_LATENCY_MS = 1000.0
#: 0xDB and preset fields of the stored state, as the options that set them are called.
_STORED_OPTIONS = {"mode_preset": "--mode-preset", "continuous_preset": "--continuous-preset",
                   "sampling.decimation": "--decimation", "sampling.flags": "--flags",
                   "baud": "--baud"}


def _parse_tcp(text: str, units: int) -> tuple[str, int]:
    """Read ``--tcp HOST:PORT``, with room for ``units`` consecutive ports unless PORT is 0.

    Args:
        text: HOST:PORT as given; an empty HOST is 127.0.0.1.
        units: How many units take consecutive ports from PORT.

    Returns:
        The host and the first port (0: free ones).

    Raises:
        OptionError: It is not HOST:PORT, or the last unit's port would pass 65535.
    """
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise OptionError("--tcp", f"{text!r} is not HOST:PORT, e.g. 127.0.0.1:0")
    last = int(port) + units - 1 if int(port) else 0
    if last > 0xFFFF:
        raise OptionError("--tcp", f"port {port} (+{units - 1} for the other units) is past "
                          "65535; give a lower port, or 0 for free ones")
    return host or "127.0.0.1", int(port)


def _parse_number(option: str, text: str | None) -> int:
    """Read a number as people write it: 0xC8, 200 or 0o310.

    Args:
        option: The option it was given to, for the error.
        text: The number; None is 0.

    Returns:
        The number.

    Raises:
        OptionError: It is not a number.
    """
    if text is None:
        return 0
    try:
        return int(text, 0)
    except ValueError:
        raise OptionError(option, f"{text!r} is not a number such as 0xC8") from None


def _bad_numbers(checks: list[tuple[str, float, float, float]]) -> Iterator[tuple[str, str]]:
    """(option, what is wrong) for every value that is not a finite number in [lo, hi]."""
    for option, value, lo, hi in checks:
        if not (math.isfinite(value) and lo <= value <= hi):
            upper = "up" if hi == math.inf else f"to {_shown(hi)}"
            yield option, f"{_shown(value)} is not a number from {_shown(lo)} {upper}"


def _shown(value: float) -> str:
    return str(int(value)) if math.isfinite(value) and value == int(value) else str(value)


def _parse_numbers(option: str, text: str | None, count: int,
                  default: tuple[float, ...], limit: float = 100.0) -> tuple[float, ...]:
    """Read ``count`` finite numbers within ±``limit`` separated by commas.

    Args:
        option: The option they were given to, for the error.
        text: The numbers; None gives ``default``.
        count: How many there must be.
        default: The numbers when none are given (and the example in the error).
        limit: The largest magnitude a number may have.

    Returns:
        The numbers.

    Raises:
        OptionError: Not ``count`` such numbers.
    """
    if text is None:
        return default
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) and abs(v) <= limit for v in values):
        raise OptionError(option, f"{text!r} is not {count} numbers within ±{_shown(limit)} "
                          f"separated by commas, e.g. {','.join(_shown(v) for v in default)}")
    return values


def _mountings(body_seed: int, mounts: Sequence[str], arms: Sequence[str],
               units: int) -> list[Mounting]:
    """Each unit's mounting on the body from ``--mount`` and ``--lever-arm``.

    Unit i takes the i-th of each; a unit past the last given sits as the body's axes,
    at its origin.

    Raises:
        OptionError: A value that is not three numbers in range.
    """
    from bridge.sim.motion import Mounting

    out = []
    for i in range(units):
        roll, pitch, yaw = _parse_numbers("--mount", mounts[i] if i < len(mounts) else None,
                                          3, (0.0, 0.0, 0.0), limit=360.0)
        x, y, z = _parse_numbers("--lever-arm", arms[i] if i < len(arms) else None, 3,
                                 (0.0, 0.0, 0.0))
        out.append(Mounting.turned((roll, pitch, yaw), (x, y, z), body_seed))
    return out


def _parse_soft_iron(text: str | None) -> tuple[float, ...]:
    """Read ``--soft-iron``: nine numbers of an invertible 3x3 matrix, row-major.

    Args:
        text: The numbers; None is the identity.

    Returns:
        The nine numbers.

    Raises:
        OptionError: Not nine numbers within ±100, or a singular matrix.
    """
    import numpy as np

    values = _parse_numbers("--soft-iron", text, 9, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    if abs(np.linalg.det(np.reshape(values, (3, 3)))) < 1e-6:
        raise OptionError("--soft-iron", "the matrix is singular (it would flatten the field "
                          "onto a plane); give an invertible one, e.g. 1.1,0,0,0,0.9,0,0,0,1")
    return values


def _check_id(option: str, text: str) -> None:
    if not text.isascii() or len(text) > ID_LENGTH or not text.isprintable():
        raise OptionError(option, f"{text!r} is not printable ASCII of at most {ID_LENGTH} "
                          "characters (the unit's ID strings are 16 ASCII bytes)")


@dataclass(frozen=True)
class SimSetup:
    """The emulator ``SimOptions`` describe, checked and ready to open.

    Attributes:
        configs: One config per unit.
        transport: ``pty`` or ``tcp``.
        host: The TCP host (with ``tcp``).
        port: The first TCP port; 0: free ones.
        faults: The line faults every unit suffers.
        links: With ``pty``: a symlink per unit to its pty; None: no links.
        delivery: How bytes reach the host (a USB port, an adapter); None: a UART.
        endpoint: What the emulator opens, for the error when it cannot (``a pty``, or
            ``--tcp`` as given).
    """

    configs: list[UnitConfig]
    transport: str
    host: str
    port: int
    faults: FaultConfig
    links: list[Path] | None
    delivery: UsbDelivery | None
    endpoint: str

    def open(self, notify: Callable[[str], None] = _log.warning) -> Simulator:
        """Start serving the units (use the simulator as a context manager to stop them).

        Args:
            notify: Hears what the emulator tells a person (a second client refused, a
                disconnect); None: its log.

        Returns:
            The running simulator.

        Raises:
            StateFileError: A unit's state file cannot be read back (``--state: ...``).
            LinkPathError: A link cannot be made (``--link: ...``).
            EmulatorError: The pty or the TCP port cannot be opened.
        """
        try:
            return Simulator(self.configs, self.transport, self.host, self.port, self.faults,
                             self.links, notify, self.delivery)
        except StateFileError as exc:
            raise StateFileError(f"--state: {exc}") from None
        except LinkPathError as exc:
            raise LinkPathError(f"--link: {exc}") from None
        except OSError as exc:
            raise EmulatorError(f"cannot open {self.endpoint}: {exc.strerror or exc}") from exc


@dataclass(frozen=True)
class SimOptions:
    """What ``gx3 sim`` is given, as a person gives it; the defaults are its own.

    Each field is the option of the same name (``hard_iron`` is ``--hard-iron``); see
    ``gx3 sim --help`` for what each does.
    """

    pty: bool = False
    tcp: str | None = None
    units: int = 1
    serial: str = "SIM0001"
    model_name: str = "3DM-GX3-25"
    model_number: str = "6225-4220"
    firmware: int = 1127
    timer_start: int = 0
    clock_ppm: Sequence[float] | None = None
    seed: int = 0
    static: bool = False
    tumble: bool = False
    body: bool = False
    mount: Sequence[str] = ()
    lever_arm: Sequence[str] = ()
    link_latency: Sequence[float] = ()
    noise_accel: float = 0.0
    noise_gyro: float = 0.0
    noise_mag: float = 0.0
    accel_noise_density: float = 0.0
    accel_random_walk: float = 0.0
    gyro_noise_density: float = 0.0
    gyro_random_walk: float = 0.0
    gyro_bias: float = 0.0
    hard_iron: str | None = None
    soft_iron: str | None = None
    no_filter_model: bool = False
    decimation: int = 10
    flags: str = "0x0003"
    continuous_preset: str | None = None
    mode_preset: int = 1
    baud: int = 115_200
    flip_rate: float = 0.0
    drop_rate: float = 0.0
    stall_every: float = 0.0
    stall_for: float = 0.05
    disconnect_every: float = 0.0
    disconnect_for: float = 1.0
    usb: bool = False
    usb_serial: bool = False
    latency_timer: int | None = None
    disconnect_power_cycles: bool = False
    state: Path | None = None
    link: Path | None = None
    duration: float | None = None

    def setup(self) -> SimSetup:
        """Check every option, then build the units' configs, faults and link.

        Returns:
            The emulator to open.

        Raises:
            OptionError: The first option that cannot be used (a value out of range,
                two that exclude each other, an ID string that is not 16 ASCII bytes).
            StateFileError: A state file cannot be written (``--state: ...``).
        """
        self._check()
        from bridge.device.link import DEFAULT_LATENCY_TIMER_MS
        from bridge.sim.motion import MotionConfig, handheld, tumbling
        from bridge.sim.serve import unit_configs
        from bridge.sim.state import Sampling, Stored, check_writable, problems
        from bridge.sim.usb import AdapterDelivery

        hard = _parse_numbers("--hard-iron", self.hard_iron, 3, (0.0, 0.0, 0.0))
        soft = _parse_soft_iron(self.soft_iron)
        preset = _parse_number("--continuous-preset", self.continuous_preset)
        stored = Stored(mode_preset=self.mode_preset, continuous_preset=preset, baud=self.baud,
                        sampling=Sampling(decimation=self.decimation,
                                          flags=_parse_number("--flags", self.flags)))
        for name, message in problems(stored):
            raise OptionError(_STORED_OPTIONS[name], message)
        host, port = _parse_tcp(self.tcp, self.units) if self.tcp else ("127.0.0.1", 0)
        motion = MotionConfig(seed=self.seed, static=self.static,
                              noise_accel_g=self.noise_accel, noise_gyro_rad_s=self.noise_gyro,
                              noise_mag_gauss=self.noise_mag,
                              accelerometer_noise_density=self.accel_noise_density,
                              accelerometer_random_walk=self.accel_random_walk,
                              gyroscope_noise_density=self.gyro_noise_density,
                              gyroscope_random_walk=self.gyro_random_walk,
                              gyro_bias_rad_s=(self.gyro_bias,) * 3,
                              hard_iron_gauss=(hard[0], hard[1], hard[2]), soft_iron=soft)
        motion = tumbling(motion) if self.tumble else motion
        motion = handheld(motion) if self.body else motion
        base = UnitConfig(serial=self.serial, model_name=self.model_name,
                          model_number=self.model_number, firmware=self.firmware,
                          timer_start=self.timer_start, motion=motion, stored=stored,
                          state_file=self.state, filter_model=not self.no_filter_model)
        configs = unit_configs(self.units, base,
                               None if self.clock_ppm is None else list(self.clock_ppm))
        if self.body:
            configs = [replace(cfg, motion=replace(cfg.motion, mounting=mounting))
                       for cfg, mounting in zip(configs, _mountings(
                           self.seed, self.mount, self.lever_arm, self.units), strict=True)]
        configs = [replace(cfg, link_latency_s=self.link_latency[i] / 1000)
                   if i < len(self.link_latency) else cfg for i, cfg in enumerate(configs)]
        for cfg in configs:
            for option, text in (("--serial", cfg.serial), ("--model-name", cfg.model_name),
                                 ("--model-number", cfg.model_number)):
                _check_id(option, text)
            try:
                if cfg.state_file is not None:
                    check_writable(cfg.state_file)
            except StateFileError as exc:
                raise StateFileError(f"--state: {exc}") from None
        links = None
        if self.link is not None:
            links = [self.link] if self.units == 1 else [
                self.link.with_name(f"{self.link.name}-{i + 1}") for i in range(self.units)]
        faults = FaultConfig(self.flip_rate, self.drop_rate, self.stall_every, self.stall_for,
                             self.disconnect_every, self.disconnect_for,
                             self.disconnect_power_cycles)
        delivery = UsbDelivery(seed=self.seed) if self.usb else None
        if self.usb_serial:
            timer_ms = (DEFAULT_LATENCY_TIMER_MS if self.latency_timer is None
                        else self.latency_timer)
            delivery = AdapterDelivery(latency_timer_s=timer_ms / 1000, seed=self.seed)
        return SimSetup(configs, "pty" if self.pty else "tcp", host, port, faults, links,
                        delivery, "a pty" if self.pty else str(self.tcp))

    def _check(self) -> None:
        """Refuse the first option out of range, or two that exclude each other."""
        if self.pty == (self.tcp is not None):
            raise OptionError("--pty/--tcp", "choose one transport: --pty or --tcp HOST:PORT")
        if self.link is not None and self.tcp is not None:
            raise OptionError("--link", "makes a symlink to a pty; it does not go with --tcp")
        checks: list[tuple[str, float, float, float]] = [
            ("--units", self.units, 1, 64), ("--firmware", self.firmware, 0, 0xFFFF_FFFF),
            ("--timer-start", self.timer_start, 0, 0xFFFF_FFFF),
            ("--seed", self.seed, 0, 2**63 - 1),
            ("--noise-accel", self.noise_accel, 0, 100),
            ("--noise-gyro", self.noise_gyro, 0, 100),
            ("--noise-mag", self.noise_mag, 0, 100), ("--gyro-bias", self.gyro_bias, -100, 100),
            ("--accel-noise-density", self.accel_noise_density, 0, 100),
            ("--accel-random-walk", self.accel_random_walk, 0, 100),
            ("--gyro-noise-density", self.gyro_noise_density, 0, 100),
            ("--gyro-random-walk", self.gyro_random_walk, 0, 100),
            ("--flip-rate", self.flip_rate, 0, 1), ("--drop-rate", self.drop_rate, 0, 1),
            ("--stall-every", self.stall_every, 0, math.inf),
            ("--stall-for", self.stall_for, 0, math.inf),
            ("--disconnect-every", self.disconnect_every, 0, math.inf),
            ("--disconnect-for", self.disconnect_for, 0, math.inf),
            *(("--clock-ppm", ppm, -MAX_CLOCK_PPM, MAX_CLOCK_PPM)
              for ppm in self.clock_ppm or ()),
            *(("--link-latency", ms, 0, MAX_LINK_LATENCY_MS) for ms in self.link_latency),
            ("--duration", 0.0 if self.duration is None else self.duration, 0, math.inf),
        ]
        for option, message in _bad_numbers(checks):
            raise OptionError(option, message)
        if self.static and self.tumble:
            raise OptionError("--static/--tumble", "choose one: hold still or tumble")
        if self.body and self.tumble:
            raise OptionError("--body/--tumble", "choose one: turned by hand on one body, or "
                              "each unit tumbling on its own")
        for option, given in (("--mount", self.mount), ("--lever-arm", self.lever_arm)):
            if given and not self.body:
                raise OptionError(option, "places a unit on the body: it goes with --body")
        for option, count in (("--mount", len(self.mount)),
                              ("--lever-arm", len(self.lever_arm)),
                              ("--link-latency", len(self.link_latency))):
            if count > self.units:
                raise OptionError(option, f"{count} given for {self.units} unit(s); give one "
                                  "per unit at most (unit 1's first)")
        if self.usb and self.usb_serial:
            raise OptionError("--usb/--usb-serial", "choose one: the unit's own USB port or "
                              "its serial port through an adapter")
        if self.latency_timer is not None and not self.usb_serial:
            raise OptionError("--latency-timer", "is the adapter's; it goes with --usb-serial")
        if self.latency_timer is not None and not 1 <= self.latency_timer <= 255:
            raise OptionError("--latency-timer", f"{self.latency_timer} ms is not in 1-255")
