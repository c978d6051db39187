"""Localization of the metric baseline on its map: tracking by scan-to-map registration, and
finding the pose in the first place (relocalization) when the given initial pose is off.

Tracking (``ScanToMap``) is a likelihood-field fit (Thrun, Burgard & Fox, "Probabilistic
Robotics", 2005, Sec. 6.4) solved by Gauss-Newton on the signed distance field of the map's
occupied cells, with bilinear interpolation and its analytic gradient (the map-gradient matcher
of Kohlbrecher et al., "A Flexible and Scalable SLAM System with Full 3D Motion Estimation", SSRR
2011), a Huber kernel, and the odometry prediction as a prior, so that the direction along a bare
corridor stays where odometry put it. It corrects centimetres and degrees, not the half metre and
ten degrees a person makes setting the initial pose by hand.

Relocalization (``Relocalizer``) is a correlative search (E. Olson, "Real-Time Correlative Scan
Matching", ICRA 2009): every pose of a grid of candidates is scored by how close the scan's points
fall to mapped walls (a Gaussian of the distance field), the best few are refined by the
Gauss-Newton fit, and the winner is taken only if enough of its points fit the map and no distinct
candidate scores nearly as well. First a window around the given pose (the protocol's error is at
most ±0.5 m and ±10°; the window is twice that), then, if nothing in it fits, the whole map's free
space at a coarser step. No ground truth is involved: the given pose is the only prior.

Points everywhere here are (N, 2) obstacle points in the robot frame; poses are map-frame [x, y, yaw].
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit import geometry as se2
from navkit.raster import FREE, OCCUPIED, GridFrame, TiledRaster

from .occupancy import GridMap

DISTANCE_STEPS = 32000  # the signed distance field's int16 steps from zero to ``distance_cap``
LIKELIHOOD_SHIFT = 5  # the relocalizer's likelihood table: one entry per 32 steps (2 mm by default)


class ScanToMapConfig(BaseModel):
    """Scan-to-map registration during navigation (likelihood field, Gauss-Newton)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="correct the odometry by registering each scan to the map")
    every_scans: int = Field(1, ge=1, description="register every n-th scan")
    voxel: float = Field(0.1, gt=0, description="m; 2D voxel filter of the scan's obstacle points")
    max_range: float = Field(12.0, gt=0, description="m; only nearer points are registered")
    min_points: int = Field(80, description="fewer points: keep the odometry")
    iterations: int = Field(10, ge=1)
    huber: float = Field(0.05, gt=0, description="m; residuals above it are down-weighted")
    max_residual: float = Field(0.4, gt=0, description="m; points farther from any mapped wall are ignored")
    residual_sigma: float = Field(0.05, gt=0, description="m; the noise of one point's residual")
    prior_sigma_xy: float = Field(0.1, gt=0, description="m; trust in the odometry prediction per update")
    prior_sigma_yaw_deg: float = Field(2.0, gt=0, description="deg; likewise for the heading")
    inlier_distance: float = Field(0.1, gt=0, description="m; a point this close to a mapped wall fits")
    min_inlier_share: float = Field(0.6, ge=0, le=1, description="fewer fitting points: reject the fit")
    max_correction: float = Field(0.5, gt=0, description="m; larger corrections are rejected")
    max_correction_yaw_deg: float = Field(10.0, gt=0)
    distance_cap: float = Field(2.0, gt=0, description="m; the distance field saturates here")
    wall_depth: float = Field(0.025, description="m inside the mapped occupied cells' boundary where walls lie, on average")


