"""Registration of two location grids in 2D, and a verdict on whether they show one place.

NavTopo (Muravyev & Yakovlev, Sec. "Graph Maintaining" and "Localization") decides whether the
robot is still inside a location, moves along edges and verifies place-recognition candidates by
matching 2D projections of scans with features; PRISM-TopoMap does it with ORB on occupancy
images and an iterative outlier rejection. This file does the same job in four steps:

1. features: ORB keypoints and descriptors on an image of the occupied cells (walls dilated and
   blurred, so that corners and wall ends give stable, oriented keypoints);
2. robust matching: Hamming nearest neighbours with Lowe's ratio test, or, with an odometry
   guess, every neighbour consistent with the guess (which also lifts repeated structure);
   2-point RANSAC for a rigid 2D transform (rotation and translation, no scale), then a
   least-squares refit on the inliers;
3. refinement: point-to-point ICP (Besl & McKay 1992) on occupied-cell centres with shrinking
   correspondence distances (nearest neighbours come from a distance transform's label map, so an
   iteration costs a lookup instead of a k-d tree query), then Gauss-Newton on the reference's
   bilinearly interpolated distance field (a likelihood-field fit, as in Cartographer's scan
   matcher), which acts point-to-line and removes ICP's sliding along rows of wall cells. Both pair
   a point only with a wall cell facing its way, if ``face_angle`` is set (``wall_faces``: each
   cell faces the observation point that saw it), so the two faces of one wall, seen from a room
   and from the corridor, are not fitted onto each other (off by default, measured). With a
   guess, where ICP took the pose beyond the verdict's wall tolerance, the field fit from the guess
   alone is scored too and the better pose kept (ICP's wide first stages can slide a partial view);
4. verdict: wall agreement (occupied cells of each grid that lie near occupied cells of the other,
   against those that fall in the other's free space) times the known-area IoU.

Direction convention (as ``navkit.geometry``): ``match(reference, query)`` returns the pose of
the query's observation point in the reference grid's frame. If the reference was observed at
pose A and the query at pose B (any common frame), the ideal result is ``between(A, B)``, and
``transform_points(result.pose, p)`` maps a point p of the query frame into the reference frame.
An ``initial_guess`` follows the same convention (e.g. ``between(odom_A, odom_B)``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.geometry import inverse, transform_points, wrap_angle
from navkit.raster import OCCUPIED, UNKNOWN, GridFrame
from navkit.scan_grid import Grid, GridConfig, grid_frame

# a prepared grid's distance field: uint16 steps of a 2048th of a cell, saturating at 32 cells
# (3.2 m at 0.1 m cells); every use of it compares with a cutoff under 30 cells (checked)
FIELD_STEPS_PER_CELL = 2048


class MatchingConfig(BaseModel):
    """Parameters of ``match``; distances in metres, angles in radians."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # features
    n_features: int = Field(default=400, gt=0, description="ORB keypoints per grid at most")
    # a wide patch (4.5 m) and two scales: wall layouts are distinctive over metres, not cells
    orb_patch_size: int = Field(default=45, ge=5, description="ORB patch side, cells")
    orb_levels: int = Field(default=2, ge=1, description="ORB pyramid levels")
    orb_scale: float = Field(default=1.4, gt=1.0, description="ORB pyramid scale step")
    orb_fast_threshold: int = Field(default=5, ge=1, description="FAST corner threshold")
    ratio_test: float = Field(default=0.95, gt=0.0, le=1.0, description="Lowe's ratio without a guess")
    # RANSAC
    ransac_iterations: int = Field(default=1000, gt=0)
    ransac_threshold: float = Field(default=0.3, gt=0.0, description="inlier keypoint distance, m")
    min_inliers: int = Field(default=5, ge=2, description="fewer RANSAC inliers: no feature hypothesis")
    ransac_hypotheses: int = Field(
        default=3,
        ge=1,
        description="hypotheses refined and scored (sequential RANSAC on the outliers)",
    )
    seed: int = 0
    # odometry guess
    guess_translation_tolerance: float = Field(
        default=2.0,
        gt=0.0,
        description="keypoint matches farther than this from the guess are dropped",
    )
    guess_rotation_tolerance: float = Field(
        default=0.5, gt=0.0, description="RANSAC hypotheses turned farther than this from the guess"
    )
    guess_first_score: float = Field(
        default=0.6,
        ge=0.0,
        le=1.0,
        description="a refined guess scoring at least this is taken without feature matching",
    )
    # ICP refinement
    icp_distances: tuple[float, ...] = Field(default=(1.0, 0.5, 0.25, 0.15), description="correspondence distance per stage, m")
    icp_iterations: int = Field(default=8, gt=0, description="iterations per stage at most")
    field_iterations: int = Field(default=10, ge=0, description="Gauss-Newton steps on the distance field after ICP (0: none)")
    field_cutoff: float = Field(default=0.2, gt=0.0, description="farther cells are left out, m")
    wall_closing: int = Field(
        default=5,
        ge=0,
        description="close gaps in rows of wall cells with a square of this many cells before matching (0: off; 5 "
        "measured, with mapping.degenerate_ratio). "
        "A wall seen at a grazing angle is a dashed row (1 degree between rays: 0.3 m apart 5 m along a wall "
        "1.5 m away), the dashes move with the robot, and fitting them pulled the pose back toward the "
        "location's centre along a rack hall's aisle, 0.1 m per update (BENCHMARKS.md, 'Design choices: "
        "closing dashed walls'). The fits use the closed walls; the verdict counts the walls seen",
    )
    face_angle: float | None = Field(
        default=120.0,
        gt=0.0,
        le=180.0,
        description="the fits (ICP, the distance field, the covariance) pair a point only with a wall cell facing "
        "its way within this (degrees; None: any pair, as before, configs/navtopo_before_faces.yaml): each wall "
        "cell faces its grid's observation point along the wall's normal, so the two faces of one wall point half "
        "a turn apart. Walls a tenth of a metre thick put both faces within the fits' reach, and a room's wall "
        "seen from inside by one grid and from the corridor by the other was fitted face to wrong face (scans of "
        "a corridor matched against a room's location 1.5-2 degrees off). With the mapping checks measure_agreement "
        "and correction_turn_deg, which the matches that share little need (alone: a tuning wing's map 3.02 degrees "
        "off, a held-out SLAM-like ring's 5.65; BENCHMARKS.md, 'Design choices: a wall's two faces' and 'NavTopo with "
        "the face test and the mapping checks as the defaults')",
    )
    # verdict
    wall_tolerance: float = Field(default=0.2, gt=0.0, description="an occupied cell this near agrees")
    # Chosen on generated scenes (benchmarks/tune_scan_matching.py, seeds 101-103, 1,800 near and
    # 3,000 far pairs; BENCHMARKS.md, "Design choices: NavTopo's scan-matching verdict"). With an
    # odometry guess (tracking, moving along an edge, mapping) 0.90 accepted no wrong pose and 95 %
    # of the right ones (0.88: 1 wrong of 1,800). Without one (place-recognition candidates) 0.96
    # together with min_score 0.40 accepted no wrong pose of 4,800 at near recall 0.52 (at min_score
    # 0.20 it let 2 far pairs through).
    min_wall_agreement: float = Field(default=0.90, ge=0.0, le=1.0, description="with an initial guess")
    min_wall_agreement_no_guess: float = Field(default=0.96, ge=0.0, le=1.0, description="without an initial guess")
    min_overlap: float = Field(default=0.2, ge=0.0, le=1.0, description="shared known area over the smaller one")
    min_matched_walls: int = Field(default=60, ge=0, description="agreeing occupied cells, both ways")
    min_score: float = Field(default=0.4, ge=0.0, le=1.0, description="wall agreement x overlap, without a guess")
    # with an odometry guess, a place seen from a few metres away through other doors shares little
    # known area yet its walls agree (0.13-0.18 overlap, agreement ~1, 140+ walls in a ring building)
    min_overlap_guess: float = Field(default=0.1, ge=0.0, le=1.0, description="min_overlap with an initial guess")
    min_score_guess: float = Field(default=0.1, ge=0.0, le=1.0, description="min_score with an initial guess")


