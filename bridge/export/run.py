"""What ``gx3 export`` runs: an archive's samples to a table or a ROS bag, as one job.

``Export`` checks a request before anything is read or written (the formats, what goes
with what, the span, the record types, the calibration files), then ``write`` turns an
archive, read with ``bridge.archive.read_samples_archive``, into the output and the
events table; ``run`` does all of it with safe outputs (each appears when complete,
nothing is left if it fails). The tables and their writers are
``bridge.export.tables``'s::

    from pathlib import Path

    from bridge.export import Export

    done = Export(Path("fleet.mcap"), Path("fleet.parquet"), align_hz=100).run()
    print(done.text())
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from bridge._text import counted, number
from bridge.analysis.magcal import UnitIron, apply, read_document, with_heading
from bridge.analysis.mounts import read_mounts
from bridge.archive.outputs import named_format
from bridge.archive.reader import ArchiveReader
from bridge.archive.times import TimeSpan
from bridge.archive.walk import read_samples_archive
from bridge.export.bags import BagWritten
from bridge.export.describe import ALIGNED_SEPARATOR, About, unit_labels
from bridge.export.mounted import shift_times, turn_units
from bridge.export.ros1_bag import check_merge, write_ros1
from bridge.export.ros2_bag import write_ros2
from bridge.export.tables import FORMATS as TABLES
from bridge.export.tables import (
    align_table,
    archive_prefix,
    event_table,
    last_info,
    offline_times,
    sample_table,
    write_table,
)
from bridge.protocol.table import DEFAULT_FILTER_WIDTH
from bridge.ros2.messages import DEFAULT_DISTRO, check_distro
from bridge.ros2.noise import ImuCovariance, ImuNoise, imu_covariance, read_noise

if TYPE_CHECKING:
    from bridge.bus.gx3_pb2 import Info

__all__ = ["Export", "Exported"]

#: What ``--format`` takes, and the extension of the file each writes.
FORMATS = {"parquet": ".parquet", "csv": ".csv", "ros2": ".mcap", "ros1": ".bag"}
#: The extensions of what an export writes: a table, or a ROS 2 (.mcap) or ROS 1 bag.
SUFFIXES = tuple(FORMATS.values())
#: The formats that are ROS bags.
BAGS = ("ros2", "ros1")


def _code(code: int | str) -> int:
    """A record type as a number, or as people write it (0xCC, 204)."""
    if isinstance(code, int):
        return code
    try:
        return int(code, 0)
    except ValueError:
        raise ValueError(f"{code!r} is not a number such as 0xC8") from None


def _output_format(output: Path, given: str | None) -> str:
    """The format ``given`` asks for, or else the output's extension names.

    Returns:
        A key of ``FORMATS``.

    Raises:
        OutputRefused: The extension names none of the formats.
        ValueError: No such format, or an extension that is not the format's.
    """
    suffix = named_format(output, *SUFFIXES)
    if given is None:
        return next(name for name, extension in FORMATS.items() if extension == suffix)
    name = given.lower()
    if name not in FORMATS:
        raise ValueError(f"--format {given}: give {', '.join(FORMATS)}")
    if suffix != FORMATS[name]:
        raise ValueError(f"--format {given} writes a {FORMATS[name]} file; name the output "
                         f"{output.with_suffix(FORMATS[name]).name}")
    return name


def _output_rate(info: Info | None) -> float | None:
    """A unit's output rate from its Info (1000 Hz / decimation); None if it has none."""
    if info is None:
        return None
    if info.output_rate_hz > 0:
        return float(info.output_rate_hz)
    return 1000.0 / info.decimation if info.decimation else None


def _unit_covariances(noise: ImuNoise | None, orientation_stddev: float | None,
                      infos: dict[str, Info | None]
                      ) -> tuple[dict[str, ImuCovariance], list[str]]:
    """Each unit's Imu covariances at its own rate and width, and what a person should know.

    The rate and the filter width are the unit's, from its Info: those its samples came
    with. A unit whose archive holds no Info gets the noise file's ``update_rate`` and
    the factory's width.
    """
    covariances, notes = {}, []
    for unit, info in sorted(infos.items()):
        rate, width = _output_rate(info), info.filter_width if info is not None else 0
        if noise is not None and (rate is None or not width):
            notes.append(f"unit {unit}: the archive holds no Info to give its output rate "
                         f"and filter width; its covariances use {noise.path.name}'s "
                         f"update_rate, {noise.update_rate_hz:g} Hz, and the factory's "
                         f"width, {DEFAULT_FILTER_WIDTH}")
        elif noise is not None and rate is not None \
                and abs(rate - noise.update_rate_hz) > 1e-6 * rate:
            notes.append(f"unit {unit}: its covariances use its output rate, {rate:g} Hz, "
                         f"and filter width, {width} (its Info), not {noise.path.name}'s "
                         f"update_rate, {noise.update_rate_hz:g} Hz")
        fallback = noise.update_rate_hz if noise is not None else 1000.0
        covariances[unit] = imu_covariance(noise, rate or fallback,
                                           width or DEFAULT_FILTER_WIDTH, orientation_stddev)
    return covariances, notes


