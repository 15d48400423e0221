"""What the Rerun recording of a fleet looks like: entity paths, plots, sizes, colours, blueprint.

Entity paths group by quantity and line, not by unit (``/plots/accel/x/imu0``,
``/plots/accel/x/imu1``), so one time-series view per line (origin ``/plots/accel/x``)
takes in every unit, including units that appear after the blueprint was sent. The
scene is ``/world`` (NED: x north, y east, z down), each unit's body under
``/world/<unit>/body``; events are under ``/events/<unit>``. Every entity, and what it
shows: ``docs/guides/rerun.md``.
"""

from __future__ import annotations

import colorsys
import re
from collections.abc import Iterable, Sequence
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

#: The GX3-25 case, about 44 x 25 x 11 mm, along the sensor x, y and z axes (the manual gives
#: no drawing; long side taken as x), in metres.
BOX_SIZE_M = (0.044, 0.025, 0.011)
#: Drawn 15 times life size (0.66 x 0.375 x 0.165 m): its half-diagonal, 0.39 m, keeps
#: neighbours 1 m apart clear of each other in any attitude.
BOX_SCALE = 15.0
#: Distance between neighbouring units along east, in metres of the scene.
UNIT_SPACING_M = 1.0
AXIS_LENGTH_M = 0.45
#: A north-east-down triad, labelled, west of the first unit: which way is which.
NED_ORIGIN_M = (0.0, -UNIT_SPACING_M, 0.0)
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

#: Units in a row of the scene's grid (east); further rows lie south of the first.
GRID_COLUMNS = 4


def _hue_color(hue: float, light: float) -> Rgb:
    """An RGB of the given hue (0..1), saturated, at ``light`` (0..1).

    Legible on the viewer's dark background.
    """
    r, g, b = colorsys.hls_to_rgb(hue % 1.0, light, 0.85)
    return round(r * 255), round(g * 255), round(b * 255)


#: One colour per unit, 16 hues 22.5 degrees apart in bit-reversed order (0, 180, 90, 270,
#: 45... degrees), so the first 2, 4, 8 units are as far apart in hue as they can be; the
#: second eight are lighter than their hue neighbours. 16 units never share a colour.
_UNIT_COLORS: tuple[Rgb, ...] = tuple(
    _hue_color(int(f"{i:04b}"[::-1], 2) / 16 + 0.03, 0.6 if i < 8 else 0.76)
    for i in range(16))
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
#: send M or Q instead (M itself is in the scene); the temperature codes split into
#: Equation 15's degrees for the magnetometer and the gyro boards' codes, which the manual
#: says are relative, with no scale.
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
    Plot("c", "c, orientation update over 1 ms", tuple(f"c{i}{j}" for i in "123" for j in "123")),
    Plot("mag_temperature", "mag temperature [°C]", ("mag",)),
    Plot("gyro_temperature", "gyro temperatures [A/D code, relative]",
         ("gyro Y/accel X", "gyro X/accel Z,Y", "gyro Z")),
    Plot("samples_per_s", "samples/s", ("rate",)),
    Plot("dropped", "dropped records [total]", ("dropped",)),
    Plot("clock_offset", "clock offset since first status [ms]", ("offset",)),
    Plot("clock_drift", "clock drift [ppm]", ("drift",)),
    Plot("host_clock", "host clock: least arrival - time_ns [ms] (< 0: ahead)", ("lag",)),
)
PLOT = {p.name: p for p in PLOTS_TABLE}


def entity_part(unit: str) -> str:
    """A unit name as one entity path part."""
    return str(rr.escape_entity_path_part(unit))


def body_path(unit: str) -> str:
    """The entity of a unit's body: its attitude, case, axes and arrows."""
    return f"{WORLD}/{entity_part(unit)}/body"


def line_origin(plot: str, label: str) -> str:
    """The entity under which every unit's ``label`` line of ``plot`` lies (one view's)."""
    lines = PLOT[plot].labels
    return f"{PLOTS}/{plot}" if len(lines) == 1 else f"{PLOTS}/{plot}/{entity_part(label)}"


def plot_paths(plot: str, unit: str) -> list[str]:
    """One entity per line of a unit's plot, in the order of its labels.

    A view per line (accel x of every unit) then holds only the series it shows.
    """
    return [f"{line_origin(plot, label)}/{entity_part(unit)}" for label in PLOT[plot].labels]


def event_path(unit: str) -> str:
    """The entity of a unit's text log of events."""
    return f"{EVENTS}/{entity_part(unit)}"


def unit_position(index: int) -> npt.NDArray[np.float32]:
    """Where the index-th unit sits in the scene.

    Rows of GRID_COLUMNS along east, each row south of the one before, so the units
    never overlap and a fleet of 16 is a square.
    """
    row, column = divmod(index, GRID_COLUMNS)
    return np.array([-row * UNIT_SPACING_M, column * UNIT_SPACING_M, 0.0], np.float32)


def unit_color(index: int) -> Rgb:
    """The index-th unit's colour, in the scene and in every plot."""
    return _UNIT_COLORS[index % len(_UNIT_COLORS)]


#: Plots of the status messages: one line per unit, beside the scene in the fleet tab.
STATUS_PLOTS = ("samples_per_s", "dropped", "clock_offset", "clock_drift", "host_clock")

