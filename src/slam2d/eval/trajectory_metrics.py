"""Trajectory error against a reference: ATE, RPE and the relations metric.

* :func:`associate` pairs every estimated pose with the reference pose
  interpolated at its timestamp.
* :func:`absolute_trajectory_error` (ATE): position and heading differences
  after the best rigid alignment (:func:`align_se2`, no scale) of the
  estimate onto the reference. It measures global consistency.
* :func:`relative_pose_error` (RPE): the error of the motion between two poses
  a fixed number of frames or a fixed reference path length apart. It
  measures local drift and does not need an alignment.
* :func:`relations_error`: the metric of Kümmerle et al. 2009 ("On measuring
  the accuracy of SLAM algorithms"), computed as Cartographer's
  ``compute_relations_metrics`` does, from a list of expected relative motions
  (:mod:`slam2d.io.relations`).

Units: metres and radians inside; rotation errors are reported in degrees
(keys end in ``_deg``). The reference trajectories of the real logs in
``../shared/datasets`` are GMapping's corrected poses, not independent ground
truth; a report should say so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.io.relations import Relations
from slam2d.io.tum import interpolate_poses

__all__ = [
    "Association",
    "associate",
    "align_se2",
    "error_stats",
    "absolute_trajectory_error",
    "relative_pose_error",
    "relations_error",
    "heading_agreement",
]

@dataclass(frozen=True)
class Association:
    """Estimated poses paired with the reference poses at the same times.

    ``times (K,)``, ``estimate (K, 3)``, ``reference (K, 3)`` in the
    estimate's order; ``unmatched`` counts estimated poses that got no
    reference pose (outside its time span or in a gap wider than ``max_gap``).
    """

    times: NDArray[np.float64]
    estimate: NDArray[np.float64]
    reference: NDArray[np.float64]
    unmatched: int


def _span(times: NDArray[np.float64], name: str) -> str:
    """``"name spans 0.000-10.000 s"`` (or ``"name is empty"``) for error messages."""
    if times.size == 0:
        return f"{name} is empty"
    return f"{name} spans {float(np.min(times)):.3f}-{float(np.max(times)):.3f} s"


def _overlap(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    return a.size > 0 and b.size > 0 and np.min(a) <= np.max(b) and np.min(b) <= np.max(a)


def associate(
    est_times: ArrayLike,
    est_poses: ArrayLike,
    ref_times: ArrayLike,
    ref_poses: ArrayLike,
    *,
    max_gap: float = 0.5,
    est_name: str = "estimate",
    ref_name: str = "reference",
) -> Association:
    """Pair each estimated pose with the reference pose interpolated at its timestamp.

    The reference is interpolated (:func:`slam2d.io.tum.interpolate_poses`)
    between neighbours at most ``max_gap`` seconds apart; estimated poses
    without a reference pose are dropped and counted in ``unmatched``. The
    estimate's order is kept. Raises :class:`InputError` (naming both
    trajectories by ``est_name`` / ``ref_name`` and their time spans) when
    they do not overlap in time or fewer than 2 pairs result.
    """
    et = np.asarray(est_times, dtype=np.float64).reshape(-1)
    ep = se2.as_poses(est_poses).reshape(-1, 3)
    rt = np.asarray(ref_times, dtype=np.float64).reshape(-1)
    rp = se2.as_poses(ref_poses).reshape(-1, 3)
    if ep.shape[0] != et.shape[0]:
        raise ValueError(f"est_poses: {ep.shape[0]} poses for {et.shape[0]} timestamps")
    spans = f"{_span(et, est_name)}, {_span(rt, ref_name)}"
    if not _overlap(et, rt):
        raise InputError(f"trajectories do not overlap in time: {spans}", field="timestamp")
    ref_at_est, valid = interpolate_poses(rt, rp, et, max_gap)
    matched = int(np.count_nonzero(valid))
    if matched < 2:
        raise InputError(
            f"only {matched} of {et.shape[0]} estimated poses have a reference pose within "
            f"{max_gap:g} s, 2 needed: {spans}",
            field="timestamp",
        )
    return Association(
        times=et[valid],
        estimate=ep[valid],
        reference=ref_at_est[valid],
        unmatched=int(et.shape[0] - matched),
    )


def align_se2(source_xy: ArrayLike, target_xy: ArrayLike) -> NDArray[np.float64]:
    """The rigid motion ``[x, y, theta]`` that best maps ``source_xy`` onto ``target_xy``.

    Least squares over ``(N, 2)`` point pairs, rotation and translation only
    (no scale), in closed form: the rotation angle is the atan2 of the
    cross-covariance of the centred points (2D Kabsch/Umeyama), the
    translation maps one centroid onto the other. ``se2.compose(T, poses)``
    then expresses source poses in the target frame. Needs at least 2 points
    (``ValueError`` otherwise). If all source points coincide the rotation is
    undetermined and 0 is returned.
    """
    src = np.asarray(source_xy, dtype=np.float64).reshape(-1, 2)
    dst = np.asarray(target_xy, dtype=np.float64).reshape(-1, 2)
    if src.shape != dst.shape:
        raise ValueError(f"source {src.shape} and target {dst.shape} point sets differ in size")
    if src.shape[0] < 2:
        raise ValueError(f"an alignment needs at least 2 point pairs; got {src.shape[0]}")
    src_mean = src.mean(axis=0)
    dst_mean = dst.mean(axis=0)
    s = src - src_mean
    d = dst - dst_mean
    # For a rotation R(theta), sum d_i . R s_i = cos(theta) * dot + sin(theta) * cross,
    # which is largest at theta = atan2(cross, dot).
    dot = float(np.sum(s[:, 0] * d[:, 0] + s[:, 1] * d[:, 1]))
    cross = float(np.sum(s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0]))
    theta = math.atan2(cross, dot)
    c, si = math.cos(theta), math.sin(theta)
    tx = dst_mean[0] - (c * src_mean[0] - si * src_mean[1])
    ty = dst_mean[1] - (si * src_mean[0] + c * src_mean[1])
    return np.array([tx, ty, theta], dtype=np.float64)


def error_stats(values: ArrayLike) -> dict[str, Any]:
    """Summary of error magnitudes: rmse, mean, median, std, max, count.

    ``std`` is the sample standard deviation (ddof=1), 0 for a single value.
    With no values every statistic is NaN and ``count`` is 0. Values are
    plain Python floats (JSON-ready).
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    n = int(v.shape[0])
    if n == 0:
        return {"rmse": math.nan, "mean": math.nan, "median": math.nan, "std": math.nan, "max": math.nan, "count": 0}
    return {
        "rmse": float(np.sqrt(np.mean(v * v))),
        "mean": float(np.mean(v)),
        "median": float(np.median(v)),
        "std": float(np.std(v, ddof=1)) if n > 1 else 0.0,
        "max": float(np.max(v)),
        "count": n,
    }


