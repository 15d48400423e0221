"""A magnetometer iron calibration in Rerun, and a RerunLogger that applies calibrations.

The recording shows, as the manual's Figure 3 does, the raw readings on their fitted
ellipsoid (its centre the hard iron) beside the corrected readings on a sphere, with
the numbers. What each entity shows: ``docs/guides/rerun.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bridge.analysis.magcal import IRONED, IronCalibration, UnitIron
from bridge.viz.logger import RerunLogger

#: Points drawn at most: enough to see the shape, few enough to stay quick.
MAX_POINTS = 5000
RAW_COLOR = (230, 120, 40)
FIT_COLOR = (60, 120, 230)
CORRECTED_COLOR = (40, 170, 90)
POINT_RADIUS = 0.004


def _quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """The xyzw quaternion of a proper rotation matrix (columns: the rotated axes)."""
    from bridge.protocol.convert import m_to_quaternion

    # m_to_quaternion takes M (earth to body) and gives the scalar-first rotation of M;
    # the ellipsoid's axes are the columns, so its rotation is M's transpose.
    q = np.asarray(m_to_quaternion(rotation.T[None]))[0]
    return np.array([q[1], q[2], q[3], q[0]])


def _blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="/raw", name="raw readings and the fitted ellipsoid"),
                rrb.Spatial3DView(origin="/corrected", name="corrected readings on a sphere"),
            ),
            rrb.TextDocumentView(origin="/calibration", name="calibration"),
            row_shares=[4, 1],
        ),
        collapse_panels=True,
    )


def write_fit(path: Path, raw: np.ndarray, cal: IronCalibration, unit: str,
              text: str) -> None:
    """Write a fit and the readings it came from to a Rerun recording.

    Args:
        path: The .rrd file to write.
        raw: The readings, (n, 3), gauss, sensor frame; NaN rows are left out.
        cal: The fit of them.
        unit: The unit, for the recording's id.
        text: The numbers, Markdown, shown beside the views.
    """
    rec = rr.RecordingStream("gx3_calibrate_mag", recording_id=f"calibrate-mag-{unit}")
    rec.save(path, default_blueprint=_blueprint())
    held = raw[np.isfinite(raw).all(axis=1)]
    shown = held[:: max(1, len(held) // MAX_POINTS)]
    corrected = cal.correct(shown)
    # raw - hard = soft^-1 c with |c| = field: axes along soft's eigenvectors, half
    # sizes field / eigenvalue.
    values, vectors = np.linalg.eigh(cal.soft_iron)
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] = -vectors[:, 0]
    axes = rr.Arrows3D(vectors=np.eye(3) * 0.3 * cal.field_gauss, labels=["x", "y", "z"],
                       colors=[(220, 60, 60), (60, 200, 60), (80, 120, 255)])
    for origin in ("/raw", "/corrected"):
        rec.log(origin, rr.ViewCoordinates.FRD, static=True)
        rec.log(f"{origin}/axes", axes, static=True)
    rec.log("/raw/readings", rr.Points3D(shown, colors=RAW_COLOR, radii=POINT_RADIUS),
            static=True)
    rec.log("/raw/ellipsoid", rr.Ellipsoids3D(
        centers=[cal.hard_iron], half_sizes=[cal.field_gauss / values],
        quaternions=[_quaternion_xyzw(vectors)], colors=FIT_COLOR,
        labels=["fitted ellipsoid"], fill_mode="MajorWireframe"), static=True)
    rec.log("/corrected/readings", rr.Points3D(corrected, colors=CORRECTED_COLOR,
                                               radii=POINT_RADIUS), static=True)
    rec.log("/corrected/sphere", rr.Ellipsoids3D(
        centers=[[0.0, 0.0, 0.0]], radii=[cal.field_gauss], colors=FIT_COLOR,
        labels=[f"|field| = {cal.field_gauss:.3f} G"], fill_mode="MajorWireframe"),
        static=True)
    rec.log("/calibration", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN),
            static=True)
    rec.flush()
    rec.disconnect()


class IronedLogger(RerunLogger):
    """A RerunLogger that shows calibrated units' mag and stab_mag corrected for iron.

    Args:
        irons: The calibrations, one per unit at most.
        *args: As ``RerunLogger``'s.
        **kwargs: As ``RerunLogger``'s.
    """

    def __init__(self, irons: Sequence[UnitIron], *args: Any, **kwargs: Any) -> None:
        self._irons = {iron.unit: iron for iron in irons}
        super().__init__(*args, **kwargs)

    def log_samples(self, unit: str, code: int, columns: Mapping[str, np.ndarray]) -> None:
        """Log a batch as ``RerunLogger.log_samples`` does, a calibrated unit's corrected.

        Args:
            unit: The unit.
            code: The record type (command byte).
            columns: As ``RerunLogger.log_samples`` takes them.

        Raises:
            ValueError: A column is missing, or the columns differ in length.
        """
        super().log_samples(unit, code, self.ironed(unit, columns))

    def ironed(self, unit: str, columns: Mapping[str, np.ndarray]) -> Mapping[str, np.ndarray]:
        """A batch's columns, the unit's mag and stab_mag corrected where it has a calibration.

        Args:
            unit: The unit.
            columns: As ``RerunLogger.log_samples`` takes them.

        Returns:
            The columns, corrected (the same columns for a unit without one).
        """
        iron = self._irons.get(unit)
        if iron is None:
            return columns
        return {name: iron.correct(value).astype(value.dtype) if name in IRONED else value
                for name, value in columns.items()}
