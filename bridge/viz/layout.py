"""What the Rerun recording of a fleet looks like: entity paths, plots, sizes, colours, blueprint.

Entity paths group by quantity, not by unit (``/plots/accel/imu0``, ``/plots/accel/imu1``),
so one time-series view per quantity (origin ``/plots/accel``) takes in every unit,
including units that appear after the blueprint was sent.

    /world                           ViewCoordinates.FRD: X north, Y east, Z down (NED)
    /world/ned                       Arrows3D labelled N, E, D: which way is which
    /world/<unit>                    Transform3D translation: units side by side, eastwards
    /world/<unit>/body               Transform3D quaternion per sample: sensor to earth (M^T)
    /world/<unit>/body/box           Boxes3D, the unit's case scaled up BOX_SCALE times
    /world/<unit>/body/axes          Arrows3D, sensor x (red), y (green), z (blue)
    /world/<unit>/body/accel         Arrows3D per sample, accel (or stab_accel), sensor frame
    /world/<unit>/body/mag           Arrows3D per sample, mag (or stab_mag), sensor frame
    /plots/<plot>/<unit>             Scalars per sample or status, SeriesLines static
    /events/<unit>                   TextLog per event
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import rerun as rr
import rerun.blueprint as rrb

from bridge.protocol.table import QUANTITIES

WORLD = "/world"
PLOTS = "/plots"
EVENTS = "/events"

#: Timeline of the aligned host-clock estimate ``time_ns`` (a timestamp).
TIME = "time"
#: Timeline of the unwrapped device timer, ``ticks / 62,500`` s (a duration).
DEVICE_TIME = "device_time"

#: The GX3-25 case, north (x) x east (y) x down (z) in the sensor frame, in metres.
BOX_SIZE_M = (0.044, 0.025, 0.011)
#: Drawn 15 times life size (0.66 x 0.375 x 0.165 m): its half-diagonal, 0.39 m, keeps
#: neighbours 1 m apart clear of each other in any attitude.
BOX_SCALE = 15.0
#: Distance between neighbouring units along east, in metres of the scene.
UNIT_SPACING_M = 1.0
AXIS_LENGTH_M = 0.45
#: A north-east-down triad, labelled, south of the first unit: which way is which.
NED_ORIGIN_M = (-UNIT_SPACING_M, 0.0, 0.0)
NED_COLOR: Rgb = (170, 170, 170)
#: Arrow lengths: 1 g of specific force is drawn 0.5 m long, 1 gauss 0.9 m long.
ACCEL_ARROW_M_PER_G = 0.5
MAG_ARROW_M_PER_GAUSS = 0.9
#: Quantity -> the arrow under the unit's body that shows it, and its length per unit.
ARROWS = {
    "accel": ("accel", ACCEL_ARROW_M_PER_G),
    "stab_accel": ("accel", ACCEL_ARROW_M_PER_G),
    "mag": ("mag", MAG_ARROW_M_PER_GAUSS),
    "stab_mag": ("mag", MAG_ARROW_M_PER_GAUSS),
}

Rgb = tuple[int, int, int]

# Okabe-Ito: tells apart for the colour blind, and reads on the viewer's dark background.
_UNIT_COLORS: tuple[Rgb, ...] = (
    (230, 159, 0), (86, 180, 233), (0, 158, 115), (240, 228, 66),
    (204, 121, 167), (213, 94, 0), (0, 114, 178),
)
AXIS_COLORS: tuple[Rgb, ...] = ((230, 60, 60), (60, 200, 60), (70, 110, 255))
ACCEL_COLOR: Rgb = (255, 255, 255)
MAG_COLOR: Rgb = (255, 80, 220)


@dataclass(frozen=True)
class Plot:
    """One time-series view: the title says the physical unit, the labels name the lines."""

    name: str
    title: str
    labels: tuple[str, ...]


def _vector(name: str, labels: tuple[str, ...] = ("x", "y", "z")) -> Plot:
    unit = QUANTITIES[name].unit
    return Plot(name, f"{name} [{unit}]" if unit else name, labels)


#: Every plot, in the order of the grid. ``euler`` also shows the attitude of records that
#: send M or Q instead; the temperature codes split into Equation 15's degrees for the
#: magnetometer and the gyro boards' codes, which the manual gives no scale for.
PLOTS_TABLE: tuple[Plot, ...] = (
    _vector("accel"),
    _vector("ang_rate"),
    _vector("mag"),
    Plot("euler", "euler [deg]", ("roll", "pitch", "yaw")),
    _vector("quaternion", ("q0", "q1", "q2", "q3")),
    _vector("stab_accel"),
    _vector("stab_mag"),
    _vector("delta_ang"),
    _vector("delta_vel"),
    _vector("raw_accel"),
    _vector("raw_ang_rate"),
    Plot("mag_temperature", "mag temperature [°C]", ("mag",)),
    Plot("gyro_temperature", "gyro temperatures [A/D code, relative]",
         ("gyro Y/accel X", "gyro X/accel Z,Y", "gyro Z")),
    Plot("samples_per_s", "samples/s", ("rate",)),
    Plot("dropped", "dropped records [total]", ("dropped",)),
    Plot("clock_offset", "clock offset since first status [ms]", ("offset",)),
    Plot("clock_drift", "clock drift [ppm]", ("drift",)),
)
PLOT = {p.name: p for p in PLOTS_TABLE}


def entity_part(unit: str) -> str:
    """A unit name as one entity path part."""
    return str(rr.escape_entity_path_part(unit))


def body_path(unit: str) -> str:
    return f"{WORLD}/{entity_part(unit)}/body"


def plot_path(plot: str, unit: str) -> str:
    return f"{PLOTS}/{plot}/{entity_part(unit)}"


def event_path(unit: str) -> str:
    return f"{EVENTS}/{entity_part(unit)}"


def unit_position(index: int) -> npt.NDArray[np.float32]:
    """Where the index-th unit sits: a row along east, so the units never overlap."""
    return np.array([0.0, index * UNIT_SPACING_M, 0.0], np.float32)


def unit_color(index: int) -> Rgb:
    return _UNIT_COLORS[index % len(_UNIT_COLORS)]


def series_colors(index: int, lines: int) -> npt.NDArray[np.uint8]:
    """One colour per line of a unit: its own hue, from light (first) to dark (last), so a
    line's unit reads at a glance and its axis from the legend."""
    base = np.array(unit_color(index), np.float64)
    if lines == 1:
        return base.astype(np.uint8)[None, :]
    shade = np.linspace(0.45, -0.35, lines)[:, None]
    light = base + (255.0 - base) * np.clip(shade, 0.0, None)
    return np.round(light * (1.0 + np.clip(shade, None, 0.0))).astype(np.uint8)