@dataclass(frozen=True)
class MatchResult:
    """What ``match`` found.

    pose: (3,) the query's observation point in the reference frame (``between(A, B)`` ideally).
    score: wall_agreement * overlap, in [0, 1]. accepted: the verdict of ``MatchingConfig``.
    inliers: RANSAC inlier keypoint matches of the feature hypothesis (0 if it was not used).
    wall_agreement: agreeing / (agreeing + contradicting) occupied cells, both ways.
    overlap: known-area IoU at ``pose``. matched_walls: agreeing occupied cells, both ways.
    source: "guess", "features" or "none" (nothing to match). elapsed_ms: wall clock.
    covariance: (3, 3) of the pose (``covariance``), None when there was nothing to match.
    """

    pose: NDArray[np.float64]
    score: float
    accepted: bool
    inliers: int
    wall_agreement: float
    overlap: float
    matched_walls: int
    source: str
    elapsed_ms: float
    covariance: NDArray[np.float64] | None = None


FACE_STEPS = 256  # a wall cell's facing direction in steps of 2π / 256 (one byte)
FACE_WINDOW = 5  # cells: the square whose wall cells give a wall cell's direction


def wall_faces(walls: NDArray[np.uint8], rows: NDArray[np.intp], cols: NDArray[np.intp], xy: NDArray) -> NDArray[np.uint8]:
    """The direction each wall cell faces (uint8, steps of 2π / ``FACE_STEPS``; ``rows``, ``cols``
    its cells in ``walls``, ``xy`` their centres in the grid's frame): the normal of the wall
    through it (the principal axes of the wall cells in a ``FACE_WINDOW`` square around it),
    turned toward the grid's observation point (the frame's origin), which saw that face. Where
    the cells around do not line up (a corner, a post) the direction toward the observation point."""
    if len(rows) == 0:
        return np.zeros(0, dtype=np.uint8)
    mask = walls.astype(np.float64)
    r_img, c_img = np.indices(walls.shape, dtype=np.float64)

    def window_sum(image: NDArray[np.float64]) -> NDArray[np.float64]:
        total = cv2.boxFilter(image, -1, (FACE_WINDOW, FACE_WINDOW), normalize=False, borderType=cv2.BORDER_CONSTANT)
        return np.asarray(total[rows, cols], dtype=np.float64)

    n = window_sum(mask)
    mean_c, mean_r = window_sum(mask * c_img) / n, window_sum(mask * r_img) / n
    cxx = window_sum(mask * c_img * c_img) / n - mean_c * mean_c  # x: columns, y: rows (the grid frame's layout)
    cyy = window_sum(mask * r_img * r_img) / n - mean_r * mean_r
    cxy = window_sum(mask * r_img * c_img) / n - mean_c * mean_r
    spread = np.sqrt((cxx - cyy) ** 2 + 4 * cxy * cxy)  # the difference of the two eigenvalues
    along = 0.5 * np.arctan2(2 * cxy, cxx - cyy)
    normal = np.stack([-np.sin(along), np.cos(along)], axis=1)
    toward = -np.asarray(xy, dtype=np.float64)
    toward /= np.maximum(np.hypot(toward[:, 0], toward[:, 1]), 1e-9)[:, None]
    lined = (n >= 3) & (spread > 0.5 * (cxx + cyy))  # one axis clearly the longer: a wall
    normal = np.where(lined[:, None], normal, toward)
    normal *= np.where(np.sum(normal * toward, axis=1) < 0, -1.0, 1.0)[:, None]
    angle = np.arctan2(normal[:, 1], normal[:, 0])
    return (np.rint(angle / (2 * np.pi) * FACE_STEPS).astype(np.int64) % FACE_STEPS).astype(np.uint8)


