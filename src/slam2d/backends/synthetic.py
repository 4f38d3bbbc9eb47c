"""Synthetic pose graphs with known truth, for tests and benchmarks (no downloads).

:func:`manhattan_graph` walks a robot on a 1 m street grid (like Olson's
Manhattan data sets M3500/M10000): each step moves 1 m forward after turning
left, right or not at all. Odometry edges link consecutive poses; loop edges
link a pose to an earlier one within ``loop_radius`` of it, at most one per
pose first, then random extra pairs until ``num_edges`` is reached. All
measurements carry Gaussian noise of the given standard deviations, and the
information matrices are their exact inverses, so the graph is statistically
consistent: at the optimum the cost is about ``3 (M - N + 1)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from slam2d.backends.graph import PoseGraph
from slam2d.core import se2

__all__ = ["manhattan_truth", "manhattan_graph", "chain_poses"]


def manhattan_truth(n: int, rng: np.random.Generator, turn_probability: float = 0.4) -> NDArray[np.float64]:
    """``n`` poses of a walk on a 1 m grid; headings are multiples of 90 degrees."""
    turns = np.where(rng.random(n - 1) < turn_probability, rng.choice([-1.0, 1.0], size=n - 1), 0.0) * (np.pi / 2)
    heading = np.concatenate([[0.0], np.cumsum(turns)])
    # step k turns at pose k, then drives 1 m along the new heading to pose k+1
    xy = np.zeros((n, 2))
    xy[1:, 0] = np.cumsum(np.cos(heading[1:]))
    xy[1:, 1] = np.cumsum(np.sin(heading[1:]))
    return np.column_stack([np.round(xy, 12), se2.wrap_angle(heading)])


def chain_poses(start: NDArray, steps: NDArray) -> NDArray[np.float64]:
    """Compose ``steps`` ``(K, 3)`` from ``start``: the dead-reckoning poses ``(K+1, 3)``.

    Headings are a cumulative sum; positions are then a cumulative sum of the
    rotated steps, so no Python loop runs per pose.
    """
    start = np.asarray(start, dtype=np.float64)
    steps = np.asarray(steps, dtype=np.float64)
    heading = start[2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    dx = c * steps[:, 0] - s * steps[:, 1]
    dy = s * steps[:, 0] + c * steps[:, 1]
    x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
    return np.column_stack([x, y, se2.wrap_angle(heading)])


def manhattan_graph(
    n: int = 5000,
    num_edges: int = 10000,
    *,
    seed: int = 0,
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.01),
    loop_radius: float = 2.0,
    initial: str = "odometry",
) -> tuple[PoseGraph, NDArray[np.float64]]:
    """A noisy Manhattan-world pose graph and its true poses.

    ``initial`` is ``"odometry"`` (poses dead-reckoned from the noisy odometry
    edges, the usual starting point), ``"truth"`` or ``"zero"`` (all at the origin).
    """
    rng = np.random.default_rng(seed)
    truth = manhattan_truth(n, rng)
    sig = np.asarray(sigma, dtype=np.float64)
    info = np.diag(1.0 / sig**2)
    odo = se2.relative(truth[:-1], truth[1:]) + rng.normal(size=(n - 1, 3)) * sig
    pairs = cKDTree(truth[:, :2]).query_pairs(loop_radius, output_type="ndarray")
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[pairs[:, 1] - pairs[:, 0] > 1]
    pairs = pairs[rng.permutation(len(pairs))]
    want = max(num_edges - (n - 1), 0)
    # one loop per later pose first (every revisit is seen), then random extra pairs
    _, first = np.unique(pairs[:, 1], return_index=True)
    rest = np.setdiff1d(np.arange(len(pairs)), first)
    chosen = np.concatenate([first[rng.permutation(len(first))], rest])[:want]
    li, lj = pairs[chosen, 0], pairs[chosen, 1]
    loops = se2.relative(truth[li], truth[lj]) + rng.normal(size=(len(li), 3)) * sig
    g = PoseGraph()
    if initial == "odometry":
        g.add_nodes(chain_poses(np.zeros(3), odo))
    elif initial == "truth":
        g.add_nodes(truth)
    elif initial == "zero":
        g.add_nodes(np.zeros((n, 3)))
    else:
        raise ValueError(f"initial must be odometry, truth or zero, not {initial!r}")
    g.add_edges(np.arange(n - 1), np.arange(1, n), odo, info)
    g.add_edges(li, lj, loops, info)
    return g, truth
