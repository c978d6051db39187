"""The odometer every system counts metres and turning with (navkit.odometer)."""

import numpy as np

from navkit.odometer import Odometer


def _square(side: float, steps: int) -> list[np.ndarray]:
    """Odometry poses round a square, counter-clockwise, turning 90° in place at each corner."""
    poses, x, y = [], 0.0, 0.0
    for k in range(4):
        yaw = k * np.pi / 2
        for _ in range(steps):
            poses.append(np.array([x, y, yaw]))
            x, y = x + side / steps * np.cos(yaw), y + side / steps * np.sin(yaw)
    poses.append(np.array([x, y, 2 * np.pi]))
    return poses


def test_a_square_drive_sums_its_perimeter_and_one_full_turn():
    odometer = Odometer()
    for pose in _square(3.0, 30):
        odometer.update(pose)
    assert np.isclose(odometer.metres, 12.0) and np.isclose(odometer.radians, 2 * np.pi)


def test_the_step_is_in_the_last_readings_frame_and_the_first_reading_only_marks():
    odometer = Odometer()
    assert np.allclose(odometer.update([5.0, 5.0, np.pi / 2]), 0.0) and odometer.metres == 0.0
    step = odometer.update([5.0, 6.0, np.pi / 2])  # 1 m along its heading: forward in its own frame
    assert np.allclose(step, [1.0, 0.0, 0.0]) and np.isclose(odometer.metres, 1.0)


def test_a_restart_skips_the_jump_and_keeps_the_sums():
    odometer = Odometer()
    odometer.update([0.0, 0.0, 0.0])
    odometer.update([2.0, 0.0, 0.0])
    odometer.restart_from([100.0, 0.0, 0.0])  # a new start: the 98 m jump is not travel
    odometer.update([101.0, 0.0, 0.0])
    assert np.isclose(odometer.metres, 3.0)
    odometer.restart_from(None)
    assert not odometer.started and odometer.last is None
    odometer.update([0.0, 0.0, 0.0])
    assert np.isclose(odometer.metres, 3.0)
