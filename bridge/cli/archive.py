"""`gx3 repair` and `gx3 export`: make an unfinished archive whole, turn one into a table."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

from bridge.cli.common import (
    FAILED,
    EndOpt,
    ForceOpt,
    StartOpt,
    app,
    err,
    fail,
    failing,
    written,
)

if TYPE_CHECKING:
    from bridge.archive.reader import ArchiveReader

# The archive and export modules (pyarrow, protobuf schemas) load only when these commands
# run, so every other gx3 command starts as fast as before.


def read_with_progress(path: Path, on_blocks: Callable[[ArchiveReader], None] | None = None
                       ) -> ArchiveReader:
    """Read an archive with progress on a terminal; warn once when it was cut short.

    ``on_blocks`` streams it (``read_archive``)."""
    from bridge.archive.walk import read_samples_archive

    size = path.stat().st_size if path.is_file() else None
    progress = Progress(TextColumn("reading"), BarColumn(), DownloadColumn(), console=err,
                        transient=True, disable=not err.is_terminal)
    problems: list[str] = []
    with progress:
        task = progress.add_task("read", total=size)
        archive = read_samples_archive(path, lambda done: progress.update(task, completed=done),
                                       problems.append, on_blocks)
    for problem in problems:
        err.print(f"[yellow]warning:[/] {problem}")
    return archive


@app.command()
def repair(
    file: Annotated[Path, typer.Argument(
        metavar="FILE.mcap",
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
    from bridge.archive.repair import default_output
    from bridge.archive.repair import repair as repair_archive
    from bridge.exceptions import ArchiveError

    output = default_output(file) if output is None else output
    with written(output, [file], force, suffixes=(".mcap",)) as temp, \
            failing(ArchiveError, temp=temp, path=output):
        report = repair_archive(file, temp)
    typer.echo(replace(report, output=output).text())


@app.command()
def export(
    archive: Annotated[Path, typer.Argument(metavar="ARCHIVE.mcap",
                                            help="Archive (.mcap) written by gx3.")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE", help="File to write: a .parquet or .csv table, a "
                                               ".mcap ROS 2 bag or a .bag ROS 1 bag; it "
                                               "appears when complete.")],
    output_format: Annotated[str | None, typer.Option(
        "--format", metavar="FORMAT",
        help="parquet, csv, ros2 (sensor_msgs/Imu and MagneticField in an MCAP bag that "
             "ros2 bag play reads) or ros1 (the same messages in a ROS 1 .bag, which "
             "Kalibr, allan_variance_ros and imu_utils read). Default: from the output's "
             "extension (.mcap: ros2, .bag: ros1); one that does not match is refused.")
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
    noise: Annotated[Path | None, typer.Option(
        "--noise", metavar="IMU.yaml",
        help="The units' measured noise, Kalibr's imu.yaml (gx3 allan writes one; keys "
             "accelerometer_noise_density, accelerometer_random_walk, "
             "gyroscope_noise_density, gyroscope_random_walk, update_rate; others are "
             "ignored). ROS bags: each Imu's angular_velocity_covariance and "
             "linear_acceleration_covariance diagonals become noise density² x 1000 Hz / "
             "min(D, M), D the unit's decimation and M its filter width from its Info "
             "(density² x the output rate while D ≤ M: the samples share cycles; the "
             "samples' own variance once D > M; the file's update_rate and the factory's "
             "width 15 only for a unit without Info), and the bag's gx3.noise metadata "
             "(ROS 1: a latched std_msgs/String on /PREFIX/gx3_noise) names the file. "
             "Parquet: the samples are unchanged; gx3.noise metadata records the file and "
             "the covariances it gives. CSV: refused (no metadata to record it in).")
    ] = None,
    orientation_stddev: Annotated[float | None, typer.Option(
        "--orientation-stddev", metavar="RAD", min=0.0,
        help="Standard deviation of the units' orientation about each axis, in radians: "
             "the orientation_covariance diagonal of every Imu that carries an "
             "orientation (0xC8, 0xCC, 0xCE, 0xDF, ...) becomes its square (the manual "
             "states no attitude accuracy; REP-145 leaves it all 0, unknown, unless one "
             "is given). Records without an orientation keep -1 in element 0. Recorded "
             "as --noise is; CSV: refused.")] = None,
    mounts: Annotated[Path | None, typer.Option(
        "--mounts", metavar="MOUNTS.yaml",
        help="How units on one body are mounted (gx3 align writes it): each unit it names "
             "gets its vectors (accel, ang_rate, mag, stab_accel, stab_mag, delta_ang, "
             "delta_vel; not the raw A/D codes) as rotation^T @ v and its attitude (M, "
             "quaternion, Euler angles, C) in the reference's axes, and its time_ns moved "
             "by time_shift_s onto the reference's time; --start and --end see the moved "
             "times. Lever arms are not applied: accel stays the specific force where the "
             "unit sits. Parquet: the file, its SHA-256 and what it holds go in the "
             "gx3.mounts metadata; ROS bags: the same as a gx3.mounts metadata record "
             "(ROS 1: a latched std_msgs/String on /PREFIX/gx3_mounts), and those units' "
             "messages are in the reference's frame; CSV: refused (no metadata to record "
             "it in).")] = None,
    ros2_distro: Annotated[str | None, typer.Option(
        "--ros2-distro", metavar="humble|jazzy",
        help="ROS 2 distribution of the bag's message definitions (--format ros2 only); "
             "Humble's and Jazzy's definitions of Imu and MagneticField are the same, so "
             "the bag is too. Default: jazzy.")] = None,
    merge: Annotated[Path | None, typer.Option(
        "--merge", metavar="CAMERA.bag",
        help="Also copy every topic and message of this ROS 1 bag (the camera's, as ROS "
             "recorded it) into the .bag written, unchanged: Kalibr reads the images and "
             "the IMU from one bag. --format ros1 only; the bag itself is not touched.")
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Export samples to Parquet or CSV, one row per sample, every unit on one timeline,
    or to a ROS 2 or ROS 1 bag.

    Columns: unit, command, timer, ticks, time_ns (ns since the Unix epoch, each unit's
    clock re-estimated over the whole recording), time_utc (the same as a UTC
    timestamp), time_uncertainty_ns (the most time_ns can be off by, as the reads bound
    it; 0: not known), live_time_ns (as the bridge published it), rx_ns, then flat quantity
    columns (accel_x .. accel_z in g, ang_rate_x .. in rad/s, mag_x .. in gauss, m11 ..
    m33, roll pitch yaw in rad, q0 .. q3, temperature_0 .. temperature_3 in A/D codes,
    ...), empty (null) where a record lacks a quantity; rows in time order. Body frame
    FRD, earth NED: M maps earth to body; the quaternion is scalar first. A Parquet
    file carries each column's unit and frame, the units' Info, the source archive and
    these options as metadata (schema gx3.v1); a CSV file each column's unit in its
    header, in brackets after its name (accel_x [g]; none after time_ns or time_utc).
    A corrupt chunk, or a message that is not what its topic says (another unit's
    sample), is left out with a warning that says what was lost; the rest is exported.

    ROS 2 (--format ros2): per unit /gx3/<unit>/imu (sensor_msgs/msg/Imu) and, for
    records with a magnetometer, /gx3/<unit>/mag (sensor_msgs/msg/MagneticField), the
    first part being the archive's key prefix and names made ROS name tokens (imu-1:
    imu_1), in an MCAP file with profile ros2, ros2msg definitions and CDR messages
    (ROS 2 Jazzy types). REP-103/145 frames: body forward-left-up in frame gx3_<unit>,
    world east-north-up; orientation body to world, linear acceleration as specific force in
    m/s² (+9.81 up when level), angular velocity rad/s, field tesla; covariance element
    0 is -1 for a quantity the record lacks; the other covariances are 0 (unknown)
    unless --noise or --orientation-stddev gives them. header.stamp and the log time are
    the time_ns a table export with the same options gives.

    ROS 1 (--format ros1, a .bag: what Kalibr, allan_variance_ros and imu_utils read):
    the same topics, frames, stamps, covariances and messages with ROS 1 Noetic's
    definitions, header.seq counting each topic's messages from 0; the metadata records
    of --noise and --mounts are latched std_msgs/String (JSON) on /gx3/gx3_noise and
    /gx3/gx3_mounts; --merge copies the camera's bag in, so that Kalibr finds both in one.
    """
    from bridge.export.run import SUFFIXES, Export
    from bridge.export.tables import FORMATS as TABLES

    try:  # the request is checked before anything is read or written
        job = Export(archive, output, output_format=output_format, units=unit,
                     types=record_type, start=start, end=end, align_hz=align, events=events,
                     mag_cal=mag_cal or (), noise=noise,
                     orientation_stddev=orientation_stddev, ros2_distro=ros2_distro,
                     merge=merge, mounts=mounts)
    except ValueError as exc:  # what the export refuses is a ValueError: exit 2
        raise fail(str(exc)) from None
    with ExitStack() as outputs:
        table_file = outputs.enter_context(written(output, job.inputs(), force,
                                                   suffixes=SUFFIXES))
        events_file = (None if events is None else outputs.enter_context(
            written(events, job.inputs(), force, suffixes=TABLES)))
        try:
            done = job.write(read_with_progress(archive), table_file, events_file)
        except ValueError as exc:  # the archive or the samples cannot give what was asked
            raise fail(str(exc)) from None
        except OSError as exc:
            raise fail(f"cannot write the export ({exc.strerror or exc}); check the space "
                       "and permissions where it goes", FAILED) from None
    for note in done.notes:
        err.print(f"[yellow]note:[/] {escape(note)}")
    err.print(done.text())
