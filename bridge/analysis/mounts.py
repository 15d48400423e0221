"""The mounts file: each unit's rotation, time shift and lever arm against a reference.

``gx3 align`` writes it and ``gx3 export --mounts`` and ``gx3 rrd --mounts`` apply it;
it is plain YAML so that other tools read it too::

    reference: imu1
    units:
      imu2:
        rotation: [[r11, r12, r13], [r21, r22, r23], [r31, r32, r33]]
        quaternion_xyzw: [x, y, z, w]
        time_shift_s: -0.0032
        lever_arm_m: [0.30, 0.00, 0.00]

``rotation`` turns the reference's axes into the unit's (v_unit = rotation @ v_ref) and
``quaternion_xyzw`` is the same rotation as a Hamilton quaternion; ``time_shift_s`` puts
the unit's instants on the reference's time (t_ref = t_unit + time_shift_s for the
same physical instant); ``lever_arm_m`` goes from the reference's accelerometer to the
unit's, in the reference's axes. A fit adds each one's 1-sigma uncertainty, the
residuals and the span it used. A file another tool writes needs only ``reference``
and, per unit, ``rotation`` or ``quaternion_xyzw``; the rest is optional.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bridge._text import utc_text
from bridge.exceptions import MountsFileError
from bridge.protocol import convert

__all__ = ["MODEL", "Mount", "MountFit", "Mounts", "mounts_yaml", "read_mounts"]

FloatArray = npt.NDArray[np.float64]

#: What the file's numbers mean, clause by clause.
MODEL_LINES = (
    "v_unit = rotation @ v_ref: rotation turns the reference's axes into the unit's, "
    "quaternion_xyzw is the same (Hamilton)",
    "t_ref = t_unit + time_shift_s for the same physical instant",
    "lever_arm_m: from the reference's accelerometer to the unit's, reference axes, metres",
)
MODEL = "; ".join(MODEL_LINES)
#: How far a rotation read from a file may be from orthonormal (its rows' dot products).
ROTATION_TOLERANCE = 1e-5


def _vector(v: FloatArray, r: FloatArray) -> FloatArray:
    out: FloatArray = v @ r  # row vectors: (r.T @ v) for each
    return out


def _attitude(m: FloatArray, r: FloatArray) -> FloatArray:
    """M (earth to the unit) to earth-to-reference axes; (n, 3, 3) or flat (n, 9)."""
    return np.asarray((r.T @ m.reshape(-1, 3, 3)).reshape(m.shape))


def _update(c: FloatArray, r: FloatArray) -> FloatArray:
    """C, which maps the unit's axes a cycle ago to now, in the reference's axes."""
    return np.asarray((r.T @ c.reshape(-1, 3, 3) @ r).reshape(c.shape))


def _quaternion(q: FloatArray, r: FloatArray) -> FloatArray:
    return convert.m_to_quaternion(r.T @ convert.quaternion_to_m(q))


def _euler(e: FloatArray, r: FloatArray) -> FloatArray:
    return convert.m_to_euler(r.T @ convert.euler_to_m(e))


#: How each quantity a record can hold is put in the reference's axes: vectors turn, the
#: attitude (M, its quaternion and Euler angles) becomes the reference axes' against
#: the earth, C turns at both ends. Raw A/D codes and temperatures are the sensor's own
#: channels, and stay as they are.
TURNS: dict[str, Callable[[FloatArray, FloatArray], FloatArray]] = {
    **dict.fromkeys(("accel", "ang_rate", "mag", "stab_accel", "stab_mag", "delta_ang",
                     "delta_vel"), _vector),
    "m": _attitude, "c": _update, "quaternion": _quaternion, "euler": _euler,
}


@dataclass(frozen=True)
class MountFit:
    """What a fit says of how sure its mounting is, and what it was fitted from.

    Attributes:
        rotation_sigma_deg: 1-sigma of the rotation about the reference's x, y, z axes.
        time_shift_sigma_s: 1-sigma of the time shift.
        lever_arm_sigma_m: 1-sigma of each element of the lever arm; None without one.
        lever_arm_note: Why the lever arm is left out, if it is.
        rate_residual_rad_s: RMS of what the rotation and shift leave of the rates.
        force_residual_m_s2: RMS of what the lever arm leaves of the specific forces.
        span_ns: First and last instant used (the reference's time, ns since the epoch).
        samples: The instants used.
    """

    rotation_sigma_deg: FloatArray
    time_shift_sigma_s: float
    lever_arm_sigma_m: FloatArray | None
    lever_arm_note: str
    rate_residual_rad_s: float
    force_residual_m_s2: float | None
    span_ns: tuple[int, int]
    samples: int


@dataclass(frozen=True)
class Mount:
    """How one unit sits against the reference.

    Attributes:
        unit: The unit.
        rotation: (3, 3), the reference's axes to the unit's: v_unit = rotation @ v_ref.
        time_shift_s: t_ref = t_unit + time_shift_s for the same physical instant.
        lever_arm_m: From the reference's accelerometer to the unit's, in the
            reference's axes; None where not known.
        fit: How sure the fit is; None for a file that does not say.
    """

    unit: str
    rotation: FloatArray
    time_shift_s: float = 0.0
    lever_arm_m: FloatArray | None = None
    fit: MountFit | None = None

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """The rotation as a Hamilton quaternion, x, y, z, w (w >= 0)."""
        return convert.rotation_to_xyzw(self.rotation)

    @property
    def shift_ns(self) -> int:
        """The time shift, whole nanoseconds."""
        return round(self.time_shift_s * 1e9)

    def express(self, columns: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A unit's quantities in the reference's axes (``TURNS``); times are not shifted.

        Args:
            columns: Quantity name -> (n, ...) values, as a record or an export holds
                them (M as (n, 3, 3) or (n, 9)); other columns pass as they are.

        Returns:
            The columns, each turned one of its own dtype; NaN rows stay NaN.
        """
        out = dict(columns)
        with np.errstate(invalid="ignore", divide="ignore"):
            for name, values in columns.items():
                turn = TURNS.get(name)
                if turn is not None:
                    out[name] = turn(np.asarray(values, np.float64),
                                     self.rotation).astype(values.dtype)
        return out


@dataclass(frozen=True)
class Mounts:
    """A mounts file: every unit's mounting against one reference.

    Attributes:
        reference: The reference unit, whose axes and time the others are put on.
        units: Each other unit's mounting, by name.
        source: What it was fitted from (the archive's name); empty where not said.
        path: The file it was read from; None for a fit not yet written.
        sha256: That file's SHA-256, hex; empty for a fit not yet written.
    """

    reference: str
    units: dict[str, Mount]
    source: str = ""
    path: Path | None = None
    sha256: str = ""

    def provenance(self) -> dict[str, object]:
        """What an output records of the file: its name, SHA-256, reference, units.

        Returns:
            The record, JSON-ready.
        """
        return {"file": self.path.name if self.path else "", "sha256": self.sha256,
                "reference": self.reference, "model": MODEL,
                "units": {u: {"rotation": m.rotation.round(9).tolist(),
                              "time_shift_s": m.time_shift_s,
                              "lever_arm_m": None if m.lever_arm_m is None
                              else m.lever_arm_m.round(6).tolist()}
                          for u, m in sorted(self.units.items())}}

    def check_units(self, present: list[str], option: str = "--mounts") -> None:
        """Refuse a file whose reference or units are not among ``present``.

        Args:
            present: The units an output holds.
            option: The option the file was given to, for the message.

        Raises:
            MountsFileError: One is missing; the message names it and the file.
        """
        name = self.path.name if self.path else "the mounts"
        for unit in [self.reference, *self.units]:
            if unit not in present:
                raise MountsFileError(f"{option} {name}: unit {unit} has no samples here "
                                      f"(units: {', '.join(present) or 'none'}); align the "
                                      "units of this archive (gx3 align)")


#: Words YAML 1.1 readers take for booleans or null, whatever their case.
_YAML_WORDS = {"true", "false", "yes", "no", "on", "off", "y", "n", "null"}


def _name(name: str) -> str:
    """A unit's name as YAML reads it back as that text: plain, or quoted."""
    plain = re.fullmatch(r"[A-Za-z][A-Za-z0-9_.\-]*", name) and name.lower() not in _YAML_WORDS
    return name if plain else json.dumps(name)


def _numbers(values: npt.ArrayLike, form: str) -> str:
    """A YAML flow list of numbers in ``form``.

    ``.2e`` writes 1.50e-05, with the dot and the signed exponent that YAML 1.1
    readers (PyYAML) need to take it for a float too.
    """
    return "[" + ", ".join(f"{float(v):{form}}" for v in np.ravel(values)) + "]"


def mounts_yaml(mounts: Mounts) -> str:
    """The mounts file's text: YAML, each fitted number with its 1-sigma.

    Args:
        mounts: The mountings (``bridge.analysis.align.align``).

    Returns:
        The text.
    """
    lines = [
        "# How each unit is mounted against the reference, from gx3 align:",
        *(f"#   {line}" for line in MODEL_LINES),
        "#   each *_sigma is the 1-sigma of what it follows",
        "# Apply it with gx3 export --mounts or gx3 rrd --mounts.",
        f"reference: {_name(mounts.reference)}",
        "units:",
    ]
    for unit, mount in mounts.units.items():
        rows = ", ".join(_numbers(row, ".9f") for row in mount.rotation)
        lines += [f"  {_name(unit)}:", f"    rotation: [{rows}]",
                  f"    quaternion_xyzw: {_numbers(mount.quaternion_xyzw, '.9f')}",
                  f"    time_shift_s: {mount.time_shift_s:.7f}"]
        if mount.lever_arm_m is not None:
            lines.append(f"    lever_arm_m: {_numbers(mount.lever_arm_m, '.5f')}")
        fit = mount.fit
        if fit is None:
            continue
        lines += [f"    rotation_sigma_deg: {_numbers(fit.rotation_sigma_deg, '.2e')}",
                  f"    time_shift_sigma_s: {fit.time_shift_sigma_s:.2e}"]
        if fit.lever_arm_sigma_m is not None:
            lines.append(f"    lever_arm_sigma_m: {_numbers(fit.lever_arm_sigma_m, '.2e')}")
        if fit.lever_arm_note:
            lines.append(f"    lever_arm_note: {json.dumps(fit.lever_arm_note)}")
        lines.append(f"    rate_residual_rad_s: {fit.rate_residual_rad_s:.3e}")
        if fit.force_residual_m_s2 is not None:
            lines.append(f"    force_residual_m_s2: {fit.force_residual_m_s2:.3e}")
        start, end = fit.span_ns
        lines += ["    span:", f"      start_utc: {utc_text(start, 'milliseconds')}",
                  f"      end_utc: {utc_text(end, 'milliseconds')}",
                  f"      seconds: {(end - start) / 1e9:.3f}",
                  f"      samples: {fit.samples}"]
    if mounts.source:
        lines.append(f"source: {json.dumps(mounts.source)}")
    return "\n".join(lines) + "\n"


def _matrix(value: object, shape: tuple[int, ...], what: str) -> FloatArray:
    """A list of numbers (nested) as an array of ``shape``, or the one-line error."""
    try:
        array = np.array(value, np.float64)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.shape != shape or not np.isfinite(array).all():
        raise ValueError(f"{what} is not {' x '.join(map(str, shape))} numbers")
    return array


def _rotation(unit: str, content: Mapping[str, object]) -> FloatArray:
    """A unit's rotation from its ``rotation`` or ``quaternion_xyzw`` (they must agree)."""
    rotation = quaternion = None
    if "rotation" in content:
        rotation = _matrix(content["rotation"], (3, 3), f"{unit}: rotation")
        if not (np.allclose(rotation @ rotation.T, np.eye(3), atol=ROTATION_TOLERANCE)
                and np.linalg.det(rotation) > 0):
            raise ValueError(f"{unit}: rotation is not a rotation (its rows must be "
                             "orthonormal, its determinant +1)")
        u, _, vt = np.linalg.svd(rotation)  # the nearest rotation, to the last bit
        rotation = u @ vt
    if "quaternion_xyzw" in content:
        q = _matrix(content["quaternion_xyzw"], (4,), f"{unit}: quaternion_xyzw")
        if not math.isclose(float(np.linalg.norm(q)), 1.0, abs_tol=ROTATION_TOLERANCE):
            raise ValueError(f"{unit}: quaternion_xyzw is not of length 1")
        quaternion = convert.xyzw_to_rotation(q)
    if rotation is None and quaternion is None:
        raise ValueError(f"{unit}: neither rotation nor quaternion_xyzw is given")
    if rotation is not None and quaternion is not None and not np.allclose(
            rotation, quaternion, atol=10 * ROTATION_TOLERANCE):
        raise ValueError(f"{unit}: rotation and quaternion_xyzw are not the same rotation")
    result = rotation if rotation is not None else quaternion
    assert result is not None
    return result


def _mount(unit: str, content: object) -> Mount:
    if not isinstance(content, Mapping):
        raise ValueError(f"{unit}: not a mapping of rotation, time_shift_s, ...")
    shift = content.get("time_shift_s", 0.0)
    if isinstance(shift, bool) or not isinstance(shift, int | float) \
            or not math.isfinite(shift):
        raise ValueError(f"{unit}: time_shift_s is {shift!r}, not a number of seconds")
    arm = content.get("lever_arm_m")
    return Mount(unit, _rotation(unit, content), float(shift),
                 None if arm is None else _matrix(arm, (3,), f"{unit}: lever_arm_m"))


def read_mounts(path: Path) -> Mounts:
    """Read a mounts file (``gx3 align`` writes one; other tools may).

    Args:
        path: The file (YAML).

    Returns:
        Each unit's mounting, with the file's name and SHA-256.

    Raises:
        MountsFileError: The file cannot be read, is not YAML, or does not hold a
            reference and a proper rotation for each unit; the message says which.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    hint = "give the mounts.yaml that gx3 align wrote"
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MountsFileError(f"{path}: cannot read it ({exc.strerror or exc}); {hint}") \
            from None
    try:
        content = YAML(typ="safe", pure=True).load(data.decode())
    except (YAMLError, UnicodeDecodeError):
        raise MountsFileError(f"{path}: not YAML; {hint}") from None
    if not isinstance(content, dict) or not isinstance(content.get("reference"), str) \
            or not isinstance(content.get("units"), dict) or not content["units"]:
        raise MountsFileError(f"{path}: not a mounts file (it needs reference: UNIT and "
                              f"units: with each unit's rotation); {hint}")
    reference, units = content["reference"], content["units"]
    try:
        mounts = {str(u): _mount(str(u), c) for u, c in units.items()}
    except ValueError as exc:
        raise MountsFileError(f"{path}: {exc}; {hint}") from None
    if reference in mounts:
        raise MountsFileError(f"{path}: the reference {reference} is among its own units; "
                              f"{hint}")
    return Mounts(reference, mounts, str(content.get("source", "")), path,
                  hashlib.sha256(data).hexdigest())
