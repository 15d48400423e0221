"""`gx3 sim`: emulated units on ptys or TCP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from bridge.cli.common import app, err, fail, parse_code
from bridge.protocol.table import BAUD_RATES, DATA_CODES


def parse_tcp(text: str) -> tuple[str, int]:
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

    Prints one endpoint per line on stdout, in the form pyserial's
    serial_for_url takes (a pty path, or socket://HOST:PORT), then runs. Each unit answers
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
    preset = parse_code(continuous_preset, "--continuous-preset")
    if preset and preset not in DATA_CODES:
        raise fail(f"--continuous-preset 0x{preset:02X} is not a data command; use one of "
                   + " ".join(f"0x{c:02X}" for c in sorted(DATA_CODES)))
    stored = Stored(mode_preset=mode_preset, continuous_preset=preset, baud=baud,
                    sampling=Sampling(decimation=decimation, flags=parse_code(flags, "--flags")))
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
    host, port = parse_tcp(tcp) if tcp else ("127.0.0.1", 0)
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
