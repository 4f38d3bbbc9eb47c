"""Point landmarks in a pose graph: 2-DOF points seen from poses as points in the robot frame.

An observation says "landmark ``l`` lies at ``z`` in the frame of pose ``i``", with a 2x2
information matrix ``Omega`` over that point (a range-bearing reading linearised at the
measured point, e.g. :mod:`slam2d.matching.wall_ends`). Its error is
``e = R_i^T (l - t_i) - z`` and its cost ``e^T Omega e``.

SPA takes them without a new solver: :func:`augmented_graph` appends every landmark as a pose
node ``(x, y, 0)`` and every observation as an edge ``z' = (z_x, z_y, 0)`` whose information
is ``Omega`` in the x, y block and zero for the heading. The SE(2) edge error's translation
``R_z'^T (t_D - t_z')`` is then exactly ``e`` (``R_z' = I``, and ``t_D`` does not depend on the
landmark node's heading), and with zero heading information the landmark's heading is touched
by nothing: its row of the normal equations is zero, the damping keeps it solvable, and its
step is zero. The edge Jacobians are SPA's own (:func:`~slam2d.backends.graph.edge_jacobians`);
:func:`point_jacobians` writes them out for the tests.

LAGO cannot take them: its first stage estimates headings from the edges' relative headings,
and a point observation has none (its heading information is zero, which makes LAGO's
orientation system singular at every landmark node). :func:`optimize_with_landmarks` hands
every back end but ``spa`` (LAGO, GTSAM) the pose graph alone and places the landmarks by the
optimised poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from slam2d.backends.base import Backend
from slam2d.backends.graph import PoseGraph

__all__ = ["PointObservations", "point_errors", "point_jacobians", "landmark_positions", "augmented_graph",
           "optimize_with_landmarks", "LANDMARK_BACKENDS"]

#: back ends that optimise the landmarks with the poses (the others get the pose graph alone)
LANDMARK_BACKENDS = ("spa",)


@dataclass
class PointObservations:
    """``pose`` (K,) node indices, ``landmark`` (K,) landmark indices, ``z`` (K, 2) the point in the
    pose's frame (m), ``information`` (K, 2, 2) (1/m^2)."""

    pose: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    landmark: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    z: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    information: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2, 2)))

    def __len__(self) -> int:
        return int(self.pose.shape[0])

    def subset(self, mask: NDArray[np.bool_]) -> PointObservations:
        return PointObservations(self.pose[mask], self.landmark[mask], self.z[mask], self.information[mask])


def _rot(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def point_errors(poses: NDArray, landmarks: NDArray, obs: PointObservations) -> NDArray[np.float64]:
    """``R_i^T (l - t_i) - z`` per observation, (K, 2)."""
    p = poses[obs.pose]
    d = landmarks[obs.landmark] - p[:, :2]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1) - obs.z


def point_jacobians(poses: NDArray, landmarks: NDArray, obs: PointObservations):
    """Errors (K, 2), ``de/d delta_pose`` (K, 2, 3) with the local (right-multiplied) pose
    perturbation SPA uses, and ``de/dl`` (K, 2, 2) for a world-frame landmark step."""
    p = poses[obs.pose]
    e = point_errors(poses, landmarks, obs)
    q = e + obs.z  # the landmark in the pose's frame
    k = p.shape[0]
    jp = np.zeros((k, 2, 3))
    jp[:, 0, 0] = -1.0
    jp[:, 1, 1] = -1.0
    jp[:, 0, 2] = q[:, 1]
    jp[:, 1, 2] = -q[:, 0]
    jl = np.swapaxes(_rot(p[:, 2]), 1, 2)
    return e, jp, jl


def landmark_positions(poses: NDArray, obs: PointObservations, count: int):
    """Each landmark's least-squares position given the poses (the information-weighted mean of its
    sightings in the world frame) and its covariance; (count, 2), (count, 2, 2). A landmark without
    observations is NaN."""
    p = poses[obs.pose]
    rot = _rot(p[:, 2])
    world = p[:, :2] + np.einsum("kij,kj->ki", rot, obs.z)
    w = rot @ obs.information @ np.swapaxes(rot, 1, 2)  # information in the world frame
    info = np.zeros((count, 2, 2))
    vec = np.zeros((count, 2))
    np.add.at(info, obs.landmark, w)
    np.add.at(vec, obs.landmark, np.einsum("kij,kj->ki", w, world))
    det = info[:, 0, 0] * info[:, 1, 1] - info[:, 0, 1] * info[:, 1, 0]
    ok = det > 1e-300
    cov = np.full((count, 2, 2), np.nan)
    cov[ok, 0, 0] = info[ok, 1, 1] / det[ok]
    cov[ok, 1, 1] = info[ok, 0, 0] / det[ok]
    cov[ok, 0, 1] = cov[ok, 1, 0] = -info[ok, 0, 1] / det[ok]
    pos = np.full((count, 2), np.nan)
    pos[ok] = np.einsum("kij,kj->ki", cov[ok], vec[ok])
    return pos, cov


def augmented_graph(graph: PoseGraph, landmarks: NDArray, obs: PointObservations) -> PoseGraph:
    """A copy of ``graph`` with landmark ``l`` as node ``graph.num_nodes + l`` at ``(x, y, 0)`` and
    every observation as an edge with zero heading information (see the module docstring)."""
    g = graph.copy()
    if len(landmarks):
        g.add_nodes(np.column_stack([landmarks, np.zeros(len(landmarks))]))
    if len(obs):
        info = np.zeros((len(obs), 3, 3))
        info[:, :2, :2] = 0.5 * (obs.information + np.swapaxes(obs.information, 1, 2))
        z = np.column_stack([obs.z, np.zeros(len(obs))])
        g.add_edges(obs.pose, graph.num_nodes + obs.landmark, z, info)
    return g


def optimize_with_landmarks(backend: Backend, graph: PoseGraph, obs: PointObservations, count: int):
    """Optimise the poses with the landmark observations; returns (result, landmark positions (count, 2)).

    The result's ``poses`` are the pose nodes only; its costs include the observations. Back ends
    not in :data:`LANDMARK_BACKENDS` (LAGO) get the pose graph alone, and the landmarks are then
    placed by the optimised poses (``extra["landmarks_skipped"]`` says so).
    """
    n = graph.num_nodes
    used = np.unique(obs.landmark) if len(obs) else np.zeros(0, np.int64)
    if backend.name not in LANDMARK_BACKENDS or used.size == 0:
        res = backend.optimize(graph)
        res.extra["landmarks_skipped"] = bool(used.size)
        pos, _ = landmark_positions(res.poses, obs, count) if len(obs) else (np.full((count, 2), np.nan), None)
        return res, pos
    # Only the observed landmarks become nodes, renumbered 0..len(used)-1.
    index = np.full(count, -1, np.int64)
    index[used] = np.arange(used.size)
    local = PointObservations(obs.pose, index[obs.landmark], obs.z, obs.information)
    start, _ = landmark_positions(graph.poses, local, used.size)
    g = augmented_graph(graph, start, local)
    g.fixed = graph.fixed
    res = backend.optimize(g)
    pos = np.full((count, 2), np.nan)
    pos[used] = res.poses[n:, :2]
    res.poses = res.poses[:n]
    res.extra["landmarks"] = int(used.size)
    res.extra["landmark_observations"] = len(obs)
    return res, pos
