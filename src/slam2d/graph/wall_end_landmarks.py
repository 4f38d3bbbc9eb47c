"""Wall ends as landmarks in the graph front end (``wall_end_landmarks``, off by default).

Along a corridor longer than the laser's reach the sequential match holds the position along
it only by its distance penalty towards the odometry, so the along-track error is the
odometry's random walk (docs/methods/what-was-tried.md, *karto, the sequential error per edge*).
The door jambs and box corners in view pin it (docs/accuracy_bound.md): each kept scan's wall
ends (:func:`slam2d.matching.wall_ends.detect_wall_ends`) are placed by the scan's matched pose
and associated with the landmarks seen in the last ``wall_end_track_nodes`` nodes (the nearest
by Mahalanobis distance, within ``wall_end_gate`` sigmas, and only when no second landmark is
within the gate too), or start a new landmark. A landmark seen from ``wall_end_min_sightings``
nodes enters the optimisation as a 2-DOF node with one point edge per sighting
(:mod:`slam2d.backends.landmarks`); every ``wall_end_optimize_interval`` nodes with new such
edges the graph is optimised, so the correction reaches the next predictions. Association is
tracking, not place recognition: a landmark not seen for a while is not looked for again (a
return is the loop closer's job), which keeps a wrong association from tying two passes.
After each optimisation a sighting whose error exceeds ``wall_end_reject_chi2`` is dropped
(clutter, a person, a wrong association) and the graph optimised again without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.backends.landmarks import (PointObservations, landmark_positions,
                                      optimize_with_landmarks, point_errors)
from slam2d.core import se2
from slam2d.core.arrays import grown
from slam2d.matching.wall_ends import detect_wall_ends
from slam2d.params import param

__all__ = ["WallEndParams", "WallEndLandmarks"]


# a feature most runs leave off: its parameters are listed after the method's own, under its name
_ADVANCED = {"advanced": True, "group": "wall-end landmarks"}


@dataclass
class WallEndParams:
    """The wall-end landmark parameters of the graph front end (not in Karto)."""

    wall_end_landmarks: bool = param(
        False,
        help="detect wall ends (door jambs, box corners: the nearer beam at a range jump) in every kept scan, "
        "track them as landmarks over the nodes that see them and add them to the pose graph as 2-DOF nodes "
        "with point edges (spa; lago ignores them) (not in Karto): they pin the position along corridors "
        "longer than the laser's reach, where the correlative match follows the odometry",
        **_ADVANCED,
    )
    wall_end_auto_range: float = param(
        0.0, unit="m", low=0.0,
        help="with wall_end_landmarks false, turn them on for a laser whose maximum range (the first scan's "
        "range_max) is under this; 0 = never (not in Karto). 8 m takes the URG-04LX (5.6 m), where they help in "
        "the simulated office, and leaves the RPLidar A1 (12 m) and the SICK logs (50-81.8 m) exactly as they are",
        **_ADVANCED,
    )
    wall_end_jump: float = param(
        0.3, unit="m", low=0.0, help="least range step from a wall end's beam to the next two beams (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_run: int = param(
        5, unit="beams", low=2, help="beams without a jump on the near wall before its end (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_maximum_incidence: float = param(
        80.0 * math.pi / 180.0, unit="rad", low=0.0, high=math.pi / 2,
        help="largest angle between the end's beam and the wall's normal (wall_end_landmarks): at grazing "
        "incidence the end is ill-defined along the wall (its along-wall sigma, the gap between two beams "
        "over the square root of 12, grows as 1 / cos)",
        **_ADVANCED,
    )
    wall_end_open_incidence: float = param(
        70.0 * math.pi / 180.0, unit="rad", low=0.0, high=math.pi / 2,
        help="where no return follows a wall end for three beams (a door into a room beyond the reach, or a "
        "grazing wall losing its returns), the largest incidence at which it is taken (wall_end_landmarks): "
        "in the simulated corridor loop a grazing wall's lost returns otherwise pass for doors",
        **_ADVANCED,
    )
    wall_end_maximum_range: float = param(
        math.inf, unit="m", low=0.0, help="wall ends farther than this are not used (wall_end_landmarks)", **_ADVANCED
    )
    wall_end_range_sigma: float = param(
        0.01, unit="m", low=0.0,
        help="least range sigma of a wall end (a sensor model's per-beam sigma is used when larger) "
        "(wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_bearing_sigma: float = param(
        0.0, unit="rad", low=0.0,
        help="bearing sigma of a wall end added in quadrature to the beam gap's uniform error (a real beam's "
        "width: partly on the edge it can still return the near surface) (wall_end_landmarks); 0 = rays, as "
        "the simulator's",
        **_ADVANCED,
    )
    wall_end_pose_sigma: float = param(
        0.05, unit="m", low=0.0,
        help="the new scan's position uncertainty against the landmarks, added in quadrature when associating "
        "(wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_gate: float = param(
        3.0, unit="sigma", low=0.0,
        help="a wall end is associated with the nearest landmark within this Mahalanobis distance, and only "
        "when it is the only one within it (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_track_nodes: int = param(
        10, unit="nodes", low=1,
        help="a landmark is looked for only while it was seen in the last this many nodes (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_minimum_sightings: int = param(
        3, unit="nodes", low=2,
        help="a landmark enters the pose graph once seen from this many nodes (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_optimize_interval: int = param(
        10, unit="nodes", low=1,
        help="optimise the graph when new landmark edges were added and this many nodes passed since the last "
        "optimisation (wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_reject_chi2: float = param(
        16.0, low=0.0,
        help="after an optimisation a landmark sighting whose chi-square (2 DOF) exceeds this is dropped "
        "(wall_end_landmarks)",
        **_ADVANCED,
    )
    wall_end_information_scale: float = param(
        1.0, low=0.0,
        help="a landmark sighting's information (the inverse of the end's covariance) is multiplied by this in "
        "the pose graph (wall_end_landmarks): the scan matches' covariances are too wide for their errors "
        "(mean chi-square at the truth 0.19 of 3 in the simulated office), so the landmarks weigh more than "
        "the matches than they should (0.3, 0.1, 0.03 measured: no gain, docs/methods/what-was-tried.md#karto)",
        **_ADVANCED,
    )


class WallEndLandmarks:
    """The landmarks and their sightings; :meth:`observe` per kept scan, :meth:`optimize` for the front end."""

    def __init__(self, params: Any, diagnostics: Any = None) -> None:
        self.params = params
        self.diagnostics = diagnostics
        self._node = np.zeros(0, np.int64)  # per sighting
        self._lm = np.zeros(0, np.int64)
        self._z = np.zeros((0, 2))
        self._info = np.zeros((0, 2, 2))
        self._alive = np.zeros(0, bool)  # False once rejected
        self._k = 0
        self._pos = np.zeros((0, 2))  # per landmark: world position (as last placed)
        self._cov = np.zeros((0, 2, 2))
        self._last = np.zeros(0, np.int64)  # node that saw it last
        self._seen = np.zeros(0, np.int64)  # nodes that saw it
        self._nl = 0
        self._pending = 0  # observations in the graph not optimised yet
        self._last_optimized_node = 0
        self.rejected = 0

    def _count(self, name: str, n: int = 1) -> None:
        if self.diagnostics is not None and n:
            self.diagnostics.count(name, n)

    @property
    def num_landmarks(self) -> int:
        return self._nl

    def observations(self) -> PointObservations:
        """The sightings in the optimisation: alive, of landmarks seen from enough nodes."""
        k = self._k
        ok = self._alive[:k] & (self._seen[self._lm[:k]] >= self.params.wall_end_minimum_sightings)
        return PointObservations(self._node[:k][ok], self._lm[:k][ok], self._z[:k][ok], self._info[:k][ok])

    def positions(self) -> NDArray[np.float64]:
        return self._pos[: self._nl].copy()

    @property
    def pending(self) -> bool:
        return self._pending > 0

    def observe(self, frontend: Any, node: int, scan: Any, sigmas: NDArray[np.float64]) -> int:
        """Detect the wall ends of node ``node``'s scan and associate them; optimise when due.

        Returns the number of sightings that went into the pose graph.
        """
        p = self.params
        sig = np.fmax(np.where(np.isfinite(sigmas), sigmas, 0.0), p.wall_end_range_sigma)
        ends = detect_wall_ends(scan, sig, jump=p.wall_end_jump, run=p.wall_end_run,
                                max_incidence=p.wall_end_maximum_incidence, open_incidence=p.wall_end_open_incidence,
                                max_range=p.wall_end_maximum_range, bearing_sigma=p.wall_end_bearing_sigma)
        self._count("wall_ends_detected", len(ends))
        added = 0
        if len(ends):
            added = self._associate(frontend.graph.poses, node, ends)
        self._pending += added
        if self._pending and node - self._last_optimized_node >= p.wall_end_optimize_interval:
            frontend.optimize()
        return added

    def _associate(self, poses: NDArray[np.float64], node: int, ends) -> int:
        p = self.params
        pose = poses[node]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        world = se2.transform_points(pose, ends.points)
        wcov = rot @ ends.covariances @ rot.T + (p.wall_end_pose_sigma**2) * np.eye(2)
        n_det = world.shape[0]
        cand = np.flatnonzero(self._last[: self._nl] >= node - p.wall_end_track_nodes)
        best = np.full(n_det, -1, np.int64)
        gate2 = p.wall_end_gate**2
        if cand.size:
            d = world[:, None, :] - self._pos[cand][None, :, :]
            S = wcov[:, None] + self._cov[cand][None]
            det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
            m2 = (S[..., 1, 1] * d[..., 0] ** 2 - 2 * S[..., 0, 1] * d[..., 0] * d[..., 1]
                  + S[..., 0, 0] * d[..., 1] ** 2) / det
            inside = m2 < gate2
            n_in = inside.sum(axis=1)
            arg = np.argmin(m2, axis=1)
            one = n_in == 1
            self._count("wall_ends_ambiguous", int((n_in > 1).sum()))
            best[one] = cand[arg[one]]
            # Two ends of one scan on one landmark: the nearer keeps it, the other is dropped.
            taken = best >= 0
            if taken.any():
                order = np.argsort(np.where(taken, m2[np.arange(n_det), arg], np.inf), kind="stable")
                seen_lm = best[order]
                dup = np.zeros(n_det, bool)
                _, first = np.unique(seen_lm, return_index=True)
                dup_sorted = np.ones(n_det, bool)
                dup_sorted[first] = False
                dup[order] = dup_sorted & (seen_lm >= 0)
                best[dup] = -2
            new = n_in == 0
        else:
            new = np.ones(n_det, bool)
        # New landmarks for the ends near none.
        k_new = int(new.sum())
        if k_new:
            ids = np.arange(self._nl, self._nl + k_new)
            self._grow_landmarks(self._nl + k_new)
            self._pos[ids] = world[new]
            self._cov[ids] = wcov[new] - (p.wall_end_pose_sigma**2) * np.eye(2)
            self._seen[ids] = 0
            self._nl += k_new
            best[new] = ids
            self._count("wall_end_landmarks", k_new)
        use = best >= 0
        lm = best[use]
        info = np.linalg.inv(ends.covariances[use]) * p.wall_end_information_scale
        k0, k = self._k, int(use.sum())
        self._node = grown(self._node, k0 + k, minimum=64)
        self._lm = grown(self._lm, k0 + k, minimum=64)
        self._z = grown(self._z, k0 + k, minimum=64)
        self._info = grown(self._info, k0 + k, minimum=64)
        self._alive = grown(self._alive, k0 + k, minimum=64)
        self._node[k0 : k0 + k] = node
        self._lm[k0 : k0 + k] = lm
        self._z[k0 : k0 + k] = ends.points[use]
        self._info[k0 : k0 + k] = info
        self._alive[k0 : k0 + k] = True
        self._k += k
        before = self._seen[lm].copy()
        self._seen[lm] += 1
        self._last[lm] = node
        self._count("wall_end_sightings", k)
        # Re-place the landmarks just seen from all their sightings (the poses as they are now).
        self._refresh(lm, poses)
        # Sightings that enter the graph: of landmarks already in, and all of those reaching the threshold.
        need = p.wall_end_minimum_sightings
        entered = int(((before + 1) >= need).sum()) + int(((before + 1) == need).sum() * (need - 1))
        return entered

    def _grow_landmarks(self, needed: int) -> None:
        self._pos = grown(self._pos, needed, minimum=64)
        self._cov = grown(self._cov, needed, minimum=64)
        self._last = grown(self._last, needed, minimum=64)
        self._seen = grown(self._seen, needed, minimum=64)

    def _refresh(self, lm: NDArray[np.int64], poses: NDArray[np.float64]) -> None:
        """Place landmarks ``lm`` from their alive sightings at ``poses``."""
        if lm.size == 0:
            return
        k = self._k
        sel = self._alive[:k] & np.isin(self._lm[:k], lm)
        obs = PointObservations(self._node[:k][sel], self._lm[:k][sel], self._z[:k][sel], self._info[:k][sel])
        pos, cov = landmark_positions(poses, obs, self._nl)
        ok = np.isfinite(pos[lm, 0])
        self._pos[lm[ok]] = pos[lm[ok]]
        self._cov[lm[ok]] = cov[lm[ok]]

    def optimize(self, backend: Any, graph: Any):
        """The front end's optimisation with the landmark edges; returns the back end's result (pose nodes)."""
        res, _ = self._solve(backend, graph)
        self._pending = 0
        self._last_optimized_node = graph.num_nodes - 1
        all_lm = np.arange(self._nl)
        self._refresh(all_lm, res.poses)
        return res

    def _solve(self, backend: Any, graph: Any):
        """Optimise, drop the sightings over ``wall_end_reject_chi2`` and optimise again: (result, landmarks)."""
        p = self.params
        obs = self.observations()
        res, pos = optimize_with_landmarks(backend, graph, obs, self._nl)
        if len(obs) and p.wall_end_reject_chi2 > 0 and not res.extra.get("landmarks_skipped", False):
            pos2, _ = landmark_positions(res.poses, obs, self._nl)
            e = point_errors(res.poses, pos2, obs)
            chi2 = np.einsum("ki,kij,kj->k", e, obs.information, e)
            bad = chi2 > p.wall_end_reject_chi2
            if bad.any():
                # Drop those sightings (clutter, a moved person, a wrong association) and solve again.
                k = self._k
                key = self._node[:k] * (self._nl + 1) + self._lm[:k]
                self._alive[:k] &= ~np.isin(key, obs.pose[bad] * (self._nl + 1) + obs.landmark[bad])
                n_bad = int(bad.sum())
                self.rejected += n_bad
                self._count("wall_end_sightings_rejected", n_bad)
                obs = self.observations()
                res2, pos = optimize_with_landmarks(backend, graph, obs, self._nl)
                res2.cost_before = res.cost_before
                res = res2
        return res, pos
