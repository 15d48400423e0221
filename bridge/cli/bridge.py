"""`gx3 bridge`: one process per unit, every sample typed, timed and on Zenoh."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import Annotated

import typer

from bridge.cli.common import (
    FAILED,
    ForceOpt,
    LogFormat,
    LogFormatOpt,
    LogLevel,
    LogLevelOpt,
    MetricsOpt,
    app,
    err,
    fail,
    log_to,
    parse_code,
    refused,
)
from bridge.cli.operate import BaudOpt, PortOpt, parse_baud
from bridge.protocol.table import BAUD_RATES, DATA_CODES

ZenohConfigOpt = Annotated[Path | None, typer.Option(
    "--zenoh-config", metavar="FILE",
    help="Zenoh JSON5 configuration (mode, endpoints, scouting, TLS, access control); "
         "the flags below override it. Default: Zenoh's own (a peer that finds others by "
         "multicast scouting). configs/ has examples.")]
ConnectOpt = Annotated[list[str] | None, typer.Option(
    "--connect", metavar="ENDPOINT", help="Zenoh endpoint to connect to, e.g. "
    "tcp/192.168.1.10:7447 (repeatable).")]
ListenOpt = Annotated[list[str] | None, typer.Option(
    "--listen", metavar="ENDPOINT", help="Zenoh endpoint to listen on, e.g. "
    "tcp/0.0.0.0:7447 (repeatable).")]
ModeOpt = Annotated[str | None, typer.Option(
    "--mode", metavar="peer|client", help="Zenoh session mode.")]
PrefixOpt = Annotated[str, typer.Option(help="First chunk of every key.")]


@app.command("bridge")
def run_bridge(
    port: PortOpt,
    baud: BaudOpt = "115200",
    unit: Annotated[str | None, typer.Option(
        help="Unit name in the keys (gx3/NAME/imu). Default: the unit's serial number. "
             "Refused (exit 2) while another running bridge holds the name.")] = None,
    prefix: PrefixOpt = "gx3",
    record: Annotated[str | None, typer.Option(
        help="Record to stream, e.g. 0xCC. Default: the unit's continuous preset, else "
             "0xCC (accel, ang_rate, mag, M).")] = None,
    decimation: Annotated[int | None, typer.Option(
        min=1, max=1000, help="Set the output rate to 1000 Hz / N (not stored unless "
                              "--persist).")] = None,
    flags: Annotated[str | None, typer.Option(
        help="Set the 0xDB data-conditioning flags, e.g. 0x1003 for quaternions.")] = None,
    filter_width: Annotated[int | None, typer.Option(
        min=1, max=32, help="Set the accel/gyro filter width.")] = None,
    mag_filter_width: Annotated[int | None, typer.Option(
        min=1, max=32, help="Set the magnetometer filter width.")] = None,
    new_baud: Annotated[int | None, typer.Option(
        help="Switch the unit's UART to this rate after bring-up (reply checked at the "
             "old rate; falls back if the unit stops answering).")] = None,
    persist: Annotated[bool, typer.Option(
        "--persist", help="Store the settings asked for above in the unit's non-volatile "
                          "memory (needed on firmware before 1.1.27 for any change).")] = False,
    poll: Annotated[float | None, typer.Option(
        min=0.1, max=1000, metavar="HZ",
        help="Ask for each record at this rate instead of continuous mode.")] = None,
    transport: Annotated[str, typer.Option(
        metavar="auto|uart|usb|usb-serial",
        help="Link between unit and host, for the latency floor and frame clock the clock "
             "model takes out: uart (line time of each record at the baud rate), usb (the "
             "unit's own USB port, 1 ms frames), usb-serial (its serial port through a "
             "USB-serial adapter: line time, then 1 ms frames; its latency timer is read "
             "from /sys/bus/usb-serial for the bring-up line and the unit's Info, and one "
             "above 1 ms is warned about, with the fix), auto (usb for /dev/ttyACM*, "
             "usb-serial for /dev/ttyUSB*, also "
             "through /dev/serial/by-id links; uart otherwise). The bring-up line says "
             "which link was found.")] = "auto",
    max_latency_ms: Annotated[float, typer.Option(
        "--max-latency-ms", min=1.0, max=1000.0, metavar="MS",
        help="Latency budget: the longest a byte may wait between reaching the port and "
             "its samples going out on Zenoh. 1 (the default): every read is framed, "
             "timed and published at once. Above 1, reads gather: after each read the "
             "bridge lets bytes collect for MS - 1 ms (1 ms is kept for framing, timing "
             "and the puts) and publishes the records it then finds together: fewer "
             "wake-ups, puts sent in bursts, less CPU. No sample is lost; none waits past "
             "the budget unless the host stalls the bridge.")] = 1.0,
    capture: Annotated[Path | None, typer.Option(
        metavar="FILE.mcap", help="Also record every read raw, with its receive time "
                                  "(an existing file is refused unless --force).")] = None,
    force: ForceOpt = False,
    metrics: MetricsOpt = None,
    publish_raw: Annotated[bool, typer.Option(
        "--publish-raw", help="Also publish every read on PREFIX/UNIT/raw with its receive "
                              "time, for gx3 record --raw.")] = False,
    ros2: Annotated[bool, typer.Option(
        "--ros2", help="Also publish every sample as ROS 2 does over rmw_zenoh_cpp: "
                       "sensor_msgs/Imu on /PREFIX/UNIT/imu and MagneticField on "
                       "/PREFIX/UNIT/mag (names made ROS-legal: imu-1 becomes imu_1), seen "
                       "by ROS 2 nodes on the same Zenoh router.")] = False,
    ros2_domain: Annotated[int | None, typer.Option(
        "--ros2-domain", min=0, max=232, metavar="N",
        help="ROS_DOMAIN_ID of the --ros2 topics. Default: 0.")] = None,
    ros2_distro: Annotated[str | None, typer.Option(
        "--ros2-distro", metavar="humble|jazzy",
        help="ROS 2 distribution of the --ros2 subscribers: their rmw_zenoh's keys and "
             "graph tokens carry the message's RIHS01 type hash on jazzy and the word "
             "TypeHashNotSupported on humble, so a node of the other one never matches. "
             "Default: jazzy.")] = None,
    noise: Annotated[Path | None, typer.Option(
        "--noise", metavar="IMU.yaml",
        help="The unit's measured noise, Kalibr's imu.yaml (gx3 allan writes one): each "
             "--ros2 Imu's angular_velocity_covariance and linear_acceleration_covariance "
             "diagonals become noise density² x 1000 Hz / min(D, M), D the unit's "
             "decimation and M its filter width as brought up (density² x the output "
             "rate while D ≤ M; not the file's update_rate). Without it they are 0, which "
             "sensor_msgs/Imu reads as unknown. A file without "
             "accelerometer_noise_density, accelerometer_random_walk, "
             "gyroscope_noise_density, gyroscope_random_walk and update_rate is refused "
             "(exit 2).")] = None,
    orientation_stddev: Annotated[float | None, typer.Option(
        "--orientation-stddev", metavar="RAD", min=0.0,
        help="Standard deviation of the unit's orientation about each axis, in radians: "
             "the orientation_covariance diagonal of every --ros2 Imu that carries an "
             "orientation becomes its square (the manual states no attitude accuracy; "
             "without it the covariance is 0, unknown, as REP-145 has it). Records "
             "without an orientation keep -1 in element 0.")] = None,
    allow_commands: Annotated[bool, typer.Option(
        "--allow-commands", help="Carry out operator commands that arrive over Zenoh "
                                 "(gx3 configure --unit …); refused otherwise.")] = False,
    cache: Annotated[float, typer.Option(
        min=0.0, metavar="SECONDS",
        help="Seconds of samples kept for subscribers that lose their link.")] = 10.0,
    zenoh_config: ZenohConfigOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    mode: ModeOpt = None,
    duration: Annotated[float | None, typer.Option(
        min=0.0, help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    give_up_after: Annotated[float | None, typer.Option(
        min=0.0, metavar="SECONDS",
        help="Exit (status 1) if the unit has not come up this many seconds after the "
             "start (0: after the first failed try). Default: keep retrying until "
             "stopped.")] = None,
    quiet: Annotated[bool, typer.Option(
        "--quiet", "-q", help="Print errors only (and why the unit is not up).")] = False,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Bridge one unit onto Zenoh: bring it up, stream, time every sample, publish.

    A port that is missing or busy, or a unit that does not answer, is retried with
    pauses growing to 5 s; the reason is printed once, and again when it changes.
    Exit status: 0 when stopped after the unit came up; 1 when it never came up
    (stopped, --duration or --give-up-after first) or on an internal error; 2 for
    bad options or a Zenoh configuration that does not open.

    Publishes gx3.v1 protobuf messages under PREFIX/UNIT/: imu (every sample),
    status (once a second), event (gaps, resets, rollovers, reconnects), the info
    queryable, a liveliness token, and with --publish-raw each read (raw); every
    message carries the CRC-32 of its payload in its attachment. With --ros2 the
    samples also go out as ROS 2 messages (REP-103 frames: body FLU, world ENU) on
    rmw_zenoh's keys (Jazzy's, or Humble's with --ros2-distro humble), with its
    attachments (sequence, time, GID: what ROS 2 reads) and graph tokens; --noise gives
    their Imu messages covariances measured on the unit, --orientation-stddev one for
    the orientation. Keeps
    streaming through pulled cables and resets. Ctrl-C or SIGTERM stop continuous
    mode and close the port.

    Events are printed as they happen, gaps summed into a line every 5 s at most
    (each stays an event of its own on the bus). Bring-up names the link it found
    (uart, usb, or usb-serial with the adapter's latency timer), warns when the serial
    line is too slow for the record at its rate, and once when an adapter's latency
    timer holds reads back longer than 1 ms, and says what to change.
    """
    log_to(log_level, log_format)
    from bridge.bus.keys import check_prefix, check_unit
    from bridge.timing.stream import TRANSPORTS
    from bridge.unit.pipeline import Options

    code = parse_code(record) if record else None
    if code is not None and code not in DATA_CODES:
        raise fail(f"--record 0x{code:02X} is not a data record; use one of "
                   + " ".join(f"0x{c:02X}" for c in sorted(DATA_CODES)))
    if new_baud is not None and new_baud not in BAUD_RATES:
        raise fail(f"--new-baud {new_baud}: use one of " + ", ".join(map(str, BAUD_RATES)))
    for given, name in ((ros2_domain, "--ros2-domain"), (ros2_distro, "--ros2-distro"),
                        (noise, "--noise"), (orientation_stddev, "--orientation-stddev")):
        if given is not None and not ros2:
            raise fail(f"{name} is for the --ros2 topics: add --ros2")
    ros2_options = None
    if ros2:
        from bridge.ros2.noise import read_noise
        from bridge.ros2.options import Ros2Options

        measured = None if noise is None else read_noise(noise)  # exit 2 if unusable
        try:
            ros2_options = Ros2Options(ros2_domain or 0, ros2_distro or "jazzy", measured,
                                       orientation_stddev)
        except ValueError as exc:  # a distribution that is not one
            raise fail(f"--ros2-distro: {exc}") from None
    if transport not in ("auto", *TRANSPORTS):
        raise fail(f"--transport {transport!r}: use auto, " + ", ".join(TRANSPORTS))
    check_prefix(prefix)
    if unit is not None:
        check_unit(unit)
    if capture is not None:
        refused(capture, force=force, suffixes=(".mcap",))
    options = Options(url=port, baud=parse_baud(baud), record=code, decimation=decimation,
                      flags=parse_code(flags) if flags else None, filter_width=filter_width,
                      mag_filter_width=mag_filter_width, new_baud=new_baud, persist=persist,
                      poll_hz=poll, transport=transport, max_latency_s=max_latency_ms / 1000)
    stop = threading.Event()

    def _stop(*_: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    from bridge.bus.session import ZenohOptions
    from bridge.unit.run import UnitBridge

    bridge = UnitBridge(
        options, prefix, unit, ZenohOptions(zenoh_config, connect or [], listen or [], mode),
        allow_commands, cache, quiet=quiet, publish_raw=publish_raw,
        ros2=ros2_options, capture=capture, force=force, metrics=metrics,
        on_capture_error=lambda exc: err.print(f"[red]error:[/] {exc}"),
        on_capture_stopped=lambda exc: err.print(f"[yellow]capture stopped:[/] {exc}"))
    outcome = bridge.run(stop, duration, give_up_after)
    if outcome.internal_error is not None:
        error = outcome.internal_error
        raise fail(f"the bridge stopped on an internal error: {type(error).__name__}: {error}",
                   FAILED)
    if not outcome.came_up:
        why = outcome.last_failure or "stopped before the first try ended"
        if outcome.gave_up:
            why += f" (gave up after {give_up_after:g} s)"
        raise fail(f"no unit came up on {port}; the last try: {why}", FAILED)
    if not quiet:
        err.print(outcome.summary)
