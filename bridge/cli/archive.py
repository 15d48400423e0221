"""`gx3 repair` and `gx3 export`: make an unfinished archive whole, turn one into a table."""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

from bridge.cli.common import EndOpt, ForceOpt, StartOpt, app, err, fail, parse_code, written

if TYPE_CHECKING:
    from bridge.recorder.reader import ArchiveReader

# The recorder modules (pyarrow, protobuf schemas) load only when these commands run, so
# every other gx3 command starts as fast as before.


def read_with_progress(path: Path) -> ArchiveReader:
    """Read an archive with progress on a terminal; warn once when it was cut short."""
    from bridge.recorder.reader import describe_problem, read_archive

    size = path.stat().st_size if path.is_file() else None
    progress = Progress(TextColumn("reading"), BarColumn(), DownloadColumn(), console=err,
                        transient=True, disable=not err.is_terminal)
    with progress:
        task = progress.add_task("read", total=size)
        archive = read_archive(path, lambda done: progress.update(task, completed=done))
    if not archive.message_count:
        raise ValueError(f"{path}: nothing readable in it ({archive.problem or 'no messages'})"
                         "; is it an archive written by gx3?")
    problem = describe_problem(archive)
    if problem:
        err.print(f"[yellow]warning:[/] {problem}; `gx3 repair` makes a finished copy")
    return archive


@app.command()
def repair(
    file: Annotated[Path, typer.Argument(
        help="Archive whose recorder did not finish it, or with a damaged chunk.")],
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", help="Repaired archive (default: FILE.repaired.mcap); it appears "
                               "when complete.")] = None,
    force: ForceOpt = False,
) -> None:
    """Rebuild a finished, indexed archive from one cut short (a killed recorder) or
    damaged (a corrupt chunk).

    Every schema, channel, metadata record and message of every intact chunk is
    copied into a new file with its index and summary: a file cut short up to its last
    complete chunk, the rest dropped and counted; in a finished file a chunk that fails
    its CRC is skipped (found again by the summary's chunk index) and what it held is
    said (time span, messages per topic). Exits 2 when nothing can be recovered. The
    input is never overwritten.
    """
    from bridge.exceptions import ArchiveError, ArchiveReadError
    from bridge.recorder.repair import default_output
    from bridge.recorder.repair import repair as repair_archive

    output = default_output(file) if output is None else output
    with written(output, [file], force) as temp:
        try:
            report = repair_archive(file, temp)
        except ArchiveReadError as exc:
            raise fail(str(exc)) from None
        except ArchiveError as exc:
            raise fail(str(exc).replace(str(temp), str(output)), 1) from None
    typer.echo(replace(report, output=output).text())


