"""Loop-closure precision against ground truth (Hess et al. 2016, Table IV: 0.2 m and 1 deg)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from slam2d.core import se2
from slam2d.io.tum import interpolate_poses

__all__ = ["loop_closure_precision"]


def loop_closure_precision(
    closures: Iterable[Mapping[str, Any]],
    truth_times: ArrayLike,
    truth_poses: ArrayLike,
    *,
    max_translation: float = 0.2,
    max_rotation_deg: float = 1.0,
    max_gap: float = 1.0,
) -> dict[str, Any]:
    """How many loop closures measured their relative pose within the tolerances of the truth.

    ``closures`` are the dicts in ``diagnostics.summary["loop_closures"]``
    (``time_from``, ``time_to``, ``measurement``: the pose of the new scan in
    the old scan's frame). Each is compared with the true relative pose of the
    robot at those two times. Returns ``{"closures", "correct", "precision",
    "translation_errors_m", "rotation_errors_deg"}``; precision is NaN when
    there are no closures (or none falls inside the truth's time span).
    """
    items = list(closures)
    t = np.asarray(truth_times, dtype=np.float64)
    p = np.asarray(truth_poses, dtype=np.float64).reshape(-1, 3)
    order = np.argsort(t, kind="stable")
    t, p = t[order], p[order]
    trans: list[float] = []
    rot: list[float] = []
    for c in items:
        found, valid = interpolate_poses(t, p, np.array([c["time_from"], c["time_to"]], dtype=np.float64), max_gap)
        if not valid.all():
            continue
        err = se2.relative(se2.relative(found[0], found[1]), np.asarray(c["measurement"], dtype=np.float64))
        trans.append(float(np.hypot(err[0], err[1])))
        rot.append(float(np.degrees(abs(err[2]))))
    tr = np.asarray(trans)
    ro = np.asarray(rot)
    correct = int(np.count_nonzero((tr <= max_translation) & (ro <= max_rotation_deg)))
    n = len(trans)
    return {
        "closures": n,
        "correct": correct,
        "precision": correct / n if n else float("nan"),
        "translation_errors_m": trans,
        "rotation_errors_deg": rot,
    }
