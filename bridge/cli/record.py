"""`gx3 record`: every unit on Zenoh into one MCAP archive, with a live view."""

from __future__ import annotations

import functools
import signal
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Group
from rich.live import Live
from rich.markup import escape
from rich.progress import Progress, TextColumn
from rich.table import Table

from bridge._text import counted, number
from bridge.cli.bridge import ConnectOpt, ListenOpt, ModeOpt, PrefixOpt, ZenohConfigOpt
from bridge.cli.common import (
    FAILED,
    ForceOpt,
    LogFormat,
    LogFormatOpt,
    LogLevel,
    LogLevelOpt,
    MetricsOpt,
    app,
    duration_text,
    err,
    fail,
    failing,
    log_to,
    written,
)

if TYPE_CHECKING:
    from bridge.bus.gx3_pb2 import HostClock
    from bridge.recorder.hosts import HostView
    from bridge.recorder.units import UnitRow


def unit_table(rows: Sequence[UnitRow], title: str) -> Table:
    """The units as a recorder sees them (``Recorder.snapshot``), in 80 columns: offset
    is how far each unit's clock offset moved since its first clock model (the offset
    itself is an instant)."""
    table = Table(title=title, title_justify="left", box=None, pad_edge=False, padding=(0, 1),
                  collapse_padding=True)
    for name, justify in (("unit", "left"), ("state", "left"), ("rate/s", "right"),
                          ("samples", "right"), ("drops", "right"), ("crc", "right"),
                          ("offset\nms", "right"), ("drift\nppm", "right"),
                          ("time", "right"), ("MB", "right")):
        table.add_column(name, justify=justify, no_wrap=True,  # type: ignore[arg-type]
                         overflow="ellipsis" if name == "unit" else "fold")
    for r in rows:
        table.add_row(
            r.unit, "[green]live[/]" if r.alive else "[red]gone[/]", f"{r.rate:,.0f}",
            f"{r.samples:,}", f"{r.dropped:,}", f"{r.checksum_failures:,}",
            "–" if r.offset_ms is None else f"{r.offset_ms:+.2f}",
            "–" if r.drift_ppm is None else f"{r.drift_ppm:+.1f}",
            duration_text(r.recorded_s), f"{r.bytes / 1e6:,.1f}")
    if not rows:
        table.add_row("[dim]waiting for units…[/]", *[""] * 9)
    return table


def _ms(ns: float) -> str:
    """A clock difference: to 10 µs where it is small, in seconds where it is huge."""
    if abs(ns) < 1e7:
        return f"{ns / 1e6:.2f} ms"
    return f"{ns / 1e6:,.0f} ms" if abs(ns) < 1e10 else f"{ns / 1e9:,.0f} s"


def _bound(bound_ns: int | None, tolerance_ns: int | None) -> str:
    """What a host's clock bound says: how far behind the recorder it can be at most, or
    (red) how far ahead it is at least; yellow beyond the tolerance."""
    from bridge.recorder.hosts import ahead

    if bound_ns is None:
        return "[dim]no samples yet[/]"
    if ahead(bound_ns):
        return f"[red]ahead by ≥ {_ms(-bound_ns)}[/]"
    text = f"{_ms(max(bound_ns, 0))} behind at most"
    return f"[yellow]{text}[/]" if tolerance_ns is not None and bound_ns > tolerance_ns else text


def _sync(state: HostClock | None) -> str:
    """A host's sync state as its kernel reports it, in a few words."""
    if state is None or not state.known:
        return "[dim]unknown[/]"
    if not state.synchronised:
        return "[red]not synchronised[/]"
    return f"synced ±{_ms(state.estimated_error_ns)}"


