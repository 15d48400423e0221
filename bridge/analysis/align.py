"""Units on one body: how each is mounted against a reference, and how its time sits.

Units bolted to one rigid body turn together: read at the same physical instant, their
angular rates are one rate in two sets of axes, omega_unit = R omega_ref (plus a
constant, their gyro biases' difference). So the rates give the rotation R and the time
shift between the two units' time stamps, found together: a Procrustes fit of R at a
shift, then a Gauss-Newton step of the shift along the rate's slope, until the shift
settles, after a first guess from the cross-correlation of the rates' magnitudes
(which no rotation changes). Their specific forces differ by where each sits: R^T
f_unit - f_ref = alpha x r + omega x (omega x r) (plus a constant: the accelerometer
biases), linear in the lever arm r, so a least-squares fit gives r wherever the body's
angular acceleration alpha and rate omega vary about every axis; both sides are
smoothed alike over ``SMOOTH_S``, which leaves the linear relation exact and the
derivative's noise small.

Everything is done on one uniform grid of instants over the stretch both units
cover (at the slower unit's rate, at most ``MAX_GRID_HZ``), each unit read at them by
cubic Hermite interpolation (within 1.3e-4 of a 0.8 Hz sway's amplitude at 25 Hz, 2e-6
at 100 Hz); instants inside a unit's gaps are left out. Each
result's 1-sigma comes from the fit's residual and the information the motion gave,
widened by the residual's correlation time. Motion that cannot give a rotation (a
still body, or turns about one axis only) is refused, saying what to record.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bridge._text import utc_text
from bridge.analysis.mounts import Mount, MountFit, Mounts
from bridge.exceptions import AlignmentError
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.protocol.table import REPLIES, TICKS_PER_SECOND

__all__ = ["MAX_GRID_HZ", "MAX_SHIFT_S", "MIN_OVERLAP_S", "UnitMotion", "align",
           "fit_mount", "unit_motion"]

FloatArray = npt.NDArray[np.float64]

#: The longest time shift looked for, either way: hosts whose clocks are further apart
#: need their clocks fixed first (``docs/guides/time.md``).
MAX_SHIFT_S = 2.0
#: The shortest stretch two units must share.
MIN_OVERLAP_S = 10.0
#: Below this RMS rate (rad/s), a body stood still; a rate that varies by less than it
#: (RMS), or along a second direction by less than this fraction of its strongest or
#: MIN_TURN_RAD_S, turned about one axis.
STILL_RAD_S = 0.1
ONE_AXIS_RATIO = 0.1
MIN_TURN_RAD_S = 0.03
#: The least correlation of the rates' magnitudes at the best shift, and the most the
#: rotation may leave of the rates (RMS, over theirs), for units on one rigid body.
MIN_MATCH = 0.5
MAX_LEFT = 0.25
#: Over this window both sides of the lever-arm fit are averaged.
SMOOTH_S = 0.04
#: The lever arm is given where the weakest direction moves the forces by at least this
#: much per metre (RMS, 1/s²), and its 1-sigma is at most LEVER_SIGMA_M on every axis.
MIN_LEVER_GAIN = 1.0
LEVER_SIGMA_M = 0.01
#: Neighbouring samples further apart than this many periods are a gap.
GAP_PERIODS = 1.5
#: The densest grid of instants worked on, Hz: faster units are read at it (a hand's
#: motion is below 1 Hz, and their filters have made their samples alike anyway).
MAX_GRID_HZ = 200.0
_SHIFT_TOLERANCE_S = 1e-9
_ITERATIONS = 30
_AXES = "xyz"

#: Where a record's angular rate and specific force come from: the quantity, and
#: whether it is an integral over the output period (divided by it to give the rate).
RATE_SOURCES = (("ang_rate", False), ("delta_ang", True))
FORCE_SOURCES = (("accel", False), ("delta_vel", True))
#: Record types that carry an angular rate, for the error that asks for one.
RATE_RECORDS = tuple(code for code, reply in sorted(REPLIES.items())
                     if {f.name for f in reply.fields} & {q for q, _ in RATE_SOURCES})


@dataclass(frozen=True)
class UnitMotion:
    """One unit's angular rate and specific force at its sample instants.

    Attributes:
        unit: The unit.
        time_ns: Each sample's instant (host ns since the epoch), ascending.
        rate: Angular rate, rad/s, (n, 3), the unit's axes.
        force: Specific force, m/s², (n, 3), the unit's axes; None where its records
            carry none.
    """

    unit: str
    time_ns: npt.NDArray[np.int64]
    rate: FloatArray
    force: FloatArray | None


def _quantity(table: Mapping[str, np.ndarray], rows: np.ndarray,
              sources: Sequence[tuple[str, bool]]) -> FloatArray | None:
    """The first of ``sources`` the rows hold, per second (integrals over their period)."""
    for name, integral in sources:
        names = [f"{name}_{a}" for a in _AXES]
        if names[0] not in table:
            continue
        values = np.column_stack([table[n][rows] for n in names]).astype(np.float64)
        if not np.isfinite(values).any():
            continue
        if integral:
            ticks = table["ticks"][rows][np.isfinite(values).all(axis=1)]
            step = float(np.median(np.diff(ticks))) if len(ticks) > 1 else 0.0
            values = values * (TICKS_PER_SECOND / step) if step > 0 else values * np.nan
        return values
    return None


def unit_motion(table: Mapping[str, np.ndarray], unit: str) -> UnitMotion:
    """A unit's rates and forces from an export's sample table.

    The angular rate from ang_rate, else delta_ang over the output period; the specific
    force from accel (g, given in m/s²), else delta_vel over the period. Rows without a
    rate, or not after the row before, are left out.

    Args:
        table: ``bridge.export.tables.sample_table``'s columns.
        unit: The unit.

    Returns:
        Its motion.

    Raises:
        AlignmentError: It has no samples in the table, or none of its records carries
            an angular rate.
    """
    rows = np.flatnonzero(table["unit"] == unit)
    if not len(rows):
        raise AlignmentError(f"unit {unit} has no samples in this span; check --start and "
                             "--end (seconds from the first sample, or ISO times)")
    rate = _quantity(table, rows, RATE_SOURCES)
    if rate is None:
        raise AlignmentError(
            f"unit {unit}: its records carry no angular rate; stream a record type "
            "that does (" + ", ".join(f"0x{c:02X}" for c in RATE_RECORDS) + ")")
    force = _quantity(table, rows, FORCE_SOURCES)
    time_ns = np.asarray(table["time_ns"][rows], np.int64)
    keep = np.flatnonzero(np.isfinite(rate).all(axis=1))
    keep = keep[np.r_[True, np.diff(time_ns[keep]) > 0]]
    return UnitMotion(unit, time_ns[keep], rate[keep],
                      None if force is None else force[keep] * STANDARD_GRAVITY)


class _Signal:
    """A unit's samples read at any instants: cubic Hermite, nothing across a gap.

    Args:
        t: Sample instants, seconds, ascending.
        values: (n, k) values.
    """

    def __init__(self, t: FloatArray, values: FloatArray) -> None:
        self.t, self.values = t, values
        self.slope = np.gradient(values, t, axis=0)
        span = np.diff(t)
        self.period = float(np.median(span))
        good = span <= GAP_PERIODS * self.period
        # an interval's end slopes look across its neighbours: none may be a gap
        self.good = good & np.r_[True, good[:-1]] & np.r_[good[1:], True]

    def at(self, x: FloatArray) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
        """Values and time derivatives at ``x``, and where they are known.

        Args:
            x: Instants, seconds.

        Returns:
            (values, derivatives, known), (len(x), k), (len(x), k), (len(x),).
        """
        t = self.t
        i = np.searchsorted(t, x, side="right") - 1
        known = (i >= 0) & (i < len(t) - 1)
        i = np.clip(i, 0, len(t) - 2)
        known &= self.good[i]
        h = (t[i + 1] - t[i])[:, None]
        u = (x - t[i])[:, None] / h
        y0, y1 = self.values[i], self.values[i + 1]
        m0, m1 = self.slope[i] * h, self.slope[i + 1] * h
        u2, u3 = u * u, u * u * u
        value = ((2 * u3 - 3 * u2 + 1) * y0 + (u3 - 2 * u2 + u) * m0
                 + (3 * u2 - 2 * u3) * y1 + (u3 - u2) * m1)
        slope = ((6 * u2 - 6 * u) * y0 + (3 * u2 - 4 * u + 1) * m0
                 + (6 * u - 6 * u2) * y1 + (3 * u2 - 2 * u) * m1) / h
        return value, slope, known


def _skew(v: FloatArray) -> FloatArray:
    """[v]x for each row of v: (n, 3) -> (n, 3, 3)."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _correlation_time(residual: FloatArray) -> float:
    """How many samples a residual's errors stay alike: 1 + 2 sum of its autocorrelation.

    Summed over lags until it first stops being positive (the initial positive
    sequence), averaged over the axes: what a 1-sigma from independent samples is
    widened by (its square root).
    """
    e = residual - residual.mean(axis=0)
    n = len(e)
    size = 1 << (2 * n - 1).bit_length()
    spectrum = np.fft.rfft(e, size, axis=0)
    auto = np.fft.irfft(spectrum * spectrum.conj(), size, axis=0)[:n].sum(axis=1)
    if not auto[0] > 0:
        return 1.0
    rho = auto / auto[0]
    stop = np.flatnonzero(rho <= 0)
    last = int(stop[0]) if len(stop) else n
    return float(max(1.0, 1.0 + 2.0 * rho[1:last].sum()))


