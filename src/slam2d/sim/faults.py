"""Faults put into a recording on purpose: odometry that missed a motion, a robot carried off.

Real odometry streams drop messages (a turn in place never reported, a push the
wheels did not feel). These make such recordings from good ones, for tests,
benchmarks and the compile warm-up.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2

__all__ = ["odometry_missing", "frames_with_odometry_missing", "kidnapped"]


def odometry_missing(odometry: Sequence[NDArray[np.float64]], k: int,
                     missed: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """The odometry poses from ``k`` on, as if the increment into ``k`` had not seen ``missed`` (robot frame).

    Every later increment stays right; the pose from ``k`` on is turned and shifted about the pose
    at ``k - 1``, as when one message was lost.
    """
    if not 1 <= k < len(odometry):
        raise ValueError(f"k: {k} must be between 1 and {len(odometry) - 1}")
    out = [np.array(o, dtype=np.float64) for o in odometry]
    anchor = out[k - 1]
    wrong = se2.compose(anchor, se2.compose(se2.relative(anchor, out[k]), se2.inverse(np.asarray(missed, float))))
    for j in range(k, len(out)):
        out[j] = se2.compose(wrong, se2.relative(np.asarray(odometry[k], float), np.asarray(odometry[j], float)))
    return out


def frames_with_odometry_missing(frames: Sequence, k: int, missed: NDArray[np.float64]) -> list:
    """``frames`` (each with odometry) with :func:`odometry_missing` applied to their odometry."""
    odometry = odometry_missing([f.odometry for f in frames], k, missed)
    return [dataclasses.replace(f, odometry=o) for f, o in zip(frames, odometry)]


def kidnapped(frames: Sequence, at: int, resume: int) -> tuple[list, float]:
    """The robot carried off after scan ``at - 1``: the scans from ``resume`` on follow, odometry unaware.

    The odometry goes on from scan ``at - 1``'s without a jump (the wheels felt nothing) and the time
    without a gap. Returns the frames and the time shift added to the resumed scans' stamps (a
    resumed scan's true pose is the truth at its stamp minus the shift).
    """
    if not 1 <= at <= resume < len(frames):
        raise ValueError(f"need 1 <= at ({at}) <= resume ({resume}) < {len(frames)}")
    period = frames[at].timestamp - frames[at - 1].timestamp
    shift = frames[at - 1].timestamp + period - frames[resume].timestamp
    last = np.asarray(frames[at - 1].odometry, float)
    base = np.asarray(frames[resume - 1].odometry, float)
    out = list(frames[:at])
    for j, f in enumerate(frames[resume:], start=at):
        odometry = se2.compose(last, se2.relative(base, np.asarray(f.odometry, float)))
        scan = dataclasses.replace(f.scan, timestamp=f.scan.timestamp + shift)
        out.append(dataclasses.replace(f, index=j, scan=scan, odometry=odometry))
    return out, shift