# The entity path repeats the unit, which the text starts with.
_EVENT_COLUMNS = rrb.archetypes.TextLogColumns(
    timeline_columns=[rrb.encodings.TimelineColumn(TIME),
                      rrb.encodings.TimelineColumn(DEVICE_TIME, visible=False)],
    text_log_columns=[rrb.encodings.TextLogColumn("LogLevel"),
                      rrb.encodings.TextLogColumn("Body"),
                      rrb.encodings.TextLogColumn("EntityPath", visible=False)])


def eye(units: int) -> rrb.EyeControls3D:
    """A camera south of the row of units and above it, looking north at its middle, so east
    is to the right and every unit is in the picture."""
    middle = unit_position(0) + (unit_position(max(units, 1) - 1) - unit_position(0)) / 2
    distance = 0.6 + 0.7 * max(units, 1) * UNIT_SPACING_M
    return rrb.EyeControls3D(position=middle + np.array([-distance, 0.0, -0.7 * distance]),
                             look_target=middle, eye_up=[0.0, 0.0, -1.0])


def blueprint(plots: Iterable[str], units: int, window_s: float | None = None
              ) -> rrb.Blueprint:
    """The default layout: the 3-D scene of ``units`` units and the events on the left, a
    grid of time-series views on the right, one per plot present, in the order of PLOTS_TABLE.

    ``window_s`` makes the plots show only the last so many seconds (for live viewing).
    """
    present = set(plots)
    ranges = None
    if window_s is not None:
        ranges = [rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.cursor_relative(
            seconds=-window_s), end=rrb.TimeRangeBoundary.cursor_relative())
            for timeline in (TIME, DEVICE_TIME)]
    views = [rrb.TimeSeriesView(origin=f"{PLOTS}/{p.name}", name=p.title, time_ranges=ranges,
                                plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop))
             for p in PLOTS_TABLE if p.name in present]
    columns = 1 if len(views) <= 3 else 2 if len(views) <= 8 else 3
    left = rrb.Vertical(
        rrb.Spatial3DView(origin=WORLD, name="attitude (NED: x north, y east, z down)",
                          eye_controls=eye(units)),
        rrb.TextLogView(origin=EVENTS, name="events", columns=_EVENT_COLUMNS),
        row_shares=[3, 1],
    )
    right = rrb.Grid(*views, grid_columns=columns) if views else None
    main = rrb.Horizontal(left, right, column_shares=[2, 3]) if right else left
    return rrb.Blueprint(main, rrb.TimePanel(timeline=TIME, state="collapsed"),
                         collapse_panels=True)
