"""Lidar odometry: KISS-ICP on cropped scans, reported in SE(2). The metric baseline's odometry
(``baselines.metric_grid``), and the lidar hints NavTopo keeps of where it made its locations
(``navtopo.graph_poses``: map-frame goals).

KISS-ICP (Vizzo et al., "KISS-ICP: In Defense of Point-to-Point ICP", RA-L 2023) registers each
scan to a local voxel map with point-to-point ICP, a robust kernel and an adaptive threshold.
What is specific to this benchmark's simulated lidar (docs/NOTES.md, "Lidar odometry and pose
graphs", and measurements on the bundled scenarios):

* floor and ceiling returns are removed before registration: a perfectly flat simulated floor
  pulls point-to-point ICP towards zero motion (20 m driven came out as 13-15 m);
* deskewing is off: the simulated scan is instantaneous (and kiss-icp aborts on the all-zero
  timestamps it would need);
* only points within ``source_range`` (12 m) are registered, while the local map takes the whole
  15 m: points seen for the first time at the edge of the range have nothing to match but the
  map's edge behind them, and pulled the estimate short in long corridors;
* each scan enters the local map ``map_delay_scans`` scans late, and with a wheel seed the first
  few scans are not registered at all: a simulated lidar samples the walls along the same
  azimuth columns in every scan, so against a map holding the previous scan zero motion fits
  exactly (the floor's effect again, from the walls). At the start of a corridor drive it lost
  0.5 m in ten scans, and over 270 m the error was 0.74 m RMS; with the delay, 0.12 m;
* the robust kernel starts at 0.5 m, not 2 m: seeded by wheel odometry, kiss-icp's prediction
  error stays below its ``min_motion_th`` and its adaptive threshold never leaves the start value;
* ``point_to_line`` (on by default): each kiss-icp estimate is refined by 2D
  point-to-line ICP against the same local map, pulled towards the wheel-seeded prediction only
  where no wall constrains, and the bootstrap scans are registered that way
  too (``line_bootstrap``). Point-to-point ICP against walls sampled along the lidar's fixed
  azimuth columns is biased even from an exact seed: with exact wheel odometry it put the far
  locations of generated trees 0.18-0.33 m off (point-to-line: 0.002-0.021 m), and with noisy odometry the heading the wheels
  had after the first few (bootstrap) scans, 0.4-0.5° on one tree, stayed in the map for good.
  Point-to-line does not care where along a wall a return lands, so the first scan's walls fix
  the heading. On the noisy drives of generated trees 103 and 105 the pose at each place's first
  visit went from 0.27 / 0.41 m off at most to 0.03 / 0.03 m, and the metric baseline's map
  (ATE, trees 101-103) from 0.086 to 0.021 m mean (BENCHMARKS.md, "Design choices: point-to-line
  lidar odometry"). Cost: about twice
  kiss-icp's CPU per scan (13 ms instead of 6.5 on the shared machine). Off, kiss-icp alone.
  Along a corridor the walls fix the heading and the cross position but not where along it the
  robot is; there (``line_corner_ratio``) the scan points that land on door jambs and corners,
  which lie on no line, pull along that free direction alone. Without that the position along
  the corridors of a generated noisy ring building (seed 101) followed the wheels' prior and
  drifted (first visits 0.46 m median off, kiss-icp alone 0.33 m); with it 0.19 m, while the
  generated trees' first visits moved by 6 mm at most (BENCHMARKS.md, "Design choices: door jambs
  fix the position along corridors").

The robot drives on a plane, so each estimate is projected to SE(2) (x, y, yaw) and, with
``planar`` on, fed back as a planar pose before the local map is updated: the unobservable z,
roll and pitch of a wall-only scan cannot drift. Optionally each registration starts from the
wheel-odometry delta instead of kiss-icp's constant-velocity prediction.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit import geometry as se2

if TYPE_CHECKING:  # kiss-icp is imported when an odometry is made: NavTopo navigates without it
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP
    from scipy.spatial import cKDTree


class OdometryConfig(BaseModel):
    """Lidar (or wheel) odometry. Defaults suit the simulated 16-beam, 15 m lidar."""

    model_config = ConfigDict(extra="forbid")

    source: Literal["lidar", "wheel"] = "lidar"
    seed_with_wheel: bool = Field(True, description="start each registration from the wheel-odometry delta")
    planar: bool = Field(True, description="keep kiss-icp's poses on the ground plane")
    max_range: float = 15.0
    min_range: float = Field(0.3, description="m; drops returns from the robot's own body")
    source_range: float = Field(12.0, description="m; only nearer points are registered, all go into the local map")
    voxel_size: float = Field(0.25, description="m; kiss-icp's local-map voxel")
    max_points_per_voxel: int = 20
    crop_min_z: float = Field(0.15, description="m above the floor; lower returns are floor")
    crop_max_z: float = Field(1.5, description="m above the floor; higher returns are ceiling")
    min_points: int = Field(50, description="fewer cropped points: trust the prediction")
    map_delay_scans: int = Field(
        2,
        ge=0,
        description="with a wheel seed, scans go into the local map this many scans late (see "
        "the module doc); without one the freshest map is needed to follow fast turns in place",
    )
    bootstrap_scans: int = Field(3, ge=0, description="with a wheel seed, trust it until the map holds this many scans")
    initial_threshold: float = Field(
        0.5,
        description="m; kiss-icp's robust-kernel scale until motion teaches it (with a good wheel "
        "seed the deviation stays under min_motion_threshold and it never adapts)",
    )
    min_motion_threshold: float = 0.1
    fixed_threshold: float | None = Field(None, description="m; a fixed robust-kernel scale instead of kiss-icp's adaptive one")
    max_num_threads: int = Field(1, description="kiss-icp threads; 0 = all cores")
    point_to_line: bool = Field(True, description="refine each kiss-icp estimate by 2D point-to-line ICP (see the module doc)")
    line_sigma: float = Field(0.03, gt=0, description="m; a scan point's distance to its wall line, one sigma")
    line_distance: float = Field(0.3, gt=0, description="m; point-to-line correspondences farther than this are dropped")
    line_neighbours: float = Field(0.3, gt=0, description="m; radius of the neighbours a map point's line is fitted to")
    line_iterations: int = Field(6, ge=1, description="Gauss-Newton steps of the point-to-line refinement")
    line_prior_xy: float = Field(0.05, gt=0, description="m; pull to the wheel-seeded prediction where walls do not constrain")
    line_prior_yaw_deg: float = Field(0.5, gt=0, description="deg; the same for the heading")
    line_corner_ratio: float = Field(
        0.2,
        ge=0,
        description="where the walls' information in the weakest direction is below this fraction of the "
        "strongest (a corridor), scan points at corners and door jambs pull along it; 0: never",
    )
    line_bootstrap: bool = Field(True, description="register the bootstrap scans by point-to-line alone")

    def kiss_config(self) -> KISSConfig:
        from kiss_icp.config import KISSConfig

        config = KISSConfig()
        config.data.max_range = self.max_range
        config.data.min_range = self.min_range
        config.data.deskew = False
        config.mapping.voxel_size = self.voxel_size
        config.mapping.max_points_per_voxel = self.max_points_per_voxel
        config.registration.max_num_threads = self.max_num_threads
        config.adaptive_threshold.initial_threshold = self.initial_threshold
        config.adaptive_threshold.min_motion_th = self.min_motion_threshold
        config.adaptive_threshold.fixed_threshold = self.fixed_threshold
        return config


def se2_to_se3(pose: NDArray) -> NDArray[np.float64]:
    """(3,) [x, y, yaw] -> 4x4 homogeneous transform on the ground plane."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    matrix = np.eye(4)
    matrix[:2, :2] = [[c, -s], [s, c]]
    matrix[:2, 3] = pose[:2]
    return matrix


