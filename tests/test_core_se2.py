"""SE(2) laws and angle wrapping, checked on random poses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from slam2d.core import se2

coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
angle = st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False)
pose = st.tuples(coord, coord, angle).map(np.array)


def same_pose(a, b, tol=1e-9):
    a, b = np.asarray(a), np.asarray(b)
    assert np.allclose(a[..., :2], b[..., :2], atol=tol * (1 + np.abs(a[..., :2]).max()))
    assert np.allclose(se2.wrap_angle(a[..., 2] - b[..., 2]), 0.0, atol=1e-9)


@given(angle)
def test_wrap_angle_range_and_equivalence(a):
    w = se2.wrap_angle(a)
    assert -np.pi <= w < np.pi
    assert np.isclose(np.cos(w), np.cos(a), atol=1e-9) and np.isclose(np.sin(w), np.sin(a), atol=1e-9)


def test_wrap_angle_edges():
    assert se2.wrap_angle(np.pi) == pytest.approx(-np.pi)
    assert se2.wrap_angle(-np.pi) == pytest.approx(-np.pi)
    assert se2.wrap_angle(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert se2.wrap_angle(0.0) == 0.0


@given(pose, pose, pose)
def test_compose_is_associative(a, b, c):
    same_pose(se2.compose(se2.compose(a, b), c), se2.compose(a, se2.compose(b, c)))


@given(pose)
def test_inverse_gives_identity(a):
    same_pose(se2.compose(a, se2.inverse(a)), np.zeros(3))
    same_pose(se2.compose(se2.inverse(a), a), np.zeros(3))


@given(pose, pose)
def test_relative_undoes_compose(a, b):
    same_pose(se2.relative(a, se2.compose(a, b)), b)
    same_pose(se2.compose(a, se2.relative(a, b)), b)


def test_compose_known_value():
    a = np.array([1.0, 2.0, np.pi / 2])
    b = np.array([1.0, 0.0, 0.0])
    same_pose(se2.compose(a, b), [1.0, 3.0, np.pi / 2])


@given(pose, pose, st.floats(0.0, 1.0))
def test_interpolate_endpoints_and_shorter_arc(a, b, t):
    same_pose(se2.interpolate(a, b, 0.0), a)
    same_pose(se2.interpolate(a, b, 1.0), b)
    mid = se2.interpolate(a, b, t)
    # heading moves along the shorter arc: never more than pi * t away from a
    assert abs(se2.wrap_angle(mid[2] - a[2])) <= np.pi * t + 1e-9


def test_interpolate_across_the_pi_seam():
    a = np.array([0.0, 0.0, np.pi - 0.1])
    b = np.array([2.0, 0.0, -np.pi + 0.1])
    mid = se2.interpolate(a, b, 0.5)
    assert mid[0] == pytest.approx(1.0)
    assert abs(se2.wrap_angle(mid[2] - np.pi)) < 1e-12


@settings(max_examples=30)
@given(arrays(np.float64, (7, 3), elements=st.floats(-100, 100)), arrays(np.float64, (7, 3), elements=st.floats(-100, 100)))
def test_vectorised_matches_single(a, b):
    stacked = se2.compose(a, b)
    for i in range(len(a)):
        same_pose(stacked[i], se2.compose(a[i], b[i]))
    rel = se2.relative(a, b)
    for i in range(len(a)):
        same_pose(rel[i], se2.relative(a[i], b[i]))


@given(pose, arrays(np.float64, (5, 2), elements=st.floats(-50, 50)))
def test_transform_points_matches_compose(p, pts):
    out = se2.transform_points(p, pts)
    as_poses = np.column_stack([pts, np.zeros(len(pts))])
    expected = se2.compose(p, as_poses)[:, :2]
    assert np.allclose(out, expected, atol=1e-9)


@given(angle)
def test_quaternion_round_trip(yaw):
    q = se2.yaw_to_quaternion(yaw)
    assert np.isclose(np.linalg.norm(q), 1.0)
    assert abs(se2.wrap_angle(se2.quaternion_to_yaw(q) - yaw)) < 1e-12


def test_pose_shape_is_checked():
    with pytest.raises(ValueError, match="3 components"):
        se2.compose([1.0, 2.0], [0.0, 0.0, 0.0])


@given(pose, pose, arrays(np.float64, (4, 2), elements=st.floats(-50, 50)))
def test_one_pose_paths_are_the_stacked_ones_bit_for_bit(a, b, pts):
    """compose, relative and transform_points take a scalar path for one float64 pose: same numbers."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    assert np.array_equal(se2.compose(a, b), se2.compose(a[None], b[None])[0])
    assert np.array_equal(se2.relative(a, b), se2.relative(a[None], b[None])[0])
    assert np.array_equal(se2.transform_points(a, pts), se2.transform_points(a[None], pts[None])[0])
    assert se2.compose(a, b).shape == (3,) and se2.transform_points(a, pts).shape == (4, 2)