def _pose_errors(estimate: NDArray[np.float64], reference: NDArray[np.float64]) -> dict[str, Any]:
    translation = np.hypot(estimate[:, 0] - reference[:, 0], estimate[:, 1] - reference[:, 1])
    rotation = np.abs(se2.wrap_angle(estimate[:, 2] - reference[:, 2]))
    return {"translation_m": error_stats(translation), "rotation_deg": error_stats(np.degrees(rotation))}


def absolute_trajectory_error(assoc: Association, *, align: bool = True) -> dict[str, Any]:
    """Absolute trajectory error of associated poses.

    With ``align`` the estimate is first moved by the rigid transform
    (:func:`align_se2`) that best fits its positions onto the reference
    positions; ``"alignment"`` is that transform ``[x, y, theta]`` (identity
    without ``align``). Returns ``{"pairs", "unmatched", "alignment",
    "translation_m", "rotation_deg", "before_alignment": {"translation_m",
    "rotation_deg"}}``; the error entries are :func:`error_stats` of the
    per-pose position distance (m) and absolute heading difference (deg).
    """
    est = se2.as_poses(assoc.estimate).reshape(-1, 3)
    ref = se2.as_poses(assoc.reference).reshape(-1, 3)
    if est.shape != ref.shape:
        raise ValueError(f"estimate {est.shape} and reference {ref.shape} differ in size")
    transform = align_se2(est[:, :2], ref[:, :2]) if align else np.zeros(3)
    aligned = se2.compose(transform, est) if align else est
    after = _pose_errors(aligned, ref)
    return {
        "pairs": int(est.shape[0]),
        "unmatched": int(assoc.unmatched),
        "alignment": [float(v) for v in transform],
        "translation_m": after["translation_m"],
        "rotation_deg": after["rotation_deg"],
        "before_alignment": _pose_errors(est, ref),
    }