class PreparedGrid:
    """A grid with what matching needs of it, computed once: prepare the current grid once to
    match it against several locations (a few ms saved per match). Features are computed on
    first use only, with the ``MatchingConfig`` given here (``match`` uses it as it is)."""

    def __init__(
        self,
        grid: Grid,
        grid_config: GridConfig | None = None,
        config: MatchingConfig | None = None,
    ):
        self.config = config or MatchingConfig()
        self.grid_config = grid_config or GridConfig()
        self.resolution = self.grid_config.resolution
        # the grid's own frame, centred on its observation point (``navtopo.local_grid``); the compiled
        # kernels below take its centre cell ``half`` and do its arithmetic themselves
        self.frame = GridFrame.centred(grid.shape[0], self.resolution)
        self.half = grid.shape[0] // 2
        # everything below works on the bounding box of the known cells plus a margin: walls lie
        # inside it, and a point outside is unknown and far from every wall
        known = grid != UNKNOWN
        known_rows = np.flatnonzero(known.any(axis=1))
        known_cols = np.flatnonzero(known.any(axis=0))
        pad = int(np.ceil(max(self.config.icp_distances, default=0.0) / self.resolution)) + 2
        if known_rows.size:
            self.row0 = max(int(known_rows[0]) - pad, 0)
            self.col0 = max(int(known_cols[0]) - pad, 0)
            row1 = min(int(known_rows[-1]) + pad + 1, grid.shape[0])
            col1 = min(int(known_cols[-1]) + pad + 1, grid.shape[1])
        else:
            self.row0 = self.col0 = row1 = col1 = 0
        self.crop = np.ascontiguousarray(grid[self.row0 : row1, self.col0 : col1])
        seen = (self.crop == OCCUPIED).astype(np.uint8)
        walls = seen
        if self.config.wall_closing > 1 and walls.size:  # an empty grid has an empty crop
            square = np.ones((self.config.wall_closing, self.config.wall_closing), np.uint8)
            walls = cv2.morphologyEx(walls, cv2.MORPH_CLOSE, square)
        frame = grid_frame(self.grid_config)

        def cells(mask: NDArray[np.uint8]) -> NDArray[np.intp]:
            rows, cols = np.nonzero(mask)
            return np.stack([rows + self.row0, cols + self.col0], axis=1)

        self.occupied_cells = cells(walls)
        rows, cols = self.occupied_cells.T  # for the nearest-wall lookup below
        self.occupied_xy = frame.to_world(self.occupied_cells)
        # the wall cells the lidar saw, which the verdict counts: a closed gap's cells were never
        # seen, and where the other grid holds them as free they would contradict a right match
        self.seen_xy = self.occupied_xy if walls is seen else frame.to_world(cells(seen))
        self.known_count = int(np.count_nonzero(self.crop))
        # compact: the distance field in 16-bit steps of ``field_unit`` (a 2048th of a cell,
        # saturating at 32 cells, past any cutoff: interpolated between cells at most 1.5 cells
        # apart, a value within one reads no saturated corner), the nearest wall cell as its index
        # in occupied_xy plus one (0: none) in 16 bits where fewer walls allow (4 bytes a cell, not 8)
        self.field_unit = self.resolution / FIELD_STEPS_PER_CELL
        reach = max(self.config.field_cutoff, self.config.wall_tolerance) / self.resolution
        if reach > np.iinfo(np.uint16).max / FIELD_STEPS_PER_CELL - 2:
            raise ValueError(
                f"matching: field_cutoff and wall_tolerance must stay under "
                f"{(np.iinfo(np.uint16).max / FIELD_STEPS_PER_CELL - 2) * self.resolution:.2f} m (the distance field's range)"
            )
        index_type = np.uint16 if len(rows) < np.iinfo(np.uint16).max else np.uint32
        if len(self.occupied_xy):
            distance, labels = cv2.distanceTransformWithLabels(
                1 - walls, cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
            )
            # map each label (one per wall cell) to the index of that cell in occupied_xy, plus one
            lut = np.zeros(int(labels.max()) + 1, dtype=index_type)
            lut[labels[rows - self.row0, cols - self.col0]] = np.arange(1, len(rows) + 1)
            self.nearest = lut[labels]
            steps = np.rint(np.minimum(distance * FIELD_STEPS_PER_CELL, np.iinfo(np.uint16).max))
            self.field = steps.astype(np.uint16)
        else:
            self.nearest = np.zeros(self.crop.shape, dtype=index_type)
            self.field = np.full(self.crop.shape, np.iinfo(np.uint16).max, dtype=np.uint16)

    def steps_within(self, metres: float) -> int:
        """The most field steps that count as within ``metres``: as the float32 field in metres
        the field was before it was kept in steps counted them (a cell exactly at the tolerance
        left out: ``float32(2) * float32(0.1) > 0.2``), so verdicts are unchanged."""
        steps = int(np.floor(metres / self.field_unit)) + 1
        while steps >= 0 and float(np.float32(steps / FIELD_STEPS_PER_CELL) * np.float32(self.resolution)) > metres:
            steps -= 1
        return steps

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held for matching (the grid's crop to its known cells and a margin,
        the distance transform, the nearest-wall lookup, wall cells and, once computed, the
        features); the full canvas is not kept."""
        arrays = [self.crop, self.occupied_cells, self.occupied_xy, self.nearest, self.field]
        total = sum(int(a.nbytes) for a in arrays)
        if self.seen_xy is not self.occupied_xy:
            total += int(self.seen_xy.nbytes)
        if "faces" in self.__dict__:
            total += int(self.faces.nbytes)
        if "features" in self.__dict__:
            xy, descriptors = self.features
            total += int(xy.nbytes) + (int(descriptors.nbytes) if descriptors is not None else 0)
        return total

    @cached_property
    def faces(self) -> NDArray[np.uint8]:
        """The direction each wall cell (``occupied_xy``) faces: ``wall_faces``, made on first use."""
        rows, cols = (self.occupied_cells - [self.row0, self.col0]).T
        walls = np.zeros(self.crop.shape, dtype=np.uint8)
        walls[rows, cols] = 1
        return wall_faces(walls, rows, cols, self.occupied_xy)

    @cached_property
    def features(self) -> tuple[NDArray, NDArray | None]:
        """ORB keypoints as metric points (K, 2) of this grid's frame, and descriptors (K, 32)."""
        if len(self.occupied_xy) == 0:
            return np.zeros((0, 2)), None
        image = cv2.dilate((self.crop == OCCUPIED).astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
        image = cv2.GaussianBlur(image, (0, 0), 1.0)
        c = self.config
        orb = cv2.ORB.create(
            nfeatures=c.n_features,
            scaleFactor=c.orb_scale,
            nlevels=c.orb_levels,
            edgeThreshold=c.orb_patch_size,
            patchSize=c.orb_patch_size,
            fastThreshold=c.orb_fast_threshold,
        )
        # pad, so that keypoints near the crop's edge keep a whole patch
        border = c.orb_patch_size + 1
        image = cv2.copyMakeBorder(image, border, border, border, border, cv2.BORDER_CONSTANT, value=0)
        keypoints, descriptors = orb.detectAndCompute(image, None)
        if descriptors is None:
            return np.zeros((0, 2)), None
        pixels = np.array([kp.pt for kp in keypoints], dtype=np.float64) - border  # (x, y) in the crop
        # sub-cell positions of the grid's cells [row, col], to metres in its frame
        xy = self.frame.to_world(np.stack([pixels[:, 1] + self.row0, pixels[:, 0] + self.col0], axis=1))
        return xy, descriptors


def prepare(
    grid: Grid | PreparedGrid,
    grid_config: GridConfig | None = None,
    config: MatchingConfig | None = None,
) -> PreparedGrid:
    """A ``PreparedGrid`` of a grid (returned as is if it already is one)."""
    if isinstance(grid, PreparedGrid):
        return grid
    return PreparedGrid(grid, grid_config, config)


def _rigid_fit(src: NDArray, dst: NDArray) -> NDArray[np.float64]:
    """Least-squares rigid transform (pose) with dst ~ R src + t, for (N, 2) pairs."""
    mean_s, mean_d = src.mean(axis=0), dst.mean(axis=0)
    s, d = src - mean_s, dst - mean_d
    theta = np.arctan2(np.sum(s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0]), np.sum(s * d))
    c, si = np.cos(theta), np.sin(theta)
    t = mean_d - np.array([c * mean_s[0] - si * mean_s[1], si * mean_s[0] + c * mean_s[1]])
    return np.array([t[0], t[1], theta])


