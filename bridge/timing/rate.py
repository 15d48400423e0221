"""Events per second over a recent window of a running count (status and dashboards)."""

from __future__ import annotations


class RateWindow:
    """The rate of a running count over a recent window.

    Args:
        span_s: The window, in seconds.
    """

    def __init__(self, span_s: float) -> None:
        self.span_s = span_s
        self._points: list[tuple[float, int]] = []

    def rate(self, now: float, count: int) -> float:
        """The count's rate now.

        Args:
            now: The time, in seconds on any clock that only moves forward.
            count: The count at ``now``.

        Returns:
            Per second, from the oldest point inside the window to (now, count); 0 with
            one point.
        """
        self._points = [(t, n) for t, n in self._points if now - t <= self.span_s]
        self._points.append((now, count))
        (t0, n0), (t1, n1) = self._points[0], self._points[-1]
        return (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0
