"""Operator actions on a unit: `gx3 info`, `configure`, `capture-bias`, `set-timer`,
`stationary-test`, `reset`.

Each works on a port directly (``--port``), or on running bridges over Zenoh
(``--unit NAME``, or a key expression such as ``'*'`` for the whole fleet) where
the bridge was started with ``--allow-commands``. A lasting change asks for
confirmation first (or takes ``--yes``).
"""

from __future__ import annotations

import functools
import inspect
import json
import sys
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar, cast, get_type_hints

import typer
from rich.console import Console
from rich.table import Table

from bridge.cli.common import app, err, fail, failing, parse_code
from bridge.device.actions import ACTIONS, run_action
from bridge.device.link import find_link
from bridge.device.port import Port
from bridge.device.session import Session, find_baud
from bridge.exceptions import DeviceError, PortError
from bridge.protocol.table import BAUD_RATES

PortOpt = Annotated[str, typer.Option(
    "--port", "-p", metavar="PORT",
    help="Device path or pyserial URL: /dev/ttyACM0, a pty, socket://HOST:PORT, "
         "rfc2217://HOST:PORT.")]
TargetPortOpt = Annotated[str | None, typer.Option(
    "--port", "-p", metavar="PORT",
    help="Act on the unit on this port: device path or pyserial URL (/dev/ttyACM0, a "
         "pty, socket://HOST:PORT, rfc2217://HOST:PORT).")]
UnitOpt = Annotated[str | None, typer.Option(
    "--unit", "-u", metavar="NAME|KEYEXPR",
    help="Instead of --port: act through running bridges over Zenoh; a unit name, or a "
         "key expression chunk such as '*' for every unit.")]
PrefixOpt = Annotated[str, typer.Option(help="Key prefix of the bridges (with --unit).")]
ZenohConfigOpt = Annotated[str | None, typer.Option(
    "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration (with --unit).")]
ConnectOpt = Annotated[list[str] | None, typer.Option(
    "--connect", metavar="ENDPOINT",
    help="Zenoh endpoint to connect to, e.g. tcp/10.0.0.2:7447 (with --unit; repeatable).")]
BaudOpt = Annotated[str, typer.Option(
    "--baud", metavar="RATE|auto",
    help="Baud rate the unit talks at now (115200 from the factory); auto tries the "
         "manual's rates.")]
YesOpt = Annotated[bool, typer.Option("--yes", "-y", help="Do not ask before a lasting "
                                      "change.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the result as JSON.")]


def parse_baud(text: str) -> int | None:
    """A baud rate the unit supports, or None for auto."""
    if text == "auto":
        return None
    if not text.isdigit() or int(text) not in BAUD_RATES:
        raise typer.BadParameter(f"--baud {text!r}: use auto or one of "
                                 + ", ".join(str(b) for b in BAUD_RATES))
    return int(text)


def _confirm(name: str, params: dict[str, Any], yes: bool) -> bool:
    if not ACTIONS[name].persists(params) or yes:
        return True
    if not sys.stdin.isatty():
        raise fail(f"{name} makes a lasting change to the unit; add --yes to confirm")
    return typer.confirm(f"{ACTIONS[name].summary}: this is a lasting change to the unit. "
                         "Continue?", default=False)


@dataclass(frozen=True)
class Target:
    """Where an action goes: a port, or bridges over Zenoh."""

    port: str | None
    baud: str
    unit: str | None
    prefix: str
    zenoh_config: str | None
    connect: list[str] | None


_TARGET_OPTIONS = [
    inspect.Parameter(name, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=default,
                      annotation=annotation)
    for name, default, annotation in [
        ("port", None, TargetPortOpt), ("baud", "115200", BaudOpt), ("unit", None, UnitOpt),
        ("prefix", "gx3", PrefixOpt), ("zenoh_config", None, ZenohConfigOpt),
        ("connect", None, ConnectOpt)]
]
Command = TypeVar("Command", bound=Callable[..., None])


