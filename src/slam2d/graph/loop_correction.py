"""Loop correction of a finished path: a pose graph over its nodes, closed by karto's loop search.

A path estimated elsewhere (gmapping's best particle) becomes a pose graph: one node per
update at the path's pose, consecutive nodes tied by the path's own relative pose with a
given information, so the local structure is the path's and is not matched again. The
nodes are fed in order to :class:`~slam2d.graph.frontend.GraphFrontend` through
:meth:`~slam2d.graph.frontend.GraphFrontend.add_placed_node`, which runs karto's loop
closure search at every node (candidate chains far along the path but near in space,
coarse then fine correlative match, response and variance thresholds, weak matches
confirmed in pairs) and the pose-graph back end after every accepted closure. A node
added after a closure hangs from the corrected previous node, so later loops are searched
from the corrected path. :func:`spread_node_corrections` carries the nodes' corrections
to the frames between them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.backends.graph import graph_cost
from slam2d.core import se2
from slam2d.params import param

__all__ = ["LoopCorrectionParams", "LoopCorrectionResult", "correct_path", "spread_node_corrections"]


# a feature most runs leave off: its parameters are listed after the method's own, under its name
_ADVANCED = {"advanced": True, "group": "loop correction"}


@dataclass
class LoopCorrectionParams:
    """The loop correction of a finished path (not in GMapping); the loop search's other settings are karto's."""

    loop_correction: bool = param(
        False, help="not in GMapping: after the last scan, the best particle's path becomes a pose graph (a node per "
        "update, consecutive nodes tied by the path's own relative poses with the motion model's srr...stt "
        "covariance times loop_correction_step_scale), karto's loop closure search runs over it node by node "
        "(coarse then fine correlative match, "
        "karto's response and variance thresholds) and SPA solves it after each closure; the trajectory (frames "
        "between updates interpolated) and map follow the corrected path; off: the filter's path", **_ADVANCED)
    loop_correction_distance: float = param(
        12.0, unit="m", low=0.0, help="loop_correction: loop candidates lie within this distance of a node "
        "(karto's loop_search_maximum_distance, 4 m there; 12 m chosen on aces seeds 0-4, docs)", **_ADVANCED)
    loop_correction_step_scale: float = param(
        0.1, low=1e-6, help="loop_correction: factor on the motion model's standard deviations of the path's steps "
        "(floored at 1 cm, 0.005 rad): the filter's steps are scan matches, far better than the odometry noise they "
        "were drawn with (0.1 chosen on aces seeds 0-4 with fr101 and fr079 not made worse, docs)", **_ADVANCED)
    loop_correction_closure_scale: float = param(
        100.0, low=1e-6, help="loop_correction: factor on the covariance of every loop closure (karto's "
        "match_covariance_scale): the correlative matcher's covariance is centimetres and tenths of a degree, tighter "
        "than a closure's error against the steps it bends (100 chosen with loop_correction_step_scale, docs)",
        **_ADVANCED)
    loop_correction_range: float = param(
        20.0, unit="m", low=0.0, help="loop_correction: returns beyond this are not matched by the loop search "
        "(karto's range_threshold, 12 m there; 20 m chosen on aces seeds 0-4, docs)", **_ADVANCED)


@dataclass
class LoopCorrectionResult:
    """The corrected node poses and what the loop search did."""

    poses: NDArray[np.float64]
    closures: list[dict[str, Any]]
    attempts: int
    cost_before: float  # the final graph's cost (sum e^T Omega e) at the given path
    cost_after: float  # and at the corrected one
    optimizations: list[dict[str, float]]
    cpu_s: float

    def summary(self, before: NDArray[np.float64]) -> dict[str, Any]:
        """The diagnostics' record: closures (with responses), attempts, cost before and after, node shifts."""
        shift = np.hypot(*(self.poses[:, :2] - before[:, :2]).T) if before.size else np.zeros(0)
        opt = self.optimizations
        return {
            "nodes": int(before.shape[0]),
            "closures": self.closures,
            "closure_count": len(self.closures),
            "attempts": self.attempts,
            "optimizations": len(opt),
            "cost_before": self.cost_before,
            "cost_after": self.cost_after,
            "max_shift_m": float(shift.max()) if shift.size else 0.0,
            "cpu_s": self.cpu_s,
        }


