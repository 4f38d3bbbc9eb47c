"""The odometry-step check every odometry-using method shares (``SlamMethod.odometry_step``)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.core.scan import LaserScan
from slam2d.methods import get_method


@pytest.fixture()
def method():
    return get_method("odometry")()


def test_a_step_is_the_increment_in_the_last_frame(method):
    last = np.array([1.0, 2.0, math.pi / 2])
    odom = np.array([1.0, 3.0, math.pi / 2 + 0.1])  # one metre along the robot's x, which points up
    delta, length, is_motion = method.odometry_step(last, odom, 2.0, 0.0)
    assert is_motion
    assert np.allclose(delta, [1.0, 0.0, 0.1])
    assert length == pytest.approx(1.0)
    assert np.allclose(se2.compose(last, delta), odom)
    assert method.diagnostics.counters["odometry_jumps"] == 0


def test_a_jump_is_counted_and_warned_and_returned(method, caplog):
    with caplog.at_level(logging.WARNING):
        delta, length, is_motion = method.odometry_step(np.zeros(3), np.array([0.0, 4.0, 0.0]), 2.0, 12.5)
    assert not is_motion
    assert length == pytest.approx(4.0) and np.allclose(delta, [0.0, 4.0, 0.0])  # the caller decides what to do
    assert method.diagnostics.counters["odometry_jumps"] == 1
    assert "odometry jumps 4.00 m at t=12.500" in caplog.text and "odometry:" in caplog.text
    # exactly at the limit is still motion; just past it is not
    assert method.odometry_step(np.zeros(3), np.array([2.0, 0.0, 0.0]), 2.0, 13.0)[2]
    assert not method.odometry_step(np.zeros(3), np.array([2.0001, 0.0, 0.0]), 2.0, 13.1)[2]
    assert method.diagnostics.counters["odometry_jumps"] == 2


@pytest.mark.parametrize("bad", [[math.nan, 0.0, 0.0], [0.0, 0.0, math.inf]])
def test_a_non_finite_step_is_a_jump(method, bad):
    assert not method.odometry_step(np.zeros(3), np.array(bad), 5.0, 0.0)[2]
    assert method.diagnostics.counters["odometry_jumps"] == 1


def _frame(odometry):
    scan = LaserScan(0.0, np.full(201, 2.0), -1.0, 0.01, 0.1, 5.0)
    return Frame(0, scan, odometry)


def test_usable_odometry(method):
    assert method.usable_odometry(_frame(None)) is None
    assert method.usable_odometry(_frame(np.array([0.0, math.nan, 0.0]))) is None
    odom = method.usable_odometry(_frame([1, 2, 3]))
    assert odom.dtype == np.float64 and np.array_equal(odom, [1.0, 2.0, 3.0])