def se3_to_se2(matrix: NDArray) -> NDArray[np.float64]:
    """4x4 transform -> (3,) [x, y, yaw]: the translation's x, y and the heading of the x axis."""
    return np.array([matrix[0, 3], matrix[1, 3], np.arctan2(matrix[1, 0], matrix[0, 0])], dtype=np.float64)


def crop_floor_and_ceiling(points: NDArray, min_z: float, max_z: float) -> NDArray[np.float64]:
    """(N, 3) robot-frame points -> (M, 3) float64 (as kiss-icp wants) with min_z < z < max_z."""
    keep = (points[:, 2] > min_z) & (points[:, 2] < max_z)
    return np.ascontiguousarray(points[keep], dtype=np.float64)


LINE_CELL = 0.05  # m: points closer than this are one point to the line fits


def _unique_xy(points: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """(N, 2) points, one kept per ``cell``-metre square (the lidar's channels hit a wall at the
    same x, y: a line fit needs neighbours along the wall, not above one another)."""
    cells = np.floor(points / cell).astype(np.int64)
    keys = (cells[:, 0] << 32) + (cells[:, 1] & 0xFFFFFFFF)
    _, first = np.unique(keys, return_index=True)
    return points[np.sort(first)]


def _line_normals(points: NDArray[np.float64], tree: cKDTree, at: NDArray[np.int64], radius: float) -> NDArray[np.float64]:
    """(len(at), 2) unit normals of the line through each ``points[at]`` and its neighbours within
    ``radius``; (NaN, NaN) where they are too few (a lone return) and (NaN, 0) where they do not
    lie on one line (a corner, a door jamb, clutter)."""
    distances, index = tree.query(points[at], k=8, distance_upper_bound=radius)
    valid = np.isfinite(distances)
    count = valid.sum(axis=1)
    neighbours = points[np.where(valid, index, 0)]  # (M, k, 2); the invalid ones weigh nothing
    weights = valid / np.maximum(count, 1)[:, None]
    mean = (neighbours * weights[:, :, None]).sum(axis=1)
    centred = (neighbours - mean[:, None, :]) * np.sqrt(weights)[:, :, None]
    sxx = (centred[:, :, 0] ** 2).sum(axis=1)
    syy = (centred[:, :, 1] ** 2).sum(axis=1)
    sxy = (centred[:, :, 0] * centred[:, :, 1]).sum(axis=1)
    # eigenvalues of [[sxx, sxy], [sxy, syy]]; the line runs along the larger one's eigenvector
    half_trace, root = (sxx + syy) / 2.0, np.sqrt(((sxx - syy) / 2.0) ** 2 + sxy**2)
    line = (count >= 4) & (half_trace - root < 0.05 * np.maximum(half_trace + root, 1e-12))
    direction = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    normals = np.stack([-np.sin(direction), np.cos(direction)], axis=1)
    normals[~line] = np.nan
    normals[~line & (count >= 4), 1] = 0.0  # (NaN, 0): enough neighbours, not on one line (a corner)
    return normals


def point_to_line(
    source: NDArray[np.float64],
    map_points: NDArray[np.float64],
    guess: NDArray[np.float64],
    config: OdometryConfig,
    prior: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """The (3,) SE(2) pose that puts the (N, 2) robot-frame ``source`` points on the walls of the
    (P, 2) ``map_points``, starting from ``guess``: Gauss-Newton on each scan point's distance
    to the line through its nearest map point and that point's neighbours (point-to-line, Censi,
    "An ICP variant using a point-to-line metric", ICRA 2008), a Cauchy kernel, and a weak prior
    on ``prior`` (default: ``guess``) for the directions no wall constrains (along a bare
    corridor). Unlike point-to-point, where along a wall a scan point lands between two map
    returns does not matter."""
    from scipy.spatial import cKDTree

    pose = np.asarray(guess, dtype=np.float64).copy()
    source, map_points = _unique_xy(source, LINE_CELL), _unique_xy(map_points, LINE_CELL)
    if len(source) < 10 or len(map_points) < 10:
        return pose
    tree = cKDTree(map_points)
    normals = np.full((len(map_points), 2), np.inf)  # inf: not computed yet, NaN: not on a line (NaN, 0: a corner)
    centre = pose.copy() if prior is None else np.asarray(prior, dtype=np.float64)
    information = np.array([config.line_prior_xy, config.line_prior_xy, np.radians(config.line_prior_yaw_deg)]) ** -2.0
    scale = config.line_distance / 3.0

    def rows(directions: NDArray, lever: NDArray) -> NDArray:
        """Jacobian rows of residuals measured along unit ``directions`` (d(R p)/dyaw = J R p)."""
        return np.column_stack([directions, directions[:, 1] * lever[:, 0] - directions[:, 0] * lever[:, 1]])

    def weights(residual: NDArray) -> NDArray:
        """Cauchy-kernel information of each residual."""
        return 1.0 / (1.0 + (residual / scale) ** 2) / config.line_sigma**2

    for _ in range(config.line_iterations):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        moved = source @ np.array([[c, s], [-s, c]]) + pose[:2]
        distance, nearest = tree.query(moved, distance_upper_bound=config.line_distance)
        nearest = nearest[np.isfinite(distance)]
        moved = moved[np.isfinite(distance)]
        new = np.unique(nearest[np.isinf(normals[nearest, 0])])
        if len(new):
            normals[new] = _line_normals(map_points, tree, new, config.line_neighbours)
        n = normals[nearest]
        on_line = np.isfinite(n[:, 0])
        if on_line.sum() < 10:
            break
        offset = moved - map_points[nearest]
        lever = moved - pose[:2]
        residual = (n[on_line] * offset[on_line]).sum(axis=1)
        jacobian = rows(n[on_line], lever[on_line])
        weight = weights(residual)
        corner = ~on_line & np.isfinite(n[:, 1])
        if config.line_corner_ratio > 0 and corner.any():
            # Walls leave a direction free (along a corridor): the door jambs and corners there
            # pull along that direction alone, as if a wall ran across it through them.
            values, vectors = np.linalg.eigh((jacobian[:, :2] * weight[:, None]).T @ jacobian[:, :2])
            if values[0] < config.line_corner_ratio * values[1]:
                free = np.broadcast_to(vectors[:, 0], (int(corner.sum()), 2))
                corner_residual = (free * offset[corner]).sum(axis=1)
                residual = np.concatenate([residual, corner_residual])
                jacobian = np.vstack([jacobian, rows(free, lever[corner])])
                weight = np.concatenate([weight, weights(corner_residual)])
        hessian = (jacobian * weight[:, None]).T @ jacobian + np.diag(information)
        difference = pose - centre
        difference[2] = se2.wrap_angle(difference[2])
        gradient = (jacobian * (weight * residual)[:, None]).sum(axis=0) + information * difference
        step = -np.linalg.solve(hessian, gradient)
        pose += step
        pose[2] = se2.wrap_angle(pose[2])
        if abs(step[0]) + abs(step[1]) < 1e-5 and abs(step[2]) < 1e-6:
            break
    return pose


class LidarOdometry:
    """Pose of the robot in the odometry frame, scan by scan.

    The odometry frame is the wheel-odometry frame of the first update: the lidar estimate is
    anchored at the first wheel pose, so ``source="lidar"`` and ``source="wheel"`` report in
    the same frame.
    """

    def __init__(self, config: OdometryConfig | None = None):
        self.config = config or OdometryConfig()
        self._kiss: KissICP | None = None
        if self.config.source == "lidar":
            from kiss_icp.kiss_icp import KissICP

            self._kiss = KissICP(self.config.kiss_config())
        self._anchor: NDArray[np.float64] | None = None  # first wheel pose
        self._last_wheel: NDArray[np.float64] | None = None
        self._map_queue: deque[tuple[NDArray, NDArray]] = deque()  # scans waiting for the map
        self._scans_in_map = 0
        self.pose = np.zeros(3)  # latest estimate, odometry frame
        self.scans = 0

    def update(self, points: NDArray[np.float32], wheel_odom: NDArray) -> NDArray[np.float64]:
        """Register one scan.

        points: (N, 3) float32, robot frame, z up from the floor (floor hits included).
        wheel_odom: (3,) wheel-odometry pose [x, y, yaw] in the odometry frame.
        Returns the (3,) SE(2) pose of the robot in the odometry frame.
        """
        wheel_odom = np.asarray(wheel_odom, dtype=np.float64)
        self.scans += 1
        if self._anchor is None:
            self._anchor = wheel_odom.copy()
            self._last_wheel = wheel_odom.copy()
        assert self._last_wheel is not None  # set with the anchor
        wheel_delta = se2.between(self._last_wheel, wheel_odom)
        self._last_wheel = wheel_odom.copy()
        if self._kiss is None:
            self.pose = wheel_odom.copy()
            return self.pose.copy()

        kiss = self._kiss
        if self.config.seed_with_wheel and self.scans > 1:
            # kiss-icp predicts last_pose @ last_delta: the wheel delta replaces constant velocity
            kiss.last_delta = se2_to_se3(wheel_delta)
        cropped = crop_floor_and_ceiling(points, self.config.crop_min_z, self.config.crop_max_z)
        if len(cropped) < self.config.min_points:
            new_pose = kiss.last_pose @ kiss.last_delta  # blind: keep the prediction
            if self.config.planar:
                new_pose = se2_to_se3(se3_to_se2(new_pose))
            kiss.last_delta = np.linalg.inv(kiss.last_pose) @ new_pose
            kiss.last_pose = new_pose
        else:
            self._register(cropped)
        self.pose = se2.compose(self._anchor, se3_to_se2(kiss.last_pose))
        return self.pose.copy()

    def _register(self, frame: NDArray[np.float64]) -> None:
        """``KissICP.register_frame`` with two changes: only points within ``source_range`` are
        registered, and (``planar``) the estimate is put on the plane before the map update."""
        kiss = self._kiss
        assert kiss is not None
        frame = kiss.preprocessor.preprocess(frame, np.zeros(len(frame)), kiss.last_delta)
        source, frame_downsample = kiss.voxelize(frame)
        # The edge of what the lidar sees moves with it: source points beyond the local map's
        # reach (seen for the first time) would be pulled back to the map's edge, biasing the
        # motion short. Registering only points well inside the range keeps them covered.
        source = source[np.linalg.norm(source, axis=1) < self.config.source_range]
        sigma = kiss.adaptive_threshold.get_threshold()
        initial_guess = kiss.last_pose @ kiss.last_delta
        bootstrap = self.config.seed_with_wheel and 0 < self._scans_in_map < self.config.bootstrap_scans
        if bootstrap and not (self.config.point_to_line and self.config.line_bootstrap):
            new_pose = initial_guess  # a map of one or two scans is all sampling pattern
        elif not bootstrap:
            new_pose = kiss.registration.align_points_to_map(
                points=source,
                voxel_map=kiss.local_map,
                initial_guess=initial_guess,
                max_correspondance_distance=3 * sigma,
                kernel=sigma,
            )
        else:
            new_pose = initial_guess  # point-to-line alone: the sampling pattern does not pull it
        if self.config.point_to_line and not kiss.local_map.empty() and (self.config.line_bootstrap or not bootstrap):
            map_xy = kiss.local_map.point_cloud()[:, :2]
            prediction = se3_to_se2(initial_guess)  # the wheel-seeded one: unbiased where walls say nothing
            new_pose = se2_to_se3(point_to_line(source[:, :2], map_xy, se3_to_se2(new_pose), self.config, prediction))
        elif self.config.planar:
            new_pose = se2_to_se3(se3_to_se2(new_pose))
        kiss.adaptive_threshold.update_model_deviation(np.linalg.inv(initial_guess) @ new_pose)
        if kiss.local_map.empty():
            kiss.local_map.update(frame_downsample, new_pose)
            self._scans_in_map = 1
        else:
            self._map_queue.append((frame_downsample, new_pose))
            delay = self.config.map_delay_scans if self.config.seed_with_wheel else 0
            while len(self._map_queue) > delay:
                kiss.local_map.update(*self._map_queue.popleft())
                self._scans_in_map += 1
        kiss.last_delta = np.linalg.inv(kiss.last_pose) @ new_pose
        kiss.last_pose = new_pose

    @property
    def nbytes(self) -> int:
        """Bytes of kiss-icp's local map points (float64 x, y, z each) and of the scans waiting to
        enter it; 0 for wheel odometry."""
        if self._kiss is None:
            return 0
        waiting = sum(frame.nbytes + pose.nbytes for frame, pose in self._map_queue)
        return int(self._kiss.local_map.point_cloud().shape[0]) * 3 * 8 + int(waiting)

    def local_map_points(self) -> NDArray[np.float64]:
        """(P, 3) points of kiss-icp's local map in kiss-icp's frame (the anchor's)."""
        if self._kiss is None:
            return np.zeros((0, 3))
        return self._kiss.local_map.point_cloud()
