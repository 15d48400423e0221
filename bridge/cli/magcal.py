"""`gx3 calibrate-mag`: a unit's hard- and soft-iron calibration from an archive."""

from __future__ import annotations

import json
from contextlib import ExitStack
from pathlib import Path
from typing import Annotated, Any

import typer

from bridge._text import counted
from bridge.cli.common import FAILED, EndOpt, ForceOpt, StartOpt, app, err, fail, written


@app.command("calibrate-mag")
def calibrate_mag(
    archive: Annotated[Path, typer.Argument(
        metavar="ARCHIVE.mcap",
        help="Archive in which the unit was turned through every orientation.")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE",
        help="Calibration file to write (.json); it appears when complete.")],
    unit: Annotated[str | None, typer.Option(
        "--unit", "-u", metavar="NAME",
        help="The unit to calibrate. Default: the archive's only unit.")] = None,
    start: StartOpt = None,
    end: EndOpt = None,
    rrd: Annotated[Path | None, typer.Option(
        "--rrd", metavar="FILE.rrd",
        help="Also draw the fit in a Rerun recording, as the manual's Figure 3: raw "
             "readings on the fitted ellipsoid beside the corrected ones on a sphere.")] = None,
    force: ForceOpt = False,
) -> None:
    """Fit the magnetometer's hard- and soft-iron calibration, which the manual leaves
    to the user once a unit is installed.

    Turn the installed unit slowly through every orientation (about each of its axes,
    upside down too) while recording, then give the archive and the unit. The readings
    of every record type with a magnetometer (mag; stab_mag if none has mag) lie on an
    ellipsoid; its fit gives, in gauss, the vector hard_iron and the symmetric 3x3 matrix
    soft_iron with corrected = soft_iron @ (raw - hard_iron), the corrected readings
    keeping the mean field magnitude. The JSON file also holds the unit, the
    span used, the residual before and after (RMS of |field| minus its mean, over the
    mean), the coverage (fraction of 20 equal directions the field was seen from) and
    any warning. Readings that span a plane (a turn about one axis), a line or a point,
    or that saw the field from one side only (a unit never upside down), are refused
    (exit 2), saying which motion is missing; a fit from readings that cover the sphere
    unevenly is written with a warning saying which axis to point along the field. Apply
    it with gx3 export --mag-cal, gx3 rrd --mag-cal or gx3 view --mag-cal.
    """
    import numpy as np

    from bridge.analysis.magcal import document, fit
    from bridge.archive.times import TimeSpan
    from bridge.cli.archive import read_with_progress
    from bridge.exceptions import CalibrationError
    from bridge.export.tables import offline_times, sample_table

    span = TimeSpan(start, end)
    with ExitStack() as outputs:
        temp = outputs.enter_context(written(output, [archive], force, suffixes=(".json",)))
        drawing = None if rrd is None else outputs.enter_context(
            written(rrd, [archive, output], force, suffixes=(".rrd",)))
        try:
            data = read_with_progress(archive)
            units = data.units()
            name = unit if unit is not None else _only_unit(archive, units)
            if name not in units:
                raise ValueError(f"{archive} has no unit {name!r} (units: "
                                 f"{', '.join(units) or 'none'}); check --unit")
            table = sample_table(data, [name], None,
                                 *span.resolve(data.first_sample_ns() or 0),
                                 offline_times(data))
            if not len(table["time_ns"]):
                raise ValueError(f"{archive}: no samples of unit {name} from --start to "
                                 "--end; check them (seconds from the first sample, or "
                                 "ISO times)")
            quantity = next((q for q in ("mag", "stab_mag") if f"{q}_x" in table), None)
            if quantity is None:
                raise ValueError(f"{archive}: unit {name} has no magnetometer readings in "
                                 "that span; record a type with mag (0xC7, 0xCB, 0xCC, "
                                 "0xD3) while turning it")
            raw = np.column_stack([table[f"{quantity}_{a}"] for a in "xyz"])
            held = np.isfinite(raw).all(axis=1)
            cal = fit(raw)
            times = table["time_ns"][held]
            content = document(cal, name, quantity, (int(times[0]), int(times[-1])),
                               archive.name)
            temp.write_text(json.dumps(content, indent=1) + "\n")
            if drawing is not None:
                from bridge.viz.magcal import write_fit

                write_fit(drawing, raw, cal, name, _summary(content))
        except CalibrationError as exc:
            raise fail(f"unit {name}: cannot calibrate: {exc}") from None
        except ValueError as exc:  # an ArchiveReadError too: what cannot be read, exit 2
            raise fail(str(exc)) from None
        except OSError as exc:
            raise fail(f"cannot write {output} ({exc.strerror or exc}); check the space and "
                       "permissions where it goes", FAILED) from None
    for warning in cal.warnings:
        err.print(f"[yellow]warning:[/] unit {name}: {warning}")
    err.print(f"wrote {output}: unit {name}, {counted(cal.readings, 'reading')}, hard iron "
              f"({', '.join(f'{v:+.4f}' for v in cal.hard_iron)}) gauss, field "
              f"{cal.field_gauss:.4f} gauss, spread {cal.residual_before:.2%} before and "
              f"{cal.residual_after:.2%} after, {cal.coverage:.0%} of directions covered")


def _summary(content: dict[str, Any]) -> str:
    """The calibration in Markdown, for the recording's text panel."""
    lines = [f"**{content['unit']}**: {content['model']} (gauss), fitted from "
             f"{content['readings']} readings over {content['span']['seconds']} s from "
             f"{content['span']['start_utc']}",
             "", f"- hard_iron: {content['hard_iron']}", f"- soft_iron: {content['soft_iron']}",
             f"- field {content['field_gauss']} gauss; spread of |field| "
             f"{content['residual_before']:.2%} raw, {content['residual_after']:.2%} corrected; "
             f"{content['coverage']:.0%} of directions covered"]
    lines += [f"- warning: {w}" for w in content["warnings"]]
    return "\n".join(lines)


def _only_unit(archive: Path, units: list[str]) -> str:
    if len(units) != 1:
        raise ValueError(f"{archive} holds {counted(len(units), 'unit')} "
                         f"({', '.join(units) or 'none'}); choose one with --unit")
    return units[0]
