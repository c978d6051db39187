"""SE(2) poses as float64 arrays ``[x, y, yaw]``.

One convention throughout the project:

* ``compose(a, b)`` is ``a ⊕ b``: the pose ``b`` (given in frame ``a``) expressed in ``a``'s parent frame.
* ``between(a, b)`` is ``a⁻¹ ⊕ b``: the pose of ``b`` expressed in the frame of ``a``.
  An edge ``(u, v, T_uv)`` of the topological graph stores ``T_uv = between(pose_u, pose_v)``.
* ``transform_points(pose, points)`` maps points given in the frame ``pose`` to its parent frame.

All functions accept a single pose ``(3,)`` or a stack ``(N, 3)`` where noted.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Pose2 = NDArray[np.float64]


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to [-pi, pi)."""
    wrapped = (np.asarray(angle, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def pose(x: float, y: float, yaw: float) -> Pose2:
    return np.array([x, y, wrap_angle(yaw)], dtype=np.float64)


def compose(a: ArrayLike, b: ArrayLike) -> Pose2:
    """``a ⊕ b`` for poses (3,) or stacks (N, 3) (broadcast)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    yaw = wrap_angle(a[..., 2] + b[..., 2])
    return np.stack([x, y, np.asarray(yaw)], axis=-1)


def chain(steps: ArrayLike) -> Pose2:
    """(K + 1, 3): the identity, then each of ``steps`` (K, 3) composed onto the pose before: where
    a chain of relative poses leads, ``compose`` applied in turn, in plain floats (a route's few
    edges cost a numpy call each otherwise)."""
    out = [(0.0, 0.0, 0.0)]
    x = y = yaw = 0.0
    for dx, dy, dyaw in np.asarray(steps, dtype=np.float64).reshape(-1, 3).tolist():
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = x + c * dx - s * dy, y + s * dx + c * dy
        yaw = (yaw + dyaw + math.pi) % (2.0 * math.pi) - math.pi
        out.append((x, y, yaw))
    return np.array(out, dtype=np.float64)


def inverse(a: ArrayLike) -> Pose2:
    """``a⁻¹`` such that ``compose(a, inverse(a))`` is the identity."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -(c * a[..., 0] + s * a[..., 1])
    y = -(-s * a[..., 0] + c * a[..., 1])
    yaw = wrap_angle(-a[..., 2])
    return np.stack([x, y, np.asarray(yaw)], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> Pose2:
    """The pose of ``b`` in the frame of ``a``: ``a⁻¹ ⊕ b``."""
    return compose(inverse(a), b)


def transform_points(frame_pose: ArrayLike, points: ArrayLike) -> NDArray:
    """Points (N, 2) or (N, 3) given in ``frame_pose``'s frame -> the parent frame.

    Only x and y are rotated and shifted; a z column passes through. The dtype is kept.
    """
    p = np.asarray(points)
    fp = np.asarray(frame_pose, dtype=np.float64)
    c, s = np.cos(fp[2]), np.sin(fp[2])
    out = np.array(p, copy=True)
    x = p[:, 0].astype(np.float64)
    y = p[:, 1].astype(np.float64)
    out[:, 0] = c * x - s * y + fp[0]
    out[:, 1] = s * x + c * y + fp[1]
    return out


def distance(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64] | float:
    """Euclidean distance of the translations."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    d = np.hypot(a[..., 0] - b[..., 0], a[..., 1] - b[..., 1])
    return float(d) if d.ndim == 0 else d


def to_matrix(a: ArrayLike) -> NDArray[np.float64]:
    """3x3 homogeneous matrix of a pose."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([[c, -s, a[0]], [s, c, a[1]], [0.0, 0.0, 1.0]])


def from_matrix(m: ArrayLike) -> Pose2:
    m = np.asarray(m, dtype=np.float64)
    return np.array([m[0, 2], m[1, 2], np.arctan2(m[1, 0], m[0, 0])], dtype=np.float64)


def arc_lengths(polyline: ArrayLike) -> NDArray[np.float64]:
    """(K,) the arc length of each vertex of a polyline (K, 2+) from its first: 0 first."""
    points = np.asarray(polyline, dtype=np.float64)[:, :2]
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])


def point_at_arc(polyline: NDArray, arcs: NDArray, arc: float) -> NDArray[np.float64]:
    """The point of a polyline (K, 2+) at arc length ``arc`` (clamped to its ends); ``arcs`` its
    ``arc_lengths``."""
    i = int(np.clip(np.searchsorted(arcs, arc), 1, len(arcs) - 1))
    span = arcs[i] - arcs[i - 1]
    t = 0.0 if span <= 0 else float(np.clip((arc - arcs[i - 1]) / span, 0.0, 1.0))
    return np.asarray(polyline[i - 1] + t * (polyline[i] - polyline[i - 1]), dtype=np.float64)


def distance_to_polyline(points: ArrayLike, polyline: ArrayLike) -> NDArray[np.float64]:
    """(M,) distance of each point (M, 2) to the polyline (K, 2), K >= 1 (a single point: to it)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    path = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
    if len(path) == 1:
        return np.hypot(*(points - path[0]).T)
    starts, vectors = path[:-1], np.diff(path, axis=0)
    lengths2 = np.maximum((vectors**2).sum(axis=1), 1e-12)
    rel = points[:, None, :] - starts[None, :, :]
    along = np.clip((rel * vectors[None]).sum(axis=2) / lengths2, 0.0, 1.0)
    closest = starts[None] + along[..., None] * vectors[None]
    return np.hypot(*(points[:, None, :] - closest).transpose(2, 0, 1)).min(axis=1)


def _compose_jacobians(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """d(a ⊕ b)/da and d(a ⊕ b)/db at (a, b), each (3, 3)."""
    c, s = np.cos(a[2]), np.sin(a[2])
    ja = np.array([[1.0, 0.0, -s * b[0] - c * b[1]], [0.0, 1.0, c * b[0] - s * b[1]], [0.0, 0.0, 1.0]])
    jb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return ja, jb


def inverse_with_covariance(a: ArrayLike, cov: ArrayLike) -> tuple[Pose2, NDArray[np.float64]]:
    """``a⁻¹`` and its covariance (3, 3), to first order."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[2]), np.sin(a[2])
    # a⁻¹ = (-(c x + s y), s x - c y, -yaw)
    j = np.array([[-c, -s, s * a[0] - c * a[1]], [s, -c, c * a[0] + s * a[1]], [0.0, 0.0, -1.0]])
    return inverse(a), j @ np.asarray(cov, dtype=np.float64) @ j.T


def compose_with_covariance(a: ArrayLike, cov_a: ArrayLike, b: ArrayLike, cov_b: ArrayLike) -> tuple[Pose2, NDArray[np.float64]]:
    """``a ⊕ b`` of independent uncertain poses and its covariance (3, 3), to first order."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ja, jb = _compose_jacobians(a, b)
    return compose(a, b), ja @ np.asarray(cov_a, dtype=np.float64) @ ja.T + jb @ np.asarray(cov_b, dtype=np.float64) @ jb.T
