"""The `gx3` command line."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated, BinaryIO, TextIO

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

from bridge.protocol.codec import Batch, json_safe
from bridge.protocol.docs import command_table_markdown, reply_schemas
from bridge.protocol.framer import Framer
from bridge.protocol.table import BAUD_RATES, DATA_CODES, REPLIES

app = typer.Typer(
    name="gx3",
    help="Tools for MicroStrain 3DM-GX3 inertial sensors: decode raw captures, emulate "
         "units on ptys or TCP, look up the command set.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True, highlight=False, soft_wrap=True)

_READ_SIZE = 1 << 20


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error for a person and return the exit to raise."""
    err.print(f"[bold red]error:[/] {escape(message)}")
    return typer.Exit(code)


def _code(text: str | None) -> int:
    """A command byte as people write it: 0xC8, 200 or 0o310; none is 0."""
    if text is None:
        return 0
    try:
        return int(text, 0)
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a number such as 0xC8") from None


def _reply_code(text: str) -> int:
    code = _code(text)
    if code not in REPLIES:
        raise typer.BadParameter(f"no reply starts with 0x{code:02X}")
    return code


def _open_input(path: str) -> BinaryIO:
    if path == "-":
        return sys.stdin.buffer
    try:
        return Path(path).open("rb")
    except FileNotFoundError:
        raise fail(f"{path}: no such file; give a capture of raw bytes, or - for stdin") from None
    except IsADirectoryError:
        raise fail(f"{path} is a directory; give a file of raw bytes") from None
    except PermissionError:
        raise fail(f"{path}: permission denied") from None


@app.command()
def decode(
    file: Annotated[str, typer.Argument(
        help="File of raw bytes as read off the line; - for stdin.")],
    little_endian: Annotated[bool, typer.Option(
        "--little-endian", help="Floats were sent little-endian (0xDB flag bit 4 set).")] = False,
    expect: Annotated[list[str] | None, typer.Option(
        "--expect", "-e", metavar="CODE",
        help="Reply code to look for, e.g. 0xC8 or 0xD4 (repeatable). "
             "Default: every data record.")] = None,
) -> None:
    """Decode a raw capture: one JSON object per record on stdout, a summary on stderr.

    Each object has "command" (integer), "timer" where the record has one, and
    each quantity under its name (accel, ang_rate, mag, m, euler, quaternion,
    temperature, …: see docs/commands.md); vectors and matrices are nested
    lists, matrices row-major. NaN is written as null. Corrupt bytes are
    skipped and counted; every intact record after them is still decoded.
    On a terminal, progress is shown on stderr.
    """
    codes = [_reply_code(c) for c in expect] if expect else sorted(DATA_CODES)
    framer = Framer(codes, little_endian=little_endian)
    out = sys.stdout
    stream = _open_input(file)
    size = None if file == "-" else os.fstat(stream.fileno()).st_size
    progress = Progress(TextColumn("decoding"), BarColumn(), DownloadColumn(),
                        TransferSpeedColumn(), console=err, transient=True,
                        disable=not err.is_terminal)
    try:
        with stream, progress:
            task = progress.add_task("decode", total=size)
            while chunk := stream.read(_READ_SIZE):
                _write(framer.feed(chunk), out)
                progress.advance(task, len(chunk))
            _write(framer.flush(), out)
        out.flush()
    except BrokenPipeError:
        sys.stderr.close()
        raise typer.Exit(0) from None
    err.print(framer.stats.summary())


def _write(batches: list[Batch], out: TextIO) -> None:
    for batch in batches:
        for record in batch.records():
            out.write(json.dumps({k: json_safe(v) for k, v in record.items()}) + "\n")


@app.command()
def commands(
    markdown: Annotated[bool, typer.Option(
        "--markdown", help="Print the table as Markdown (what docs/commands.md holds).")] = False,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print every reply's wire layout as JSON (what schemas/replies.json "
        "holds).")] = False,
) -> None:
    """List every 3DM-GX3 command with its bytes, parameters and reply layout."""
    text = command_table_markdown()
    if as_json:
        sys.stdout.write(json.dumps(reply_schemas(), indent=1) + "\n")
    elif markdown:
        sys.stdout.write(text)
    else:
        from rich.markdown import Markdown

        Console().print(Markdown(text))