@dataclass(frozen=True)
class Exported:
    """What an export wrote.

    Attributes:
        output: The table or bag.
        samples: The samples exported.
        units: How many units they are of.
        bag: With a ROS bag: its messages of each type; None for a table.
        align_hz: With an aligned table: its rate, Hz.
        instants: With an aligned table: its rows (instants of the grid).
        events_path: The events table, if one was asked for.
        events: The events in it.
        notes: What a person should know about how it was made (which rate and filter
            width the covariances use).
        merged: With a ROS 1 bag: the bag merged into it, if one was.
    """

    output: Path
    samples: int
    units: int
    bag: BagWritten | None = None
    align_hz: float | None = None
    instants: int | None = None
    events_path: Path | None = None
    events: int = 0
    notes: tuple[str, ...] = ()
    merged: Path | None = None

    def text(self) -> str:
        """What was written, in one line for a person.

        Returns:
            The line.
        """
        of = f"{counted(self.samples, 'sample')} of {counted(self.units, 'unit')} to {self.output}"
        if self.bag is not None:
            text = (f"wrote {number(self.bag.imu)} Imu and {number(self.bag.mag)} "
                    f"MagneticField messages of {of}")
            if self.merged is not None:
                text += f", and {number(self.bag.merged)} messages of {self.merged}"
        elif self.align_hz is not None:
            text = (f"wrote {counted(self.instants or 0, 'instant')} at {self.align_hz:g} Hz "
                    f"of {of}")
        else:
            text = f"wrote {of}"
        if self.events_path is not None:
            text += f"; {counted(self.events, 'event')} to {self.events_path}"
        return text