def relative_pose_error(assoc: Association, *, per: str = "frame", delta: float = 1.0) -> dict[str, Any]:
    """Relative pose error between poses ``delta`` frames or ``delta`` metres apart.

    ``per="frame"``: pairs ``(i, i + int(delta))`` in association order.
    ``per="metre"``: for each ``i`` the first ``j > i`` whose reference path
    length from ``i`` is at least ``delta`` metres; poses with no such ``j``
    are dropped. For each pair the error is ``E = ⊖(ref_i⁻¹ ⊕ ref_j) ⊕
    (est_i⁻¹ ⊕ est_j)``, its translation ``||E_xy||`` (m) and rotation
    ``|E_theta|`` (deg). Returns ``{"per", "delta", "pairs", "translation_m",
    "rotation_deg"}`` plus, for ``per="metre"``, ``"translation_percent"``
    (100 * error / path length) and ``"rotation_deg_per_m"``. With no pairs,
    ``pairs`` is 0 and the statistics are NaN. A ``per`` other than
    ``"frame"``/``"metre"`` or a ``delta`` that selects no step raises
    :class:`InputError`.
    """
    est = se2.as_poses(assoc.estimate).reshape(-1, 3)
    ref = se2.as_poses(assoc.reference).reshape(-1, 3)
    if est.shape != ref.shape:
        raise ValueError(f"estimate {est.shape} and reference {ref.shape} differ in size")
    n = est.shape[0]
    path_length: NDArray[np.float64] | None = None
    if per == "frame":
        step = int(delta)
        if step < 1:
            raise InputError(f"{delta!r} frames: the RPE step must be at least 1 frame", field="delta")
        first = np.arange(max(n - step, 0))
        second = first + step
    elif per == "metre":
        if not (math.isfinite(delta) and delta > 0):
            raise InputError(f"{delta!r} m: the RPE distance must be a positive number of metres", field="delta")
        steps = np.hypot(np.diff(ref[:, 0]), np.diff(ref[:, 1]))
        travelled = np.concatenate(([0.0], np.cumsum(steps)))
        # first j with travelled[j] >= travelled[i] + delta; delta > 0 makes j > i
        j = np.searchsorted(travelled, travelled + delta, side="left")
        keep = j < n
        first = np.flatnonzero(keep)
        second = j[keep]
        path_length = travelled[second] - travelled[first]
    else:
        raise InputError(f"{per!r} is not an RPE unit; use 'frame' or 'metre'", field="per")

    ref_motion = se2.relative(ref[first], ref[second])
    est_motion = se2.relative(est[first], est[second])
    error = se2.relative(ref_motion, est_motion).reshape(-1, 3)
    translation = np.hypot(error[:, 0], error[:, 1])
    rotation_deg = np.degrees(np.abs(error[:, 2]))
    out: dict[str, Any] = {
        "per": per,
        "delta": delta,
        "pairs": int(first.shape[0]),
        "translation_m": error_stats(translation),
        "rotation_deg": error_stats(rotation_deg),
    }
    if path_length is not None:
        out["translation_percent"] = error_stats(100.0 * translation / path_length)
        out["rotation_deg_per_m"] = error_stats(rotation_deg / path_length)
    return out


def _mean_std(values: NDArray[np.float64]) -> dict[str, float]:
    """Mean and sample standard deviation (ddof=1; 0 for one value)."""
    n = values.shape[0]
    return {
        "mean": float(np.mean(values)),
        "std": float(np.std(values, ddof=1)) if n > 1 else 0.0,
    }


