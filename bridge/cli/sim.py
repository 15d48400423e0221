"""`gx3 sim`: emulated units on ptys or TCP."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from bridge.cli.common import LogFormat, LogFormatOpt, LogLevel, LogLevelOpt, app, err, fail, log_to
from bridge.exceptions import OptionError

ID_LENGTH = 16
MAX_CLOCK_PPM = 10_000.0
#: 0xDB and preset fields of the stored state, as the options that set them are called.
_STORED_OPTIONS = {"mode_preset": "--mode-preset", "continuous_preset": "--continuous-preset",
                   "sampling.decimation": "--decimation", "sampling.flags": "--flags",
                   "baud": "--baud"}


def parse_tcp(text: str, units: int) -> tuple[str, int]:
    """HOST:PORT, with room for ``units`` consecutive ports unless PORT is 0."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise OptionError("--tcp", f"{text!r} is not HOST:PORT, e.g. 127.0.0.1:0")
    last = int(port) + units - 1 if int(port) else 0
    if last > 0xFFFF:
        raise OptionError("--tcp", f"port {port} (+{units - 1} for the other units) is past "
                          "65535; give a lower port, or 0 for free ones")
    return host or "127.0.0.1", int(port)


def parse_number(option: str, text: str | None) -> int:
    """A number as people write it: 0xC8, 200 or 0o310; none is 0."""
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


def parse_numbers(option: str, text: str | None, count: int,
                  default: tuple[float, ...]) -> tuple[float, ...]:
    """``count`` finite numbers separated by commas (none given: ``default``)."""
    if text is None:
        return default
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) and abs(v) <= 100 for v in values):
        raise OptionError(option, f"{text!r} is not {count} numbers within ±100 separated by "
                          f"commas, e.g. {','.join(_shown(v) for v in default)}")
    return values


