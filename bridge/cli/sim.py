"""`gx3 sim`: emulated units on ptys or TCP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from bridge._text import counted, number
from bridge.cli.common import (
    FAILED,
    LogFormat,
    LogFormatOpt,
    LogLevel,
    LogLevelOpt,
    app,
    err,
    fail,
    log_to,
)


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
    body: Annotated[bool, typer.Option(
        "--body", help="Fix every unit to one rigid body turned by hand (brisk turns about "
                       "all three axes, 0.15-0.8 Hz, and 0.3 g of linear acceleration, the "
                       "seed's), each seen through its own --mount and --lever-arm: what "
                       "gx3 align needs. Units share the body's motion whatever their "
                       "clocks.")] = False,
    mount: Annotated[list[str] | None, typer.Option(
        metavar="ROLL,PITCH,YAW",
        help="With --body: how a unit's axes are turned against the body's, degrees, as a "
             "unit's attitude against north-east-down (yaw, then pitch, then roll); "
             "repeat for unit 1, 2, …; units past the last sit as the body.")] = None,
    lever_arm: Annotated[list[str] | None, typer.Option(
        metavar="X,Y,Z",
        help="With --body: where a unit sits from the body's origin, metres, in the body's "
             "axes; repeat for unit 1, 2, …; units past the last sit at the origin.")]
    = None,
    link_latency: Annotated[list[float] | None, typer.Option(
        metavar="MS",
        help="A constant delay on a unit's link each way, ms, 0-1000 (a long cable, a "
             "converter, a wireless serial link): one no clock model can see, which gx3 "
             "align measures; repeat for unit 1, 2, …; units past the last have none.")]
    = None,
    noise_accel: Annotated[float, typer.Option(help="Accel noise, g (1σ, before the "
                                               "filter).")] = 0.0,
    noise_gyro: Annotated[float, typer.Option(help="Gyro noise, rad/s (1σ, before the "
                                              "filter).")] = 0.0,
    noise_mag: Annotated[float, typer.Option(help="Magnetometer noise, gauss (1σ, before the "
                                             "filter).")] = 0.0,
    accel_noise_density: Annotated[float, typer.Option(
        help="Accel white noise density, m/s²/√Hz, as Kalibr's accelerometer_noise_density "
             "(what gx3 allan reads off): each sample's noise is this over the square root "
             "of its period, whatever the filter.")] = 0.0,
    accel_random_walk: Annotated[float, typer.Option(
        help="Accel bias random walk, m/s³/√Hz, as Kalibr's accelerometer_random_walk: the "
             "bias wanders from zero at power-up.")] = 0.0,
    gyro_noise_density: Annotated[float, typer.Option(
        help="Gyro white noise density, rad/s/√Hz, as Kalibr's gyroscope_noise_density.")
    ] = 0.0,
    gyro_random_walk: Annotated[float, typer.Option(
        help="Gyro bias random walk, rad/s²/√Hz, as Kalibr's gyroscope_random_walk.")] = 0.0,
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

    import numpy as np

    from bridge.protocol.convert import m_to_euler
    from bridge.sim.options import SimOptions

    setup = SimOptions(
        pty=pty, tcp=tcp, units=units, serial=serial, model_name=model_name,
        model_number=model_number, firmware=firmware, timer_start=timer_start,
        clock_ppm=clock_ppm, seed=seed, static=static, tumble=tumble, body=body,
        mount=mount or (), lever_arm=lever_arm or (), link_latency=link_latency or (),
        noise_accel=noise_accel,
        noise_gyro=noise_gyro, noise_mag=noise_mag, gyro_bias=gyro_bias,
        accel_noise_density=accel_noise_density, accel_random_walk=accel_random_walk,
        gyro_noise_density=gyro_noise_density, gyro_random_walk=gyro_random_walk,
        hard_iron=hard_iron, soft_iron=soft_iron, no_filter_model=no_filter_model,
        decimation=decimation, flags=flags, continuous_preset=continuous_preset,
        mode_preset=mode_preset, baud=baud,
        flip_rate=flip_rate, drop_rate=drop_rate, stall_every=stall_every, stall_for=stall_for,
        disconnect_every=disconnect_every, disconnect_for=disconnect_for, usb=usb,
        usb_serial=usb_serial, latency_timer=latency_timer,
        disconnect_power_cycles=disconnect_power_cycles, state=state, link=link,
        duration=duration).setup()
    simulator = setup.open(notify=lambda text: err.print(escape(text)))
    stop = {"now": False}

    def _interrupt(*_: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    with simulator:
        for endpoint in simulator.endpoints:
            print(endpoint, flush=True)
        for cfg in setup.configs:
            where = ""
            if cfg.motion.mounting is not None:
                turned = np.degrees(m_to_euler(cfg.motion.mounting.matrix))
                where = (", on the body turned ({:g}, {:g}, {:g})° at ({:g}, {:g}, {:g}) m"
                         .format(*turned.round(2), *cfg.motion.mounting.lever_arm_m))
            if cfg.link_latency_s:
                where += f", link +{cfg.link_latency_s * 1e3:g} ms"
            err.print(f"[dim]unit {escape(cfg.serial)}: clock {cfg.clock_ppm:+.1f} ppm, "
                      f"seed {cfg.motion.seed}{escape(where)}[/]")
        deadline = None if duration is None else time.monotonic() + duration
        while not stop["now"] and simulator.error is None:
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(0.05)
    if simulator.error is not None:
        raise fail(f"emulator stopped: {simulator.error}", FAILED)
    for slot in simulator.slots:
        u = slot.unit
        err.print(f"{escape(u.config.serial)}: {counted(u.records_sent, 'record')} sent, "
                  f"{number(u.records_skipped)} skipped (line busy), "
                  f"{counted(slot.lost, 'byte')} not delivered (no host connected, or host "
                  "not reading)")