def correct_path(scans: list[Any], poses: NDArray[np.float64], odometry: NDArray[np.float64],
                 times: NDArray[np.float64], information: NDArray[np.float64], params: LoopCorrectionParams, *,
                 sensor_model: Any = None, diagnostics: Any = None) -> LoopCorrectionResult:
    """The path ``poses`` (N, 3) of the scans (each a :class:`~slam2d.core.frames.Scan`) corrected by loop closures.

    ``information`` (N-1, 3, 3): of each step ``relative(poses[k], poses[k+1])`` in node k's frame.
    ``odometry`` and ``times`` are the nodes' (karto's bookkeeping; the edges do not use the odometry).
    The loop search and back end are karto's defaults but for ``loop_correction_distance``,
    ``loop_correction_range`` and ``loop_correction_closure_scale`` (its ``match_covariance_scale``); without
    an accepted closure the poses come back unchanged.
    """
    from slam2d.graph.frontend import GraphFrontend
    from slam2d.graph.params import GraphSlamParams

    cpu = time.process_time()
    poses = np.asarray(poses, dtype=np.float64)
    kp = GraphSlamParams(loop_search_maximum_distance=params.loop_correction_distance,
                         range_threshold=params.loop_correction_range, wall_end_landmarks=False,
                         match_covariance_scale=params.loop_correction_closure_scale,
                         wall_refinement=False)
    fe = GraphFrontend(kp, sensor_model=sensor_model, diagnostics=diagnostics)
    steps = se2.relative(poses[:-1], poses[1:])
    for k, scan in enumerate(scans):
        if k == 0:
            fe.add_placed_node(scan, poses[0], float(times[0]))
        else:
            fe.add_placed_node(scan, odometry[k], float(times[k]), steps[k - 1], information[k - 1])
    if fe.loop_closures:
        fe.optimize()  # as karto's finish: a last pass over the edges added since the last closure
    out = fe.graph.poses.copy() if fe.loop_closures else poses.copy()
    g = fe.graph
    args = (g.edge_i, g.edge_j, g.measurements, g.information)
    return LoopCorrectionResult(out, [c.as_dict() for c in fe.loop_closures], len(fe.loop_attempts),
                                graph_cost(poses, *args), graph_cost(out, *args), list(fe.optimizations),
                                time.process_time() - cpu)


def spread_node_corrections(nodes: NDArray[np.float64], steps: NDArray[np.float64], anchor: NDArray[np.int64],
                            offset: NDArray[np.float64]) -> NDArray[np.float64]:
    """Frame poses hung from (corrected) nodes, each node's correction spread over the frames after it.

    A frame lies at ``offset`` from its ``anchor`` node. ``steps[k]`` is the pose of node k+1 relative to node k
    along which the frames between them were placed; whatever the correction changed (node k+1 against node k
    composed with that step) is applied to each frame by the share of the step's motion (translation plus
    rotation) the frame has done, instead of dead reckoning to a jump at node k+1.
    """
    dead_reckoned = se2.compose(nodes[anchor], offset)
    inner = anchor < len(nodes) - 1
    if np.any(inner):
        k = anchor[inner]
        step = steps[k]
        correction = se2.relative(se2.compose(nodes[k], step), nodes[k + 1])
        done = np.hypot(offset[inner, 0], offset[inner, 1]) + np.abs(offset[inner, 2])
        total = np.hypot(step[:, 0], step[:, 1]) + np.abs(step[:, 2])
        share = np.clip(np.divide(done, total, out=np.zeros_like(done), where=total > 1e-12), 0.0, 1.0)
        dead_reckoned[inner] = se2.compose(
            dead_reckoned[inner], se2.interpolate(np.zeros_like(correction), correction, share)
        )
    return dead_reckoned