@njit(cache=True, nogil=True)
def _ransac(src, dst, iterations, threshold, seed, guess_yaw, yaw_tolerance):  # pragma: no cover
    """2-point RANSAC for dst ~ R src + t. Returns (x, y, yaw, inlier count)."""
    np.random.seed(seed)
    n = src.shape[0]
    best = np.zeros(3)
    best_count = 0
    threshold2 = threshold * threshold
    for _ in range(iterations):
        i = np.random.randint(n)
        j = np.random.randint(n)
        vs_x, vs_y = src[j, 0] - src[i, 0], src[j, 1] - src[i, 1]
        vd_x, vd_y = dst[j, 0] - dst[i, 0], dst[j, 1] - dst[i, 1]
        length_s = np.sqrt(vs_x * vs_x + vs_y * vs_y)
        length_d = np.sqrt(vd_x * vd_x + vd_y * vd_y)
        # a rigid motion keeps lengths; a short baseline gives a poor angle
        if length_s < 0.8 or abs(length_s - length_d) > threshold:
            continue
        theta = np.arctan2(vd_y, vd_x) - np.arctan2(vs_y, vs_x)
        deviation = (theta - guess_yaw + np.pi) % (2.0 * np.pi) - np.pi
        if abs(deviation) > yaw_tolerance:
            continue
        c, s = np.cos(theta), np.sin(theta)
        mx, my = 0.5 * (src[i, 0] + src[j, 0]), 0.5 * (src[i, 1] + src[j, 1])
        tx = 0.5 * (dst[i, 0] + dst[j, 0]) - (c * mx - s * my)
        ty = 0.5 * (dst[i, 1] + dst[j, 1]) - (s * mx + c * my)
        count = 0
        for k in range(n):
            ex = c * src[k, 0] - s * src[k, 1] + tx - dst[k, 0]
            ey = s * src[k, 0] + c * src[k, 1] + ty - dst[k, 1]
            if ex * ex + ey * ey < threshold2:
                count += 1
        if count > best_count:
            best_count = count
            best[0], best[1], best[2] = tx, ty, theta
    return best[0], best[1], best[2], best_count


