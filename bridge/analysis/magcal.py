"""Hard- and soft-iron calibration of a magnetometer from readings taken while it turned.

Iron near the sensor maps the true field h to raw = S h + b: a constant offset b (hard
iron) and a linear distortion S (soft iron), so readings that would lie on a sphere lie
on an ellipsoid. An algebraic least-squares fit of the general quadric gives that
ellipsoid; its centre is b, and the symmetric square root of its shape, scaled so the
corrected readings keep the mean field magnitude, undoes S up to a rotation (which no
fit from magnitudes alone can see, so none is added): corrected = soft @ (raw - hard).
The fit needs the field seen from many directions; a unit turned about one axis only
gives readings on a plane, and the calibration says which motion is missing.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bridge._text import utc_text
from bridge.exceptions import CalibrationError

FloatArray = npt.NDArray[np.float64]

MODEL = "corrected = soft_iron @ (raw - hard_iron)"
MIN_READINGS = 50
#: Below this ratio of the readings' thinnest to widest spread, they lie on a plane; below
#: this ratio of their widest spread to their mean magnitude, they hardly moved at all.
FLAT_RATIO = 0.1
STILL_RATIO = 0.05
#: Coverage (fraction of the 20 direction bins hit) under which the fit is refused, and
#: under which it is given with a warning.
REFUSE_COVERAGE = 0.25
WARN_COVERAGE = 0.6
#: The length of the readings' mean direction over which the fit is refused, and over
#: which it is given with a warning: 0 for readings all round the sphere, 0.5 for a
#: hemisphere, near 1 for a cap.
REFUSE_LOPSIDED = 0.6
WARN_LOPSIDED = 0.3
#: A direction bin counts as covered with at least this many readings in it.
_MIN_PER_BIN = 3
_AXES = "xyz"
_PHI = (1.0 + math.sqrt(5.0)) / 2.0


@dataclass(frozen=True)
class Iron:
    """corrected = soft_iron @ (raw - hard_iron), gauss."""

    hard_iron: FloatArray
    soft_iron: FloatArray

    def correct(self, raw: npt.ArrayLike) -> FloatArray:
        """Readings corrected for the iron; NaN rows stay NaN.

        Args:
            raw: Raw readings, (n, 3), gauss, body frame.

        Returns:
            The corrected readings, (n, 3).
        """
        out: FloatArray = (np.asarray(raw, np.float64) - self.hard_iron) @ self.soft_iron.T
        return out


@dataclass(frozen=True)
class IronCalibration(Iron):
    """A fit: the iron (soft_iron symmetric), and how well it fits and what it saw."""

    field_gauss: float  # mean magnitude of the corrected readings
    residual_before: float  # RMS of |raw| - mean, over the mean
    residual_after: float  # the same of the corrected readings
    coverage: float  # fraction of the 20 icosahedron-face direction bins the readings hit
    readings: int
    warnings: tuple[str, ...]


def _face_centres() -> FloatArray:
    """The 20 face centres of an icosahedron (a dodecahedron's vertices), unit length."""
    a, b = 1.0 / _PHI, _PHI
    points: list[tuple[float, float, float]] = [
        (x, y, z) for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)]
    for s in (-1, 1):
        for t in (-1, 1):
            points += [(0.0, s * a, t * b), (s * a, t * b, 0.0), (t * b, 0.0, s * a)]
    centres = np.array(points, np.float64)
    normed: FloatArray = centres / np.linalg.norm(centres, axis=1, keepdims=True)
    return normed


_BINS = _face_centres()


def _coverage(directions: FloatArray) -> float:
    """Fraction of the sphere's 20 icosahedron faces that hold at least a few directions."""
    nearest = np.argmax(directions @ _BINS.T, axis=1)
    counts = np.bincount(nearest, minlength=len(_BINS))
    return float(np.mean(counts >= _MIN_PER_BIN))


def _relative_spread(vectors: FloatArray) -> float:
    """RMS of each vector's magnitude minus their mean magnitude, over that mean."""
    size = np.linalg.norm(vectors, axis=1)
    mean = float(size.mean())
    return float(np.sqrt(np.mean((size - mean) ** 2)) / mean) if mean > 0 else math.inf


