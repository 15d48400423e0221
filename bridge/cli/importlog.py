"""`gx3 import`: byte logs with no receive times (a data logger's) into an archive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

from bridge.cli.bridge import PrefixOpt
from bridge.cli.common import ForceOpt, app, err, fail, failing, written


@app.command("import")
def import_command(
    logs: Annotated[list[Path], typer.Argument(
        metavar="LOG", show_default=False,
        help="Byte logs of one unit, in the order they were written: what the unit sent, "
             "as a data logger, cat /dev/ttyUSB0 or a terminal program saved it.")],
    unit: Annotated[str, typer.Option(
        "--unit", "-u", metavar="NAME", help="The unit's name in the archive's keys.")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE.mcap",
        help="Archive to write; it appears when complete.")],
    start: Annotated[list[str] | None, typer.Option(
        metavar="TIME", help="The instant of the first log's first record: ISO 8601 with "
                             "its zone (2026-11-28T06:00:00Z, ...+02:00). Repeat it for a "
                             "unit reset in the logs: each further --start is the first "
                             "record's instant after the next reset, in order.")] = None,
    start_from_name: Annotated[str | None, typer.Option(
        metavar="PATTERN", help="Instead of --start: each log's start from its name "
                                "(without the extension), a strptime pattern such as "
                                "log_%Y%m%d_%H%M%S; UTC unless it has %z.")] = None,
    little_endian: Annotated[bool, typer.Option(
        "--little-endian", help="Floats start little-endian (0xDB flag bit 4 set); 0xDB "
        "replies in the logs switch the order from there on.")] = False,
    prefix: PrefixOpt = "gx3",
    force: ForceOpt = False,
) -> None:
    """Import byte logs with no receive times into an archive, timed by the unit's timer.

    The unit's timer is the only clock: each sample's time_ns is the start plus the
    unit's time since its first record, less its filter delay (from a 0xDB reply in the
    logs, else the factory's width 15), as everywhere else. Every record of every data
    type is kept; rollovers are unwrapped, a jump forward by more than the output period
    (from a 0xDB reply, else the timer's own steps) is a gap (GAP event, with the records
    lost), a record whose corrupt timer the next one belies is dropped (GLITCH), and a
    timer that goes back is a reset: it starts a new epoch at the next --start, or at the
    start of the log it begins (--start-from-name); with neither it is refused, since no
    byte tells when it came. The archive's metadata says that no host clock timed it
    (host_clock none), and gx3 export, rrd, calibrate-mag, allan and --format ros2 read
    it as any archive.
    """
    from bridge.exceptions import LogImportError
    from bridge.ingest.bytelog import LogFile, import_logs, name_time, parse_start

    if start and start_from_name is not None:
        raise fail("give --start or --start-from-name, not both")
    if not start and start_from_name is None:
        raise fail("give the first record's instant: --start TIME, or --start-from-name "
                   "PATTERN for logs named by time")
    for log in logs:
        if not log.is_file():
            raise fail(f"{log}: no such file; give the byte logs of one unit")
    starts = [parse_start(text) for text in start or ()]
    if start_from_name is not None:
        files = [LogFile(log, name_time(log, start_from_name)) for log in logs]
    else:
        files = [LogFile(logs[0], starts[0]), *map(LogFile, logs[1:])]
    total = sum(log.stat().st_size for log in logs)
    progress = Progress(TextColumn("importing"), BarColumn(), DownloadColumn(), console=err,
                        transient=True, disable=not err.is_terminal)
    with written(output, logs, force, suffixes=(".mcap",)) as temp, \
            failing(OSError, unless=(LogImportError,), temp=temp, path=output), progress:
        task = progress.add_task("import", total=total)
        done = import_logs(files, temp, unit, prefix, little_endian,
                           lambda n: progress.advance(task, n), restarts=starts[1:])
    err.print(done.text(), highlight=False)
    err.print(f"wrote {output}", highlight=False)
