"""The graph front end's nodes: each kept scan's points, its reference for matching, where it lies, its edges.

:class:`NodeStore` is a part of :class:`~slam2d.graph.frontend.GraphFrontend`, which holds the
state it reads (``params``, ``graph``, ``sequential``, the per-node lists made in its ``__init__``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.graph.kernels import (_beam_points, _closest_row, _edge_between, _equal_rows, _reachable,
    _transform_rows, _transform_xy, _within)

__all__ = ["NodeStore"]

# np.eye(3) * 1e-12, added to a covariance to keep it invertible; never written to.
_TINY_EYE = np.eye(3) * 1e-12
_TINY_EYE.flags.writeable = False


class NodeStore:
    """Scan points, node references and positions, and the edges between nodes (a part of GraphFrontend)."""

    # ----------------------------------------------------------------- points

    def _scan_points(self, scan, sig, use) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The scan's points (base frame) of the beams in ``use`` and their smear sigmas.

        ``sig`` None: the points only (a scan matched as a query, never drawn), sigmas None.
        """
        p = self.params
        cos, sin = self._beam_directions(scan)
        # Scan.points()' arithmetic, with the beam directions' cos and sin computed once per layout.
        mount = se2._one(scan.mount)
        if mount is not None:
            # In one compiled pass: the same products and sums in the same order as transform_points'.
            points = _beam_points(mount[0], mount[1], math.cos(mount[2]), math.sin(mount[2]), scan.ranges, cos, sin, use)
        else:
            r = scan.ranges[use]
            points = se2.transform_points(scan.mount, np.stack([r * cos[use], r * sin[use]], axis=-1))
        if sig is None:
            return points, None
        # The range sigmas widened by a share of the beam gap (a point stands for its stretch of wall).
        sigmas = self.sequential.reference_sigmas(sig, use, scan.ranges, p.smear_beam_spacing, scan.angle_increment)
        return points, sigmas

    def _beam_directions(self, scan) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        key = (scan.angle_min, scan.angle_increment, scan.num_beams)
        got = self._directions.get(key)
        if got is None:
            a = scan.angles
            got = self._directions[key] = (np.cos(a), np.sin(a))
        return got

    def _world_points(self, i: int) -> NDArray[np.float64]:
        w = self._world[i]
        if w is None:
            x0, y0, t = self.graph.poses[i].tolist()
            # transform_points' arithmetic in one compiled pass (no numpy temporaries per node).
            w = _transform_xy(x0, y0, math.cos(t), math.sin(t), self._ref[i][0])
            self._world[i] = w
        return w

    def _node_reference(self, i: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Node i as a matching reference: its points with the gaps filled (world frame) and their sigmas."""
        w = self._world[i]  # (asked for every node of every new grid: the cached points without a second call)
        return (self._world_points(i) if w is None else w), self._ref[i][1]

    # ----------------------------------------------------------------- positions

    def reference_positions(self, poses: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Where each node is for distance tests: barycentre of its points, or the robot position."""
        if poses is None and self.params.use_scan_barycenter:
            # Asked several times per kept scan while the poses rarely change: the last answer is
            # reused while the poses are the same (compared by value, so in-place edits count).
            cached = self._ref_cache
            poses = self.graph.poses
            n = poses.shape[0]
            if cached is not None:
                old, out = cached
                k = old.shape[0]
                # The rows old and poses share from the start, compared as np.array_equal does (==).
                same = _equal_rows(old, poses) if old.ndim == poses.ndim == 2 and old.shape[1] == poses.shape[1] == 3 else -1
                if k == n and same == n:
                    return out
                # A kept scan appends a node, then may move it (the near links' mean): only the new or
                # last rows are transformed again (elementwise, so each row is what the whole would give).
                if 0 < k <= n and same >= k - 1:
                    first = k - 1 if same == k - 1 else k
                    ref = np.empty((n, 2))
                    ref[:first] = out[:first]
                    # se2.transform_points(poses[first:], bary[first:n, None, :]) row by row, its arithmetic.
                    _transform_rows(poses, self._bary_base, np.cos(poses[first:, 2]), np.sin(poses[first:, 2]),
                                    first, ref)
                    ref.flags.writeable = False
                    self._ref_cache = (poses.copy(), ref)
                    return ref
            out = se2.transform_points(poses, self._bary_base[:, None, :])[:, 0, :]
            out.flags.writeable = False
            self._ref_cache = (poses.copy(), out)
            return out
        poses = self.graph.poses if poses is None else poses
        if not self.params.use_scan_barycenter:
            return poses[:, :2].copy()
        return se2.transform_points(poses, self._bary_base[:, None, :])[:, 0, :]

    def _near_and_linked(self, node: int, ref_xy: NDArray[np.float64], max_distance: float):
        """(nodes within ``max_distance`` of ``node``'s reference position, Karto's FindNearLinkedScans: the
        nodes reachable from ``node`` through nodes within that distance)."""
        n = self.graph.num_nodes
        near = _within(np.ascontiguousarray(ref_xy, dtype=np.float64), node, max_distance**2 + 1e-9)
        return near, _reachable(node, near, np.asarray(self.graph.edge_i, dtype=np.int64),
                                np.asarray(self.graph.edge_j, dtype=np.int64), n)

    def _closest_to_node(self, chain: list[int], node: int, pose: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to the node's (``pose`` before it has one)."""
        ref = self.reference_positions()
        return self._closest_to(chain, ref[node] if node < len(ref) else pose[:2])

    def _closest_in_chain(self, chain: list[int], pose: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to the new scan at ``pose`` (LinkChainToScan's choice)."""
        node = self.graph.num_nodes - 1
        target = se2.transform_points(pose, self._bary_base[node][None, :])[0] if self.params.use_scan_barycenter else pose[:2]
        return self._closest_to(chain, target)

    def _closest_to(self, chain: list[int], target: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to ``target`` (the first on a tie)."""
        ref = self.reference_positions()
        # np.argmin(((ref[chain] - target) ** 2).sum(axis=1)) in one compiled pass (the same sums).
        return int(chain[_closest_row(ref, np.asarray(chain, dtype=np.int64), float(target[0]), float(target[1]))])

    def _path_length(self, i: int, j: int) -> float:
        """Distance the robot travelled from node i to node j along the graph's current poses."""
        xy = self.graph.poses[i : j + 1, :2]
        return float(np.hypot(*np.diff(xy, axis=0).T).sum()) if j > i else 0.0

    # ----------------------------------------------------------------- matches and edges

    def _match_information(self, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """The information a scan-match edge gets from its covariance (scaled by match_covariance_scale)."""
        return np.linalg.inv(covariance) / self.params.match_covariance_scale

    def _add_edge(self, i: int, j: int, pose_j: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Edge i -> j measuring ``pose_j`` seen from node i's current pose; world covariance rotated into i."""
        z = se2.relative(self.graph.poses[i], pose_j)
        self.graph.add_edge(i, j, z, self._match_information(self._local_covariance(i, covariance)))

    def _local_covariance(self, i: int, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """A world-frame match covariance rotated into node i's frame, as an edge from i holds it."""
        c, s = math.cos(self.graph.poses[i][2]), math.sin(self.graph.poses[i][2])
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = rot @ covariance @ rot.T
        return 0.5 * (cov + cov.T) + _TINY_EYE

    def _has_edge(self, i: int, j: int) -> bool:
        # np.any(((ei == i) & (ej == j)) | ((ei == j) & (ej == i))) in one compiled pass (stops at the first).
        return bool(_edge_between(self.graph.edge_i, self.graph.edge_j, int(i), int(j)))

    def _link_chain_to_scan(self, chain: list[int], node: int, pose: NDArray[np.float64], cov: NDArray[np.float64]) -> int:
        """Karto's LinkChainToScan: an edge from the chain's scan closest to ``pose``; returns that scan."""
        closest = self._closest_to_node(chain, node, pose)
        if not self._has_edge(closest, node):
            self._add_edge(closest, node, pose, cov)
        return closest
