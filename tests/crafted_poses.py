"""Poses along a drawn route, for tests that build graphs of locations by hand."""

from __future__ import annotations

import numpy as np


def poses_along(corners: list[tuple[float, float]], spacing: float) -> list[np.ndarray]:
    """Poses every ``spacing`` metres along the polyline ``corners``, each facing along its leg
    (the last corner itself left out)."""
    poses = []
    for (x0, y0), (x1, y1) in zip(corners[:-1], corners[1:], strict=True):
        yaw = float(np.arctan2(y1 - y0, x1 - x0))
        for t in np.arange(0.0, np.hypot(x1 - x0, y1 - y0) - 1e-9, spacing):
            poses.append(np.array([x0 + t * np.cos(yaw), y0 + t * np.sin(yaw), yaw]))
    return poses