def _feature_hypothesis(
    reference: PreparedGrid, query: PreparedGrid, guess: NDArray | None, config: MatchingConfig
) -> list[tuple[NDArray, int]]:
    """Poses of the query in the reference from ORB matches and RANSAC, best first, each with
    its inlier count."""
    ref_xy, ref_desc = reference.features
    query_xy, query_desc = query.features
    if ref_desc is None or query_desc is None or len(ref_xy) < 2 or len(query_xy) < 2:
        return []
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    if guess is None:
        pairs = [
            m[0]
            for m in matcher.knnMatch(query_desc, ref_desc, k=2)
            if len(m) == 2 and m[0].distance < config.ratio_test * m[1].distance
        ]
        q_idx = np.array([m.queryIdx for m in pairs], dtype=np.int64)
        r_idx = np.array([m.trainIdx for m in pairs], dtype=np.int64)
    else:
        # every descriptor neighbour near where the guess puts the keypoint
        knn = matcher.knnMatch(query_desc, ref_desc, k=min(8, len(ref_xy)))
        q_idx = np.array([m.queryIdx for ms in knn for m in ms], dtype=np.int64)
        r_idx = np.array([m.trainIdx for ms in knn for m in ms], dtype=np.int64)
        if len(q_idx):
            predicted = transform_points(guess, query_xy[q_idx])
            near = np.hypot(*(predicted - ref_xy[r_idx]).T) < config.guess_translation_tolerance
            q_idx, r_idx = q_idx[near], r_idx[near]
    src, dst = query_xy[q_idx], ref_xy[r_idx]
    yaw = 0.0 if guess is None else float(guess[2])
    tolerance = np.inf if guess is None else config.guess_rotation_tolerance
    hypotheses: list[tuple[NDArray, int]] = []
    # sequential RANSAC: the best rigid fit, then the best among the matches it left out, ...
    while len(hypotheses) < config.ransac_hypotheses and len(src) >= config.min_inliers:
        x, y, theta, count = _ransac(src, dst, config.ransac_iterations, config.ransac_threshold, config.seed, yaw, tolerance)
        if count < config.min_inliers:
            break
        residual = np.hypot(*(transform_points(np.array([x, y, theta]), src) - dst).T)
        inliers = residual < config.ransac_threshold
        pose = _rigid_fit(src[inliers], dst[inliers])
        pose[2] = wrap_angle(pose[2])
        hypotheses.append((pose, int(np.count_nonzero(inliers))))
        src, dst = src[~inliers], dst[~inliers]
    return hypotheses


@njit(cache=True, nogil=True)
def _cell_in_crop(x, y, row0, col0, half, resolution, height, width):  # pragma: no cover
    """Crop indices (row, col) of a metric point, or (-1, -1) off the crop."""
    col = int(np.floor(x / resolution)) + half - col0
    row = int(np.floor(y / resolution)) + half - row0
    if row < 0 or col < 0 or row >= height or col >= width:
        return -1, -1
    return row, col


@njit(cache=True, nogil=True)
def _icp(points, pose, target_xy, nearest, row0, col0, half, resolution, distances, iterations, faces):
    """Point-to-point ICP: the pose (x, y, yaw) that puts ``points`` onto ``target_xy``.

    Each point's partner is the occupied cell nearest to the cell it falls in (``nearest``, a
    crop-sized label map), kept if within the stage's distance and facing the point's way
    (``faces``: ``_faces``); the closed-form 2D fit of the pairs updates the pose. Stages shrink
    the distance so far outliers stop pulling.
    """
    point_faces, target_faces, face_cos = faces
    height, width = nearest.shape
    x, y, yaw = pose[0], pose[1], pose[2]
    n = points.shape[0]
    src = np.empty((n, 2))
    dst = np.empty((n, 2))
    for max_distance in distances:
        limit = (max_distance + resolution) ** 2
        for _ in range(iterations):
            c, s = np.cos(yaw), np.sin(yaw)
            m = 0
            for k in range(n):
                px = c * points[k, 0] - s * points[k, 1] + x
                py = s * points[k, 0] + c * points[k, 1] + y
                row, col = _cell_in_crop(px, py, row0, col0, half, resolution, height, width)
                if row < 0:
                    continue
                j = np.int64(nearest[row, col]) - 1  # stored plus one: 0 is no wall
                if j < 0 or not _facing(point_faces[k], target_faces[j], c, s, face_cos):
                    continue
                dx, dy = target_xy[j, 0] - px, target_xy[j, 1] - py
                if dx * dx + dy * dy > limit:
                    continue
                src[m, 0], src[m, 1] = px, py
                dst[m, 0], dst[m, 1] = target_xy[j, 0], target_xy[j, 1]
                m += 1
            if m < 3:
                return np.array([x, y, yaw])
            ms_x, ms_y = src[:m, 0].mean(), src[:m, 1].mean()
            md_x, md_y = dst[:m, 0].mean(), dst[:m, 1].mean()
            cross = 0.0
            dot = 0.0
            for k in range(m):
                ax, ay = src[k, 0] - ms_x, src[k, 1] - ms_y
                bx, by = dst[k, 0] - md_x, dst[k, 1] - md_y
                cross += ax * by - ay * bx
                dot += ax * bx + ay * by
            d_yaw = np.arctan2(cross, dot)
            dc, ds = np.cos(d_yaw), np.sin(d_yaw)
            d_x = md_x - (dc * ms_x - ds * ms_y)
            d_y = md_y - (ds * ms_x + dc * ms_y)
            x, y = dc * x - ds * y + d_x, ds * x + dc * y + d_y
            yaw = yaw + d_yaw
            if d_x * d_x + d_y * d_y < 1e-8 and abs(d_yaw) < 1e-5:
                break
    return np.array([x, y, yaw])


