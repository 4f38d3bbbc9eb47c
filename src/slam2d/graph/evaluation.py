"""Graph SLAM against ground truth: loop-closure precision, and what the sequential matcher can reach.

* :func:`loop_closure_precision`: closures within 0.2 m and 1 deg of the truth
  (Hess et al. 2016, Table IV).
* :func:`sequential_bound`: each kept scan matched against the previous ones
  placed at their *true* poses, from the odometry prediction. Chaining these
  matches is what the front end would reach with a perfect local map and no
  loop closure or near link; the matches whose x, y spread fills the window
  (a corridor longer than the laser's range) are where that chain drifts.
* :func:`closure_bound`: the front end's own sequential edges plus a perfect loop
  closure (the true relative pose) at every return to a place: what loop closing
  could reach at best with these sequential matches; ``exact`` replaces components
  of those edges by the truth, which splits the error budget.
* :func:`sequential_edge_errors`: each sequential edge's error against the truth along
  the true step, across it and in heading, with the sigmas the edge claims and the
  odometry step's error split the same way.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.backends import PoseGraph, get_backend
from slam2d.core import se2
from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
from slam2d.io.tum import by_time, interpolate_poses

__all__ = ["closure_bound", "loop_closure_precision", "sequential_bound", "sequential_edge_errors"]


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
    t, p = by_time(np.asarray(truth_times, dtype=np.float64), np.asarray(truth_poses, dtype=np.float64).reshape(-1, 3))
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


def sequential_bound(frontend: Any, node_truth: ArrayLike, *, window: int = 10) -> dict[str, Any]:
    """Sequential matches of a finished front end's kept scans against a perfect local map.

    ``frontend`` is a :class:`~slam2d.graph.frontend.GraphFrontend` after a run
    (its kept scans and their odometry); ``node_truth`` (N, 3) the true pose of
    each node's scan. Node j is matched (with the penalty, as the front end
    does) against nodes ``j - window .. j - 1`` at their true poses, from the
    true pose of node j - 1 plus the odometry step. Returns the per-step
    translation errors of the match and of the odometry prediction (m), which
    steps were degenerate (x, y variance at the window's size), and the
    trajectory those matches chain into (first node at its true pose) with its
    RMSE against the truth after the rigid alignment ATE uses.
    """
    truth = np.asarray(node_truth, dtype=np.float64).reshape(-1, 3)
    n = frontend.num_nodes
    if truth.shape[0] != n:
        raise ValueError(f"node_truth has {truth.shape[0]} poses for {n} nodes")
    odom = frontend.odometry_at_nodes()
    m = frontend.sequential
    pts = [frontend.node_points(i) for i in range(n)]
    world = [se2.transform_points(truth[i], pts[i][0]) for i in range(n)]
    match_err = np.zeros(max(n - 1, 0))
    prior_err = np.zeros(max(n - 1, 0))
    degenerate = np.zeros(max(n - 1, 0), dtype=bool)
    chained = [truth[0]] if n else []
    for j in range(1, n):  # one match per node: an evaluation, not a per-scan path
        prior = se2.compose(truth[j - 1], se2.relative(odom[j - 1], odom[j]))
        a = max(0, j - window)
        ref = np.concatenate(world[a:j])
        sig = np.concatenate([p[1] for p in pts[a:j]])
        r = m.match(ref, sig, pts[j][0], prior, penalize=True, refine=True)
        e = se2.relative(truth[j], r.pose)
        match_err[j - 1] = float(np.hypot(e[0], e[1]))
        e = se2.relative(truth[j], prior)
        prior_err[j - 1] = float(np.hypot(e[0], e[1]))
        degenerate[j - 1] = float(np.linalg.eigvalsh(r.covariance[:2, :2])[-1]) >= m.search_size**2 - 1e-9
        chained.append(se2.compose(chained[-1], se2.relative(truth[j - 1], r.pose)))
    chain = np.asarray(chained, dtype=np.float64).reshape(-1, 3)
    rmse = float("nan")
    if n > 2:  # aligned as ATE aligns a trajectory with its truth
        times = frontend.node_times()
        rmse = absolute_trajectory_error(associate(times, chain, times, truth))["translation_m"]["rmse"]
    return {
        "match_error_m": match_err,
        "prediction_error_m": prior_err,
        "degenerate": degenerate,
        "chained": chain,
        "chained_rmse_m": rmse,
    }


def _sequential_edges(graph: Any) -> NDArray[np.int64]:
    """Per node k < n - 1, the index of the first edge k -> k + 1 (the sequential match's), -1 if none."""
    ei, ej = np.asarray(graph.edge_i), np.asarray(graph.edge_j)
    out = np.full(max(graph.num_nodes - 1, 0), -1, dtype=np.int64)
    for k in np.nonzero(ej == ei + 1)[0][::-1]:  # reversed: the first edge of a pair is written last
        out[ei[k]] = k
    return out


def _step_axes(truth_step: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit vectors along and across true steps (in the first node's frame); a step under 1 mm (a turn on
    the spot) takes the robot's own x axis as along."""
    length = np.hypot(truth_step[:, 0], truth_step[:, 1])
    along = np.where(length[:, None] > 1e-3, truth_step[:, :2] / np.maximum(length, 1e-12)[:, None], [1.0, 0.0])
    return along, np.stack([-along[:, 1], along[:, 0]], axis=1)


def sequential_edge_errors(frontend: Any, node_truth: ArrayLike) -> dict[str, Any]:
    """Error of every sequential edge of a finished run against the truth, split along / across / heading.

    The sequential edge of node k is the first edge k -> k + 1 (the sequential match, measured
    from node k's pose when node k + 1 was added). Its error is the measurement minus the true
    relative pose, in node k's frame, projected on the true step's direction (``along_m``,
    positive: too long), across it (``cross_m``, positive: to the left) and in heading
    (``heading_rad``). ``sigma_*`` are the standard deviations the edge's information matrix
    claims in those directions, ``odometry_*`` the odometry step's errors split the same way,
    ``degenerate`` marks edges whose x, y covariance has the sequential window's size (a match
    flat along a corridor), and ``node`` is k. Nodes without a sequential edge are left out.
    """
    truth = np.asarray(node_truth, dtype=np.float64).reshape(-1, 3)
    g = frontend.graph
    n = g.num_nodes
    if truth.shape[0] != n:
        raise ValueError(f"node_truth has {truth.shape[0]} poses for {n} nodes")
    seq = _sequential_edges(g)
    node = np.nonzero(seq >= 0)[0]
    k = seq[node]
    z = np.asarray(g.measurements, dtype=np.float64).reshape(-1, 3)[k]
    info = np.asarray(g.information, dtype=np.float64).reshape(-1, 3, 3)[k]
    true_step = se2.relative(truth[node], truth[node + 1])
    odom = frontend.odometry_at_nodes()
    odom_step = se2.relative(odom[node], odom[node + 1])
    u, v = _step_axes(true_step)
    cov = np.linalg.inv(info)
    d = z[:, :2] - true_step[:, :2]
    do = odom_step[:, :2] - true_step[:, :2]
    size = frontend.sequential.search_size
    return {
        "node": node,
        "along_m": (d * u).sum(axis=1),
        "cross_m": (d * v).sum(axis=1),
        "heading_rad": se2.wrap_angle(z[:, 2] - true_step[:, 2]),
        "sigma_along_m": np.sqrt(np.einsum("ni,nij,nj->n", u, cov[:, :2, :2], u)),
        "sigma_cross_m": np.sqrt(np.einsum("ni,nij,nj->n", v, cov[:, :2, :2], v)),
        "sigma_heading_rad": np.sqrt(cov[:, 2, 2]),
        "odometry_along_m": (do * u).sum(axis=1),
        "odometry_cross_m": (do * v).sum(axis=1),
        "odometry_heading_rad": se2.wrap_angle(odom_step[:, 2] - true_step[:, 2]),
        "degenerate": np.linalg.eigvalsh(cov[:, :2, :2])[:, -1] >= 0.99 * size**2,
    }


def closure_bound(
    frontend: Any,
    node_truth: ArrayLike,
    *,
    radius: float = 1.0,
    min_separation: int = 30,
    all_edges: bool = False,
    backend: str = "spa",
    exact: Iterable[str] = (),
) -> dict[str, Any]:
    """The ATE a finished front end's graph reaches with a perfect loop closure at every return.

    Node j gets an edge holding the true relative pose (sigma 1 cm, 0.18 deg) to the
    node, at least ``min_separation`` nodes older, whose true position is closest to its
    own, if that is within ``radius``. The other edges are the graph's sequential ones
    (node k to k + 1: the matches as the front end weighted them), or with ``all_edges``
    every edge it made (near links and its own closures too). The graph is optimised from
    the front end's poses. Returns ``{"closures", "ate_m"}`` (node RMSE after the rigid
    alignment ATE uses) and ``"ate_before_m"``, the same for the front end's own poses.
    Where this stays above a target, no loop closing can reach it: the sequential
    edges' error between the returns is what is left. ``exact`` names components of the
    sequential edges to replace by the truth before optimising (``"along"``, ``"cross"``:
    the step's error along / across the true step, as :func:`sequential_edge_errors` splits
    it; ``"heading"``): which of them the remaining error comes from.
    """
    exact = set(exact)
    if exact - {"along", "cross", "heading"}:
        raise ValueError(f"exact takes along, cross, heading; got {sorted(exact)}")
    truth = np.asarray(node_truth, dtype=np.float64).reshape(-1, 3)
    g = frontend.graph
    n = g.num_nodes
    if truth.shape[0] != n:
        raise ValueError(f"node_truth has {truth.shape[0]} poses for {n} nodes")
    ei, ej = np.asarray(g.edge_i), np.asarray(g.edge_j)
    keep = np.ones(ei.size, dtype=bool) if all_edges else ej == ei + 1
    z = np.array(g.measurements, dtype=np.float64).reshape(-1, 3)
    if exact:
        seq = _sequential_edges(g)
        node = np.nonzero(seq >= 0)[0]
        k = seq[node]
        true_step = se2.relative(truth[node], truth[node + 1])
        u, v = _step_axes(true_step)
        d = z[k, :2] - true_step[:, :2]
        a = np.zeros(node.size) if "along" in exact else (d * u).sum(axis=1)
        c = np.zeros(node.size) if "cross" in exact else (d * v).sum(axis=1)
        z[k, :2] = true_step[:, :2] + a[:, None] * u + c[:, None] * v
        if "heading" in exact:
            z[k, 2] = true_step[:, 2]
    h = PoseGraph()
    h.add_nodes(g.poses)
    if keep.any():
        h.add_edges(ei[keep], ej[keep], z[keep], np.asarray(g.information)[keep])
    closures = 0
    info = np.diag([1e4, 1e4, 1e5])
    for j in range(min_separation, n):  # one check per node: an evaluation, not a per-scan path
        d = np.hypot(*(truth[: j - min_separation + 1, :2] - truth[j, :2]).T)
        i = int(np.argmin(d))
        if d[i] <= radius:
            h.add_edge(i, j, se2.relative(truth[i], truth[j]), info)
            closures += 1
    times = frontend.node_times()

    def ate(poses: NDArray[np.float64]) -> float:
        return absolute_trajectory_error(associate(times, poses, times, truth))["translation_m"]["rmse"]

    res = get_backend(backend).optimize(h)
    return {"closures": closures, "ate_m": ate(res.poses), "ate_before_m": ate(g.poses)}
