"""`gx3 align`: how units on one body are mounted against a reference, from an archive."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from bridge._text import counted
from bridge.cli.common import FAILED, EndOpt, ForceOpt, StartOpt, app, err, fail, written

if TYPE_CHECKING:
    from bridge.analysis.mounts import Mount

#: The extensions of what -o writes: YAML.
SUFFIXES = (".yaml", ".yml")


def _line(mount: Mount) -> str:
    """One unit's result for a person: turn, shift and lever arm, each with its 1-sigma."""
    fit = mount.fit
    assert fit is not None
    angle = math.degrees(2 * math.acos(min(1.0, abs(float(mount.quaternion_xyzw[3])))))
    text = (f"{mount.unit}: turned {angle:.2f}° (±{float(fit.rotation_sigma_deg.max()):.3f}°), "
            f"time shift {mount.time_shift_s * 1e3:+.3f} ms "
            f"(±{fit.time_shift_sigma_s * 1e3:.3f} ms)")
    if mount.lever_arm_m is not None and fit.lever_arm_sigma_m is not None:
        arm = ", ".join(f"{v:+.3f}" for v in mount.lever_arm_m)
        text += f", lever arm ({arm}) m (±{float(fit.lever_arm_sigma_m.max()) * 1e3:.2f} mm)"
    else:
        text += f", no lever arm: {fit.lever_arm_note}"
    return text


@app.command()
def align(
    archive: Annotated[Path, typer.Argument(
        metavar="ARCHIVE.mcap",
        help="Archive in which the units, fixed to one body, were turned by hand.")],
    unit: Annotated[list[str], typer.Option(
        "--unit", "-u", metavar="NAME",
        help="The reference first, then each unit to align against it (repeat: -u REF "
             "-u UNIT [-u UNIT ...]).")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE.yaml",
        help="Mounts file to write (YAML); it appears when complete.")],
    start: StartOpt = None,
    end: EndOpt = None,
    force: ForceOpt = False,
) -> None:
    """Find how units fixed to one body are mounted against a reference, and how each
    one's time sits against it, from their motion alone.

    Fix the units to one rigid body and turn it by hand about all three of its axes,
    briskly back and forth, for a minute while recording (--start and --end pick that
    stretch). For each unit against the reference (the first -u), the angular rates give
    the rotation from the reference's axes to the unit's (rotation, v_unit = rotation @
    v_ref, and quaternion_xyzw, the same as a Hamilton quaternion) and the time shift
    (time_shift_s: t_ref = t_unit + time_shift_s for the same physical instant, up to
    ±2 s: a long cable, a converter, a wireless link or a hub that no clock model can
    see); the specific forces give the lever arm from the reference's accelerometer to
    the unit's in the reference's axes (lever_arm_m), where the body's turning makes it
    observable, else lever_arm_note says why not. Each comes with its 1-sigma
    (rotation_sigma_deg about the reference's x, y, z; time_shift_sigma_s;
    lever_arm_sigma_m), the residuals (rate_residual_rad_s, force_residual_m_s2) and the
    span used. Times are each unit's as gx3 export gives them. Fewer than two units, a
    unit not in the archive, units with no time together, a body that stood still or
    turned about one axis only, or a unit that does not turn with the reference are
    refused (exit 2, nothing written), saying what to record. Apply the file with gx3
    export --mounts or gx3 rrd --mounts.
    """
    from bridge.analysis.align import align as fit_mounts
    from bridge.analysis.align import unit_motion
    from bridge.analysis.mounts import mounts_yaml
    from bridge.archive.times import TimeSpan
    from bridge.cli.archive import read_with_progress
    from bridge.exceptions import AlignmentError
    from bridge.export.tables import offline_times, sample_table

    names = list(unit)
    if len(names) < 2:
        raise fail("give two units or more: the reference first, then each unit to align "
                   "against it (-u REF -u UNIT ...)")
    span = TimeSpan(start, end)
    with written(output, [archive], force, suffixes=SUFFIXES) as temp:
        try:
            data = read_with_progress(archive)
            missing = [u for u in names if u not in data.units()]
            if missing:
                raise ValueError(f"{archive} has no unit {missing[0]} (units: "
                                 f"{', '.join(data.units()) or 'none'}); check --unit")
            window = span.resolve(data.first_sample_ns() or 0)
            times = offline_times(data)
            # a unit's table at a time: a fleet's at once would hold every sample twice
            motions = [unit_motion(sample_table(data, [u], None, *window, times), u)
                       for u in names]
            progress = Progress(TextColumn("aligning"), BarColumn(), MofNCompleteColumn(),
                                console=err, transient=True, disable=not err.is_terminal)
            with progress:
                task = progress.add_task("align", total=len(names) - 1)
                mounts = fit_mounts(motions, archive.name,
                                    lambda _: progress.advance(task))
            temp.write_text(mounts_yaml(mounts))
        except (AlignmentError, ValueError) as exc:  # ArchiveReadError too: exit 2
            raise fail(str(exc)) from None
        except OSError as exc:
            raise fail(f"cannot write {output} ({exc.strerror or exc}); check the space and "
                       "permissions where it goes", FAILED) from None
    err.print(f"wrote {escape(str(output))}: {counted(len(mounts.units), 'unit')} against "
              f"{escape(names[0])}")
    for mount in mounts.units.values():
        err.print(f"  {escape(_line(mount))}")