class Export:
    """One export of an archive's samples: a Parquet or CSV table, or a ROS 2 or ROS 1 bag.

    A table has one row per sample, every unit on one timeline (``align_hz``: one row
    per instant of a common grid); a bag has sensor_msgs/Imu and MagneticField messages.
    The request is checked when the job is made, before anything is read or written.

    Args:
        archive: The archive (.mcap) gx3 wrote.
        output: The file to write: .parquet or .csv, .mcap for a ROS 2 bag, .bag for a
            ROS 1 bag.
        output_format: A key of ``FORMATS`` (``parquet``, ``csv``, ``ros2``, ``ros1``);
            None: from ``output``'s extension.
        units: Only these units; None: every unit.
        types: Only records of these commands (numbers, or text such as ``0xCC``); None:
            every type.
        start: The first instant: an ISO time, or seconds from the first sample.
        end: The end instant (exclusive), as ``start``.
        align_hz: Resample every unit onto one grid at this rate (tables only).
        events: Also write every event per unit to this .parquet or .csv file.
        mag_cal: Iron calibrations (``gx3 calibrate-mag`` files), one per unit: its
            readings are corrected and a table gains its heading.
        noise: The units' measured noise, Kalibr's imu.yaml: a bag's Imu messages carry
            the covariances it gives at each unit's output rate and filter width; a
            Parquet table records the file and those covariances in its ``gx3.noise``
            metadata. A CSV file has nowhere to record it and is refused.
        orientation_stddev: The standard deviation of the units' orientation about each
            axis, rad: a bag's Imu messages that carry an orientation get its square on
            their orientation covariance's diagonal (else all 0: unknown); recorded as
            ``noise`` is.
        ros2_distro: The ROS 2 distribution of a ROS 2 bag (``jazzy``, ``humble``).
        merge: A ROS 1 bag (the camera's) to copy into a ROS 1 bag whole, so that one
            bag holds what Kalibr reads.
        mounts: A mounts file (``gx3 align``): each unit it names is put in the
            reference's axes and on its time; a Parquet table or a bag records the file
            and its SHA-256 (``gx3.mounts``), and a bag's messages of those units are in
            the reference's frame. A CSV file has nowhere to record it and is refused.

    Raises:
        OutputRefused: An output's extension names none of the formats it can hold.
        ValueError: The request cannot be met: a calibration, noise or mounts file that
            cannot be read, a format that does not fit the output's extension, --align
            with a bag, the events table on the output's own file, a record type or time
            that is not one, an end before the start (TimeSpanError), --noise,
            --orientation-stddev or --mounts with a CSV file, a negative standard
            deviation, --ros2-distro with another format, --merge with another format
            or a bag that cannot be read.
    """

    def __init__(self, archive: Path, output: Path, *, output_format: str | None = None,
                 units: Sequence[str] | None = None, types: Sequence[int | str] | None = None,
                 start: str | None = None, end: str | None = None,
                 align_hz: float | None = None, events: Path | None = None,
                 mag_cal: Sequence[Path] = (), noise: Path | None = None,
                 orientation_stddev: float | None = None,
                 ros2_distro: str | None = None, merge: Path | None = None,
                 mounts: Path | None = None) -> None:
        self.archive, self.output, self.events = archive, output, events
        self.units = None if units is None else list(units)
        self.start, self.end, self.align_hz = start, end, align_hz
        self.irons: list[UnitIron] = [read_document(path) for path in mag_cal]
        self.format = _output_format(output, output_format)
        if self.format in BAGS and align_hz is not None:
            raise ValueError("--align makes a table; a ROS bag keeps every sample at its "
                             f"own time (leave out --align or --format {self.format})")
        if ros2_distro is not None and self.format != "ros2":
            raise ValueError(f"--ros2-distro {ros2_distro} is for a ROS 2 bag; a "
                             + ("ROS 1 bag has Noetic's messages" if self.format == "ros1"
                                else "table is the same for every ROS")
                             + " (leave it out or --format ros2)")
        for option, given in (("--noise", noise), ("--orientation-stddev", orientation_stddev)):
            if given is not None and self.format == "csv":
                raise ValueError(f"{option} is recorded in a Parquet table's metadata or "
                                 "used in a ROS bag; a CSV file has no metadata to record "
                                 f"it in (write .parquet, or leave out {option})")
        if mounts is not None and self.format == "csv":
            raise ValueError("--mounts changes the samples, and a table records which "
                             "file did in its metadata; a CSV file has none (write "
                             ".parquet, or leave out --mounts)")
        if orientation_stddev is not None and not (math.isfinite(orientation_stddev)
                                                   and orientation_stddev >= 0):
            raise ValueError(f"--orientation-stddev {orientation_stddev}: give the standard "
                             "deviation of the orientation in radians, 0 or more")
        self.orientation_stddev = orientation_stddev
        if merge is not None and self.format != "ros1":
            raise ValueError(f"--merge {merge} copies a ROS 1 bag into a ROS 1 bag; write a "
                             ".bag (or --format ros1), or leave out --merge")
        if merge is not None:
            check_merge(merge)
        self.merge = merge
        self.distro = check_distro(ros2_distro or DEFAULT_DISTRO)
        self.noise = None if noise is None else read_noise(noise)
        self.mounts = None if mounts is None else read_mounts(mounts)
        if events is not None:
            named_format(events, *TABLES)
            if events.absolute() == output.absolute():
                raise ValueError(f"--events {events} is the table's own file; give it "
                                 "another name")
        self.types = [_code(c) for c in types] if types else None
        self.span = TimeSpan(start, end)

    def inputs(self) -> list[Path]:
        """The files the export reads, which no output may be.

        Returns:
            The archive, and the bag to merge if there is one.
        """
        return [self.archive] if self.merge is None else [self.archive, self.merge]

    def read(self, on_read: Callable[[int], None] | None = None,
             on_problem: Callable[[str], None] | None = None) -> ArchiveReader:
        """Read the archive (``read_samples_archive``).

        Args:
            on_read: Hears the bytes read so far.
            on_problem: Hears what is wrong with an archive cut short or damaged.

        Returns:
            Everything readable in it.

        Raises:
            ArchiveReadError: The file is missing, empty, unreadable or not MCAP at all.
            ValueError: Nothing in it can be read as messages.
        """
        return read_samples_archive(self.archive, on_read, on_problem)

    def write(self, data: ArchiveReader, table_file: Path,
              events_file: Path | None = None) -> Exported:
        """Export the samples of ``data`` (this job's archive, read).

        Args:
            data: The archive, as ``read`` gives it.
            table_file: Where to write the table or bag (the output, or a temporary
                file the caller puts in its place).
            events_file: Where to write the events table (with ``events``).

        Returns:
            What was written.

        Raises:
            ValueError: No samples match, the end is not after the start
                (TimeSpanError), a calibration's unit has none, a mounts file names a unit
                the archive lacks, or a sample's time does not fit a ROS time stamp.
            OSError: An output cannot be written.
        """
        lo_ns, hi_ns = self.span.resolve(data.first_sample_ns() or 0)
        times = offline_times(data)
        if self.mounts is not None:
            self.mounts.check_units(data.units())
            times = shift_times(times, self.mounts)
        table = sample_table(data, self.units, self.types, lo_ns, hi_ns, times)
        rows = len(table["time_ns"])
        if not rows:
            raise ValueError(f"{self.archive}: no samples match (units: "
                             f"{', '.join(data.units()) or 'none'}); check --unit, "
                             "--type, --start and --end")
        names = sorted(set(table["unit"].tolist()))
        irons = self.irons
        apply(table, irons)
        if self.mounts is not None:
            turn_units(table, self.mounts)
        infos = {u: last_info(data, u) for u in names}
        covariances: dict[str, ImuCovariance] = {}
        noted: dict[str, object] = {}
        notes: list[str] = []
        if self.noise is not None or self.orientation_stddev is not None:
            covariances, notes = _unit_covariances(self.noise, self.orientation_stddev,
                                                   infos)
            noted = (self.noise.provenance() if self.noise is not None else {}) | {
                "orientation_stddev": self.orientation_stddev,
                "units": {u: c.as_dict() for u, c in covariances.items()}}
        about = About(self.archive, infos, {
            "units": self.units, "types": self.types, "start": self.start, "end": self.end,
            "start_ns": lo_ns, "end_ns": hi_ns, "align_hz": self.align_hz,
            "time_ns": "re-estimated"},
            {iron.unit: iron.content for iron in irons}, noted,
            {} if self.mounts is None else self.mounts.provenance())
        done = Exported(self.output, rows, len(names), events_path=self.events,
                        notes=tuple(notes))
        prefix = archive_prefix(data)
        records = {name: content for name, content in (("gx3.noise", noted),
                                                       ("gx3.mounts", about.mounts))
                   if content}
        frames = {} if self.mounts is None else dict.fromkeys(self.mounts.units,
                                                              self.mounts.reference)
        if self.format == "ros2":
            done = replace(done, bag=write_ros2(
                table, table_file, prefix, distro=self.distro, covariances=covariances,
                metadata={name: {k: v if isinstance(v, str) else json.dumps(v)
                                 for k, v in content.items()}
                          for name, content in records.items()} or None, frames=frames))
        elif self.format == "ros1":
            done = replace(done, merged=self.merge, bag=write_ros1(
                table, table_file, prefix, covariances=covariances, metadata=records,
                frames=frames, merge=self.merge))
        elif self.align_hz is not None:
            table = align_table(table, self.align_hz)
            if irons:
                labels = unit_labels(names)
                table = with_heading(table, [labels[i.unit] + ALIGNED_SEPARATOR
                                             for i in irons])
            done = replace(done, align_hz=self.align_hz, instants=len(table["time_ns"]))
        elif irons:
            table = with_heading(table, units=[i.unit for i in irons])
        if self.format not in BAGS:
            write_table(table, table_file, about)
        if events_file is not None:
            events = event_table(data, self.units, lo_ns, hi_ns)
            write_table(events, events_file, about)
            done = replace(done, events=len(events["time_ns"]))
        return done

    def run(self, force: bool = False, on_read: Callable[[int], None] | None = None,
            on_problem: Callable[[str], None] | None = None) -> Exported:
        """Read the archive and write the outputs, each of which appears when complete.

        Args:
            force: Replace an output that exists (never the archive, nor a file another
                process is writing).
            on_read: Hears the bytes read so far.
            on_problem: Hears what is wrong with an archive cut short or damaged.

        Returns:
            What was written.

        Raises:
            OutputRefused: An output would destroy data (the archive, a file that exists
                without ``force``, another process's).
            ArchiveReadError: The archive is missing, empty, unreadable or not MCAP.
            ValueError: Nothing matches, or what matches cannot be exported as asked.
            OSError: An output cannot be written.
        """
        from bridge.archive.outputs import staged

        with ExitStack() as outputs:
            table_file = outputs.enter_context(staged(self.output, self.inputs(), force))
            events_file = (None if self.events is None else
                           outputs.enter_context(staged(self.events, self.inputs(), force)))
            return self.write(self.read(on_read, on_problem), table_file, events_file)
