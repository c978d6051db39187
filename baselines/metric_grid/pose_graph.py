"""Keyframe pose graph of the metric baseline, with verified loop closures (gtsam).

The classic graph-SLAM back end (Grisetti et al., "A Tutorial on Graph-Based SLAM", 2010), in
SE(2) because the robot drives on a plane:

* a keyframe every ``keyframe_distance`` metres of travel or ``keyframe_yaw_deg`` of turning,
  holding its odometry pose and a lean 2D scan: obstacle points after a 0.1 m voxel filter
  (plus, optionally, the free-space ranges the global grid is traced with);
* odometry factors (``BetweenFactorPose2``) between consecutive keyframes, and optionally on each
  keyframe a weak prior on the heading the odometry gives it (``heading_sigma_deg``, widening with
  travel by ``heading_drift_deg_per_sqrt_m``; lidar odometry only): the odometry factors alone
  model the heading as a random walk of ``odometry_sigma_yaw_deg`` a keyframe, so they leave the
  turn of the whole map about the first keyframe nearly free, and loop closures turned consistent
  noisy maps by 0.3-0.4° (a few decimetres at 50 m) while kiss-icp's own heading stayed within
  0.1-0.2° of the truth;
* loop-closure candidates that are near in the current estimate yet far along the trajectory,
  verified by registering the new keyframe's points to a small submap around the candidate
  with kiss-icp's point-to-point registration (coarse to fine), then checked for fitness, RMSE,
  geometric constraint (a corridor's walls alone cannot fix the position along it) and
  consistency with the estimate;
* loop factors behind a Cauchy robust kernel (docs/NOTES.md: it survived 10 false closures where
  Huber did not), optimised incrementally with iSAM2 (``relinearizeSkip=1`` and one extra
  update after a closure), or in batch with Levenberg-Marquardt by ``optimize()``.

Poses are ``[x, y, yaw]`` in the map frame, which is the odometry frame of the first keyframe.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import gtsam
import numpy as np
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.registration import Registration
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from navkit import geometry as se2
from navkit.files import atomic_write
from navkit.odometer import Odometer
from navkit.odometry import se2_to_se3, se3_to_se2

from .scan2d import voxel_filter_2d

FORMAT = "navtopo-metric-pose-graph/1"


class LoopClosureConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    min_travel: float = Field(8.0, description="m along the trajectory between the two keyframes")
    search_radius: float = Field(3.0, description="m between them in the current estimate")
    max_attempts: int = Field(2, description="candidates verified per new keyframe")
    cooldown_keyframes: int = Field(2, ge=0, description="keyframes after a closure before the next search (revisits)")
    submap_neighbours: int = Field(3, description="keyframes either side of the candidate")
    stage_voxels: tuple[float, ...] = Field((1.0, 0.5, 0.25), description="coarse-to-fine ICP, m")
    yaw_seeds_deg: tuple[float, ...] = (0.0, -6.0, 6.0)
    inlier_distance: float = Field(0.15, description="m; a source point with a target point this near")
    min_fitness: float = Field(0.6, description="share of source points that are inliers")
    max_rmse: float = Field(0.08, description="m over inliers")
    min_constraint: float = Field(0.08, description="smaller eigenvalue of the mean n n^T of inlier normals (max 0.5)")
    min_points: int = 60
    # the verified pose may differ from the estimate by what odometry can drift over the gap
    max_correction: float = Field(1.0, description="m between the estimate and the verified pose")
    max_correction_per_m: float = Field(0.04, description="m more per metre travelled in between")
    max_correction_yaw_deg: float = 10.0
    max_correction_yaw_deg_per_m: float = 0.6
    sigma_xy: float = 0.05
    sigma_yaw_deg: float = 1.0
    cauchy_scale: float = 1.0


class PoseGraphConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    keyframe_distance: float = Field(0.75, description="m of travel between keyframes")
    keyframe_yaw_deg: float = Field(20.0, description="or this much turning")
    voxel_size: float = Field(0.1, description="m; 2D voxel filter of stored obstacle points")
    odometry_sigma_xy: float = Field(0.02, description="m, plus odometry_sigma_xy_per_m")
    odometry_sigma_xy_per_m: float = 0.02
    odometry_sigma_yaw_deg: float = 0.5
    odometry_sigma_yaw_deg_per_m: float = 0.5
    heading_sigma_deg: float | None = Field(
        None,
        gt=0,
        description="deg; a prior on each keyframe's heading at its odometry heading, one sigma at the start "
        "(None: none). Far weaker than the odometry factors locally, it fixes the one mode they leave nearly "
        "free: the turn of the whole map about the first keyframe. Only for an odometry whose heading does not "
        "wander (lidar odometry registered to walls: config.NOISY_ODOMETRY); not for noisy wheels",
    )
    heading_drift_deg_per_sqrt_m: float = Field(
        0.3, ge=0, description="deg per sqrt(m of travel): the heading prior widens as the odometry's heading may drift"
    )
    optimizer: Literal["isam2", "lm"] = Field(
        "isam2", description="iSAM2 after every keyframe, or Levenberg-Marquardt in optimize() only"
    )
    loop: LoopClosureConfig = Field(default_factory=LoopClosureConfig)


@dataclass
class Keyframe:
    """One keyframe. points: (M, 2) float32 obstacle points in the keyframe's own frame;
    free_ranges: (B,) float16 free-space range per azimuth bin (0: none) or an empty array."""

    odom_pose: NDArray[np.float64]
    travel: float
    points: NDArray[np.float32]
    free_ranges: NDArray[np.float16]

    @property
    def nbytes(self) -> int:
        return int(self.odom_pose.nbytes + 8 + self.points.nbytes + self.free_ranges.nbytes)


@dataclass
class LoopClosure:
    """A verified loop: the measured pose of keyframe ``new`` in the frame of keyframe ``old``."""

    old: int
    new: int
    pose: NDArray[np.float64]
    fitness: float
    rmse: float
    constraint: float


def _to_pose2(pose: NDArray) -> gtsam.Pose2:
    return gtsam.Pose2(float(pose[0]), float(pose[1]), float(pose[2]))


def _as_3d(points: NDArray) -> NDArray[np.float64]:
    out = np.zeros((len(points), 3))
    out[:, :2] = points
    return out


@dataclass
class Registration2D:
    pose: NDArray[np.float64]  # source frame in the target frame
    fitness: float
    rmse: float
    constraint: float


def register_scans(source: NDArray, target: NDArray, initial: NDArray, config: LoopClosureConfig) -> Registration2D:
    """Align 2D points ``source`` to ``target`` from ``initial`` (source frame in target frame).

    kiss-icp's point-to-point ICP (robust kernel) on voxel maps from coarse to fine, started
    from each yaw seed in turn until one reaches ``min_fitness``; else the best fitness wins.
    """
    tree = cKDTree(target)
    maps = []
    for voxel in config.stage_voxels:
        voxel_map = VoxelHashMap(voxel_size=voxel, max_distance=1e6, max_points_per_voxel=30)
        voxel_map.add_points(_as_3d(target))
        maps.append(voxel_map)
    registration = Registration(max_num_iterations=100, convergence_criterion=1e-4, max_num_threads=1)
    source_3d = _as_3d(source)
    best: tuple[float, NDArray] | None = None
    for seed in config.yaw_seeds_deg:
        guess = se2_to_se3(se2.compose(initial, [0.0, 0.0, np.deg2rad(seed)]))
        for voxel, voxel_map in zip(config.stage_voxels, maps, strict=True):
            guess = registration.align_points_to_map(
                points=source_3d,
                voxel_map=voxel_map,
                initial_guess=guess,
                max_correspondance_distance=voxel,
                kernel=voxel / 3.0,
            )
        pose = se3_to_se2(guess)
        moved = se2.transform_points(pose, np.asarray(source, dtype=np.float64))
        dist, _ = tree.query(moved, distance_upper_bound=config.inlier_distance)
        fitness = float(np.isfinite(dist).mean())
        if best is None or fitness > best[0]:
            best = (fitness, pose)
        if fitness >= config.min_fitness:
            break
    assert best is not None
    return _score(source, target, tree, best[1], config.inlier_distance)


def _score(source, target, tree: cKDTree, pose, inlier_distance: float) -> Registration2D:
    """Fitness, inlier RMSE and geometric constraint of ``source`` at ``pose`` on ``target``."""
    moved = se2.transform_points(pose, np.asarray(source, dtype=np.float64))
    dist, index = tree.query(moved, distance_upper_bound=inlier_distance)
    inliers = np.isfinite(dist)
    count = int(inliers.sum())
    if count < 3:
        return Registration2D(pose, 0.0, np.inf, 0.0)
    rmse = float(np.sqrt(np.mean(dist[inliers] ** 2)))
    # normals of the matched target points (PCA of 8 neighbours); the translational information
    # of point-to-line residuals is the mean of n n^T: a bare corridor gives one direction only
    matched = target[index[inliers]]
    _, neighbours = tree.query(matched, k=min(8, len(target)))
    local = target[neighbours] - target[neighbours].mean(axis=1, keepdims=True)
    covariances = np.einsum("nki,nkj->nij", local, local)
    _, vectors = np.linalg.eigh(covariances)
    normals = vectors[:, :, 0]
    information = normals.T @ normals / count
    constraint = float(np.linalg.eigvalsh(information)[0])
    return Registration2D(pose, count / len(source), rmse, constraint)


class PoseGraph:
    """Keyframes, odometry and loop factors, and the current estimate of every keyframe pose."""

    def __init__(self, config: PoseGraphConfig | None = None):
        self.config = config or PoseGraphConfig()
        self.keyframes: list[Keyframe] = []
        self.loops: list[LoopClosure] = []
        self._estimate = np.zeros((0, 3))
        self._odometer = Odometer()  # the travelled distance, from every scan offered
        self._graph = gtsam.NonlinearFactorGraph()
        self._isam = self._new_isam()
        self.loop_attempts = 0

    @staticmethod
    def _new_isam() -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        return gtsam.ISAM2(params)

    # --- building -----------------------------------------------------------------------------

    def add_scan(
        self,
        odom_pose: NDArray,
        obstacle_points_2d: NDArray | None,
        free_ranges: NDArray | None = None,
    ) -> bool:
        """Offer one scan; returns True when it became a keyframe.

        odom_pose: (3,) odometry pose of the scan. obstacle_points_2d: (N, >=2) obstacle points in
        the robot frame (x, y used). free_ranges: optional (B,) free range per azimuth bin.
        Call it for every scan: the travelled distance is accumulated from all of them.
        """
        odom_pose = np.asarray(odom_pose, dtype=np.float64)
        self._odometer.update(odom_pose)
        if not self.needs_keyframe(odom_pose):
            return False
        if obstacle_points_2d is None:
            raise ValueError("add_scan: a keyframe is due, its obstacle points are needed")
        points = voxel_filter_2d(obstacle_points_2d, self.config.voxel_size)
        ranges = np.zeros(0, np.float16) if free_ranges is None else np.asarray(free_ranges, dtype=np.float16).copy()
        self.keyframes.append(Keyframe(odom_pose.copy(), self._odometer.metres, points, ranges))
        self._add_odometry_factor(len(self.keyframes) - 1)
        if self.config.loop.enabled:
            self._close_loops(len(self.keyframes) - 1)
        return True

    def needs_keyframe(self, odom_pose: NDArray) -> bool:
        """Whether a scan at ``odom_pose`` would become a keyframe (no side effect): callers may
        compute the keyframe scan only then, and pass ``None`` points to ``add_scan`` otherwise."""
        if not self.keyframes:
            return True
        last = self.keyframes[-1].odom_pose
        delta = se2.between(last, odom_pose)
        return bool(
            np.hypot(delta[0], delta[1]) >= self.config.keyframe_distance
            or abs(delta[2]) >= np.deg2rad(self.config.keyframe_yaw_deg)
        )

    def _odometry_noise(self, delta: NDArray) -> gtsam.noiseModel.Base:
        c = self.config
        dist = float(np.hypot(delta[0], delta[1]))
        xy = c.odometry_sigma_xy + c.odometry_sigma_xy_per_m * dist
        yaw = np.deg2rad(c.odometry_sigma_yaw_deg + c.odometry_sigma_yaw_deg_per_m * dist)
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([xy, xy, yaw]))

    def _keyframe_factors(self, k: int) -> list[gtsam.NonlinearFactor]:
        """Keyframe ``k``'s factors: keyframe 0 anchors the map frame at its odometry pose; each later
        one is tied to the one before by the odometry between them, and (``heading_sigma_deg``) its
        heading to the odometry's, widening with the travel since keyframe 0."""
        c = self.config
        keyframe = self.keyframes[k]
        if k == 0:
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))
            return [gtsam.PriorFactorPose2(0, _to_pose2(keyframe.odom_pose), prior)]
        delta = se2.between(self.keyframes[k - 1].odom_pose, keyframe.odom_pose)
        factors: list[gtsam.NonlinearFactor] = [gtsam.BetweenFactorPose2(k - 1, k, _to_pose2(delta), self._odometry_noise(delta))]
        if c.heading_sigma_deg is not None:
            travel = max(keyframe.travel - self.keyframes[0].travel, 0.0)
            sigma = np.deg2rad(np.hypot(c.heading_sigma_deg, c.heading_drift_deg_per_sqrt_m * np.sqrt(travel)))
            heading = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e6, 1e6, sigma]))  # the position left free
            factors.append(gtsam.PriorFactorPose2(k, _to_pose2(keyframe.odom_pose), heading))
        return factors

    def _loop_factor(self, closure: LoopClosure) -> gtsam.NonlinearFactor:
        return gtsam.BetweenFactorPose2(closure.old, closure.new, _to_pose2(closure.pose), self._loop_noise())

    def _add_odometry_factor(self, k: int) -> None:
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for factor in self._keyframe_factors(k):
            graph.add(factor)
        if k == 0:
            initial = self.keyframes[0].odom_pose
        else:  # initial values composed from the current estimate, not from raw odometry
            delta = se2.between(self.keyframes[k - 1].odom_pose, self.keyframes[k].odom_pose)
            initial = se2.compose(self._estimate[k - 1], delta)
        values.insert(k, _to_pose2(initial))
        self._estimate = np.vstack([self._estimate, initial[None, :]])
        self._graph.push_back(graph)
        if self.config.optimizer == "isam2":
            self._isam.update(graph, values)
            self._refresh_estimate()

    def _refresh_estimate(self) -> None:
        estimate = self._isam.calculateEstimate()
        self._estimate = np.asarray(gtsam.utilities.extractPose2(estimate), dtype=np.float64)

    # --- loop closures ------------------------------------------------------------------------

    def _loop_candidates(self, k: int) -> list[int]:
        c = self.config.loop
        travel = np.array([kf.travel for kf in self.keyframes[:k]])
        far_along = travel <= self.keyframes[k].travel - c.min_travel
        if not far_along.any():
            return []
        dist = np.asarray(se2.distance(self._estimate[:k], self._estimate[k]))
        eligible = np.flatnonzero(far_along & (dist <= c.search_radius))
        ordered = eligible[np.argsort(dist[eligible])]
        chosen: list[int] = []
        for j in ordered:  # candidates from different stretches of the trajectory
            if all(abs(j - i) > c.submap_neighbours for i in chosen):
                chosen.append(int(j))
            if len(chosen) == c.max_attempts:
                break
        return chosen

    def _submap(self, j: int) -> NDArray[np.float64]:
        """Obstacle points of keyframes j-n..j+n in the frame of keyframe j (current estimate)."""
        n = self.config.loop.submap_neighbours
        parts = []
        for i in range(max(0, j - n), min(len(self.keyframes) - 1, j + n + 1)):
            pose_in_j = se2.between(self._estimate[j], self._estimate[i])
            parts.append(se2.transform_points(pose_in_j, self.keyframes[i].points.astype(np.float64)))
        return np.concatenate(parts)

    def verify_loop(self, old: int, new: int) -> LoopClosure | None:
        """Register keyframe ``new`` to the submap around ``old``; a closure if all checks pass."""
        c = self.config.loop
        source = self.keyframes[new].points
        target = self._submap(old)
        if len(source) < c.min_points or len(target) < c.min_points:
            return None
        self.loop_attempts += 1
        initial = se2.between(self._estimate[old], self._estimate[new])
        result = register_scans(source, target, initial, c)
        correction = se2.between(initial, result.pose)
        gap = self.keyframes[new].travel - self.keyframes[old].travel
        max_shift = c.max_correction + c.max_correction_per_m * gap
        max_turn = np.deg2rad(c.max_correction_yaw_deg + c.max_correction_yaw_deg_per_m * gap)
        if (
            result.fitness < c.min_fitness
            or result.rmse > c.max_rmse
            or result.constraint < c.min_constraint
            or np.hypot(correction[0], correction[1]) > max_shift
            or abs(correction[2]) > max_turn
        ):
            return None
        return LoopClosure(old, new, result.pose, result.fitness, result.rmse, result.constraint)

    def _close_loops(self, k: int) -> None:
        if self.loops and k - self.loops[-1].new <= self.config.loop.cooldown_keyframes:
            return
        for j in self._loop_candidates(k):
            closure = self.verify_loop(j, k)
            if closure is not None:
                self.add_loop(closure)

    def _loop_noise(self) -> gtsam.noiseModel.Base:
        c = self.config.loop
        gaussian = gtsam.noiseModel.Diagonal.Sigmas(np.array([c.sigma_xy, c.sigma_xy, np.deg2rad(c.sigma_yaw_deg)]))
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(c.cauchy_scale), gaussian)

    def add_loop(self, closure: LoopClosure) -> None:
        """Add a loop factor (robust) and, with iSAM2, update the estimate."""
        self.loops.append(closure)
        graph = gtsam.NonlinearFactorGraph()
        graph.add(self._loop_factor(closure))
        self._graph.push_back(graph)
        if self.config.optimizer == "isam2":
            self._isam.update(graph, gtsam.Values())
            self._isam.update()  # one more relinearisation: iSAM2 lags a large correction
            self._refresh_estimate()

    # --- results ------------------------------------------------------------------------------

    def optimize(self) -> NDArray[np.float64]:
        """Batch Levenberg-Marquardt over the whole graph from the current estimate; (K, 3)."""
        if not self.keyframes:
            return self._estimate.copy()
        initial = gtsam.Values()
        for k, pose in enumerate(self._estimate):
            initial.insert(k, _to_pose2(pose))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        result = gtsam.LevenbergMarquardtOptimizer(self._graph, initial, params).optimize()
        self._estimate = np.asarray(gtsam.utilities.extractPose2(result), dtype=np.float64)
        return self._estimate.copy()

    def poses(self) -> NDArray[np.float64]:
        """(K, 3) current estimate of the keyframe poses in the map frame."""
        return self._estimate.copy()

    def map_pose(self, odom_pose: NDArray) -> NDArray[np.float64]:
        """Map-frame estimate of an odometry pose, carried from the latest keyframe."""
        if not self.keyframes:
            return np.asarray(odom_pose, dtype=np.float64).copy()
        delta = se2.between(self.keyframes[-1].odom_pose, odom_pose)
        return se2.compose(self._estimate[-1], delta)

    @property
    def travel(self) -> float:
        return self._odometer.metres

    @property
    def nbytes(self) -> int:
        """Exact bytes of the stored arrays: keyframes, estimate and loop measurements.

        gtsam's own factor graph and Bayes tree are not counted (not measurable from Python);
        they are rebuilt from these arrays by ``load``.
        """
        loops = len(self.loops) * (2 * 8 + 3 * 8 + 3 * 8)  # pair, pose, scores
        return sum(kf.nbytes for kf in self.keyframes) + int(self._estimate.nbytes) + loops

    # --- persistence --------------------------------------------------------------------------

    def save(self, directory: str | Path) -> None:
        """Write ``pose_graph.json`` (config, counts) and ``pose_graph.npz`` (arrays)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        counts = [len(kf.points) for kf in self.keyframes]
        bins = max((len(kf.free_ranges) for kf in self.keyframes), default=0)
        free = np.zeros((len(self.keyframes), bins), np.float16)
        for k, kf in enumerate(self.keyframes):
            free[k, : len(kf.free_ranges)] = kf.free_ranges
        arrays: dict[str, Any] = {
            "odom_poses": np.array([kf.odom_pose for kf in self.keyframes]).reshape(-1, 3),
            "travel": np.array([kf.travel for kf in self.keyframes], dtype=np.float64),
            "point_offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            "points": (np.concatenate([kf.points for kf in self.keyframes]) if self.keyframes else np.zeros((0, 2), np.float32)),
            "free_ranges": free,
            "estimate": self._estimate,
            "loop_pairs": np.array([[lc.old, lc.new] for lc in self.loops], np.int64).reshape(-1, 2),
            "loop_poses": np.array([lc.pose for lc in self.loops]).reshape(-1, 3),
            "loop_scores": np.array([[lc.fitness, lc.rmse, lc.constraint] for lc in self.loops]).reshape(-1, 3),
        }
        npz = io.BytesIO()  # the bytes np.savez writes to a file, written whole or not at all
        np.savez(npz, **arrays)
        atomic_write(directory / "pose_graph.npz", npz.getvalue())
        meta = {
            "format": FORMAT,
            "keyframes": len(self.keyframes),
            "loops": len(self.loops),
            "travel_m": self._odometer.metres,
            "config": self.config.model_dump(mode="json"),
        }
        atomic_write(directory / "pose_graph.json", json.dumps(meta, indent=2))

    @classmethod
    def load(cls, directory: str | Path) -> PoseGraph:
        directory = Path(directory)
        meta = json.loads((directory / "pose_graph.json").read_text())
        if meta.get("format") != FORMAT:
            raise ValueError(f"{directory}/pose_graph.json: format is not {FORMAT}")
        graph = cls(PoseGraphConfig.model_validate(meta["config"]))
        with np.load(directory / "pose_graph.npz") as data:
            arrays = {name: data[name] for name in data.files}
        offsets = arrays["point_offsets"]
        for k in range(len(arrays["odom_poses"])):
            free = arrays["free_ranges"][k] if arrays["free_ranges"].shape[1] else np.zeros(0)
            graph.keyframes.append(
                Keyframe(
                    arrays["odom_poses"][k].copy(),
                    float(arrays["travel"][k]),
                    arrays["points"][offsets[k] : offsets[k + 1]].copy(),
                    np.asarray(free, dtype=np.float16).copy(),
                )
            )
        graph._odometer.metres = float(meta["travel_m"])
        graph._odometer.restart_from(graph.keyframes[-1].odom_pose if graph.keyframes else None)
        graph._rebuild(arrays)
        return graph

    def _rebuild(self, arrays: dict[str, NDArray]) -> None:
        """Factors from the stored keyframes and loops; values from the stored estimate."""
        estimate = arrays["estimate"]
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k in range(len(self.keyframes)):
            for factor in self._keyframe_factors(k):
                graph.add(factor)
            values.insert(k, _to_pose2(estimate[k]))
        for (old, new), pose, scores in zip(arrays["loop_pairs"], arrays["loop_poses"], arrays["loop_scores"], strict=True):
            closure = LoopClosure(int(old), int(new), pose.copy(), *(float(v) for v in scores))
            self.loops.append(closure)
            graph.add(self._loop_factor(closure))
        self._graph = graph
        self._estimate = np.asarray(estimate, dtype=np.float64).reshape(-1, 3).copy()
        if self.config.optimizer == "isam2" and self.keyframes:
            self._isam = self._new_isam()
            self._isam.update(graph, values)