def _parse_tcp(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise typer.BadParameter(f"{text!r} is not HOST:PORT, e.g. 127.0.0.1:0")
    return host or "127.0.0.1", int(port)


@app.command()
def sim(
    pty: Annotated[bool, typer.Option(
        "--pty", help="Serve each unit on a pseudo-terminal.")] = False,
    tcp: Annotated[str | None, typer.Option(
        "--tcp", metavar="HOST:PORT",
        help="Serve each unit over TCP for socket://HOST:PORT; port 0 picks free ports, "
             "otherwise unit i gets PORT+i.")] = None,
    units: Annotated[int, typer.Option("--units", "-n", min=1, max=64,
                                       help="How many independent units to run.")] = 1,
    serial: Annotated[str, typer.Option(help="Serial number (with several units, -1, -2, … "
                                        "is appended).")] = "SIM0001",
    model_name: Annotated[str, typer.Option(help="Model name string (0xEA selector 2).")] = (
        "3DM-GX3-25"),
    model_number: Annotated[str, typer.Option(help="Model number string (0xEA selector 0).")] = (
        "6225-4220"),
    firmware: Annotated[int, typer.Option(help="Firmware version number (0xE9).")] = 1127,
    timer_start: Annotated[int, typer.Option(
        min=0, max=0xFFFF_FFFF,
        help="Timer value at power-up; near 4294967295 crosses the rollover at once.")] = 0,
    clock_ppm: Annotated[list[float] | None, typer.Option(
        help="Clock error in ppm; repeat for unit 1, 2, …  Default: each unit draws its "
             "own within the manual's ±100 ppm.")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the motion, noise and faults of unit 1 "
                                      "(unit i uses seed+i-1).")] = 0,
    static: Annotated[bool, typer.Option("--static", help="Hold every unit still.")] = False,
    noise_accel: Annotated[float, typer.Option(help="Accel noise, g (1σ).")] = 0.0,
    noise_gyro: Annotated[float, typer.Option(help="Gyro noise, rad/s (1σ).")] = 0.0,
    noise_mag: Annotated[float, typer.Option(help="Magnetometer noise, gauss (1σ).")] = 0.0,
    gyro_bias: Annotated[float, typer.Option(
        help="True gyro bias on every axis, rad/s (what 0xCD finds on a still unit).")] = 0.0,
    decimation: Annotated[int, typer.Option(min=1, max=1000,
                                            help="Stored 0xDB decimation (1000 Hz / N).")] = 10,
    flags: Annotated[str, typer.Option(help="Stored 0xDB data-conditioning flags.")] = "0x0003",
    continuous_preset: Annotated[str | None, typer.Option(
        help="Stored continuous preset, e.g. 0xC2 (factory: none).")] = None,
    mode_preset: Annotated[int, typer.Option(
        min=1, max=3, help="Stored mode preset: 1 active, 2 continuous, 3 idle.")] = 1,
    baud: Annotated[int, typer.Option(help="Stored UART baud rate.")] = 115_200,
    flip_rate: Annotated[float, typer.Option(help="Per-byte chance of one flipped bit.")] = 0.0,
    drop_rate: Annotated[float, typer.Option(help="Per-byte chance of a dropped byte.")] = 0.0,
    stall_every: Annotated[float, typer.Option(
        help="Mean seconds between USB snubs that hold output back (0: never).")] = 0.0,
    stall_for: Annotated[float, typer.Option(help="Length of a snub, seconds.")] = 0.05,
    disconnect_every: Annotated[float, typer.Option(
        help="Mean seconds between disconnects (0: never).")] = 0.0,
    disconnect_for: Annotated[float, typer.Option(help="Length of a disconnect, s.")] = 1.0,
    state: Annotated[Path | None, typer.Option(
        help="File holding the non-volatile memory across restarts (several units: "
             "NAME-1.json, NAME-2.json, …).")] = None,
    link: Annotated[Path | None, typer.Option(
        help="With --pty: a symlink to the pty that survives disconnects (several units: "
             "LINK-1, LINK-2, …).")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Stop after this many seconds (default: run until interrupted).")] = None,
) -> None:
    """Emulate 3DM-GX3 units byte for byte, on ptys or TCP, until interrupted.

    Prints one endpoint per line on stdout, in the form `gx3 bridge --port`
    takes (a pty path, or socket://HOST:PORT), then runs. Each unit answers
    every command of the manual, streams in continuous mode at the line's pace,
    and keeps its non-volatile memory in --state if given.
    """
    import signal
    import time

    from bridge.sim.faults import FaultConfig
    from bridge.sim.motion import MotionConfig
    from bridge.sim.serve import Simulator, unit_configs
    from bridge.sim.state import Sampling, StateFileError, Stored
    from bridge.sim.unit import UnitConfig

    if pty == (tcp is not None):
        raise fail("choose one transport: --pty or --tcp HOST:PORT")
    if baud not in BAUD_RATES:
        raise fail(f"--baud {baud} is not one the unit supports: "
                   + ", ".join(str(b) for b in BAUD_RATES))
    preset = _code(continuous_preset)
    if preset and preset not in DATA_CODES:
        raise fail(f"--continuous-preset 0x{preset:02X} is not a data command; use one of "
                   + " ".join(f"0x{c:02X}" for c in sorted(DATA_CODES)))
    stored = Stored(mode_preset=mode_preset, continuous_preset=preset, baud=baud,
                    sampling=Sampling(decimation=decimation, flags=_code(flags)))
    motion = MotionConfig(seed=seed, static=static, noise_accel_g=noise_accel,
                          noise_gyro_rad_s=noise_gyro, noise_mag_gauss=noise_mag,
                          gyro_bias_rad_s=(gyro_bias,) * 3)
    base = UnitConfig(serial=serial, model_name=model_name, model_number=model_number,
                      firmware=firmware, timer_start=timer_start, motion=motion, stored=stored,
                      state_file=state)
    configs = unit_configs(units, base, clock_ppm)
    links = None
    if link is not None:
        links = [link] if units == 1 else [link.with_name(f"{link.name}-{i + 1}")
                                            for i in range(units)]
    faults = FaultConfig(flip_rate, drop_rate, stall_every, stall_for, disconnect_every,
                         disconnect_for)
    host, port = _parse_tcp(tcp) if tcp else ("127.0.0.1", 0)
    try:
        simulator = Simulator(configs, "pty" if pty else "tcp", host, port, faults, links)
    except StateFileError as exc:
        raise fail(str(exc)) from None
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
            err.print(f"[dim]unit {cfg.serial}: clock {cfg.clock_ppm:+.1f} ppm, "
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
        err.print(f"{u.config.serial}: {u.records_sent} records sent, {u.records_skipped} "
                  f"skipped (line busy), {slot.lost} bytes not delivered (no host connected, or "
                  "host not reading)")