def _hosts_table(hosts: Sequence[HostView], tolerance_ns: int | None, whole: bool) -> Table:
    """Each bridge host's clock against the recorder's: over the last seconds while
    recording, over the whole recording at the end. Fits 80 columns."""
    from bridge.recorder.hosts import HOST_WINDOW_S

    over = "over the recording" if whole else f"last {HOST_WINDOW_S} s"
    table = Table(title=f"bridge hosts' clocks against the recorder's ({over})",
                  title_justify="left", box=None, pad_edge=False)
    for name, width in (("host", 14), ("units", 12), ("clock", 26), ("sync", 17)):
        table.add_column(name, max_width=width, no_wrap=True, overflow="ellipsis")
    for h in hosts:
        table.add_row(escape(h.host) or "[dim]unnamed[/]", escape(", ".join(h.units)),
                      _bound(h.whole_ns if whole else h.bound_ns, tolerance_ns),
                      _sync(h.clock))
    return table


@app.command("record")
def record(
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", metavar="FILE.mcap",
        help="Archive to write (default: gx3-DATE-TIME.mcap here). An existing file is "
             "refused unless --force; one another recorder is writing, always.")] = None,
    units: Annotated[str, typer.Option(
        metavar="KEYEXPR", help="Units to record: a name, or a key expression chunk "
                                "such as '*' (every unit) or 'lab-*'.")] = "*",
    prefix: PrefixOpt = "gx3",
    raw: Annotated[bool, typer.Option(
        "--raw", help="Also record each unit's raw reads where its bridge publishes them "
                 "(gx3 bridge --publish-raw); gx3 replay takes the archive.")] = False,
    history: Annotated[int, typer.Option(
        min=0, help="Ask each bridge's cache for this many past samples on joining.")] = 0,
    max_host_offset_ms: Annotated[float | None, typer.Option(
        metavar="MS",
        help="Tolerance, in ms (above 0): warn, and archive a HOST_CLOCK_OFFSET event "
             "for each of its units, when a bridge host's clock may be behind the "
             "recorder's by more than this, i.e. none of its samples of the last 10 s "
             "arrived sooner than this after the instant it was stamped with (a network "
             "that slow is told the same way). Told once, again only after the host was "
             "back within the tolerance by 0.1 ms. A host provably ahead of the "
             "recorder by more than 0.1 ms is told whether or not this is given. "
             "Default: no tolerance.")] = None,
    rrd: Annotated[Path | None, typer.Option(
        metavar="FILE.rrd", help="Also write a Rerun recording as the archive is recorded (an "
                                 "existing one only with --force).")]
    = None,
    rrd_max_rate: Annotated[float | None, typer.Option(
        metavar="HZ",
        help="Thin --rrd for a recording that runs for days: each plotted line as the least "
             "and the greatest value of each 1/HZ s bin, at the instants they happened, "
             "attitude at HZ; status and events whole (the archive keeps every sample). "
             "Lines reach the file 128 bins at a time (2 min at 1 Hz). Default: every "
             "sample.")] = None,
    split_mb: Annotated[float | None, typer.Option(
        min=1.0, help="Start a new numbered file (FILE_0001.mcap, FILE_0002.mcap, ...) when "
                      "one reaches this size, MB. Numbers go on after the parts already "
                      "there: a restarted recorder adds parts, never replaces one.")] = None,
    split_minutes: Annotated[float | None, typer.Option(
        min=0.1, help="Start a new numbered file after this many minutes (numbered as "
                      "--split-mb).")] = None,
    duration: Annotated[float | None, typer.Option(
        min=0.0, help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q",
                                        help="No live view; errors and warnings only.")]
    = False,
    force: ForceOpt = False,
    metrics: MetricsOpt = None,
    zenoh_config: ZenohConfigOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    mode: ModeOpt = None,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Record every unit's samples, status, events and info into one MCAP archive.

    Units are found by their bridges' liveliness tokens and may join late, leave and
    come back. Samples keep the very protobuf bytes from Zenoh, with the schemas
    embedded. Each unit also gets a foxglove.FrameTransform channel (REP-103 frames:
    gx3_world east-north-up, gx3_world_ned, gx3_<unit>_frd) with a point cloud of its
    body axes, and every event is also a foxglove.Log on <prefix>/log: Foxglove's 3D
    and Log panels show them with no plugin, and `rerun FILE.mcap` opens a 3-D view of
    each unit's axes beside a text log of the events (it plots no samples: `gx3 rrd`
    renders those). Messages are written in log-time order: each
    waits half a second for any logged before it, and the file is flushed every
    second, so a crash loses at most the last 1.5 s (`gx3 repair` finishes such a
    file). Ctrl-C or SIGTERM finish the archive properly. Each file is locked while it
    is written: a second recorder given the same file is refused at once, naming the
    first one's process.

    Every message is checked before it is archived (the CRC-32 in its attachment, its
    unit against its key). What does not reach the archive (samples lost in transit,
    messages rejected, samples shed while the disk could not keep up) and a unit
    published by two bridges at once are archived as events of the unit, with count
    and span, and printed as warnings.

    Each bridge host's clock is compared with the recorder's: a sample cannot arrive
    before the instant it was stamped with, so the least of (arrival - time_ns) is the
    most the host can be behind, and a negative one proves it ahead. The live view and
    the summary show it per host with the host's sync state; a host ahead by more than
    0.1 ms (or behind beyond --max-host-offset-ms) is archived as a HOST_CLOCK_OFFSET
    event of each of its units, once until it clears. The recorder's host and sync
    state go into the archive's metadata (gx3.archive), and each host's bound over the
    whole recording into gx3.hosts at the end.
    """
    log_to(log_level, log_format)
    from bridge.archive.outputs import named_format
    from bridge.bus.keys import check_prefix
    from bridge.bus.session import ZenohOptions
    from bridge.recorder.hosts import host_tolerance_ns
    from bridge.recorder.recording import Recording

    check_prefix(prefix)
    try:
        host_tolerance_ns(max_host_offset_ms)
    except ValueError as exc:
        raise fail(f"--max-host-offset-ms {exc}") from None
    for given, suffix in ((output, ".mcap"), (rrd, ".rrd")):
        if given is not None:
            named_format(given, suffix)
    path = output or Path(time.strftime("gx3-%Y%m%d-%H%M%S.mcap"))
    table = not quiet and log_format is LogFormat.text  # the live table is for people
    rrd_writer = None
    if rrd_max_rate is not None:
        from bridge.viz.thin import bin_width_ns

        if rrd is None:
            raise fail("--rrd-max-rate thins the Rerun recording: give --rrd FILE.rrd too")
        try:
            bin_width_ns(rrd_max_rate)
        except ValueError as exc:
            raise fail(f"--rrd-max-rate: {exc}") from None
    if rrd is not None:  # Rerun loads only for a recording that writes one
        from bridge.viz.sources import RrdWriter

        rrd_writer = functools.partial(RrdWriter, prefix=prefix, max_rate_hz=rrd_max_rate)

    def announce(unit: str, joined: bool) -> None:
        if not quiet:
            err.print(f"[dim]{time.strftime('%H:%M:%S')}[/] {unit} "
                      + ("[green]joined[/]" if joined else "[red]left[/]"))

    recording = Recording(
        path, ZenohOptions(zenoh_config, connect or [], listen or [], mode), prefix=prefix,
        units=units, raw=raw, history=history, max_host_offset_ms=max_host_offset_ms,
        split_bytes=None if split_mb is None else int(split_mb * 1e6),
        split_seconds=None if split_minutes is None else split_minutes * 60, force=force,
        rrd=rrd, rrd_writer=rrd_writer, metrics=metrics, on_unit=announce,
        on_event=lambda unit, event: err.print(
            f"[yellow]warning:[/] {event.detail}", highlight=False, soft_wrap=True))
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())

    def view(whole: bool = False) -> Group:
        """The units' table, and the hosts' once there are any (their clocks over the
        whole recording when ``whole``)."""
        recorder = recording.recorder
        hosts = recorder.hosts()
        title = (f"recording {path} · {duration_text(recording.elapsed_s)} · "
                 f"{recorder.written:,} messages")
        return Group(unit_table(recorder.snapshot(), title),
                     *([_hosts_table(hosts, recorder.max_host_offset_ns, whole)]
                       if hosts else []))

    with recording, Live(console=err, refresh_per_second=2, transient=True,
                         auto_refresh=False) as live:
        recording.run(stop, duration,
                      every=(lambda: live.update(view(), refresh=True)) if table else None)
    if recording.error is not None:
        raise fail(str(recording.error), FAILED)
    if table:
        err.print(view(whole=True))
    if not quiet:
        files = ", ".join(str(p) for p in recording.paths)
        err.print(f"wrote {files}; {counted(recording.recorder.misses, 'sample')} reported "
                  "lost in transit")
    err.file.flush()


@app.command("replay")
def replay_command(
    captures: Annotated[list[Path], typer.Argument(
        metavar="CAPTURE.mcap", help="Raw captures (gx3 bridge --capture, or archives "
                                        "recorded with --raw).")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="ARCHIVE.mcap",
        help="Archive to write; it appears when complete (nothing is left there if the "
             "replay fails or is interrupted).")],
    prefix: PrefixOpt = "gx3",
    jobs: Annotated[int, typer.Option(
        "--jobs", "-j", min=0, help="Processes replaying at once, a capture file each (a unit "
                                    "each when there are fewer files); 0: one per core.")] = 0,
    force: ForceOpt = False,
    transport: Annotated[str | None, typer.Option(
        metavar="uart|usb|usb-serial",
        help="Time every unit as linked this way (a UART; the unit's own USB port; a "
             "USB-serial adapter), whatever a capture's metadata says or its receive "
             "times show.")] = None,
) -> None:
    """Run raw captures through the bridge's framer and timing into an archive, no Zenoh.

    Gives the samples and live time_ns the bridge published when the capture was
    made. A capture from another program is understood from its bytes: record type,
    rate and float byte order; and its link from its receive times (reads crowding
    just after the host's 1 ms USB frames, reads ending mid-record, their spacing
    against the serial line's byte time: UART, the unit's own USB port, or a
    USB-serial adapter with a 1 or 16 ms latency timer). What was inferred is said on
    the unit's line. Units are replayed side by side on the machine's cores; each
    unit's samples are the same as replayed alone.
    """
    from bridge.exceptions import ArchiveError, ReplayError, UnusableCapture
    from bridge.ingest.replay import Replayed, replay
    from bridge.timing.stream import TRANSPORTS

    if transport is not None and transport not in TRANSPORTS:
        raise fail(f"--transport {transport!r}: use " + ", ".join(TRANSPORTS))

    for path in captures:
        if not path.is_file():
            raise fail(f"{path}: no such file; give a raw capture (gx3 bridge --capture)")

    # refreshed here, not by Rich's thread: replay forks its workers after this starts
    progress = Progress(TextColumn("replaying"), TextColumn("{task.completed:,.0f} samples"),
                        TextColumn("{task.fields[done]} done"), console=err,
                        transient=True, auto_refresh=False, disable=not err.is_terminal)
    task = progress.add_task("replay", total=None, units=0, done=counted(0, "unit"))
    shown = [0.0]

    def report(result: Replayed) -> None:
        events = ", ".join(f"{number(n)} {kind}" for kind, n in sorted(result.events.items()))
        guessed = f" (inferred: {', '.join(result.inferred)})" if result.inferred else ""
        progress.console.print(f"{result.unit}: {counted(result.samples, 'sample')}"
                               + (f", {events}" if events else "") + guessed)
        units = progress.tasks[0].fields["units"] + 1
        progress.update(task, units=units, done=counted(units, "unit"), refresh=True)

    def advance(samples: int) -> None:
        progress.advance(task, samples)
        if time.monotonic() - shown[0] >= 0.2:
            shown[0] = time.monotonic()
            progress.refresh()

    with written(output, captures, force, suffixes=(".mcap",)) as temp, \
            failing(ReplayError, ArchiveError, unless=(UnusableCapture,), temp=temp,
                    path=output), progress:
        results = replay(captures, temp, prefix, on_unit=report, jobs=jobs or None,
                         on_samples=advance, transport=transport)
    err.print(f"wrote {output}: {counted(sum(r.samples for r in results), 'sample')} of "
              f"{counted(len(results), 'unit')}")