def targeted(command: Command) -> Command:
    """Give an action command the options that say where it goes (--port, --baud,
    --unit, --prefix, --zenoh-config, --connect) and hand them to it as one ``target``."""
    hints = get_type_hints(command, include_extras=True)  # the options' Annotated metadata
    own = [p.replace(annotation=hints[p.name])
           for p in inspect.signature(command).parameters.values() if p.name != "target"]

    @functools.wraps(command)
    def with_target(**options: Any) -> None:
        target = Target(**{p.name: options.pop(p.name) for p in _TARGET_OPTIONS})
        command(target=target, **options)

    with_target.__signature__ = inspect.Signature([*_TARGET_OPTIONS, *own])  # type: ignore[attr-defined]
    with_target.__annotations__ = {p.name: p.annotation for p in [*_TARGET_OPTIONS, *own]}
    return cast(Command, with_target)


def _run(target: Target, name: str, params: dict[str, Any], yes: bool, as_json: bool) -> None:
    if (target.port is None) == (target.unit is None):
        raise fail("give either --port (a unit on a serial port) or --unit (running bridges "
                   "over Zenoh)")
    if not _confirm(name, params, yes):
        raise fail("cancelled; nothing was sent", 1)
    if target.unit is not None:
        _run_remote(target, name, params, as_json)
        return
    assert target.port is not None
    _run_local(target.port, target.baud, name, params, as_json)


def _run_remote(target: Target, name: str, params: dict[str, Any], as_json: bool) -> None:
    from bridge.bus.remote import ask_units
    from bridge.exceptions import RemoteError

    with failing(RemoteError):
        results = ask_units(target.prefix, target.unit or "*", name, params,
                            zenoh_config=target.zenoh_config, connect=target.connect or [])
    failed = False
    for unit, ok, result in results:
        if not as_json:
            Console().print(f"[bold]{unit}[/]")
        if ok:
            show(result, as_json)
        else:
            failed = True
            err.print(f"[red]{unit}:[/] {result.get('error', result)}")
    if failed:
        raise typer.Exit(1)


def _run_local(port_url: str, baud_text: str, name: str, params: dict[str, Any],
               as_json: bool) -> None:
    baud = parse_baud(baud_text)
    port = find_baud(port_url, 115_200)[0] if baud is None else Port.open(port_url, baud)
    with closing(port), failing(PortError, DeviceError):  # opened: the unit let us down
        session = Session(port)
        session.paced = find_link(port_url).transport != "usb"  # a serial line's pace
        session.quiesce()
        info = session.identify()
        result = run_action(name, session, info, params, confirmed=True)
    show(result, as_json)


def _for_people(key: str, value: Any) -> tuple[str, str] | None:
    """A result's entry as a person reads it (presets and records named, flags in hex),
    or None for one that says nothing here (no record streams on a port)."""
    from bridge.protocol.docs import mode_text, record_text

    if key == "firmware":
        return None  # its firmware_text says it as the manual writes versions
    if key == "firmware_text":
        return "firmware", str(value)
    if key == "record":
        return None if not value else ("streaming", record_text(value))
    if key == "continuous_preset":
        return key, record_text(value)
    if key == "mode_preset":
        return key, mode_text(value)
    if isinstance(value, dict):
        return key, ", ".join(f"{k}=0x{v:04X}" if k == "flags" else f"{k}={v}"
                              for k, v in value.items())
    return key, str(value)


def show(result: dict[str, Any], as_json: bool) -> None:
    """A result for people (a two-column table) or for programs (JSON, values as the
    unit gave them)."""
    if as_json:
        sys.stdout.write(json.dumps(result) + "\n")
        return
    table = Table(show_header=False, box=None, pad_edge=False)
    for key, value in result.items():
        entry = _for_people(key, value)
        if entry is not None:
            name, text = entry
            table.add_row(f"[bold yellow]{name}[/]" if name == "warning" else f"[bold]{name}[/]",
                          text)
    Console().print(table)


@app.command()
@targeted
def info(target: Target, as_json: JsonOpt = False) -> None:
    """Read a unit's firmware, ID strings, sampling settings and presets (changes nothing)."""
    _run(target, "info", {}, True, as_json)


