"""A unit's Allan deviation as a picture: log-log, each axis, the lines Kalibr reads.

Rerun's plots have a time axis and a linear value axis (0.41), and an Allan deviation
needs both axes logarithmic, so the picture is drawn with matplotlib's Agg backend (no
display) into a PNG, SVG or PDF: one panel per sensor, each axis's curve, the -1/2 and
+1/2 slope lines of the worst axis and the points Kalibr reads off them (tau = 1 s and
3 s), the white noise as the unit's filter shapes it, and the span fitted. matplotlib
says what it does (building its font cache) through its own log, which is kept off the
user's terminal.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from bridge.analysis.allan import FLICKER_FLOOR, white_variance
from bridge.analysis.noise import SensorNoise, UnitNoise, stretch_text

__all__ = ["write_allan_plot"]

_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")  # x red, y green, z blue, as in the viewer


def _panel(ax: object, noise: UnitNoise, sensor: SensorNoise) -> None:
    """One sensor's curves, lines, read-off points and fitted span on a log-log axis."""
    from matplotlib.axes import Axes

    assert isinstance(ax, Axes)
    tau = noise.tau
    for i, colour in enumerate(_COLOURS):
        fit = sensor.axes[i]
        ax.loglog(tau, sensor.adev[i], color=colour, lw=1.6, label=f"{'xyz'[i]}")
        low = fit.bias_instability * FLICKER_FLOOR
        ax.plot([fit.bias_instability_tau], [low], "v", color=colour, ms=6, mfc="none")
    n, k = sensor.noise_density, sensor.random_walk
    worst_n = max(sensor.axes, key=lambda a: a.noise_density)
    worst_k = max(sensor.axes, key=lambda a: a.random_walk)
    span = np.geomspace(tau[0] / 2, tau[-1] * 2, 50)
    ax.loglog(span, n / np.sqrt(span), "k--", lw=1.0,
              label=f"N: slope -½, τ = 1 s → {n:.3g}")
    factors = np.round(tau * noise.rate_hz).astype(np.int64)
    shaped = n * np.sqrt(white_variance(factors, noise.filter_width, noise.decimation))
    ax.loglog(tau, shaped, color="0.45", ls="-.", lw=1.0,
              label=f"N through the filter (M {noise.filter_width}, D {noise.decimation})")
    ax.loglog(span, k * np.sqrt(span / 3.0), "k:", lw=1.2,
              label=f"K: slope +½, τ = 3 s → {sensor.walk_text()}")
    ax.plot([1.0], [worst_n.noise_density], "ko", ms=7)
    ax.plot([3.0], [worst_k.random_walk], "ks", ms=7)
    fitted = [fit.fit_tau for fit in sensor.axes]
    ax.axvspan(min(f[0] for f in fitted), max(f[1] for f in fitted), color="0.92",
               zorder=0, label="τ fitted")
    finite = sensor.adev[np.isfinite(sensor.adev)]
    if finite.size:  # room for the curves and both read-off points
        ax.set_ylim(min(float(finite.min()), k) / 2, max(float(finite.max()), n) * 2)
    ax.set_xlim(span[0], span[-1])
    ax.grid(True, which="major", alpha=0.5)
    ax.grid(True, which="minor", alpha=0.15)
    ax.set_xlabel("averaging time τ [s]")
    unit, walk_unit = (("m/s²", "m/s³") if sensor.unit == "m/s^2" else ("rad/s", "rad/s²"))
    ax.set_ylabel(f"Allan deviation [{unit}]")
    ax.set_title(f"{sensor.sensor}: N {n:.3g} {unit}/√Hz, K {sensor.walk_text()} "
                 f"{walk_unit}/√Hz", fontsize=10)
    ax.legend(fontsize=8, loc="upper center")  # the read-off points sit low on the left


def write_allan_plot(path: Path, noise: UnitNoise, kind: str = "png") -> None:
    """Draw a unit's Allan deviation into a picture.

    Args:
        path: The file to write (replaced if it exists: the caller decides).
        noise: The unit's noise.
        kind: Its format: ``png``, ``svg`` or ``pdf``.
    """
    logging.getLogger("matplotlib").setLevel(logging.ERROR)
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 5.2), dpi=110, layout="constrained")
    left, right = figure.subplots(1, 2)
    _panel(left, noise, noise.accelerometer)
    _panel(right, noise, noise.gyroscope)
    figure.suptitle(f"unit {noise.unit}: {stretch_text(noise)}; ▽ flat minimum "
                    "(bias instability × 0.664); ● ■ Kalibr's read-off", fontsize=10)
    figure.savefig(path, format=kind)
