"""SE(2) algebra: property tests of the one convention every module uses."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from navkit import geometry as se2

coordinate = st.floats(-100, 100, allow_nan=False)
angle = st.floats(-10, 10, allow_nan=False)
poses = st.tuples(coordinate, coordinate, angle).map(lambda p: se2.pose(*p))


def close(a, b, tol=1e-9) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return bool(np.allclose(a[..., :2], b[..., :2], atol=tol) and np.allclose(se2.wrap_angle(a[..., 2] - b[..., 2]), 0, atol=tol))


@given(poses, poses, poses)
def test_composition_is_associative(a, b, c):
    assert close(se2.compose(se2.compose(a, b), c), se2.compose(a, se2.compose(b, c)), 1e-7)


@given(poses)
def test_a_pose_composed_with_its_inverse_is_the_identity(a):
    assert close(se2.compose(a, se2.inverse(a)), np.zeros(3), 1e-9)
    assert close(se2.compose(se2.inverse(a), a), np.zeros(3), 1e-9)


@given(poses, poses)
def test_between_is_b_in_the_frame_of_a(a, b):
    relative = se2.between(a, b)
    assert close(se2.compose(a, relative), b, 1e-7)
    assert close(se2.between(b, a), se2.inverse(relative), 1e-7)


@given(poses, st.lists(st.tuples(coordinate, coordinate), min_size=1, max_size=10))
def test_transforming_points_agrees_with_composing_poses(frame, points):
    points = np.array(points)
    as_poses = np.column_stack([points, np.zeros(len(points))])
    expected = se2.compose(frame, as_poses)[:, :2]
    assert np.allclose(se2.transform_points(frame, points), expected, atol=1e-9)
    # and back again through the inverse frame
    assert np.allclose(se2.transform_points(se2.inverse(frame), se2.transform_points(frame, points)), points, atol=1e-7)


@given(poses)
def test_matrix_round_trip(a):
    assert close(se2.from_matrix(se2.to_matrix(a)), a, 1e-9)


@given(angle)
def test_wrapped_angles_lie_in_minus_pi_to_pi(x):
    wrapped = se2.wrap_angle(x)
    assert -np.pi <= wrapped < np.pi
    assert np.isclose(np.sin(wrapped), np.sin(x)) and np.isclose(np.cos(wrapped), np.cos(x))


def test_a_concrete_example_pins_the_direction_convention():
    robot = np.array([2.0, 1.0, np.pi / 2])  # at (2, 1) facing +y
    ahead = np.array([2.0, 4.0, np.pi / 2])  # 3 m in front of it
    assert close(se2.between(robot, ahead), [3.0, 0.0, 0.0])
    assert np.allclose(se2.transform_points(robot, np.array([[1.0, 0.0]])), [[2.0, 2.0]])


def _sampled_covariance(function, means, covariances, samples=200_000):
    rng = np.random.default_rng(7)
    draws = [m + rng.multivariate_normal(np.zeros(3), c, samples) for m, c in zip(means, covariances, strict=True)]
    out = function(*draws) - function(*means)
    out[:, 2] = se2.wrap_angle(out[:, 2])
    return np.cov(out.T)


def test_propagated_covariances_match_sampling():
    """First-order covariances of a ⊕ b and a⁻¹ against 200k samples of small pose errors."""
    a, b = np.array([1.0, 2.0, 0.7]), np.array([3.0, -1.0, -0.4])
    cov_a, cov_b = np.diag([0.01, 0.02, 0.003]), np.diag([0.02, 0.01, 0.001])
    _, composed = se2.compose_with_covariance(a, cov_a, b, cov_b)
    assert np.allclose(composed, _sampled_covariance(se2.compose, [a, b], [cov_a, cov_b]), atol=5e-4)
    _, inverted = se2.inverse_with_covariance(a, cov_a)
    assert np.allclose(inverted, _sampled_covariance(se2.inverse, [a], [cov_a]), atol=5e-4)


def test_arc_lengths_are_the_running_sum_of_segment_lengths():
    from navkit.geometry import arc_lengths

    path = np.array([[0.0, 0.0, 9.0], [3.0, 4.0, 9.0], [3.0, 4.0, 9.0], [3.0, 6.0, 9.0]])
    assert np.allclose(arc_lengths(path), [0.0, 5.0, 5.0, 7.0])
    assert arc_lengths(path[:1]).tolist() == [0.0]


def test_a_chain_of_relative_poses_leads_where_composing_them_in_turn_does():
    rng = np.random.default_rng(7)
    steps = rng.normal(size=(30, 3)) * np.array([3.0, 3.0, 2.5])
    expected = [np.zeros(3)]
    for step in steps:
        expected.append(se2.compose(expected[-1], step))
    assert np.allclose(se2.chain(steps), np.array(expected), atol=1e-12)
    assert np.array_equal(se2.chain(np.zeros((0, 3))), np.zeros((1, 3)))
