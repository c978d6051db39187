"""The PyBullet world: static walls, obstacles, floor and ceiling; a unicycle robot; a 3D lidar.

* One static concave triangle mesh holds the walls (the world's wall segments extruded to
  ``wall_height``), every obstacle box (sides and top; with ``with_changes``, the scenario's
  navigation-time ``world.changes`` boxes too), the floor and the ceiling. It is written
  as an OBJ file (no vertex limit, docs/NOTES.md) and loaded in DIRECT mode.
* The robot is a cylinder of the scenario's radius, 1 cm above the floor. Motion is unicycle
  kinematics in substeps of ``SUBSTEP_S``; a substep that would collide (PyBullet closest points
  between the robot and the static mesh) is cut at contact by bisection and counted as a collision.
* The lidar casts ``channels × 360/horizontal_resolution`` rays with ``rayTestBatch``
  (≤ 16383 rays a call); returns are (N, 3) float32 points in the robot frame, z measured from
  the floor below the robot, floor and ceiling hits included; Gaussian range noise.
* Odometry is integrated from the true motion of every substep; with noise, each substep of
  length d gets a forward error ~ N(0, translation·√d) and a heading error
  ~ N(0, rotation_deg_per_m·√d): random walks whose variance grows per metre travelled. The odometry
  frame is the pose at ``reset``.

Lock-step: nothing moves between ``observe`` and ``step``; the caller's compute time does not
change what happens.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit.types import Command, Observation
from scenarios import Scenario
from scenarios.schema import SUBSTEP_S  # kinematic integration step; trajectories are sampled at this tick


def _quiet_import_pybullet():
    """pybullet prints its build time on stderr (from C, at import), where it would sit above the
    one-line answers of every command: stderr goes to /dev/null while it loads."""
    import os
    import sys

    sys.stderr.flush()
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pb = _quiet_import_pybullet()
MAX_RAYS_PER_CALL = 16383  # rayTestBatch refuses more (docs/NOTES.md)
FLOOR_MARGIN_M = 5.0
ROBOT_FLOOR_GAP_M = 0.01
WORLD_GROUP, ROBOT_GROUP = 1, 2  # collision filter groups: rays see the world only
NOISE_SALT = 0x5E75  # keeps noise streams apart from the scenario's own seeded choices
MAPPING_STREAM, TRIAL_STREAM = 1, 2


def _quad(a: NDArray, b: NDArray, z0: float, z1: float) -> tuple[NDArray, NDArray]:
    v = np.array([[a[0], a[1], z0], [b[0], b[1], z0], [b[0], b[1], z1], [a[0], a[1], z1]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def world_mesh(scenario: Scenario, with_changes: bool = False) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices (V, 3) and triangles (T, 3) of the static world; with the scenario's
    navigation-time ``world.changes`` as boxes too if ``with_changes``."""
    world = scenario.world
    height = world.wall_height
    seg = world.wall_segments
    n = len(seg)
    # walls: one quad per segment, vectorised
    a, b = seg[:, 0], seg[:, 1]
    zeros, tops = np.zeros(n), np.full(n, height)
    wall_v = np.stack([np.c_[a, zeros], np.c_[b, zeros], np.c_[b, tops], np.c_[a, tops]], axis=1).reshape(-1, 3)
    base = (np.arange(n) * 4)[:, None]
    wall_f = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=0)
    vertices = [wall_v]
    faces = [wall_f]
    count = len(wall_v)
    boxes = [*world.obstacles, *(scenario.spec.world.changes if with_changes else [])]
    for ob in boxes:
        c, s = np.cos(np.radians(ob.yaw)), np.sin(np.radians(ob.yaw))
        hx, hy = ob.size[0] / 2.0, ob.size[1] / 2.0
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) @ np.array([[c, s], [-s, c]]) + ob.center
        box_v = np.vstack([np.c_[corners, np.zeros(4)], np.c_[corners, np.full(4, ob.height)]])
        box_f = np.array(
            [[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7], [4, 5, 6], [4, 6, 7]]
        )
        vertices.append(box_v)
        faces.append(box_f + count)
        count += 8
    xmin, ymin, xmax, ymax = world.bounds
    m = FLOOR_MARGIN_M
    plane = np.array([[xmin - m, ymin - m], [xmax + m, ymin - m], [xmax + m, ymax + m], [xmin - m, ymax + m]])
    # the floor faces up and the ceiling down (with the floor's winding, upward rays went
    # through the ceiling: seen in PyBullet 3.2.7); walls are hit from either side.
    for z, tri in [(0.0, [[0, 1, 2], [0, 2, 3]])] + ([(height, [[0, 2, 1], [0, 3, 2]])] if world.ceiling else []):
        vertices.append(np.c_[plane, np.full(4, z)])
        faces.append(np.array(tri) + count)
        count += 4
    return np.vstack(vertices), np.vstack(faces).astype(np.int64)