def relations_error(
    est_times: ArrayLike,
    est_poses: ArrayLike,
    relations: Relations,
    *,
    max_gap: float = 0.5,
    est_name: str = "estimate",
) -> dict[str, Any]:
    """The relations metric of Kümmerle et al. 2009, as Cartographer's ``compute_relations_metrics``.

    For each relation ``(t1, t2, expected)`` the estimate is interpolated at
    ``t1`` and ``t2`` (gaps up to ``max_gap`` s); relations outside the
    estimate are skipped and counted. The error is ``(p1⁻¹ ⊕ p2) ⊕
    expected⁻¹``; its translation ``||xy||`` (m) and rotation ``|theta|``
    (deg) are summarised as mean and sample std of the absolute and of the
    squared values. Returns ``{"relations", "used", "skipped",
    "translation_abs_m", "translation_sq_m2", "rotation_abs_deg",
    "rotation_sq_deg2", "translation_max_m"}``. Raises :class:`InputError`
    naming the relations file and both time spans when no relation is covered.
    """
    et = np.asarray(est_times, dtype=np.float64).reshape(-1)
    ep = se2.as_poses(est_poses).reshape(-1, 3)
    total = len(relations)
    pose1, valid1 = interpolate_poses(et, ep, relations.t1, max_gap)
    pose2, valid2 = interpolate_poses(et, ep, relations.t2, max_gap)
    covered = valid1 & valid2
    used = int(np.count_nonzero(covered))
    if used == 0:
        relation_times = np.concatenate((relations.t1, relations.t2))
        raise InputError(
            f"no relation falls within the estimate's poses (gaps up to {max_gap:g} s): "
            f"{_span(relation_times, 'relations')}, {_span(et, est_name)}",
            path=relations.path,
            field="timestamp",
        )
    error = se2.compose(
        se2.relative(pose1[covered], pose2[covered]), se2.inverse(relations.motion[covered])
    ).reshape(-1, 3)
    translation = np.hypot(error[:, 0], error[:, 1])
    rotation_deg = np.degrees(np.abs(error[:, 2]))
    return {
        "relations": total,
        "used": used,
        "skipped": total - used,
        "translation_abs_m": _mean_std(translation),
        "translation_sq_m2": _mean_std(translation**2),
        "rotation_abs_deg": _mean_std(rotation_deg),
        "rotation_sq_deg2": _mean_std(rotation_deg**2),
        "translation_max_m": float(np.max(translation)),
    }


def heading_agreement(
    times: ArrayLike, poses: ArrayLike, ref_times: ArrayLike, ref_poses: ArrayLike, *, delta: int = 50,
    max_gap: float = 0.5,
) -> dict[str, Any]:
    """How well a trajectory's headings agree with a reference's (e.g. another method's on the same log), in degrees.

    Why: a map with one part turned against the rest can still score well on
    map-only measures (each part agrees with itself), but its headings then
    differ from a consistent reference's by the turn for the rest of the run.
    ``heading_p95_deg``: 95th percentile of |heading - reference heading|
    after the best rigid alignment of the positions (:func:`align_se2`, as
    ATE). ``relative_p95_deg``: 95th percentile of the difference in heading
    change over ``delta`` poses (local turns; a slow drift barely shows).
    """
    assoc = associate(times, poses, ref_times, ref_poses, max_gap=max_gap)
    est = se2.as_poses(assoc.estimate).reshape(-1, 3)
    ref = se2.as_poses(assoc.reference).reshape(-1, 3)
    transform = align_se2(est[:, :2], ref[:, :2])
    diff = np.abs(se2.wrap_angle(est[:, 2] + transform[2] - ref[:, 2]))
    d = max(1, min(int(delta), est.shape[0] - 1))
    turn = se2.wrap_angle((est[d:, 2] - est[:-d, 2]) - (ref[d:, 2] - ref[:-d, 2]))
    return {
        "pairs": int(est.shape[0]),
        "heading_p95_deg": float(np.degrees(np.percentile(diff, 95))),
        "heading_max_deg": float(np.degrees(diff.max())),
        "relative_p95_deg": float(np.degrees(np.percentile(np.abs(turn), 95))),
    }
