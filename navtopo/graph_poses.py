"""Where the locations lie in the map frame: a pose-graph relaxation of the graph of locations,
used only to turn a map-frame goal into the paper's ``(v_goal, T_goal)``.

A location's odometry hint is the odometry pose where it was made: exact with precise odometry,
but with noisy odometry it drifts without bound (a heading random walk of 0.5°/m is ~16° after a
kilometre). The edges' relative poses come from scan matching and do not drift. This module finds
the vertex poses that best agree with both (Gauss-Newton on SE(2), as in Grisetti et al., "A
Tutorial on Graph-Based SLAM", 2010): every edge with its matching's accuracy, and the hints'
relative poses between locations made one after the other, with a noise that grows with the
odometry travelled in between — estimated from the data, as the spread of the hints' disagreement
with the scan-matched edges, so no setting has to be named. The first location, made at the
mapping run's first pose, anchors the map frame. Navigation itself never uses these poses: it
lives in the locations' own frames.

The edges do not drift, but each is off by ~0.25° (rms, precise or noisy odometry alike: matching
two single-scan grids of 0.1 m cells, whose optimum itself sits that far from the truth), and on a
tree of locations nothing closes: chained over twenty edges to a far branch that is a degree,
1-1.5 m at 80 m. A graph made with ``NavTopoConfig.lidar_hints`` also keeps, per location, the
pose of a lidar odometry (KISS-ICP refined point-to-line, ``navkit.odometry``) run alongside the
mapping: scan-to-map registration of every scan drifts far less than either. On the noisy drives of
generated 150 m trees (seeds 101-103) the map poses were 0.02-0.08 m off at most, kiss-icp alone
0.09-0.25 m, the relaxation over the odometry hints 0.22-0.90 m. The relaxation takes the lidar
hints where the odometry is the odd one out (``hint_chain``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sparse
from numpy.typing import NDArray
from scipy.sparse.linalg import spsolve

from navkit.geometry import arc_lengths, between, wrap_angle
from navtopo.graph import TopologicalGraph

EDGE_SIGMA_XY = 0.05  # m: scan matching of location grids (edge errors ~4 cm median, up to 0.2 m)
# (edge rotation errors ~0.3° median, up to 2°). It is also subtracted from the hints' measured
# disagreement with the edges: at 1° it explained away the whole heading noise of 0.5°/m odometry
# and the relaxation trusted drifting hints (map poses 1.3 m off on a generated noisy ring, 0.5°:
# 1.1 m; no change with precise odometry; benchmarks: BENCHMARKS.md, "Design choices: the
# relaxation's edge heading sigma for map poses")
EDGE_SIGMA_YAW = np.radians(0.5)
HINT_FLOOR_XY = 0.001  # m: no relative hint is trusted more than this ...
HINT_FLOOR_YAW = np.radians(0.01)  # ... or this
# m/sqrt(m): the least noise a lidar hint is given per metre between two locations. Read off the
# data, the lidar hints' noise is nil (the lidar odometry agrees with each edge better than the edge is
# sure of itself), and at HINT_FLOOR_XY no loop closure could bend them: along corridors of look-alike
# rooms the lidar odometry slid 0.1-0.2 m a corridor, and a generated noisy wing's map poses were 0.5 m
# off 20-30 m from the map's origin (goals converted that far off ended `reached_wrong_place`). 0.005 m
# per sqrt(m) (0.05 m over 100 m), chosen on eleven generated noisy maps: the worst location 0.50 -> 0.24 m,
# none left over 0.25 m (6.5 % before); 0.0025 or 0.01 left 1.1 and 2.3 % (BENCHMARKS.md, "Design
# choices: the lidar hints' drift floor for map poses")
LIDAR_DRIFT_XY = 0.005
ANCHOR_SIGMA = 1e-6
EXPLAINED = 2.0  # what the edges explain of the disagreement, in their variances (see _hint_noise)
CHI2_MEDIAN_1 = 0.4549  # median of chi-square with 1 degree of freedom
CHI2_MEDIAN_2 = 1.3863  # ... with 2 (2 ln 2)


def _residuals(poses: NDArray, u: NDArray, v: NDArray, measured: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """For every constraint k: e_k = between(measured_k, between(x_u, x_v)) (K, 3) and its Jacobians
    with respect to x_u and x_v (K, 3, 3)."""
    xu, xv = poses[u], poses[v]
    cu, su = np.cos(xu[:, 2]), np.sin(xu[:, 2])
    cm, sm = np.cos(measured[:, 2]), np.sin(measured[:, 2])
    dx, dy = xv[:, 0] - xu[:, 0], xv[:, 1] - xu[:, 1]
    # relative pose of v in u, then its difference with the measurement (in the measurement's frame)
    rx, ry = cu * dx + su * dy, -su * dx + cu * dy
    ex, ey = rx - measured[:, 0], ry - measured[:, 1]
    residual = np.stack([cm * ex + sm * ey, -sm * ex + cm * ey, wrap_angle(xv[:, 2] - xu[:, 2] - measured[:, 2])], axis=1)
    rm_t = np.stack([np.stack([cm, sm], -1), np.stack([-sm, cm], -1)], axis=1)  # (K, 2, 2)
    ru_t = np.stack([np.stack([cu, su], -1), np.stack([-su, cu], -1)], axis=1)
    k = len(u)
    a = np.zeros((k, 3, 3))
    b = np.zeros((k, 3, 3))
    rr = rm_t @ ru_t
    a[:, :2, :2] = -rr
    a[:, :2, 2] = (rm_t @ np.stack([-su * dx + cu * dy, -cu * dx - su * dy], axis=1)[:, :, None])[:, :, 0]
    a[:, 2, 2] = -1.0
    b[:, :2, :2] = rr
    b[:, 2, 2] = 1.0
    return residual, a, b


def _hint_noise(graph: TopologicalGraph, travel: NDArray, hints: NDArray | None = None) -> tuple[float, float]:
    """Per-√metre noise of the hints (default: the odometry hints), from how far they disagree with
    the scan-matched edges (over the odometry travelled between the two locations' making), less
    what the edges' own error explains."""
    if hints is None:
        hints = np.array([v.pose_hint for v in graph.vertices], dtype=np.float64)
    xy, yaw, metres = [], [], []
    for u, v, pose_uv in graph.edges():
        error = between(pose_uv, between(hints[u], hints[v]))
        xy.append(float(np.hypot(error[0], error[1])) ** 2)
        yaw.append(float(wrap_angle(error[2])) ** 2)
        metres.append(max(abs(float(travel[v] - travel[u])), 0.5))
    if not xy:
        return 0.0, 0.0  # no edge: the hints alone place the locations
    per_metre = float(np.median(metres))
    # what the edges' own errors explain is counted twice over: edges a little worse than their
    # assumed sigma made exact hints look noisy (loop_office_door, precise: k_yaw 0.04 deg/sqrt(m),
    # relaxed poses 0.19 m median off the exact hints, goals converted 0.4 m off); on generated
    # noisy drives the map poses moved by 1-10 % (BENCHMARKS.md, "Design choices: map poses' hint noise")
    # medians, robust to the odd wrong edge, turned into variances: the median of a squared normal
    # is 0.455 sigma^2 (chi-square, 1 degree of freedom), of a squared 2D distance 1.386 sigma^2 a side
    k_xy = np.sqrt(max(float(np.median(xy)) / CHI2_MEDIAN_2 - EXPLAINED * EDGE_SIGMA_XY**2, 0.0) / per_metre)
    k_yaw = np.sqrt(max(float(np.median(yaw)) / CHI2_MEDIAN_1 - EXPLAINED * EDGE_SIGMA_YAW**2, 0.0) / per_metre)
    return float(k_xy), float(k_yaw)


def hint_chain(graph: TopologicalGraph) -> tuple[str, NDArray[np.float64]]:
    """The hints the relaxation uses: ``("odometry", ...)`` the odometry poses where the locations
    were made, or ``("lidar", ...)`` the lidar-odometry poses (when every location has one).

    Over each edge, three estimates of the turn between its ends: the edge's, the odometry's and the
    lidar's. The lidar hints are taken when the odometry disagrees with them more than they disagree
    with the edges (median squared heading differences): then the odometry is the odd one out. With
    exact odometry the two hints agree within a few hundredths of a degree an edge, far below the
    edges' own ~0.25°, and the odometry is kept (choosing by agreement with the edges alone picked
    the lidar on one of four generated precise drives: 0.21 m off instead of exact); with odometry
    drifting 0.5°/√m it disagrees ~1° an edge and the lidar is taken (BENCHMARKS.md, "Design choices:
    lidar hints for map-frame goals").
    """
    odometry = np.array([v.pose_hint for v in graph.vertices], dtype=np.float64).reshape(-1, 3)
    if not graph.vertices or any(v.lidar_hint is None for v in graph.vertices) or not graph.edge_count:
        return "odometry", odometry
    lidar = np.array([v.lidar_hint for v in graph.vertices], dtype=np.float64)
    with_edges, between_hints = [], []
    for u, v, pose_uv in graph.edges():
        lidar_uv = between(lidar[u], lidar[v])
        with_edges.append(float(wrap_angle(lidar_uv[2] - pose_uv[2])) ** 2)
        between_hints.append(float(wrap_angle(between(odometry[u], odometry[v])[2] - lidar_uv[2])) ** 2)
    return ("lidar", lidar) if np.median(between_hints) > np.median(with_edges) else ("odometry", odometry)


def _travel(graph: TopologicalGraph, hints: NDArray) -> NDArray[np.float64]:
    """Metres of odometry travelled before each location was made (an older graph without them: the
    hints' spacing stands in)."""
    travel = np.array([v.odometer if v.odometer is not None else np.nan for v in graph.vertices], dtype=np.float64)
    if np.isnan(travel).any():
        travel = arc_lengths(hints)
    return travel


def relaxed_poses(graph: TopologicalGraph, iterations: int = 10) -> NDArray[np.float64]:
    """(V, 3) vertex poses in the map frame (the first vertex's), from edges and hints (see above)."""
    n = len(graph)
    if n == 0:
        return np.zeros((0, 3))
    if n == 1:  # nothing to relax (the constraints below would be none): the first vertex anchors the frame
        return np.asarray(hint_chain(graph)[1], dtype=np.float64).copy()
    travel = _travel(graph, np.array([v.pose_hint for v in graph.vertices], dtype=np.float64))
    kind, hints = hint_chain(graph)
    k_xy, k_yaw = _hint_noise(graph, travel, hints)
    if kind == "lidar":
        k_xy = max(k_xy, LIDAR_DRIFT_XY)
    edges = graph.edges()
    chain = np.arange(1, n)
    metres = np.maximum(np.abs(travel[chain] - travel[chain - 1]), 0.1)
    root = np.sqrt(metres)
    # a heading random walk moves the position too: sideways by k_yaw * sqrt(L^3 / 3) over L metres
    # driven (straight); over tens of metres that, not the translation noise, is the hint's error
    lateral = np.sqrt((k_xy * root) ** 2 + k_yaw**2 * metres**3 / 3.0)
    u = np.concatenate([[e[0] for e in edges], chain - 1]).astype(np.int64)
    v = np.concatenate([[e[1] for e in edges], chain]).astype(np.int64)
    measured = np.vstack([np.array([e[2] for e in edges]).reshape(-1, 3), [between(hints[i - 1], hints[i]) for i in chain]])
    sigma = np.vstack(
        [
            np.tile([EDGE_SIGMA_XY, EDGE_SIGMA_XY, EDGE_SIGMA_YAW], (len(edges), 1)),
            np.stack(
                [
                    np.maximum(HINT_FLOOR_XY, lateral),
                    np.maximum(HINT_FLOOR_XY, lateral),
                    np.maximum(HINT_FLOOR_YAW, k_yaw * root),
                ],
                axis=1,
            ).reshape(-1, 3),
        ]
    )
    w2 = 1.0 / sigma**2
    # block positions of H_uu, H_vv, H_uv, H_vu for every constraint (3 x 3 each)
    offsets = np.arange(3)
    rows = np.stack([3 * u, 3 * v, 3 * u, 3 * v], axis=1)[:, :, None, None] + offsets[None, None, :, None]
    cols = np.stack([3 * u, 3 * v, 3 * v, 3 * u], axis=1)[:, :, None, None] + offsets[None, None, None, :]
    rows, cols = np.broadcast_arrays(rows, cols)
    anchor = np.arange(3)
    poses = hints.copy()
    for _ in range(iterations):
        residual, a, b = _residuals(poses, u, v, measured)
        wa, wb = a * w2[:, :, None], b * w2[:, :, None]
        at_wa = np.einsum("kij,kil->kjl", a, wa)
        bt_wb = np.einsum("kij,kil->kjl", b, wb)
        at_wb = np.einsum("kij,kil->kjl", a, wb)
        blocks = np.stack([at_wa, bt_wb, at_wb, at_wb.transpose(0, 2, 1)], axis=1)
        gradient = np.zeros(3 * n)
        np.add.at(gradient, (3 * u[:, None] + offsets).ravel(), np.einsum("kij,ki->kj", a, w2 * residual).ravel())
        np.add.at(gradient, (3 * v[:, None] + offsets).ravel(), np.einsum("kij,ki->kj", b, w2 * residual).ravel())
        # the first vertex anchors the map frame
        gradient[:3] += (poses[0] - hints[0]) / ANCHOR_SIGMA**2
        hessian = sparse.csr_matrix(
            (
                np.concatenate([blocks.ravel(), np.full(3, 1.0 / ANCHOR_SIGMA**2)]),
                (np.concatenate([rows.ravel(), anchor]), np.concatenate([cols.ravel(), anchor])),
            ),
            shape=(3 * n, 3 * n),
        )
        step = spsolve(hessian.tocsc(), -gradient).reshape(n, 3)
        poses += step
        poses[:, 2] = wrap_angle(poses[:, 2])
        if np.abs(step).max() < 1e-7:
            break
    return poses