def parse_soft_iron(text: str | None) -> tuple[float, ...]:
    """Nine numbers of an invertible 3x3 matrix, row-major."""
    import numpy as np

    values = parse_numbers("--soft-iron", text, 9, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    if abs(np.linalg.det(np.reshape(values, (3, 3)))) < 1e-6:
        raise OptionError("--soft-iron", "the matrix is singular (it would flatten the field "
                          "onto a plane); give an invertible one, e.g. 1.1,0,0,0,0.9,0,0,0,1")
    return values


def _bad_id(option: str, text: str) -> str | None:
    if not text.isascii() or len(text) > ID_LENGTH or not text.isprintable():
        return (f"{option}: {text!r} is not printable ASCII of at most {ID_LENGTH} characters "
                "(the unit's ID strings are 16 ASCII bytes)")
    return None


@app.command()
def sim(
    pty: Annotated[bool, typer.Option(
        "--pty", help="Serve each unit on a pseudo-terminal.")] = False,
    tcp: Annotated[str | None, typer.Option(
        "--tcp", metavar="HOST:PORT",
        help="Serve each unit over TCP for socket://HOST:PORT; port 0 picks free ports, "
             "otherwise unit i gets PORT+i. One host at a time: a second client is "
             "refused (closed at once, with a notice on stderr).")] = None,
    units: Annotated[int, typer.Option("--units", "-n",
                                       help="How many independent units to run (1-64).")] = 1,
    serial: Annotated[str, typer.Option(help="Serial number, ASCII, at most 16 characters "
                                        "(with several units, -1, -2, … is appended).")] = (
        "SIM0001"),
    model_name: Annotated[str, typer.Option(
        help="Model name string (0xEA selector 2), ASCII, at most 16 characters.")] = (
        "3DM-GX3-25"),
    model_number: Annotated[str, typer.Option(
        help="Model number string (0xEA selector 0), ASCII, at most 16 characters.")] = (
        "6225-4220"),
    firmware: Annotated[int, typer.Option(
        help="Firmware version number (0xE9), 0 to 4294967295.")] = 1127,
    timer_start: Annotated[int, typer.Option(
        help="Timer value at power-up, 0 to 4294967295; near the top crosses the "
             "rollover at once.")] = 0,
    clock_ppm: Annotated[list[float] | None, typer.Option(
        help="Clock error in ppm (within ±10000); repeat for unit 1, 2, …  Default: each "
             "unit draws its own within the manual's ±100 ppm.")] = None,
    seed: Annotated[int, typer.Option(help="Seed (0 or more) of the motion, noise and faults "
                                      "of unit 1 (unit i uses seed+i-1).")] = 0,
    static: Annotated[bool, typer.Option("--static", help="Hold every unit still.")] = False,
    tumble: Annotated[bool, typer.Option(
        "--tumble", help="Turn every unit through all orientations (roll and yaw keep "
                         "turning, pitch swings ±55°): the motion a magnetometer iron "
                         "calibration needs.")] = False,
    noise_accel: Annotated[float, typer.Option(help="Accel noise, g (1σ, before the "
                                               "filter).")] = 0.0,
    noise_gyro: Annotated[float, typer.Option(help="Gyro noise, rad/s (1σ, before the "
                                              "filter).")] = 0.0,
    noise_mag: Annotated[float, typer.Option(help="Magnetometer noise, gauss (1σ, before the "
                                             "filter).")] = 0.0,
    gyro_bias: Annotated[float, typer.Option(
        help="True gyro bias on every axis, rad/s (what 0xCD finds on a still unit).")] = 0.0,
    hard_iron: Annotated[str | None, typer.Option(
        metavar="X,Y,Z",
        help="Hard-iron offset of the magnetometer, gauss. The mag reads soft @ true + hard "
             "(the true field in the body frame; mag and stab_mag alike).")] = None,
    soft_iron: Annotated[str | None, typer.Option(
        metavar="A,B,…,I",
        help="Soft-iron matrix of the magnetometer, nine numbers row-major (default: "
             "identity); see --hard-iron.")] = None,
    no_filter_model: Annotated[bool, typer.Option(
        "--no-filter-model",
        help="Leave out the unit's moving-average filters (modelled by default: values "
             "describe the instant (width-1)/2 ms before the record's cycle, and noise is "
             "divided by sqrt(width)).")] = False,
    decimation: Annotated[int, typer.Option(
        help="Stored 0xDB decimation, 1-1000 (1000 Hz / N).")] = 10,
    flags: Annotated[str, typer.Option(
        help="Stored 0xDB data-conditioning flags, 16 bits.")] = "0x0003",
    continuous_preset: Annotated[str | None, typer.Option(
        help="Stored continuous preset, e.g. 0xC2 (factory: none).")] = None,
    mode_preset: Annotated[int, typer.Option(
        help="Stored mode preset: 1 active, 2 continuous, 3 idle.")] = 1,
    baud: Annotated[int, typer.Option(
        help="Stored UART baud rate: 115200, 230400, 460800 or 921600.")] = 115_200,
    flip_rate: Annotated[float, typer.Option(
        help="Per-byte chance (0-1) of one flipped bit.")] = 0.0,
    drop_rate: Annotated[float, typer.Option(
        help="Per-byte chance (0-1) of a dropped byte.")] = 0.0,
    stall_every: Annotated[float, typer.Option(
        help="Mean seconds between USB snubs that hold output back (0: never).")] = 0.0,
    stall_for: Annotated[float, typer.Option(help="Length of a snub, seconds.")] = 0.05,
    disconnect_every: Annotated[float, typer.Option(
        help="Mean seconds between disconnects (0: never).")] = 0.0,
    disconnect_for: Annotated[float, typer.Option(help="Length of a disconnect, s.")] = 1.0,
    usb: Annotated[bool, typer.Option(
        "--usb", help="Each unit is on its own USB port: the baud rate has no effect, and "
                      "bytes reach the host in 1 ms frames after an OS latency, with stalls "
                      "now and then that deliver a burst (what the clock model must "
                      "handle).")] = False,
    usb_serial: Annotated[bool, typer.Option(
        "--usb-serial", help="Each unit is wired through a USB-serial adapter (FTDI-like, "
                             "a /dev/ttyUSB* port): bytes cross the serial line at the baud "
                             "rate into the adapter, which hands them to the host at its 1 ms "
                             "frames in 62-byte packets, sent when a packet is full or its "
                             "latency timer has run out; so reads often end mid-record. OS "
                             "latency and stalls as with --usb.")] = False,
    latency_timer: Annotated[int | None, typer.Option(
        help="With --usb-serial: the adapter's latency timer, ms, 1-255 (16, Linux's "
             "default, unless given; 1 with the rule in configs/udev).")] = None,
    disconnect_power_cycles: Annotated[bool, typer.Option(
        "--disconnect-power-cycles",
        help="A disconnect also cuts a USB-powered unit's power: on replug it boots (timer "
             "from 0, settings from non-volatile memory, settling time).")] = False,
    state: Annotated[Path | None, typer.Option(
        help="File holding the non-volatile memory across restarts (several units: "
             "NAME-1.json, NAME-2.json, …).")] = None,
    link: Annotated[Path | None, typer.Option(
        help="With --pty: a symlink to the pty that survives disconnects, removed on exit "
             "(several units: LINK-1, LINK-2, …). An existing file there is never "
             "replaced, only a stale link to a pty.")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Stop after this many seconds (default: run until interrupted).")] = None,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Emulate 3DM-GX3 units byte for byte, on ptys or TCP, until interrupted.

    Prints one endpoint per line on stdout: what a serial program opens (a pty
    path, or a socket://HOST:PORT URL for pyserial), then runs. Each unit answers
    every command of the manual, streams in continuous mode at the line's pace,
    and keeps its non-volatile memory in --state if given.
    """
    log_to(log_level, log_format)
    import signal
    import time

    from bridge.device.link import DEFAULT_LATENCY_TIMER_MS
    from bridge.exceptions import LinkPathError, StateFileError
    from bridge.sim.faults import FaultConfig
    from bridge.sim.motion import MotionConfig, tumbling
    from bridge.sim.serve import Simulator, unit_configs
    from bridge.sim.state import Sampling, Stored, check_writable, problems
    from bridge.sim.unit import UnitConfig
    from bridge.sim.usb import AdapterDelivery, UsbDelivery

    try:
        if pty == (tcp is not None):
            raise OptionError("--pty/--tcp", "choose one transport: --pty or --tcp HOST:PORT")
        if link is not None and tcp is not None:
            raise OptionError("--link", "makes a symlink to a pty; it does not go with --tcp")
        checks: list[tuple[str, float, float, float]] = [
            ("--units", units, 1, 64), ("--firmware", firmware, 0, 0xFFFF_FFFF),
            ("--timer-start", timer_start, 0, 0xFFFF_FFFF), ("--seed", seed, 0, 2**63 - 1),
            ("--noise-accel", noise_accel, 0, 100), ("--noise-gyro", noise_gyro, 0, 100),
            ("--noise-mag", noise_mag, 0, 100), ("--gyro-bias", gyro_bias, -100, 100),
            ("--flip-rate", flip_rate, 0, 1), ("--drop-rate", drop_rate, 0, 1),
            ("--stall-every", stall_every, 0, math.inf), ("--stall-for", stall_for, 0, math.inf),
            ("--disconnect-every", disconnect_every, 0, math.inf),
            ("--disconnect-for", disconnect_for, 0, math.inf),
            *(("--clock-ppm", ppm, -MAX_CLOCK_PPM, MAX_CLOCK_PPM) for ppm in clock_ppm or ()),
            ("--duration", 0.0 if duration is None else duration, 0, math.inf),
        ]
        for option, message in _bad_numbers(checks):
            raise OptionError(option, message)
        if static and tumble:
            raise OptionError("--static/--tumble", "choose one: hold still or tumble")
        if usb and usb_serial:
            raise OptionError("--usb/--usb-serial", "choose one: the unit's own USB port or "
                              "its serial port through an adapter")
        if latency_timer is not None and not usb_serial:
            raise OptionError("--latency-timer", "is the adapter's; it goes with --usb-serial")
        if latency_timer is not None and not 1 <= latency_timer <= 255:
            raise OptionError("--latency-timer", f"{latency_timer} ms is not in 1-255")
        hard = parse_numbers("--hard-iron", hard_iron, 3, (0.0, 0.0, 0.0))
        soft = parse_soft_iron(soft_iron)
        preset = parse_number("--continuous-preset", continuous_preset)
        stored = Stored(mode_preset=mode_preset, continuous_preset=preset, baud=baud,
                        sampling=Sampling(decimation=decimation,
                                          flags=parse_number("--flags", flags)))
        for name, message in problems(stored):
            raise OptionError(_STORED_OPTIONS[name], message)
        host, port = parse_tcp(tcp, units) if tcp else ("127.0.0.1", 0)
    except OptionError as exc:
        raise fail(str(exc)) from None
    motion = MotionConfig(seed=seed, static=static, noise_accel_g=noise_accel,
                          noise_gyro_rad_s=noise_gyro, noise_mag_gauss=noise_mag,
                          gyro_bias_rad_s=(gyro_bias,) * 3,
                          hard_iron_gauss=(hard[0], hard[1], hard[2]), soft_iron=soft)
    motion = tumbling(motion) if tumble else motion
    base = UnitConfig(serial=serial, model_name=model_name, model_number=model_number,
                      firmware=firmware, timer_start=timer_start, motion=motion, stored=stored,
                      state_file=state, filter_model=not no_filter_model)
    configs = unit_configs(units, base, clock_ppm)
    for cfg in configs:
        for option, text in (("--serial", cfg.serial), ("--model-name", cfg.model_name),
                             ("--model-number", cfg.model_number)):
            if (wrong := _bad_id(option, text)) is not None:
                raise fail(wrong)
        try:
            if cfg.state_file is not None:
                check_writable(cfg.state_file)
        except StateFileError as exc:
            raise fail(f"--state: {exc}") from None
    links = None
    if link is not None:
        links = [link] if units == 1 else [link.with_name(f"{link.name}-{i + 1}")
                                            for i in range(units)]
    faults = FaultConfig(flip_rate, drop_rate, stall_every, stall_for, disconnect_every,
                         disconnect_for, disconnect_power_cycles)
    delivery = UsbDelivery(seed=seed) if usb else None
    if usb_serial:
        timer_ms = DEFAULT_LATENCY_TIMER_MS if latency_timer is None else latency_timer
        delivery = AdapterDelivery(latency_timer_s=timer_ms / 1000, seed=seed)
    try:
        simulator = Simulator(configs, "pty" if pty else "tcp", host, port, faults, links,
                              notify=lambda text: err.print(escape(text)),
                              usb=delivery)
    except StateFileError as exc:
        raise fail(f"--state: {exc}") from None
    except LinkPathError as exc:
        raise fail(f"--link: {exc}") from None
    except OSError as exc:
        raise fail(f"cannot open {'a pty' if pty else tcp}: {exc.strerror or exc}") from None
    stop = {"now": False}

    def _interrupt(*_: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    with simulator:
        for endpoint in simulator.endpoints:
            print(endpoint, flush=True)
        for cfg in configs:
            err.print(f"[dim]unit {escape(cfg.serial)}: clock {cfg.clock_ppm:+.1f} ppm, "
                      f"seed {cfg.motion.seed}[/]")
        deadline = None if duration is None else time.monotonic() + duration
        while not stop["now"] and simulator.error is None:
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(0.05)
    if simulator.error is not None:
        raise fail(f"emulator stopped: {simulator.error}", 1)
    for slot in simulator.slots:
        u = slot.unit
        err.print(f"{escape(u.config.serial)}: {u.records_sent} records sent, "
                  f"{u.records_skipped} skipped (line busy), {slot.lost} bytes not delivered "
                  "(no host connected, or host not reading)")
