"""`gx3 allan`: a still unit's IMU noise for Kalibr, VINS and OpenVINS, from an archive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from bridge.cli.common import (
    FAILED,
    REFUSED,
    EndOpt,
    ForceOpt,
    StartOpt,
    app,
    err,
    fail,
    refused,
    written,
)

_PLACEHOLDER = "{unit}"
#: What -o writes (Kalibr's imu.yaml), and the pictures --plot draws, by extension.
_YAML = (".yaml", ".yml")
_PICTURES = (".png", ".svg", ".pdf")


def _per_unit(option: str, path: Path, units: list[str]) -> dict[str, Path]:
    """Each unit's file from a path that names one (with {unit} when there are several)."""
    if len(units) > 1 and _PLACEHOLDER not in str(path):
        raise fail(f"{option} {path}: {len(units)} units ({', '.join(units)}) need one file "
                   f"each; put {_PLACEHOLDER} in the name, such as imu_{_PLACEHOLDER}.yaml")
    return {u: Path(str(path).replace(_PLACEHOLDER, u)) for u in units}


@app.command()
def allan(
    archive: Annotated[Path, typer.Argument(
        metavar="ARCHIVE.mcap",
        help="Archive of the unit standing still (recorded, replayed or repaired).")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="FILE.yaml",
        help="Kalibr imu.yaml to write (.yaml or .yml); it appears when complete. With "
             "several units, {unit} in the name stands for each.")],
    unit: Annotated[list[str] | None, typer.Option(
        "--unit", "-u", metavar="NAME",
        help="A unit to measure; repeat for several. Default: every unit in the "
             "archive.")] = None,
    plot: Annotated[Path | None, typer.Option(
        "--plot", metavar="FILE.png",
        help="Also draw the Allan deviation of each axis, log-log, with the lines and "
             "points Kalibr reads and the span fitted: .png, .svg or .pdf, as the name "
             "says ({unit} as in --output).")] = None,
    start: StartOpt = None,
    end: EndOpt = None,
    jobs: Annotated[int | None, typer.Option(
        "--jobs", "-j", min=1, metavar="N",
        help="Units measured at once, a process each. Default: one per core.")] = None,
    force: ForceOpt = False,
) -> None:
    """Measure a still unit's noise (Allan deviation) and write Kalibr's imu.yaml.

    Record the unit standing still, untouched, on a steady surface at a steady
    temperature: minutes give the white noise densities, hours (3 or more; 8 for a tight
    estimate) the bias random walks. The overlapping Allan deviation of each axis of the
    accelerometer (m/s²) and the gyroscope (rad/s) is computed over the contiguous
    stretches of the recording: gaps and resets cut it, and are never bridged (a timer
    rollover does not: its step is exact). As Kalibr's wiki defines them, the noise
    density is the slope -1/2 line at τ = 1 s and the random walk the slope +1/2 line at
    τ = 3 s, in continuous-time units. The unit averages M calculation cycles (its
    filter width, from its Info; the factory's 15, with a warning, if the archive has
    none) and sends every D-th: that shapes the curve at short τ, so the fit models it
    exactly and starts at 10 × (M + D) ms; the densities are the sensor's own, whatever
    the rate and width. The worst axis of each sensor goes into Kalibr's four keys,
    beside the unit's ROS 2 topic (as gx3 export names it) and its rate. Each axis's
    values, the bias instability (the flat minimum) and its τ, M, D, the τ range fitted
    and the data used go under the key gx3_allan, which Kalibr ignores. A unit that
    moved (its specific force off 1 g, turning, or its one-second means wandering) is
    refused (exit 2), saying when; so is a curve with no white noise in it, rather than
    a density of 0. A recording too short for the random walks gives them with a
    warning saying how long to record.
    """
    from bridge.analysis.noise import (
        UnitSamples,
        collect_samples,
        kalibr_yaml,
        stretch_text,
        units_noise,
    )
    from bridge.archive.outputs import named_format
    from bridge.archive.times import TimeSpan
    from bridge.cli.archive import read_with_progress
    from bridge.exceptions import CalibrationError
    from bridge.export.tables import archive_prefix
    from bridge.ros2.messages import ros_topic

    span = TimeSpan(start, end)
    asked = list(dict.fromkeys(unit)) if unit else None
    for option, path, suffixes in (("--output", output, _YAML), ("--plot", plot, _PICTURES)):
        if path is None:  # refused before hours of reading, not after
            continue
        named_format(path, *suffixes)
        for each in _per_unit(option, path, asked).values() if asked else ():
            refused(each, [archive], force, suffixes=suffixes)
    kept, take, first = collect_samples(asked)
    try:
        data = read_with_progress(archive, take)
    except ValueError as exc:  # an ArchiveReadError too: what cannot be read, exit 2
        raise fail(str(exc)) from None
    units = asked if asked is not None else data.units()
    missing = [u for u in units if u not in data.units()]
    if missing or not units:
        raise fail(f"{archive} has no unit {', '.join(missing) or 'at all'} (units: "
                   f"{', '.join(data.units()) or 'none'}); check --unit")
    outputs = _per_unit("--output", output, units)
    plots = _per_unit("--plot", plot, units) if plot is not None else {}
    results = units_noise([kept.get(u, UnitSamples(u)) for u in units],
                          *span.resolve(first[0] if first else 0), jobs)
    prefix = archive_prefix(data)
    refusals = 0
    for name, result in zip(units, results, strict=True):
        if isinstance(result, CalibrationError):
            if len(units) == 1:
                raise fail(str(result))
            err.print(f"[bold red]error:[/] {result}")
            refusals += 1
            continue
        with written(outputs[name], [archive], force, suffixes=_YAML) as temp:
            try:
                temp.write_text(kalibr_yaml(result, ros_topic(prefix, name, "imu"),
                                            archive.name))
            except OSError as exc:
                raise fail(f"cannot write {outputs[name]} ({exc.strerror or exc}); check "
                           "the space and permissions where it goes", FAILED) from None
        if name in plots:
            from bridge.viz.allan import write_allan_plot

            with written(plots[name], [archive, outputs[name]], force,
                         suffixes=_PICTURES) as temp:
                write_allan_plot(temp, result, plots[name].suffix.lower().lstrip("."))
        for warning in result.warnings:
            err.print(f"[yellow]warning:[/] unit {name}: {warning}")
        acc, gyr = result.accelerometer, result.gyroscope
        err.print(
            f"wrote {outputs[name]}"
            + (f" and {plots[name]}" if name in plots else "")
            + f": unit {name}, accelerometer N {acc.noise_density:.3g} m/s²/√Hz, "
            f"K {acc.walk_text()} m/s³/√Hz; gyroscope N {gyr.noise_density:.3g} "
            f"rad/s/√Hz, K {gyr.walk_text()} rad/s²/√Hz; from {stretch_text(result)}")
    if refusals:
        raise typer.Exit(REFUSED)