def write_obj(path: Path, vertices: NDArray, faces: NDArray) -> None:
    with open(path, "w") as f:
        f.write("".join(f"v {x:.5f} {y:.5f} {z:.5f}\n" for x, y, z in vertices))
        f.write("".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in faces))


def ray_directions(channels: int, fov: tuple[float, float], horizontal_resolution: float) -> NDArray[np.float64]:
    """(channels * sectors, 3) unit directions in the robot frame, channel-major."""
    elevations = np.radians(np.linspace(fov[0], fov[1], channels)) if channels > 1 else np.radians([np.mean(fov)])
    azimuths = np.radians(np.arange(0.0, 360.0, horizontal_resolution))
    el, az = np.meshgrid(elevations, azimuths, indexing="ij")
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)


@dataclass
class StepResult:
    collided: bool
    travelled_m: float


class Simulator:
    """A scenario's world in PyBullet (DIRECT), a robot in it and its sensors.

    ``with_changes``: build the scenario's ``world.changes`` (boxes that appear only in the
    navigation stage) into the static world; the mapping stage runs without them. The ground
    truth of that stage is ``scenario.navigation_world``."""

    def __init__(self, scenario: Scenario, seed: int = 0, with_changes: bool = False) -> None:
        self.scenario = scenario
        self.with_changes = bool(with_changes)
        self.robot_spec = scenario.spec.robot
        self.sensor = scenario.spec.sensor
        self.noise = scenario.spec.odometry.noise
        self.seed = int(seed)
        self.rng = np.random.default_rng([self.seed, NOISE_SALT])
        self.client = pb.connect(pb.DIRECT)
        pb.setPhysicsEngineParameter(numSolverIterations=1, physicsClientId=self.client)
        vertices, faces = world_mesh(scenario, with_changes=self.with_changes)
        with tempfile.TemporaryDirectory(prefix="navtopo-sim-") as tmp:
            obj = Path(tmp) / "world.obj"
            write_obj(obj, vertices, faces)
            shape = pb.createCollisionShape(
                pb.GEOM_MESH, fileName=str(obj), flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=self.client
            )
        self.world_body = pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape, physicsClientId=self.client)
        self.mesh_triangles = len(faces)
        self.robot_height = min(1.2, scenario.world.wall_height - 2 * ROBOT_FLOOR_GAP_M)
        robot_shape = pb.createCollisionShape(
            pb.GEOM_CYLINDER, radius=self.robot_spec.radius, height=self.robot_height, physicsClientId=self.client
        )
        self.robot_body = pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=robot_shape, physicsClientId=self.client)
        # the lidar must not see the robot's own body: rays test collision group 1 only
        pb.setCollisionFilterGroupMask(self.world_body, -1, WORLD_GROUP, WORLD_GROUP | ROBOT_GROUP, physicsClientId=self.client)
        pb.setCollisionFilterGroupMask(self.robot_body, -1, ROBOT_GROUP, WORLD_GROUP, physicsClientId=self.client)
        self.directions = ray_directions(self.sensor.channels, self.sensor.vertical_fov, self.sensor.horizontal_resolution)
        self.time = 0.0
        self._pose = np.zeros(3)
        self._odom = np.zeros(3)
        self.collisions = 0
        self.trajectory: list[tuple[float, float, float, float]] = []
        self.travelled_m = 0.0
        self.reset(scenario.route_start if len(scenario.route) > 1 else np.zeros(3))

    # -- state ---------------------------------------------------------------------------------

    def reset(self, pose: NDArray | list[float], time: float = 0.0, stream: tuple[int, ...] = (0,)) -> None:
        """Place the robot (scenario frame); the odometry frame restarts at this pose.

        stream: which noise stream the run draws from, e.g. ``(MAPPING,)`` or ``(TRIAL, index)``:
        sensor and odometry noise depend only on (seed, stream), not on what ran before in this
        process, so a trial's noise is the same with any number of workers and on resume.
        """
        self.rng = np.random.default_rng([self.seed, NOISE_SALT, *stream])
        self._pose = np.asarray(pose, dtype=np.float64).copy()
        self._start = self._pose.copy()
        self._odom = np.zeros(3)
        self.time = time
        self.collisions = 0
        self.travelled_m = 0.0
        self.trajectory = [(self.time, *self._pose)]

    @property
    def true_pose(self) -> NDArray[np.float64]:
        return self._pose.copy()

    @property
    def odom_pose(self) -> NDArray[np.float64]:
        return self._odom.copy()

    def trajectory_array(self) -> NDArray[np.float64]:
        """(T, 4) rows of (time, x, y, yaw), one per substep."""
        return np.asarray(self.trajectory, dtype=np.float64)

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None  # type: ignore[assignment]

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- sensing -------------------------------------------------------------------------------

    def observe(self) -> Observation:
        return Observation(stamp=self.time, points=self.scan(), odom=self.odom_pose)

    def scan(self, pose: NDArray | None = None) -> NDArray[np.float32]:
        """Lidar returns (N, 3) float32 in the robot frame from ``pose`` (default: the true pose)."""
        x, y, yaw = self._pose if pose is None else pose
        c, s = np.cos(yaw), np.sin(yaw)
        d = self.directions
        world_dirs = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
        origin = np.array([x, y, self.sensor.mount_height])
        max_range = self.sensor.max_range
        starts = np.broadcast_to(origin, world_dirs.shape)
        ends = origin + world_dirs * max_range
        fractions = np.empty(len(d))
        hit = np.empty(len(d), dtype=bool)
        for i in range(0, len(d), MAX_RAYS_PER_CALL):
            results = pb.rayTestBatch(
                starts[i : i + MAX_RAYS_PER_CALL],
                ends[i : i + MAX_RAYS_PER_CALL],
                numThreads=0,
                collisionFilterMask=WORLD_GROUP,
                physicsClientId=self.client,
            )
            hit[i : i + len(results)] = [r[0] >= 0 for r in results]
            fractions[i : i + len(results)] = [r[2] for r in results]
        ranges = fractions[hit] * max_range
        if self.sensor.range_noise > 0:
            ranges = ranges + self.rng.normal(0.0, self.sensor.range_noise, ranges.shape)
        ranges = np.clip(ranges, 0.0, max_range)
        points = d[hit] * ranges[:, None]
        points[:, 2] += self.sensor.mount_height
        return points.astype(np.float32)

    # -- motion --------------------------------------------------------------------------------

    def collides(self, pose: NDArray) -> bool:
        z = ROBOT_FLOOR_GAP_M + self.robot_height / 2.0
        pb.resetBasePositionAndOrientation(self.robot_body, [pose[0], pose[1], z], [0, 0, 0, 1], physicsClientId=self.client)
        return len(pb.getClosestPoints(self.robot_body, self.world_body, distance=0.0, physicsClientId=self.client)) > 0

    @staticmethod
    def _integrate(pose: NDArray, linear: float, angular: float, dt: float) -> NDArray:
        """Exact unicycle motion over dt (arc)."""
        x, y, yaw = pose
        if abs(angular) < 1e-9:
            return np.array([x + linear * dt * np.cos(yaw), y + linear * dt * np.sin(yaw), yaw])
        radius = linear / angular
        new_yaw = yaw + angular * dt
        return np.array(
            [x + radius * (np.sin(new_yaw) - np.sin(yaw)), y - radius * (np.cos(new_yaw) - np.cos(yaw)), se2.wrap_angle(new_yaw)]
        )

    def step(self, command: Command, duration: float | None = None) -> StepResult:
        """Apply ``command`` for ``duration`` (default: one sensor period), in substeps."""
        duration = 1.0 / self.sensor.rate_hz if duration is None else duration
        linear = float(np.clip(command.linear, -self.robot_spec.max_linear, self.robot_spec.max_linear))
        angular = float(np.clip(command.angular, -self.robot_spec.max_angular, self.robot_spec.max_angular))
        substeps = max(1, int(round(duration / SUBSTEP_S)))
        dt = duration / substeps
        collided = False
        travelled = 0.0
        for substep in range(substeps):
            target = self._integrate(self._pose, linear, angular, dt)
            if linear != 0.0 and self.collides(target):
                collided = True
                lo, hi = 0.0, 1.0  # fraction of the substep that stays collision-free
                for _ in range(8):
                    mid = 0.5 * (lo + hi)
                    if self.collides(self._integrate(self._pose, linear, angular, dt * mid)):
                        hi = mid
                    else:
                        lo = mid
                target = self._integrate(self._pose, linear, angular, dt * lo)
            travelled += self._advance(target)
            self.time += dt
            self.trajectory.append((self.time, *self._pose))
            if collided:
                self.collisions += 1
                # the rest of the period passes with the robot standing at contact
                remaining = duration - dt * (substep + 1)
                if remaining > 1e-9:
                    self.time += remaining
                    self.trajectory.append((self.time, *self._pose))
                break
        self.travelled_m += travelled
        return StepResult(collided=collided, travelled_m=travelled)

    def _advance(self, new_pose: NDArray) -> float:
        delta = se2.between(self._pose, new_pose)
        distance = float(np.hypot(delta[0], delta[1]))
        if self.noise is not None and distance > 0:
            delta = delta.copy()
            forward = np.cos(delta[2] / 2.0), np.sin(delta[2] / 2.0)
            along = self.rng.normal(0.0, self.noise.translation * np.sqrt(distance))
            delta[0] += along * forward[0]
            delta[1] += along * forward[1]
            delta[2] += self.rng.normal(0.0, np.radians(self.noise.rotation_deg_per_m) * np.sqrt(distance))
        if self.noise is None:
            self._odom = se2.between(self._start, new_pose)  # exact: no accumulated rounding
        else:
            self._odom = se2.compose(self._odom, delta)
        self._pose = np.asarray(new_pose, dtype=np.float64)
        return distance