def _axis_name(direction: FloatArray) -> str:
    """'its z axis' when a direction is close to a body axis, else its components."""
    i = int(np.argmax(np.abs(direction)))
    if abs(direction[i]) > 0.9:
        return f"its {_AXES[i]} axis"
    return "an axis near ({:+.2f}, {:+.2f}, {:+.2f})".format(*direction)


def _flatness(raw: FloatArray) -> None:
    """Refuse readings that span a line or a plane, naming the turn that would fix it."""
    spread, axes = np.linalg.eigh(np.cov(raw.T))
    widest = max(float(spread[2]), 1e-30)
    if math.sqrt(widest) < STILL_RATIO * float(np.mean(np.linalg.norm(raw, axis=1))):
        raise CalibrationError(
            "the readings hardly change: the unit stood still; turn it slowly through "
            "every orientation (about its x, y and z axes, upside down too) while recording")
    if math.sqrt(max(float(spread[1]), 0.0) / widest) < FLAT_RATIO:
        raise CalibrationError(
            "the readings barely change direction (they span a line): the unit hardly "
            "turned; turn it slowly through every orientation (about its x, y and z axes, "
            "upside down too) while recording")
    if math.sqrt(max(float(spread[0]), 0.0) / widest) < FLAT_RATIO:
        normal = axes[:, 0]
        others = [a for i, a in enumerate(_AXES) if i != int(np.argmax(np.abs(normal)))]
        raise CalibrationError(
            "the readings span a plane: the unit turned about one axis only "
            f"({_axis_name(normal)}); tilt it: turn it also about its {others[0]} and "
            f"{others[1]} axes (upside down too) while recording")


def _quadric(points: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """A, b, d of the quadric x'Ax + 2b'x + d = 0 nearest the points (algebraic fit)."""
    x, y, z = points.T
    design = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y,
                              2 * x, 2 * y, 2 * z, np.ones_like(x)])
    v = np.linalg.svd(design, full_matrices=False)[2][-1]
    a = np.array([[v[0], v[5], v[4]], [v[5], v[1], v[3]], [v[4], v[3], v[2]]])
    return a, v[6:9], float(v[9])


def _sqrtm_spd(matrix: FloatArray) -> FloatArray:
    values, vectors = np.linalg.eigh(matrix)
    root: FloatArray = (vectors * np.sqrt(values)) @ vectors.T
    return root


def fit(raw: npt.ArrayLike) -> IronCalibration:
    """Hard and soft iron from magnetometer readings taken while the unit turned.

    Rows with a NaN are left out. A fit from readings that cover the sphere only in part
    comes with warnings.

    Args:
        raw: Readings, (n, 3), gauss, body frame.

    Returns:
        The iron, and how well it fits and what the readings saw.

    Raises:
        CalibrationError: The readings cannot pin an ellipsoid down; it says what motion
            is missing.
    """
    points = np.asarray(raw, np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < MIN_READINGS:
        raise CalibrationError(f"{len(points)} magnetometer readings; a fit needs at least "
                               f"{MIN_READINGS}, taken while the unit turns through every "
                               "orientation")
    _flatness(points)
    # Centred and scaled to about 1 so that the quadric's terms are of one size.
    origin = points.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((points - origin) ** 2, axis=1))))
    a, b, d = _quadric((points - origin) / scale)
    try:
        centre = -np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        raise CalibrationError(_not_an_ellipsoid()) from None
    shape = a / (float(centre @ a @ centre) - d)
    if not np.all(np.linalg.eigvalsh(shape) > 0):
        raise CalibrationError(_not_an_ellipsoid())
    hard = origin + scale * centre
    unit_sphere = _sqrtm_spd(shape) / scale  # maps raw - hard onto the unit sphere
    field = float(np.mean(np.linalg.norm(points - hard, axis=1)))
    soft = field * unit_sphere
    soft = (soft + soft.T) / 2.0
    corrected = (points - hard) @ soft.T
    directions = corrected / np.linalg.norm(corrected, axis=1, keepdims=True)
    covered = _coverage(directions)
    # A fit to one side of the sphere can stretch that side over most of it: the
    # readings' mean direction still shows them crowded there (0 all round, 1 one way).
    lopsided = float(np.linalg.norm(directions.mean(axis=0)))
    if covered < REFUSE_COVERAGE or lopsided > REFUSE_LOPSIDED:
        raise CalibrationError(
            f"the readings saw the field from one side only ({covered:.0%} of directions "
            f"covered, mean direction {lopsided:.2f} of the way to one side): "
            f"{_missing(corrected)}")
    warnings = () if covered >= WARN_COVERAGE and lopsided <= WARN_LOPSIDED else (
        f"the readings cover the sphere unevenly ({covered:.0%} of directions, mean "
        f"direction {lopsided:.2f} of the way to one side), so the fit is uncertain: "
        f"{_missing(corrected)}",)
    return IronCalibration(hard_iron=hard, soft_iron=soft,
                           field_gauss=float(np.mean(np.linalg.norm(corrected, axis=1))),
                           residual_before=_relative_spread(points),
                           residual_after=_relative_spread(corrected), coverage=covered,
                           readings=len(points), warnings=warnings)