def _procrustes(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """R (proper) and c minimising sum |b - R a - c|^2 over the rows."""
    a0, b0 = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((b - b0).T @ (a - a0))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    return r, b0 - r @ a0


def _when(origin_ns: int, seconds: float) -> str:
    return utc_text(origin_ns + round(seconds * 1e9), "seconds")


def _check_turning(rate: FloatArray, unit: str, span: str) -> None:
    """Refuse rates that cannot show a rotation: a still body, or turns about one axis.

    The fit takes out a constant rate (the gyros' biases), so a steady spin shows no
    more than a still body does about the other axes: what counts is how the rate
    varies, about at least two axes.
    """
    size = math.sqrt(float(np.mean(np.sum(rate * rate, axis=1))))
    spread, axes = np.linalg.eigh(np.cov(rate.T))
    strongest, second = (math.sqrt(max(float(v), 0.0)) for v in spread[[2, 1]])
    if size < STILL_RAD_S:
        raise AlignmentError(
            f"{unit} hardly turned {span} (its rate was {size:.3f} rad/s RMS): the body "
            "stood still; record it turned by hand about all three of its axes, a minute "
            "of brisk turns back and forth")
    if strongest < STILL_RAD_S or second < max(ONE_AXIS_RATIO * strongest, MIN_TURN_RAD_S):
        axis = axes[:, 2] if strongest >= STILL_RAD_S else rate.mean(axis=0) / size
        i = int(np.argmax(np.abs(axis)))
        named = (f"its {_AXES[i]} axis" if abs(axis[i]) > 0.9 else
                 "an axis near ({:+.2f}, {:+.2f}, {:+.2f})".format(*axis))
        others = " and ".join(a for a in _AXES if a != _AXES[i])
        raise AlignmentError(
            f"{unit} turned about one axis only ({named}) {span}: a rotation about it "
            f"cannot be seen; record the body turned by hand about its {others} axes too, "
            "a minute of brisk turns back and forth")


def _coarse_shift(a: FloatArray, a_known: npt.NDArray[np.bool_], b: FloatArray,
                  b_known: npt.NDArray[np.bool_], step: float) -> tuple[float, float]:
    """The shift (s) that best lines up the rates' magnitudes, and their correlation there.

    b(t - shift) matches a(t): the peak of sum_k |a|[k] |b|[k - lag] over lags within
    ``MAX_SHIFT_S``, refined by a parabola through it and its neighbours.
    """
    def centred(v: FloatArray, known: npt.NDArray[np.bool_]) -> FloatArray:
        size = np.linalg.norm(v, axis=1)
        return np.where(known, size - size[known].mean(), 0.0)

    x, y = centred(a, a_known), centred(b, b_known)
    n = len(x)
    size = 1 << (2 * n - 1).bit_length()
    corr = np.fft.irfft(np.fft.rfft(x, size) * np.fft.rfft(y, size).conj(), size)
    reach = min(int(MAX_SHIFT_S / step), n - 1)
    lags = np.arange(-reach, reach + 1)
    values = corr[lags % size]
    best = int(np.argmax(values))
    offset = 0.0
    if 0 < best < len(values) - 1:
        left, mid, right = values[best - 1 : best + 2]
        bend = left - 2 * mid + right
        offset = 0.5 * (left - right) / bend if bend < 0 else 0.0
    match = float(values[best] / math.sqrt(float(x @ x) * float(y @ y) or 1.0))
    return (lags[best] + offset) * step, match


@dataclass(frozen=True)
class _Rates:
    """The fit of the rates: rotation, shift, gyro offset, their covariance, residual."""

    rotation: FloatArray
    shift_s: float
    offset: FloatArray
    sigma_deg: FloatArray
    shift_sigma_s: float
    residual: float
    left: float  # the residual's RMS over the rates'


def _slope(a: FloatArray, known: npt.NDArray[np.bool_], step: float
           ) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """The rates' time derivative as a difference across ``SMOOTH_S``, and where known.

    Never from the instant itself, nor from the samples its interpolation used (at
    least 3 grid steps either way): a derivative that shared an instant's noise would
    pull the shift that zeroes its product with the residual.
    """
    half = max(3, round(SMOOTH_S / 2 / step))
    out = np.zeros_like(a)
    out[half:-half] = (a[2 * half:] - a[: -2 * half]) / (2 * half * step)
    ok = np.zeros_like(known)
    ok[half:-half] = known[2 * half:] & known[: -2 * half]
    return out, ok


def _fit_rates(a: FloatArray, a_known: npt.NDArray[np.bool_], unit: _Signal,
               grid: FloatArray, step: float, shift: float) -> _Rates:
    """Rotation and shift together, from a first guess of the shift.

    Gauss-Newton on the shift, its Jacobian the reference's rate's slope turned into
    the unit's axes: what b(t - s) changes by with s, free of either unit's noise at t.
    """
    slope, slope_known = _slope(a, a_known, step)
    for _ in range(_ITERATIONS):
        b, _, known = unit.at(grid - shift)
        ok = a_known & known & slope_known
        ra, rb = a[ok], b[ok]
        r, c = _procrustes(ra, rb)
        e = rb - ra @ r.T - c
        rd = slope[ok] @ r.T
        step_s = float(np.sum(rd * e) / np.sum(rd * rd))
        shift += step_s
        if abs(step_s) < _SHIFT_TOLERANCE_S:
            break
    # The information of (small turn about the reference's axes, shift, offset):
    # e = b(t - s) - R a - c, de/dtheta = R [a]x, de/ds = -b' (taken as R a'), de/dc = -I.
    n = len(ra)
    info = np.zeros((7, 7))
    info[:3, :3] = np.sum(ra * ra) * np.eye(3) - ra.T @ ra
    info[:3, 3] = np.cross(ra, rd @ r).sum(axis=0)
    info[:3, 4:] = _skew(ra.sum(axis=0)) @ r.T
    info[3, 3] = np.sum(rd * rd)
    info[3, 4:] = rd.sum(axis=0)
    info[4:, 4:] = n * np.eye(3)
    info = np.triu(info) + np.triu(info, 1).T
    variance = float(np.sum(e * e)) / max(3 * n - 7, 1) * _correlation_time(e)
    cov = variance * np.linalg.inv(info)
    residual = math.sqrt(float(np.mean(np.sum(e * e, axis=1))))
    spread = math.sqrt(float(np.mean(np.sum((rb - rb.mean(axis=0)) ** 2, axis=1))))
    return _Rates(r, shift, c, np.degrees(np.sqrt(np.diag(cov)[:3])),
                  math.sqrt(float(cov[3, 3])), residual, residual / max(spread, 1e-12))


def _boxcar(x: FloatArray, width: int) -> FloatArray:
    """Centred moving average over ``width`` (odd) rows; NaN where it runs off the ends."""
    total = np.cumsum(np.concatenate([np.zeros((1, *x.shape[1:])), x]), axis=0)
    out = np.full(x.shape, np.nan)
    half = width // 2
    out[half : len(x) - half] = (total[width:] - total[:-width]) / width
    return out


@dataclass(frozen=True)
class _Lever:
    arm: FloatArray | None
    sigma: FloatArray | None
    note: str
    residual: float | None


def _fit_lever(grid: FloatArray, step: float, known: npt.NDArray[np.bool_],
               rate: FloatArray, ref_force: _Signal, unit_force: _Signal,
               rates: _Rates) -> _Lever:
    """The lever arm from R^T f_unit - f_ref = [alpha]x r + [omega]x^2 r + d."""
    r = rates.rotation
    fr, _, fr_known = ref_force.at(grid)
    fu, _, fu_known = unit_force.at(grid - rates.shift_s)
    ok = known & fr_known & fu_known
    alpha = np.gradient(rate, step, axis=0)
    ok[1:-1] &= ok[:-2] & ok[2:]  # the derivative looks at both neighbours
    design = _skew(alpha) + _skew(rate) @ _skew(rate)
    width = max(1, round(SMOOTH_S / step)) | 1
    whole = _boxcar(ok[:, None].astype(np.float64), width)[:, 0] > 1 - 1e-9
    lhs = _boxcar(np.where(ok[:, None, None], design, 0.0), width)[whole]
    rhs = _boxcar(np.where(ok[:, None], fu @ r - fr, 0.0), width)[whole]
    n = len(rhs)
    if n < 10:
        return _Lever(None, None, "too few instants where both units' forces are known",
                      None)
    lhs, rhs = lhs - lhs.mean(axis=0), rhs - rhs.mean(axis=0)
    normal = np.einsum("kij,kil->jl", lhs, lhs)
    arm = np.linalg.solve(normal, np.einsum("kij,ki->j", lhs, rhs))
    e = rhs - lhs @ arm
    residual = math.sqrt(float(np.mean(np.sum(e * e, axis=1))))
    variance = float(np.sum(e * e)) / max(3 * n - 6, 1) * _correlation_time(e)
    sigma = np.sqrt(np.diag(variance * np.linalg.inv(normal)))
    gains, directions = np.linalg.eigh(normal / n)
    weakest = math.sqrt(max(float(gains[0]), 0.0))
    if weakest < MIN_LEVER_GAIN or sigma.max() > LEVER_SIGMA_M:
        axis = directions[:, 0]
        i = int(np.argmax(np.abs(axis)))
        along = (f"the reference's {_AXES[i]} axis" if abs(axis[i]) > 0.9 else
                 "({:+.2f}, {:+.2f}, {:+.2f}) in the reference's axes".format(*axis))
        return _Lever(None, None, (
            f"not observable: along {along} the body's turning moved the forces by only "
            f"{weakest:.2f} m/s² per metre of lever arm (1-sigma {sigma.max() * 100:.1f} "
            "cm); turn the body back and forth more briskly about every axis"), residual)
    return _Lever(arm, sigma, "", residual)


def fit_mount(ref: UnitMotion, unit: UnitMotion) -> Mount:
    """How ``unit`` is mounted against ``ref``, and how its time sits against ``ref``'s.

    Args:
        ref: The reference's motion.
        unit: The unit's motion.

    Returns:
        The mounting: rotation, time shift, lever arm where observable, each with its
        1-sigma, the residuals and the span used.

    Raises:
        AlignmentError: They do not overlap in time long enough, the body did not turn
            enough to show a rotation, or the unit does not move with the reference;
            the message says what to record.
    """
    lo = max(int(ref.time_ns[0]), int(unit.time_ns[0])) if len(ref.time_ns) and len(
        unit.time_ns) else 0
    hi = min(int(ref.time_ns[-1]), int(unit.time_ns[-1])) if lo else 0
    if (hi - lo) / 1e9 < MIN_OVERLAP_S:
        together = (f"they share only {max(hi - lo, 0) / 1e9:.1f} s" if lo and hi > lo
                    else "they have no samples at the same time")
        raise AlignmentError(
            f"{ref.unit} and {unit.unit}: {together}; align units recorded together, at "
            f"least {MIN_OVERLAP_S:g} s of it while the body is turned by hand (check "
            "--start and --end)")

    def signal(motion: UnitMotion, values: FloatArray) -> _Signal:
        return _Signal((motion.time_ns - lo) / 1e9, values)

    ref_rate, unit_rate = signal(ref, ref.rate), signal(unit, unit.rate)
    step = max(ref_rate.period, unit_rate.period, 1.0 / MAX_GRID_HZ)
    grid = np.arange(0.0, (hi - lo) / 1e9, step)
    a, _, a_known = ref_rate.at(grid)
    span = f"from {_when(lo, 0.0)} to {_when(hi, 0.0)}"
    _check_turning(a[a_known], ref.unit, span)
    b, _, b_known = unit_rate.at(grid)
    both = float(np.sum(a_known & b_known)) * step
    if both < MIN_OVERLAP_S:
        raise AlignmentError(
            f"{ref.unit} and {unit.unit}: they share only {both:.1f} s of samples {span} "
            f"(gaps); align units recorded together, at least {MIN_OVERLAP_S:g} s of it "
            "while the body is turned by hand")
    shift, match = _coarse_shift(a, a_known, b, b_known, step)
    if match < MIN_MATCH:
        raise AlignmentError(
            f"{unit.unit} does not turn with {ref.unit} {span} (their rates match by "
            f"{match:.2f} at best, within ±{MAX_SHIFT_S:g} s): align units on one rigid "
            f"body, and set the hosts' clocks within {MAX_SHIFT_S:g} s of each other")
    rates = _fit_rates(a, a_known, unit_rate, grid, step, shift)
    if rates.left > MAX_LEFT or abs(rates.shift_s) > MAX_SHIFT_S:
        raise AlignmentError(
            f"{unit.unit}'s rates are not {ref.unit}'s turned {span} (the best rotation "
            f"leaves {rates.left:.0%} of them): align units on one rigid body")
    b, _, b_known = unit_rate.at(grid - rates.shift_s)
    known = a_known & b_known
    used = grid[known]
    if ref.force is None or unit.force is None:
        lacking = ref.unit if ref.force is None else unit.unit
        lever = _Lever(None, None, f"{lacking}'s records carry no specific force "
                                   "(accel or delta_vel)", None)
    else:
        mean_rate = 0.5 * (a + (b - rates.offset) @ rates.rotation)
        lever = _fit_lever(grid, step, known, np.where(known[:, None], mean_rate, 0.0),
                           signal(ref, ref.force), signal(unit, unit.force), rates)
    fit = MountFit(rotation_sigma_deg=rates.sigma_deg, time_shift_sigma_s=rates.shift_sigma_s,
                   lever_arm_sigma_m=lever.sigma, lever_arm_note=lever.note,
                   rate_residual_rad_s=rates.residual, force_residual_m_s2=lever.residual,
                   span_ns=(lo + round(used[0] * 1e9), lo + round(used[-1] * 1e9)),
                   samples=len(used))
    return Mount(unit.unit, rates.rotation, rates.shift_s, lever.arm, fit)


def align(motions: Sequence[UnitMotion], source: str = "",
          on_unit: Callable[[str], None] | None = None) -> Mounts:
    """Every unit's mounting against the first, the reference.

    Args:
        motions: The reference's motion, then each other unit's.
        source: What they were read from (the archive's name), for the record.
        on_unit: Hears each unit as it is done.

    Returns:
        The mountings.

    Raises:
        AlignmentError: Fewer than two units, one given twice, or one whose motion
            cannot give its mounting (``fit_mount``).
    """
    names = [m.unit for m in motions]
    if len(motions) < 2:
        raise AlignmentError("align needs two units or more: the reference first, then "
                             "each unit to align against it (-u REF -u UNIT ...)")
    if len(set(names)) < len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise AlignmentError(f"unit {twice} is given twice; give each unit once")
    ref, *others = motions
    mounts = {}
    for unit in others:
        mounts[unit.unit] = fit_mount(ref, unit)
        if on_unit is not None:
            on_unit(unit.unit)
    return Mounts(ref.unit, mounts, source)
