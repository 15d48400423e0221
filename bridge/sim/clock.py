"""A unit's crystal: a constant rate error plus a slow, smooth, seeded wander.

Real crystals drift with temperature by a few ppm over minutes. The wander is a
sum of a few sinusoids in the rate error, so its integral (the phase) has a closed
form and the map host -> device is smooth and strictly increasing; its inverse is
found by Newton's method to well under a nanosecond. Without wander the maps are
the plain linear ones, bit for bit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

_COMPONENTS = 3


class UnitClock:
    """Device seconds since ``t0`` as a function of host monotonic seconds."""

    def __init__(self, t0: float, ppm: float, wander_ppm: float = 0.0,
                 wander_period_s: float = 300.0, seed: int = 0) -> None:
        if wander_ppm and wander_period_s <= 0:
            raise ValueError(f"clock wander period must be positive, got {wander_period_s}")
        self.t0 = t0
        self.scale = 1.0 + ppm * 1e-6
        rng = np.random.default_rng(seed)
        # Periods spread around the nominal time scale; weights sum to one so the
        # rate excursion stays within +-wander_ppm.
        self._omega = 2 * math.pi / (wander_period_s * rng.uniform(0.6, 1.6, _COMPONENTS))
        weights = rng.uniform(0.5, 1.0, _COMPONENTS)
        self._amp = wander_ppm * 1e-6 * weights / weights.sum()
        self._phase = rng.uniform(0, 2 * math.pi, _COMPONENTS)
        self.wanders = wander_ppm != 0.0
        self._terms = list(zip(self._amp.tolist(), self._omega.tolist(), self._phase.tolist(),
                               strict=True))

    def rate_ppm(self, host: npt.ArrayLike) -> np.ndarray:
        """The clock's rate error at host time ``host`` (ppm), for tests and plots."""
        tau = np.asarray(host, np.float64)[..., None] - self.t0
        wander = (self._amp * np.sin(self._omega * tau + self._phase)).sum(axis=-1)
        return np.asarray((self.scale - 1.0 + wander) * 1e6)

    def _wander(self, tau: np.ndarray) -> np.ndarray:
        arg = self._omega * tau[..., None] + self._phase
        return np.asarray(((np.cos(self._phase) - np.cos(arg)) * self._amp / self._omega)
                          .sum(axis=-1))

    def _wander_rate(self, tau: np.ndarray) -> np.ndarray:
        return np.asarray((self._amp * np.sin(self._omega * tau[..., None] + self._phase))
                          .sum(axis=-1))

    def device(self, host: npt.ArrayLike) -> Any:
        """Device seconds at host time ``host`` (a float for a scalar, else an array)."""
        tau = np.asarray(host, np.float64) - self.t0
        if not self.wanders:
            return (tau * self.scale)[()]
        return (tau * self.scale + self._wander(tau))[()]

    def host(self, device: npt.ArrayLike) -> Any:
        """Host time at device seconds ``device``: the exact inverse of ``device``."""
        if self.wanders and np.ndim(device) == 0:
            return self._host_scalar(float(device))  # type: ignore[arg-type]
        dev = np.asarray(device, np.float64)
        if not self.wanders:
            return (self.t0 + dev / self.scale)[()]
        tau = dev / self.scale
        for _ in range(3):
            tau = tau - (tau * self.scale + self._wander(tau) - dev) / (
                self.scale + self._wander_rate(tau))
        return (self.t0 + tau)[()]

    def _host_scalar(self, device: float) -> float:
        """``host`` for one value without NumPy's per-call cost (same arithmetic)."""
        tau = device / self.scale
        for _ in range(3):
            phase = rate = 0.0
            for amp, omega, phi in self._terms:
                phase += (math.cos(phi) - math.cos(omega * tau + phi)) * amp / omega
                rate += amp * math.sin(omega * tau + phi)
            tau = tau - (tau * self.scale + phase - device) / (self.scale + rate)
        return self.t0 + tau