@njit(cache=True, nogil=True)
def _wall_counts(points, pose, crop, field, row0, col0, half, resolution, tolerance_steps):
    """(agree, conflict): points (occupied cells of one grid) moved by ``pose`` into the other
    grid that lie within ``tolerance_steps`` (the field's steps) of its occupied cells, and those
    that fall into its free space farther than that."""
    height, width = crop.shape
    c, s = np.cos(pose[2]), np.sin(pose[2])
    agree = 0
    conflict = 0
    for k in range(points.shape[0]):
        px = c * points[k, 0] - s * points[k, 1] + pose[0]
        py = s * points[k, 0] + c * points[k, 1] + pose[1]
        row, col = _cell_in_crop(px, py, row0, col0, half, resolution, height, width)
        if row < 0:
            continue
        if field[row, col] <= tolerance_steps:
            agree += 1
        elif crop[row, col] == 1:  # FREE
            conflict += 1
    return agree, conflict


@njit(cache=True, nogil=True)
def _known_intersection(crop_a, row0_a, col0_a, crop_b, row0_b, col0_b, pose_ab, half, res):
    """Known cells of grid a whose centres, moved into grid b's frame by ``pose_ab`` (the pose of
    a's frame in b's), fall on known cells of b."""
    height_b, width_b = crop_b.shape
    c, s = np.cos(pose_ab[2]), np.sin(pose_ab[2])
    count = 0
    for r in range(crop_a.shape[0]):
        ya = (r + row0_a - half + 0.5) * res
        for q in range(crop_a.shape[1]):
            if crop_a[r, q] == 0:  # UNKNOWN
                continue
            xa = (q + col0_a - half + 0.5) * res
            px = c * xa - s * ya + pose_ab[0]
            py = s * xa + c * ya + pose_ab[1]
            row, col = _cell_in_crop(px, py, row0_b, col0_b, half, res, height_b, width_b)
            if row >= 0 and crop_b[row, col] != 0:
                count += 1
    return count


@njit(cache=True, nogil=True)
def _field_normal_equations(
    points, x, y, yaw, field, unit, row0, col0, half, resolution, cutoff, nearest, faces
):  # pragma: no cover
    """Gauss-Newton's ``J^T J`` (3 x 3) and ``J^T d`` (3) of the points' bilinearly interpolated
    distances on the field (its steps of ``unit`` metres) at pose (x, y, yaw), the sum of squared
    distances and the number of points used (those within ``cutoff`` whose nearest wall cell,
    ``nearest``, faces their way: ``faces``, see ``_faces``)."""
    point_faces, target_faces, face_cos = faces
    height, width = field.shape
    c, s = np.cos(yaw), np.sin(yaw)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    jac = np.empty(3)
    squares = 0.0
    used = 0
    for k in range(points.shape[0]):
        qx, qy = points[k, 0], points[k, 1]
        px = c * qx - s * qy + x
        py = s * qx + c * qy + y
        # continuous crop coordinates with cell centres at integers
        u = px / resolution + half - col0 - 0.5
        v = py / resolution + half - row0 - 0.5
        j0 = int(np.floor(u))
        i0 = int(np.floor(v))
        if i0 < 0 or j0 < 0 or i0 + 1 >= height or j0 + 1 >= width:
            continue
        fu, fv = u - j0, v - i0
        f00, f01 = field[i0, j0] * unit, field[i0, j0 + 1] * unit
        f10, f11 = field[i0 + 1, j0] * unit, field[i0 + 1, j0 + 1] * unit
        d = (1 - fv) * ((1 - fu) * f00 + fu * f01) + fv * ((1 - fu) * f10 + fu * f11)
        if d > cutoff:
            continue
        if face_cos >= -1.0:  # the face test on: the wall cell nearest the cell the point falls in faces its way
            j = np.int64(nearest[int(np.floor(v + 0.5)), int(np.floor(u + 0.5))]) - 1
            if j < 0 or not _facing(point_faces[k], target_faces[j], c, s, face_cos):
                continue
        gx = ((1 - fv) * (f01 - f00) + fv * (f11 - f10)) / resolution
        gy = ((1 - fu) * (f10 - f00) + fu * (f11 - f01)) / resolution
        jac[0], jac[1] = gx, gy
        jac[2] = gx * (-s * qx - c * qy) + gy * (c * qx - s * qy)
        for a in range(3):
            g[a] += jac[a] * d
            for b in range(3):
                h[a, b] += jac[a] * jac[b]
        squares += d * d
        used += 1
    return h, g, squares, used


@njit(cache=True, nogil=True)
def _field_fit(points, pose, field, unit, row0, col0, half, resolution, cutoff, nearest, faces, iterations):
    """Gauss-Newton on the distance field of the target's occupied cells: the pose minimising
    the squared, bilinearly interpolated distances of ``points`` (those within ``cutoff``).

    Along a row of wall cells the interpolated distance is the offset across the row, so this
    is point-to-line matching: no sliding bias from the cell spacing, unlike point-to-point.
    """
    x, y, yaw = pose[0], pose[1], pose[2]
    for _ in range(iterations):
        h, g, _, used = _field_normal_equations(
            points, x, y, yaw, field, unit, row0, col0, half, resolution, cutoff, nearest, faces
        )
        if used < 3:
            break
        for a in range(3):
            h[a, a] += 1e-6 + 1e-3 * h[a, a]  # Levenberg damping
        step = np.linalg.solve(h, -g)
        x += step[0]
        y += step[1]
        yaw += step[2]
        if step[0] * step[0] + step[1] * step[1] < 1e-8 and abs(step[2]) < 1e-5:
            break
    return np.array([x, y, yaw])


def _field(reference: PreparedGrid) -> tuple[NDArray[np.uint16], float, int, int, int, float]:
    """The reference's distance field, its unit and its crop's placement, as the field functions take them."""
    return reference.field, reference.field_unit, reference.row0, reference.col0, reference.half, reference.resolution