class ScanToMap:
    """Fits 2D obstacle points to the signed distance field of a grid's occupied cells.

    distance[row, col] int16, in steps of ``unit`` metres (``distance_cap`` / ``DISTANCE_STEPS``,
    0.06 mm by default): from each cell centre to the expected wall surface (``wall_depth``
    inside the boundary of the occupied cells), negative inside it. Half the bytes of float32 and
    a thousandth of the fit's noise; kept as the tiles that come nearer a wall than the cap
    (``navkit.raster.TiledRaster``: a third of a corridor building's map, the rest one shared tile).
    """

    def __init__(self, grid: GridMap, config: ScanToMapConfig) -> None:
        self.config = config
        self.origin = grid.origin.astype(np.float64)
        self.resolution = float(grid.resolution)
        occupied = grid.cells == OCCUPIED
        res = self.resolution
        # Signed: + outside the occupied cells, - inside, zero ``wall_depth`` inside their boundary,
        # where the true wall surface lies on average. A cell is occupied when a return falls
        # anywhere in it, so the mapped boundary stands in front of the surface; fitting to the
        # boundary (or to the occupied cell centres) left 2-3 cm of bias on ``tiny``, a quarter
        # cell 3.5 mm.
        outside = cv2.distanceTransform((~occupied).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
        inside = cv2.distanceTransform(occupied.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
        signed = np.where(occupied, -(inside - res / 2), outside - res / 2) + config.wall_depth
        self.unit = config.distance_cap / DISTANCE_STEPS
        steps = np.round(np.clip(signed, -config.distance_cap, config.distance_cap) / self.unit).astype(np.int16)
        self.distance = TiledRaster.of(steps, DISTANCE_STEPS)

    @property
    def nbytes(self) -> int:
        return int(self.distance.nbytes)

    def sample(self, xy: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Distance (N,) and its gradient (N,) x2 at map points xy (N, 2), bilinear between centres."""
        u = (xy[:, 0] - self.origin[0]) / self.resolution - 0.5
        v = (xy[:, 1] - self.origin[1]) / self.resolution - 0.5
        height, width = self.distance.shape
        j0 = np.floor(u).astype(np.int64)
        i0 = np.floor(v).astype(np.int64)
        inside = (i0 >= 0) & (i0 < height - 1) & (j0 >= 0) & (j0 < width - 1)
        i0 = np.clip(i0, 0, height - 2)
        j0 = np.clip(j0, 0, width - 2)
        fu, fv = u - j0, v - i0
        d00 = self.distance.at(i0, j0)
        d01 = self.distance.at(i0, j0 + 1)
        d10 = self.distance.at(i0 + 1, j0)
        d11 = self.distance.at(i0 + 1, j0 + 1)
        d00, d01, d10, d11 = (d.astype(np.float64) * self.unit for d in (d00, d01, d10, d11))
        value = (1 - fv) * ((1 - fu) * d00 + fu * d01) + fv * ((1 - fu) * d10 + fu * d11)
        grad_x = ((1 - fv) * (d01 - d00) + fv * (d11 - d10)) / self.resolution
        grad_y = ((1 - fu) * (d10 - d00) + fu * (d11 - d01)) / self.resolution
        value = np.where(inside, value, self.config.distance_cap)
        return value, np.where(inside, grad_x, 0.0), np.where(inside, grad_y, 0.0)

    def refine(self, points: NDArray, predicted: NDArray, prior_scale: float = 1.0) -> NDArray[np.float64]:
        """Gauss-Newton from ``predicted`` (3,) map frame: the pose that puts the points (N, 2, robot
        frame) on the mapped walls, held to ``predicted`` by the prior (sigmas times ``prior_scale``)."""
        c = self.config
        sigmas = np.array([c.prior_sigma_xy, c.prior_sigma_xy, np.deg2rad(c.prior_sigma_yaw_deg)]) * prior_scale
        prior = np.diag(1.0 / sigmas**2)
        pose = np.asarray(predicted, dtype=np.float64).copy()
        px, py = points[:, 0].astype(np.float64), points[:, 1].astype(np.float64)
        for _ in range(c.iterations):
            cos, sin = math.cos(pose[2]), math.sin(pose[2])
            world = np.stack([pose[0] + cos * px - sin * py, pose[1] + sin * px + cos * py], axis=-1)
            residual, grad_x, grad_y = self.sample(world)
            magnitude = np.abs(residual)
            weight = np.where(magnitude <= c.huber, 1.0, c.huber / np.maximum(magnitude, 1e-9))
            weight = np.where(magnitude < c.max_residual, weight, 0.0) / c.residual_sigma**2
            jacobian = np.stack([grad_x, grad_y, grad_x * (-sin * px - cos * py) + grad_y * (cos * px - sin * py)], axis=-1)
            offset = pose - predicted
            offset[2] = se2.wrap_angle(offset[2])
            hessian = (jacobian * weight[:, None]).T @ jacobian + prior
            gradient = (jacobian * weight[:, None]).T @ residual + prior @ offset
            step = -np.linalg.solve(hessian, gradient)
            pose += step
            if np.hypot(step[0], step[1]) < 1e-4 and abs(step[2]) < 1e-5:
                break
        pose[2] = se2.wrap_angle(pose[2])
        return pose

    def inlier_share(self, points: NDArray, pose: NDArray) -> float:
        """Share of the points (N, 2, robot frame) within ``inlier_distance`` of a mapped wall at ``pose``."""
        world = se2.transform_points(pose, np.asarray(points, dtype=np.float64)[:, :2])
        return float((np.abs(self.sample(world)[0]) <= self.config.inlier_distance).mean())

    def fit(self, points: NDArray, predicted: NDArray) -> tuple[NDArray[np.float64], float] | None:
        """points: (N, 2) robot frame; predicted: (3,) map-frame pose. Returns (pose, inlier share)
        of an accepted fit, or None (too few points, too few fit, or a correction too large)."""
        c = self.config
        if len(points) < c.min_points:
            return None
        pose = self.refine(points, predicted)
        share = self.inlier_share(points, pose)
        correction = se2.between(predicted, pose)
        if (
            share < c.min_inlier_share
            or np.hypot(correction[0], correction[1]) > c.max_correction
            or abs(correction[2]) > np.deg2rad(c.max_correction_yaw_deg)
        ):
            return None
        return pose, share


class RelocalizationConfig(BaseModel):
    """The correlative search that finds the robot's pose on the map (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="search for the pose before the first plan (False: trust the given pose)")
    window_xy: float = Field(1.0, gt=0, description="m either side of the given pose, along x and y")
    window_yaw_deg: float = Field(20.0, gt=0, description="deg either side of the given heading")
    step_yaw_deg: float = Field(2.0, gt=0, description="deg between candidate headings in the window")
    global_search: bool = Field(True, description="when nothing in the window fits, search all mapped free space")
    global_step_xy: float = Field(0.5, gt=0, description="m between candidate positions of the global search")
    global_step_yaw_deg: float = Field(5.0, gt=0, description="deg between candidate headings of the global search")
    global_range: float = Field(6.0, gt=0, description="m; the global search scores only nearer points")
    score_sigma: float = Field(0.1, gt=0, description="m; a point's score is exp(-d^2 / 2 sigma^2), d its distance to a wall")
    max_points: int = Field(300, ge=10, description="points scored per candidate (an even subsample)")
    refine: int = Field(6, ge=1, description="best distinct candidates refined by the Gauss-Newton fit")
    distinct_distance: float = Field(1.0, gt=0, description="m; candidates farther apart are different places")
    min_inlier_share: float = Field(0.75, ge=0, le=1, description="share of points within inlier_distance of a wall")
    min_margin: float = Field(0.1, ge=0, le=1, description="the winner's share must beat a distinct rival's by this")
    turn_rate: float = Field(0.6, gt=0, description="rad/s: turn in place to see more while no pose is found")
    timeout: float = Field(30.0, gt=0, description="s of simulated time without a pose: fail with not_localized")
    lost_after: int = Field(15, ge=1, description="consecutive rejected tracking fits before the window search runs again")
    # a kidnapped start (no initial pose given): places followed as hypotheses, weighed look by look
    # (tracking.py's module docstring)
    look_turn_deg: float = Field(
        30.0,
        gt=0,
        description="kidnapped: a look (the hypotheses fitted, the whole map searched) at the first scan and "
        "after each this many deg of turning ...",
    )
    look_distance: float = Field(0.25, gt=0, description="... or m of motion (odometry)")
    confirm_looks: int = Field(
        3, ge=1, description="kidnapped: looks that must verify the one hypothesis left before its pose is taken ..."
    )
    confirm_turn_deg: float = Field(
        90.0, ge=0, description="... over at least this much turning (different views of the place) and ..."
    )
    confirm_distance: float = Field(
        3.0,
        ge=0,
        description="... this many m of motion (NavTopo's start-up's confirm_span: a building symmetric under a half "
        "turn fits one place's views turning on the spot as well as the other's)",
    )
    confirm_xy: float = Field(
        0.3, gt=0, description="m: a look verifies a hypothesis when the fit from where odometry carried it moves it no more ..."
    )
    confirm_yaw_deg: float = Field(5.0, gt=0, description="... and this many deg")
    drop_after: int = Field(
        3,
        ge=1,
        description="kidnapped: looks against a hypothesis (the scan fits elsewhere better by min_margin, or it does "
        "not fit there at all), less those for it, that drop it (NavTopo's start-up's)",
    )
    confirm_alone_distance: float = Field(
        1.0, ge=0, description="kidnapped: m a hypothesis must be followed after its last rival fell before it is taken ..."
    )
    confirm_alone_looks: int = Field(3, ge=1, description="... and looks that verify it meanwhile (NavTopo's start-up's)")
    max_hypotheses: int = Field(12, ge=1, description="kidnapped: hypotheses followed at once (the least supported give way)")
    recheck_looks: int = Field(
        12,
        ge=0,
        description="kidnapped: a place found while others are followed must fit this many last looks about as "
        "well as the best place then (NavTopo's start-up's far_history)",
    )
    explore_after_deg: float = Field(
        360.0,
        ge=0,
        description="kidnapped: deg turned in place before the robot moves toward open space for new views (the "
        "exploring moves of NavTopo's start-up, navkit.explore), while no pose is confirmed",
    )
    explore_distance: float = Field(1.5, gt=0, description="m of each exploring move (NavTopo's start-up's)")
    kidnapped_timeout: float = Field(
        90.0, gt=0, description="s of simulated time without a confirmed pose from a kidnapped start (NavTopo's start-up's)"
    )


def _square(centre_xy: NDArray, half: float, step: float) -> NDArray[np.float64]:
    """(M, 2) candidate positions every ``step`` metres up to ``half`` either side of ``centre_xy``
    along x and y (both ends included)."""
    offsets = np.arange(-half, half + 1e-9, step)
    return np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2) + centre_xy


def _headings(centre_yaw: float, half_deg: float, step_deg: float) -> NDArray[np.float64]:
    """Candidate headings (rad) every ``step_deg`` up to ``half_deg`` either side of ``centre_yaw``."""
    return centre_yaw + np.radians(np.arange(-half_deg, half_deg + 1e-9, step_deg))


class Relocalizer:
    """Correlative search of the map for the pose of a scan, around a guess or everywhere."""

    def __init__(self, grid: GridMap, scan_to_map: ScanToMap, robot_radius: float, config: RelocalizationConfig) -> None:
        self.config = config
        self.scan_to_map = scan_to_map
        self.origin = scan_to_map.origin
        self.resolution = scan_to_map.resolution
        # what the search scores: a Gaussian of the distance to the expected wall surface, read
        # through a table of the distance field's steps (no likelihood raster: 4 bytes a cell saved)
        entry_m = scan_to_map.unit * (1 << LIKELIHOOD_SHIFT)
        steps = np.arange((DISTANCE_STEPS >> LIKELIHOOD_SHIFT) + 1, dtype=np.float64) * entry_m
        self._likelihood_of_step = np.exp(-0.5 * (steps / config.score_sigma) ** 2).astype(np.float32)
        # where a global search may put the robot: known free cells the robot fits in (bit-packed:
        # read once, on the first global search)
        free = (grid.cells == FREE).astype(np.uint8)
        clearance = cv2.distanceTransform(np.pad(free, 1), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
        self._fits_shape = free.shape
        self._fits = np.packbits(clearance * self.resolution >= robot_radius, axis=None)
        self._global_positions: NDArray[np.float64] | None = None
        self.ambiguous = False  # the last search refused two places that fit about as well

    @property
    def nbytes(self) -> int:
        positions = self._global_positions.nbytes if self._global_positions is not None else 0
        return int(self._likelihood_of_step.nbytes + self._fits.nbytes + positions)

    # -- scoring -----------------------------------------------------------------------------------

    def _subsample(self, points: NDArray, max_range: float | None = None) -> NDArray[np.float64]:
        points = np.asarray(points, dtype=np.float64)[:, :2]
        if max_range is not None:
            points = points[np.hypot(points[:, 0], points[:, 1]) <= max_range]
        if len(points) > self.config.max_points:
            points = points[np.linspace(0, len(points) - 1, self.config.max_points).astype(np.int64)]
        return points

    def _scores(self, points: NDArray, positions: NDArray, yaws: NDArray) -> NDArray[np.float64]:
        """(len(yaws), len(positions)) mean likelihood of the points at every candidate pose."""
        distance = self.scan_to_map.distance
        height, width = distance.shape
        likelihood = self._likelihood_of_step
        scores = np.empty((len(yaws), len(positions)))
        cell_positions = (positions - self.origin) / self.resolution
        for k, yaw in enumerate(yaws):
            c, s = math.cos(yaw), math.sin(yaw)
            rotated = np.stack([c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]], axis=1)
            cols = np.floor(cell_positions[:, None, 0] + rotated[None, :, 0] / self.resolution).astype(np.int64)
            rows = np.floor(cell_positions[:, None, 1] + rotated[None, :, 1] / self.resolution).astype(np.int64)
            inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
            steps = distance.at(np.where(inside, rows, 0), np.where(inside, cols, 0))
            values = np.where(inside, likelihood[np.abs(steps) >> LIKELIHOOD_SHIFT], 0.0)
            scores[k] = values.mean(axis=1)
        return scores

    def _best_distinct(self, scores: NDArray, positions: NDArray, yaws: NDArray, count: int) -> list[NDArray[np.float64]]:
        """The ``count`` best candidate poses, no two within ``distinct_distance`` of each other."""
        order = np.argsort(scores, axis=None)[::-1]
        chosen: list[NDArray[np.float64]] = []
        for flat_index in order[: 50 * count]:
            k, i = np.unravel_index(flat_index, scores.shape)
            pose = np.array([positions[i, 0], positions[i, 1], yaws[k]])
            if all(np.hypot(*(pose[:2] - other[:2])) >= self.config.distinct_distance for other in chosen):
                chosen.append(pose)
                if len(chosen) == count:
                    break
        return chosen

    def _refined(self, points: NDArray, candidates: list[NDArray]) -> list[tuple[float, NDArray[np.float64]]]:
        """Each candidate refined by the Gauss-Newton fit, with its inlier share, best first."""
        refined = []
        for pose in candidates:
            fitted = self.scan_to_map.refine(points, pose, prior_scale=3.0)
            refined.append((self.scan_to_map.inlier_share(points, fitted), fitted))
        refined.sort(key=lambda r: -r[0])
        return refined

    def _decide(self, points: NDArray, candidates: list[NDArray]) -> tuple[NDArray[np.float64], float] | None:
        """Refine each candidate by the Gauss-Newton fit; the best if it fits and has no close rival."""
        return self._decide_refined(self._refined(points, candidates))

    def _decide_refined(self, refined: list[tuple[float, NDArray[np.float64]]]) -> tuple[NDArray[np.float64], float] | None:
        """Of refined places (best first): the best if it fits and has no close rival."""
        best_share, best = refined[0]
        self.ambiguous = False
        if best_share < self.config.min_inlier_share:
            return None
        for share, pose in refined[1:]:
            if np.hypot(*(pose[:2] - best[:2])) >= self.config.distinct_distance and share > best_share - self.config.min_margin:
                self.ambiguous = True
                return None  # two places explain the scan about as well: do not guess
        return best, best_share

    # -- searches ------------------------------------------------------------------------------------

    def around(self, points: NDArray, guess: NDArray) -> tuple[NDArray[np.float64], float] | None:
        """Search the window around ``guess`` (map frame)."""
        c = self.config
        points = self._subsample(points)
        if len(points) < 20:
            return None
        positions = _square(guess[:2], c.window_xy, self.resolution)
        yaws = _headings(guess[2], c.window_yaw_deg, c.step_yaw_deg)
        scores = self._scores(points, positions, yaws)
        # inside the window two candidates a metre apart are rarely different places: refine the
        # best few and let the fit decide, with the rival check over the whole set
        return self._decide(points, self._best_distinct(scores, positions, yaws, self.config.refine))

    def everywhere(self, points: NDArray) -> tuple[NDArray[np.float64], float] | None:
        """Search all mapped free space the robot fits in, coarse then fine: the best place if it fits
        and no distinct one fits about as well."""
        found = self.places(points)
        return self._decide_refined(found) if found else None

    def places(self, points: NDArray) -> list[tuple[float, NDArray[np.float64]]]:
        """Every place the global search refines (coarse seeds, then fine windows, then the fit), with
        its inlier share, best first; empty when the scan has too few points or nowhere fits the robot."""
        c = self.config
        near = self._subsample(points, c.global_range)
        if len(near) < 20:
            return []
        if self._global_positions is None:
            step = max(int(round(c.global_step_xy / self.resolution)), 1)
            fits = np.unpackbits(self._fits, count=int(np.prod(self._fits_shape))).reshape(self._fits_shape)
            rows, cols = np.nonzero(fits[::step, ::step])
            cells = np.stack([rows * step, cols * step], axis=1)
            self._global_positions = GridFrame(self.origin, self.resolution).to_world(cells)
        positions = self._global_positions
        if not len(positions):
            return []
        yaws = np.radians(np.arange(-180.0, 180.0, c.global_step_yaw_deg))
        coarse = self._scores(near, positions, yaws)
        seeds = self._best_distinct(coarse, positions, yaws, 3 * c.refine)
        # each seed: a fine window of half the coarse step, then the fit
        fine_points = self._subsample(points)
        candidates = []
        for seed in seeds:
            window = _square(seed[:2], c.global_step_xy / 2, self.resolution)
            yaw_window = _headings(seed[2], c.global_step_yaw_deg, 1.0)
            fine = self._scores(fine_points, window, yaw_window)
            k, i = np.unravel_index(int(np.argmax(fine)), fine.shape)
            candidates.append(np.array([window[i, 0], window[i, 1], yaw_window[k]]))
        return self._refined(fine_points, candidates)