def _not_an_ellipsoid() -> str:
    return ("the readings do not lie on an ellipsoid (no sensible iron model fits them); "
            "record again, turning the unit slowly through every orientation away from "
            "magnets and moving metal")


def _missing(corrected: FloatArray) -> str:
    """Which body axes never had the field along them, and what to do.

    Where every axis had it, the side the readings crowd away from.
    """
    directions = corrected / np.linalg.norm(corrected, axis=1, keepdims=True)
    names = []
    for i, axis in enumerate(_AXES):
        for sign, mark in ((1.0, "+"), (-1.0, "-")):
            if not np.any(sign * directions[:, i] > math.cos(math.radians(45.0))):
                names.append(f"{mark}{axis}")
    along = "(north and steeply down at mid latitudes)"
    if not names:
        mean = directions.mean(axis=0)
        i = int(np.argmax(np.abs(mean)))
        crowded, empty = ("+", "-") if mean[i] > 0 else ("-", "+")
        return (f"the field lay mostly along its {crowded}{_AXES[i]} axis; turn the unit so "
                f"that its {empty}{_AXES[i]} axis points along the field {along} as long")
    if len(names) == 1:
        return (f"the field never lay along its {names[0]} axis; turn the unit so that this "
                f"axis points along the field {along}")
    return (f"the field never lay along its {', '.join(names)} axes; turn the unit so that "
            f"each of them points along the field {along} in turn")


def document(cal: IronCalibration, unit: str, quantity: str, span_ns: tuple[int, int],
             source: str) -> dict[str, object]:
    """The calibration file's content: the iron, and what it was fitted from and how well."""
    start, end = span_ns
    return {
        "unit": unit,
        "hard_iron": [round(float(v), 7) for v in cal.hard_iron],
        "soft_iron": [[round(float(v), 7) for v in row] for row in cal.soft_iron],
        "model": MODEL,
        "physical_unit": "gauss",
        "field_gauss": round(cal.field_gauss, 6),
        "residual_before": round(cal.residual_before, 6),
        "residual_after": round(cal.residual_after, 6),
        "coverage": round(cal.coverage, 3),
        "readings": cal.readings,
        "quantity": quantity,
        "span": {"start_ns": start, "end_ns": end,
                 "start_utc": utc_text(start, "milliseconds"),
                 "end_utc": utc_text(end, "milliseconds"),
                 "seconds": round((end - start) / 1e9, 3)},
        "source": source,
        "warnings": list(cal.warnings),
    }



@dataclass(frozen=True)
class UnitIron(Iron):
    """A calibration file as read back: whose it is, and all it says."""

    unit: str
    content: dict[str, object]