# The text starts with the event's time of day and its unit: Rerun sizes its own time
# column to its header, which cuts the time off, and the entity path repeats the unit.
_EVENT_COLUMNS = rrb.archetypes.TextLogColumns(
    timeline_columns=[rrb.encodings.TimelineColumn(TIME, visible=False)],
    text_log_columns=[rrb.encodings.TextLogColumn("LogLevel"),
                      rrb.encodings.TextLogColumn("Body"),
                      rrb.encodings.TextLogColumn("EntityPath", visible=False)])


def _eye(units: int) -> rrb.EyeControls3D:
    """A camera south of the grid of units and above it, looking north at its middle.

    So east is to the right and every unit is in the picture.
    """
    count = max(units, 1)
    first, last = unit_position(0), unit_position(count - 1)
    rows, columns = -last[0] / UNIT_SPACING_M + 1, min(count, GRID_COLUMNS)
    middle = np.array([first[0] + last[0], (columns - 1) * UNIT_SPACING_M, 0.0]) / 2
    distance = 1.0 + 0.8 * max(columns, rows) * UNIT_SPACING_M
    return rrb.EyeControls3D(position=middle + np.array([-0.8 * distance, 0.0, -distance]),
                             look_target=middle, eye_up=[0.0, 0.0, -1.0])


#: Units per plot view: Rerun's plot legend lists about a dozen entries at most, so a view
#: holds the lines of at most 8 units and a larger fleet gets a view per group of 8.
UNITS_PER_VIEW = 8


def natural_key(unit: str) -> tuple[tuple[int, int | str], ...]:
    """Sorts imu2 before imu10."""
    return tuple((0, int(part)) if part.isdigit() else (1, part)
                 for part in re.split(r"(\d+)", unit) if part)


def _line_views(plot: Plot, group: Sequence[str] | None,
                ranges: list[rrb.VisibleTimeRange] | None) -> list[rrb.TimeSeriesView]:
    """One view per line of ``plot`` (x, y, z...), each with that line of every unit.

    Or of the units of ``group``: the units' colours tell them apart, and every one has
    its entry in the legend.
    """
    views = []
    for label in plot.labels:
        origin = line_origin(plot.name, label)
        name = plot.title if len(plot.labels) == 1 else (
            f"{plot.name} {label}{plot.title[len(plot.name):]}")
        if group:
            name += f" ({group[0]}–{group[-1]})"
        views.append(rrb.TimeSeriesView(
            origin=origin, name=name, time_ranges=ranges,
            contents=[f"{origin}/{entity_part(unit)}" for unit in group] if group
            else "$origin/**", plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop)))
    return views


def blueprint(plots: Iterable[str], units: Sequence[str], window_s: float | None = None
              ) -> rrb.Blueprint:
    """The default layout, in tabs.

    "fleet": the 3-D scene of ``units`` and the events, beside the status plots (up to 8
    units; a larger fleet has them in a "status" tab). Then a tab per quantity present,
    in the order of PLOTS_TABLE, with one view per axis (x, y, z side by side) holding
    that axis of every unit (of 8 units, in rows).

    Why: Rerun has no unit selector, and a view of every unit's x, y and z is unreadable
    past a few units, with its legend cut short; a view per axis has one line per unit,
    in the unit's colour (as its box in the scene), so 16 units stay legible and every
    line is named. A unit is hidden with a click on its legend entry. ``window_s`` makes
    the plots show only the last so many seconds (for live viewing).
    """
    present = set(plots)
    ranges = None
    if window_s is not None:
        ranges = [rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.cursor_relative(
            seconds=-window_s), end=rrb.TimeRangeBoundary.cursor_relative())
            for timeline in (TIME, DEVICE_TIME)]
    # One group (None: the views take in every unit, also those the blueprint predates), or
    # groups of UNITS_PER_VIEW units.
    groups: list[Sequence[str] | None] = [None] if len(units) <= UNITS_PER_VIEW else [
        units[i:i + UNITS_PER_VIEW] for i in range(0, len(units), UNITS_PER_VIEW)]
    shown = [p for p in PLOTS_TABLE if p.name in present]
    status = [view for group in groups for p in shown if p.name in STATUS_PLOTS
              for view in _line_views(p, group, ranges)]
    scene = rrb.Vertical(
        rrb.Spatial3DView(origin=WORLD, name="attitude (NED: x north, y east, z down)",
                          eye_controls=_eye(len(units))),
        rrb.TextLogView(origin=EVENTS, name="events", columns=_EVENT_COLUMNS),
        row_shares=[3, 2],
    )
    tabs: list[rrb.Container] = []
    if status and len(groups) == 1:
        tabs.append(rrb.Horizontal(scene, rrb.Grid(*status, grid_columns=2),
                                   column_shares=[3, 2], name="fleet"))
    else:
        tabs.append(rrb.Vertical(scene, name="fleet"))
        if status:
            tabs.append(rrb.Grid(*status, grid_columns=4, name="status"))
    for p in shown:
        if p.name not in STATUS_PLOTS:
            views = [view for group in groups for view in _line_views(p, group, ranges)]
            lines = len(p.labels)
            tabs.append(rrb.Grid(*views, grid_columns=2 if lines == 4 else min(lines, 3),
                                 name=p.title))
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0),
                         rrb.TimePanel(timeline=TIME, state="collapsed"), collapse_panels=True)