@app.command()
@targeted
def configure(
    target: Target,
    decimation: Annotated[int | None, typer.Option(
        min=1, max=1000, help="Output rate = 1000 Hz / N.")] = None,
    flags: Annotated[str | None, typer.Option(
        help="0xDB data-conditioning flags, e.g. 0x0003 (bit 4: little-endian floats, "
             "bit 12: quaternion).")] = None,
    filter_width: Annotated[int | None, typer.Option(
        min=1, max=32, help="Accel/gyro moving-average width (delay (N-1)/2 ms).")] = None,
    mag_filter_width: Annotated[int | None, typer.Option(
        min=1, max=32, help="Magnetometer moving-average width.")] = None,
    up_compensation: Annotated[int | None, typer.Option(
        min=1, max=1000, help="Gravity correction time constant, s.")] = None,
    north_compensation: Annotated[int | None, typer.Option(
        min=1, max=1000, help="North correction time constant, s.")] = None,
    new_baud: Annotated[int | None, typer.Option(
        help="Switch the UART to this rate (115200, 230400, 460800, 921600).")] = None,
    mode_preset: Annotated[int | None, typer.Option(
        min=1, max=3, help="Stored wake-up mode: 1 active, 2 continuous, 3 idle "
                           "(lasting).")] = None,
    continuous_preset: Annotated[str | None, typer.Option(
        help="Stored continuous record, e.g. 0xCC (lasting).")] = None,
    persist: Annotated[bool, typer.Option(
        "--persist", help="Store sampling/baud changes in non-volatile memory.")] = False,
    yes: YesOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Change sampling settings, the baud rate or the stored presets.

    Sampling and baud changes are temporary unless --persist (on firmware before
    1.1.27 any sampling change is stored: that needs --persist too). Presets are
    always stored. Lasting changes ask for confirmation. A rate the serial line is
    too slow for (record bytes x rate above baud/10) is set, with a warning that
    says what to change.
    """
    if new_baud is not None and new_baud not in BAUD_RATES:
        raise fail(f"--new-baud {new_baud}: use one of " + ", ".join(map(str, BAUD_RATES)))
    params: dict[str, Any] = {
        "decimation": decimation, "flags": parse_code(flags) if flags else None,
        "filter_width": filter_width, "mag_filter_width": mag_filter_width,
        "up_compensation": up_compensation, "north_compensation": north_compensation,
        "baud": new_baud, "mode_preset": mode_preset,
        "continuous_preset": parse_code(continuous_preset) if continuous_preset else None,
        "persist": persist,
    }
    _run(target, "configure", params, yes, as_json)


@app.command("capture-bias")
@targeted
def capture_bias(
    target: Target,
    sampling_ms: Annotated[int, typer.Option(
        min=1, max=65_535, help="Averaging time, ms (the manual advises 10000-30000).")] = 10_000,
    persist: Annotated[bool, typer.Option(
        "--persist", help="Store the captured bias in non-volatile memory (0xD0).")] = False,
    yes: YesOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Capture the gyro bias (0xCD): keep the unit perfectly still while it samples."""
    err.print(f"[dim]sampling for {sampling_ms / 1000:g} s: keep the unit still…[/]")
    _run(target, "capture_bias", {"sampling_ms": sampling_ms, "persist": persist}, yes,
         as_json)


@app.command("set-timer")
@targeted
def set_timer(
    target: Target,
    value: Annotated[int, typer.Option(min=0, max=0xFFFF_FFFF,
                                       help="New timer value, ticks.")] = 0,
    as_json: JsonOpt = False,
) -> None:
    """Restart the unit's timer at a value (0xD7; not stored)."""
    _run(target, "set_timer", {"value": value}, True, as_json)


@app.command("stationary-test")
@targeted
def stationary_test(target: Target, as_json: JsonOpt = False) -> None:
    """Run the self-test (0xDA) on a still unit and print its flags."""
    _run(target, "stationary_test", {}, True, as_json)


@app.command()
@targeted
def reset(target: Target, yes: YesOpt = False, as_json: JsonOpt = False) -> None:
    """Soft-reset the unit (0xFE): it restarts from its stored settings."""
    _run(target, "reset", {}, yes, as_json)
