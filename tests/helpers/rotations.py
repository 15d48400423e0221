"""Rotation matrices by the textbook formulas, independent of ``bridge.protocol.convert``."""

from __future__ import annotations

import numpy as np


def rotation(xyzw: np.ndarray) -> np.ndarray:
    """Hamilton rotation matrix of an x, y, z, w quaternion (textbook formula)."""
    x, y, z, w = xyzw / np.linalg.norm(xyzw)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