@app.command()
def export(
    archive: Annotated[Path, typer.Argument(help="Archive (.mcap) written by gx3.")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE", help="File to write: a .parquet or .csv table, or a "
                                               ".mcap ROS 2 bag (--format ros2); it appears "
                                               "when complete.")],
    output_format: Annotated[str | None, typer.Option(
        "--format", metavar="FORMAT",
        help="parquet, csv or ros2 (sensor_msgs/Imu and MagneticField in an MCAP bag that "
             "ros2 bag play reads). Default: from the output's extension (.mcap: ros2).")
    ] = None,
    unit: Annotated[list[str] | None, typer.Option(
        "--unit", "-u", metavar="NAME",
        help="Only this unit (repeatable). Default: every unit.")] = None,
    record_type: Annotated[list[str] | None, typer.Option(
        "--type", "-t", metavar="CODE",
        help="Only records of this command, e.g. 0xCC (repeatable).")] = None,
    start: StartOpt = None,
    end: EndOpt = None,
    align: Annotated[float | None, typer.Option(
        metavar="RATE",
        help="Resample every unit onto one time grid at RATE Hz: one row per instant, "
             "columns named <unit>__<column> (the unit name lower-cased, characters other "
             "than a-z 0-9 _ made _, unit_ before one that starts with no letter; a Parquet "
             "file's gx3.units metadata names each unit's prefix); linear for vectors, "
             "slerp for orientation, empty (null) outside a unit's samples and inside "
             "gaps. Tables only.")] = None,
    events: Annotated[Path | None, typer.Option(
        metavar="FILE",
        help="Also write every event (gap, reset, rollover, reconnect, ...) per unit with "
             "its time to this .parquet or .csv file: unit, time_ns, time_utc, ticks, "
             "kind, amount (records dropped for a GAP, bytes skipped for a RESYNC, "
             "messages for LOST, REJECTED and SHED, else 1), detail.")] = None,
    mag_cal: Annotated[list[Path] | None, typer.Option(
        "--mag-cal", metavar="FILE",
        help="Iron calibration (JSON) of one unit from gx3 calibrate-mag (repeatable, one "
             "per unit): that unit's mag and stab_mag become the corrected readings, "
             "soft_iron @ (raw - hard_iron); a table gains mag_heading, the tilt-compensated "
             "heading from accel and the corrected mag, beside the unit's own yaw; a "
             "Parquet file records each calibration in its gx3.mag_cal metadata.")] = None,
    force: ForceOpt = False,
) -> None:
    """Export samples to Parquet or CSV, one row per sample, every unit on one timeline,
    or to a ROS 2 bag.

    Columns: unit, command, timer, ticks, time_ns (ns since the Unix epoch, each unit's
    clock re-estimated over the whole recording), time_utc (the same as a UTC
    timestamp), live_time_ns (as the bridge published it), rx_ns, then flat quantity
    columns (accel_x .. accel_z in g, ang_rate_x .. in rad/s, mag_x .. in gauss, m11 ..
    m33, roll pitch yaw in rad, q0 .. q3, temperature_0 .. temperature_3 in A/D codes,
    ...), empty (null) where a record lacks a quantity; rows in time order. Body frame
    FRD, earth NED: M maps earth to body; the quaternion is scalar first. A Parquet
    file carries each column's unit and frame, the units' Info, the source archive and
    these options as metadata (schema gx3.v1).
    A corrupt chunk, or a message that is not what its topic says (another unit's
    sample), is left out with a warning that says what was lost; the rest is exported.

    ROS 2 (--format ros2): per unit /gx3/<unit>/imu (sensor_msgs/msg/Imu) and, for
    records with a magnetometer, /gx3/<unit>/mag (sensor_msgs/msg/MagneticField), the
    first part being the archive's key prefix and names made ROS name tokens (imu-1:
    imu_1), in an MCAP file with profile ros2, ros2msg definitions and CDR messages
    (ROS 2 Jazzy types). REP-103/145 frames: body forward-left-up in frame gx3_<unit>,
    world east-north-up; orientation body to world, linear acceleration as specific force in
    m/s² (+9.81 up when level), angular velocity rad/s, field tesla; covariance element
    0 is -1 for a quantity the record lacks. header.stamp and the log time are the
    time_ns a table export with the same options gives.
    """
    from bridge.exceptions import ArchiveReadError
    from bridge.recorder.describe import ALIGNED_SEPARATOR, About, unit_labels
    from bridge.recorder.export import (
        align_table,
        archive_prefix,
        check_format,
        event_table,
        last_info,
        offline_times,
        parse_time,
        sample_table,
        write_table,
    )
    from bridge.recorder.magcal import apply, read_document, with_heading
    from bridge.recorder.ros2_export import write_ros2

    try:
        irons = [read_document(path) for path in mag_cal or ()]
        ros2 = _wants_ros2(output, output_format)
        if ros2 and align is not None:
            raise ValueError("--align makes a table; a ROS 2 bag keeps every sample at its "
                             "own time (leave out --align or --format ros2)")
        if not ros2:
            check_format(output)
        if events is not None:
            check_format(events)
            if events.absolute() == output.absolute():
                raise ValueError(f"--events {events} is the table's own file; give it "
                                 "another name")
        codes = [parse_code(c) for c in record_type] if record_type else None
        lo = parse_time(start) if start else None
        hi = parse_time(end) if end else None
    except (ValueError, typer.BadParameter) as exc:
        raise fail(str(exc)) from None
    with ExitStack() as outputs:
        table_file = outputs.enter_context(written(output, [archive], force))
        events_file = (None if events is None
                       else outputs.enter_context(written(events, [archive], force)))
        try:
            data = read_with_progress(archive)
            first = data.first_sample_ns() or 0
            lo_ns = lo.resolve(first) if lo else None
            hi_ns = hi.resolve(first) if hi else None
            table = sample_table(data, unit, codes, lo_ns, hi_ns, offline_times(data))
            rows = len(table["time_ns"])
            if not rows:
                raise ValueError(f"{archive}: no samples match (units: "
                                 f"{', '.join(data.units()) or 'none'}); check --unit, "
                                 "--type, --start and --end")
            names = sorted(set(table["unit"].tolist()))
            n_units = len(names)
            apply(table, irons)
            about = About(archive, {u: last_info(data, u) for u in names}, {
                "units": unit, "types": codes, "start": start, "end": end, "start_ns": lo_ns,
                "end_ns": hi_ns, "align_hz": align, "time_ns": "re-estimated"},
                {iron.unit: iron.content for iron in irons})
            if ros2:
                bag = write_ros2(table, table_file, archive_prefix(data))
                msg = (f"wrote {bag.imu} Imu and {bag.mag} MagneticField messages of {rows} "
                       f"samples of {n_units} units to {output}")
            elif align is not None:
                table = align_table(table, align)
                if irons:
                    labels = unit_labels(names)
                    table = with_heading(table, [labels[i.unit] + ALIGNED_SEPARATOR
                                                 for i in irons])
                msg = (f"wrote {len(table['time_ns'])} instants at {align:g} Hz of {rows} "
                       f"samples of {n_units} units to {output}")
            else:
                table = with_heading(table, units=[i.unit for i in irons]) if irons else table
                msg = f"wrote {rows} samples of {n_units} units to {output}"
            if not ros2:
                write_table(table, table_file, about)
            if events_file is not None:
                ev = event_table(data, unit, lo_ns, hi_ns)
                write_table(ev, events_file, about)
                msg += f"; {len(ev['time_ns'])} events to {events}"
        except (ArchiveReadError, ValueError) as exc:
            raise fail(str(exc)) from None
        except OSError as exc:
            raise fail(f"cannot write the export ({exc.strerror or exc}); check the space "
                       "and permissions where it goes", 1) from None
    err.print(msg)


def _wants_ros2(output: Path, given: str | None) -> bool:
    """Whether --format (or else the output's extension) asks for a ROS 2 bag."""
    suffix = output.suffix.lower()
    if given is None:
        return suffix == ".mcap"
    if given.lower() not in ("parquet", "csv", "ros2"):
        raise ValueError(f"--format {given}: give parquet, csv or ros2")
    wanted = ".mcap" if given.lower() == "ros2" else f".{given.lower()}"
    if suffix != wanted:
        raise ValueError(f"--format {given} writes a {wanted} file; name the output "
                         f"{output.with_suffix(wanted).name}")
    return wanted == ".mcap"