def read_document(path: Path) -> UnitIron:
    """Read a calibration file that ``gx3 calibrate-mag`` wrote.

    Args:
        path: The file (JSON).

    Returns:
        The calibration, whose unit it is, and all the file says.

    Raises:
        ValueError: The file cannot be read or is not a calibration; it says which.
    """
    try:
        content = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except (ValueError, UnicodeDecodeError):
        raise ValueError(f"{path}: not JSON; give a file that gx3 calibrate-mag wrote") from None
    try:
        unit = content["unit"]
        hard = np.array(content["hard_iron"], np.float64)
        soft = np.array(content["soft_iron"], np.float64)
    except (KeyError, TypeError, ValueError):
        hard = soft = np.zeros(0)
        unit = None
    if (not isinstance(unit, str) or hard.shape != (3,) or soft.shape != (3, 3)
            or not np.isfinite(hard).all() or not np.isfinite(soft).all()
            or abs(np.linalg.det(soft)) < 1e-9):
        raise ValueError(f"{path}: not a calibration (it needs unit, hard_iron [x, y, z] and "
                         "an invertible soft_iron [[...], [...], [...]]); give a file that "
                         "gx3 calibrate-mag wrote")
    return UnitIron(hard, soft, unit, content)


#: The quantities iron distorts: the magnetometer and the unit's gyro-stabilised estimate
#: of it, which it makes from the same sensor.
IRONED = ("mag", "stab_mag")
HEADING = "mag_heading"


def apply(table: dict[str, np.ndarray], irons: Sequence[UnitIron]) -> None:
    """Correct, in place, each calibrated unit's mag and stab_mag columns in an export."""
    units = sorted(set(table["unit"].tolist()))
    seen: set[str] = set()
    for iron in irons:
        if iron.unit not in units:
            raise ValueError(f"--mag-cal: the calibration of unit {iron.unit} has no samples "
                             f"in this export (units: {', '.join(units) or 'none'})")
        if iron.unit in seen:
            raise ValueError(f"--mag-cal: two calibrations of unit {iron.unit}; give one")
        seen.add(iron.unit)
        rows = table["unit"] == iron.unit
        for quantity in IRONED:
            names = [f"{quantity}_{a}" for a in _AXES]
            if names[0] in table:
                raw = np.column_stack([table[n][rows] for n in names])
                for name, column in zip(names, iron.correct(raw).T, strict=True):
                    table[name][rows] = column


def _tilt_heading(accel: npt.ArrayLike, mag: npt.ArrayLike) -> FloatArray:
    """Heading [rad, -pi..pi, from magnetic north toward east] of the body x axis.

    From the specific force (down is against it when the unit is not accelerating) and
    the field, both body FRD: the yaw a level compass would show, whatever the tilt.
    """
    down = -np.asarray(accel, np.float64)
    east = np.cross(down, np.asarray(mag, np.float64))
    north = np.cross(east, down)
    heading: FloatArray = np.arctan2(east[:, 0] * np.linalg.norm(north, axis=1),
                                     north[:, 0] * np.linalg.norm(east, axis=1))
    return heading


def with_heading(table: dict[str, np.ndarray], prefixes: Iterable[str] = ("",),
                 units: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """The table with a ``mag_heading`` column beside each yaw (or after mag).

    One per column prefix (an aligned table's ``<unit>__``) where the table has accel and
    mag; with ``units``, rows of other units (whose mag is not corrected) have none.
    """
    out = dict(table)
    others = ~np.isin(table["unit"], list(units)) if units else None
    for p in prefixes:
        needed = [f"{p}{q}_{a}" for q in ("accel", "mag") for a in _AXES]
        if not all(n in table for n in needed):
            continue
        values = np.column_stack([table[n] for n in needed])
        heading = _tilt_heading(values[:, :3], values[:, 3:]).astype(np.float32)
        if others is not None:
            heading[others] = np.nan
        after = f"{p}yaw" if f"{p}yaw" in table else f"{p}mag_z"
        items = list(out.items())
        at = [k for k, _ in items].index(after) + 1
        out = dict([*items[:at], (f"{p}{HEADING}", heading), *items[at:]])
    return out