_NO_FACES = np.zeros(0, dtype=np.uint8)  # the face test off: nothing is looked up
# each face step's unit vector
_FACE_UNITS = np.stack(
    [np.cos(np.arange(FACE_STEPS) * 2 * np.pi / FACE_STEPS), np.sin(np.arange(FACE_STEPS) * 2 * np.pi / FACE_STEPS)], axis=1
)


def _faces(reference: PreparedGrid, query: PreparedGrid, config: MatchingConfig) -> tuple[NDArray, NDArray, float]:
    """What the fits take to pair a query point only with a reference wall cell facing its way:
    the query's faces, the reference's, and the cosine of ``face_angle`` (below -1: any pairs)."""
    if config.face_angle is None:
        return _NO_FACES, _NO_FACES, -2.0
    return query.faces, reference.faces, float(np.cos(np.radians(config.face_angle)))


@njit(cache=True, nogil=True, inline="always")
def _facing(point_face, target_face, c, s, face_cos):  # pragma: no cover
    """Whether a query wall cell facing ``point_face`` (its frame; turned by the pose's cosine and
    sine ``c``, ``s``) and a reference wall cell facing ``target_face`` face the same way (the
    cosine between the two at least ``face_cos``)."""
    if face_cos < -1.0:
        return True
    px, py = _FACE_UNITS[point_face, 0], _FACE_UNITS[point_face, 1]
    return (c * px - s * py) * _FACE_UNITS[target_face, 0] + (s * px + c * py) * _FACE_UNITS[target_face, 1] >= face_cos


def covariance(reference: PreparedGrid, query: PreparedGrid, pose: ArrayLike, config: MatchingConfig) -> NDArray[np.float64]:
    """The pose's covariance (3 x 3; x, y in m², yaw in rad²) from the distance-field fit at it: the
    inverse information times the residuals' variance (at least a quarter cell's). Few walls in
    common, or walls of one direction only, leave the rotation (or the slide along them) weakly
    fixed: the matches whose rotation is off by a degree are the ones this calls uncertain
    (BENCHMARKS.md, "Design choices: edge measurements")."""
    pose = np.asarray(pose, dtype=np.float64)
    x, y, yaw = pose[0], pose[1], pose[2]
    h, _, squares, used = _field_normal_equations(
        query.occupied_xy, x, y, yaw, *_field(reference), config.field_cutoff, reference.nearest, _faces(reference, query, config)
    )
    if used <= 3:
        return np.diag([1.0, 1.0, 1.0])  # nothing fixes the pose: a metre and a radian
    variance = max(squares / (used - 3), (0.25 * reference.resolution) ** 2)
    try:
        return variance * np.linalg.inv(h + 1e-9 * np.eye(3))
    except np.linalg.LinAlgError:
        return np.diag([1.0, 1.0, 1.0])


def refine(
    reference: PreparedGrid, query: PreparedGrid, pose: ArrayLike, config: MatchingConfig, icp: bool = True
) -> NDArray[np.float64]:
    """The query's pose in the reference, refined from ``pose``: ICP of the query's occupied
    cells onto the reference's, then the distance-field fit (see the module docstring);
    ``icp`` False: the distance-field fit alone (it stays at the walls nearest ``pose``)."""
    pose = np.asarray(pose, dtype=np.float64)
    if len(query.occupied_xy) < 3 or len(reference.occupied_xy) < 3:
        return pose.copy()
    refined = pose.copy()
    if icp:
        refined = _icp(
            query.occupied_xy,
            pose,
            reference.occupied_xy,
            reference.nearest,
            reference.row0,
            reference.col0,
            reference.half,
            reference.resolution,
            np.asarray(config.icp_distances, dtype=np.float64),
            config.icp_iterations,
            _faces(reference, query, config),
        )
    if config.field_iterations:
        refined = _field_fit(
            query.occupied_xy,
            refined,
            *_field(reference),
            config.field_cutoff,
            reference.nearest,
            _faces(reference, query, config),
            config.field_iterations,
        )
    refined[2] = wrap_angle(refined[2])
    return refined


def verdict(
    reference: PreparedGrid, query: PreparedGrid, pose: ArrayLike, config: MatchingConfig
) -> tuple[float, float, float, int]:
    """(score, wall agreement, overlap, matched walls) of the query placed at ``pose``.

    Wall agreement counts, both ways, occupied cells of one grid (as seen: not the cells
    ``wall_closing`` adds, which the fit uses) within ``wall_tolerance`` of an
    occupied cell of the other (agree) or in its free space (contradict); cells landing in the
    other's unknown space count for neither. Overlap is the shared known area over the smaller
    known area (``local_grid.overlap``'s measure, by sampling cell centres; not the IoU, which
    falls when one scan sees far into rooms the other does not). Score = agreement x overlap.
    """
    pose = np.asarray(pose, dtype=np.float64)
    agree = conflict = 0
    for source, target, frame in ((query, reference, pose), (reference, query, inverse(pose))):
        a, c = _wall_counts(
            source.seen_xy,
            frame,
            target.crop,
            target.field,
            target.row0,
            target.col0,
            target.half,
            target.resolution,
            target.steps_within(config.wall_tolerance),
        )
        agree += a
        conflict += c
    wall_agreement = agree / (agree + conflict) if agree + conflict else 0.0
    both = _known_intersection(
        query.crop,
        query.row0,
        query.col0,
        reference.crop,
        reference.row0,
        reference.col0,
        pose,
        reference.half,
        reference.resolution,
    )
    smaller = min(reference.known_count, query.known_count)
    shared = min(both / smaller, 1.0) if smaller > 0 else 0.0
    return wall_agreement * shared, wall_agreement, shared, agree


def match(
    reference: Grid | PreparedGrid,
    query: Grid | PreparedGrid,
    initial_guess: ArrayLike | None = None,
    config: MatchingConfig | None = None,
    grid_config: GridConfig | None = None,
    strict: bool = False,
) -> MatchResult:
    """Register ``query`` to ``reference``: the pose of the query's observation point in the
    reference frame (``between(A, B)`` for grids observed at poses A and B), with a verdict.
    ``strict``: judge by the thresholds without a guess even with one (a place to be recognised,
    as opposed to the place the robot is tracked in).

    initial_guess: (3,) the same pose from odometry, if known: it is refined first and, if that
    scores ``guess_first_score``, taken without feature matching; otherwise it gates the feature
    matches and RANSAC hypotheses. Without it, features and RANSAC search all poses.
    """
    start = time.perf_counter()
    config = config or MatchingConfig()
    reference = prepare(reference, grid_config, config)
    query = prepare(query, grid_config, config)
    guess = None if initial_guess is None else np.asarray(initial_guess, dtype=np.float64)

    if guess is not None and not strict:
        min_agreement, min_overlap, min_score = config.min_wall_agreement, config.min_overlap_guess, config.min_score_guess
    else:
        min_agreement, min_overlap, min_score = config.min_wall_agreement_no_guess, config.min_overlap, config.min_score

    def passes(scored) -> bool:
        score, agreement, shared, matched = scored
        return bool(
            score >= min_score and agreement >= min_agreement and shared >= min_overlap and matched >= config.min_matched_walls
        )

    def result(pose, scored, inliers, source) -> MatchResult:
        accepted = source != "none" and passes(scored)
        pose = np.array([pose[0], pose[1], wrap_angle(pose[2])], dtype=np.float64)
        spread = None if source == "none" else covariance(reference, query, pose, config)
        elapsed = (time.perf_counter() - start) * 1e3
        score, agreement, iou, matched = scored
        return MatchResult(pose, score, accepted, inliers, agreement, iou, matched, source, elapsed, spread)

    if len(reference.occupied_xy) < 3 or len(query.occupied_xy) < 3:
        return result(guess if guess is not None else np.zeros(3), (0.0, 0.0, 0.0, 0), 0, "none")

    candidates = []  # (scored, pose, inliers, source)
    if guess is not None:
        pose = refine(reference, query, guess, config)
        scored = verdict(reference, query, pose, config)
        if config.field_iterations and float(np.hypot(*(pose[:2] - guess[:2]))) > config.wall_tolerance:
            # ICP's first stages pair cells up to a metre apart: a view that shares part of the
            # place can slide to a pose that agrees worse than the guess it started from (a route
            # step in a rack hall, 0.03 m off by odometry, moved 0.46 m off: agreement 0.98 at the
            # guess, 0.91 after). The distance-field fit alone stays at the guess's walls; the
            # better of the two by the ranking below is kept.
            near = refine(reference, query, guess, config, icp=False)
            near_scored = verdict(reference, query, near, config)
            if _rank(near_scored) > _rank(scored):
                pose, scored = near, near_scored
        if scored[0] >= config.guess_first_score and passes(scored):
            return result(pose, scored, 0, "guess")
        candidates.append((scored, pose, 0, "guess"))
    for feature_pose, inliers in _feature_hypothesis(reference, query, guess, config):
        pose = refine(reference, query, feature_pose, config)
        candidates.append((verdict(reference, query, pose, config), pose, inliers, "features"))
    if not candidates:
        return result(np.zeros(3), (0.0, 0.0, 0.0, 0), 0, "none")
    scored, pose, inliers, source = max(candidates, key=lambda c: _rank(c[0]))
    return result(pose, scored, inliers, source)


def rival_minimum(
    reference: PreparedGrid,
    query: PreparedGrid,
    result: MatchResult,
    guess: ArrayLike,
    radius: float,
    apart: float,
    apart_yaw: float,
    config: MatchingConfig,
) -> NDArray[np.float64] | None:
    """A pose where the distance-field fit settles within ``radius`` of ``guess`` that ranks at least
    as well as ``result`` (wall agreement x sqrt(overlap), as ``match`` ranks its candidates) yet
    lies more than ``apart`` (m) or ``apart_yaw`` (rad) from its pose; None if there is none. The
    fit starts from the guess and from the guess moved ``radius`` either way along each axis.

    A match's covariance is taken at its own minimum: where the cost has several minima of one
    rank within the window the guess allows, the match is no surer than the window (the cross
    aisle of a rack hall, only rack ends a few metres off to fix the pose along it: minima 0.3 m
    apart ranked 0.53-0.58 while the covariance claimed 0.02 m)."""
    guess = np.asarray(guess, dtype=np.float64)
    own = _rank((result.score, result.wall_agreement, result.overlap, result.matched_walls))
    starts = [guess] + [guess + np.array([dx, dy, 0.0]) for dx, dy in ((radius, 0), (-radius, 0), (0, radius), (0, -radius))]
    for start in starts:
        pose = refine(reference, query, start, config, icp=False)
        step = pose - result.pose
        if float(np.hypot(step[0], step[1])) <= apart and abs(float(wrap_angle(step[2]))) <= apart_yaw:
            continue
        if _rank(verdict(reference, query, pose, config)) >= own:
            return pose
    return None


def _rank(scored: tuple[float, float, float, int]) -> float:
    """A verdict's rank among a match's candidates: agreement x sqrt(overlap). Wall agreement tells
    right from wrong better than a larger overlap does (a corridor turned by 180° can overlap
    more, yet agree less)."""
    return float(scored[1] * np.sqrt(scored[2]))
