"""The SLAM-method wrapper shared by ``karto`` and ``lago``: frames in, optimised trajectory and map out."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.backends import PoseGraph
from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.graph.frontend import GraphFrontend
from slam2d.graph.loop_correction import spread_node_corrections
from slam2d.graph.params import GraphSlamParams
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.methods.base import SlamMethod
from slam2d.params import describe

__all__ = ["GraphSlam"]


class GraphSlam(SlamMethod):
    """Karto's front end over a pose-graph back end (``params.backend``).

    The pose of a frame that added no node is its anchor node's pose plus the
    odometry moved since that node, so :meth:`trajectory` follows every
    optimisation. The map holds the kept scans at their optimised poses; it is
    updated scan by scan and rebuilt after an optimisation moved the nodes.
    """

    Params = GraphSlamParams
    DIAGNOSTICS = {
        "response": "sequential scan-match response of a kept scan [0-1]",
        "correction_m": "distance the sequential match moved the odometry prediction [m]",
        "near_links": "near chains linked to the kept scan [count]",
        "loop_closures": "loop closures accepted at the kept scan [count]",
        "nodes": "nodes in the pose graph [count]",
        "recovery_response": "response of the wide recovery search, when the sequential match was stuck on its "
        "window's edge or weak [0-1]",
        "recovery_m": "how far an accepted recovery moved the sequential match [m]",
    }

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        self.frontend = GraphFrontend(self.params, sensor_model=self.sensor_model, diagnostics=self.diagnostics)
        self._anchor: list[int] = []  # per placed frame: the node its pose hangs from
        self._offset: list[NDArray[np.float64]] = []  # and its pose relative to that node
        self._revisit: list[bool] = []  # and whether that node is an old one a revisit frame hung from
        self._frame_times: list[float] = []
        self._grid: OccupancyGrid | None = None
        self._grid_nodes = 0  # nodes drawn into the grid
        self._grid_version = -1  # optimisation count the grid was drawn at
        # wall_refinement over all frames: per placed frame its scan, odometry and node (-1: none)
        self._frame_scans: list[Any] = []
        self._frame_odom: list[Any] = []
        self._frame_node: list[int] = []
        self._refined: NDArray[np.float64] | None = None  # the refined pose of every placed frame
        # placed frames that follow a relocation: the odometry from the frame before is another recording's
        self._frame_breaks: list[int] = []
        self._relocated = False

    def _grid_params(self) -> GridParams:
        names = {p.name for p in describe(GridParams)}
        return GridParams(**{n: getattr(self.params, n) for n in names})

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        self.frontend.relocate(pose)
        self._relocated = True

    def _anchor_to_map(self, pose: NDArray[np.float64]) -> None:
        self.frontend.anchor_to_map(pose)

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        nodes = self.frontend.num_nodes
        values = self.frontend.process(frame)
        fe = self.frontend
        if fe.anchor >= 0:
            self._anchor.append(fe.anchor)
            self._offset.append(np.asarray(fe.offset, dtype=np.float64))
            self._revisit.append(fe.revisit_anchor)
            self._frame_times.append(frame.timestamp)
            if self.params.wall_refinement and self.params.wall_refinement_frames:
                if self._relocated and self._frame_scans:
                    self._frame_breaks.append(len(self._frame_scans))
                self._relocated = False
                self._frame_scans.append(frame.scan)
                self._frame_odom.append(frame.odometry)
                self._frame_node.append(fe.anchor if fe.num_nodes > nodes else -1)
        if values is not None:
            values = dict(values)
            values["nodes"] = float(fe.num_nodes)
        return values

    def current_pose(self) -> NDArray[np.float64] | None:
        if not self._anchor:
            return None
        return se2.compose(self.frontend.graph.poses[self._anchor[-1]], self._offset[-1])

    def trajectory(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if not self._anchor:
            return np.zeros(0), np.zeros((0, 3))
        if self._refined is not None:
            return np.asarray(self._frame_times), self._refined.copy()
        fe = self.frontend
        nodes = fe.graph.poses
        anchor = np.asarray(self._anchor)
        offset = np.stack(self._offset)
        # Between two nodes, spread the correction the next node got over the frames in between
        # (by the share of the odometry motion done), instead of dead reckoning to the jump.
        dead_reckoned = spread_node_corrections(nodes, fe.between_node_steps(), anchor, offset)
        revisit = np.asarray(self._revisit, dtype=bool)
        if revisit.any():
            # Hung from an old node (revisit_without_nodes): not between it and the next, so nothing to spread.
            dead_reckoned[revisit] = se2.compose(nodes[anchor[revisit]], offset[revisit])
        return np.asarray(self._frame_times), dead_reckoned

    def map(self) -> OccupancyGrid:
        fe = self.frontend
        version = len(fe.optimizations)
        if self._grid is None or self._grid_version != version:
            self._grid = fe.build_map(self._grid_params())
            self._grid_version = version
        else:
            for i in range(self._grid_nodes, fe.num_nodes):
                self._grid.integrate(fe.kept_scans[i], fe.graph.poses[i])
        self._grid_nodes = fe.num_nodes
        return self._grid

    def finish(self) -> None:
        fe = self.frontend
        if (fe.loop_closures or (fe.wall_ends is not None and fe.wall_ends.pending)) and fe.graph.num_edges:
            fe.optimize()  # a last pass over the edges added since the last closure
        if self.params.wall_refinement and fe.num_nodes > 1:
            self.refine_walls()
        s = fe.summary()
        fe.release_caches()  # the correlation grids (up to 128 MB) are not needed for the map and outputs
        self.diagnostics.summary.update(
            {
                "nodes": s["nodes"],
                "edges": s["edges"],
                "backend": self.params.backend,
                "loop_closures": s["loop_closures"],
                "loop_attempts": s["loop_attempts"],
                "optimizations": s["optimizations"],
                "grid_builds": s["grid_builds"],
                "grid_extensions": s["grid_extensions"],
                "grid_draws": s["grid_draws"],
                "grid_points_smeared": s["grid_points_smeared"],
                "grid_kept": s["grid_kept"],
            }
        )

    def refine_walls(self) -> None:
        """The wall bundle adjustment (``wall_refinement``): over every placed frame when each has odometry
        (``wall_refinement_frames``), else over the graph's nodes; the trajectory and map follow."""
        fe = self.frontend
        frames = None
        if self.params.wall_refinement_frames and self._frame_scans and all(o is not None for o in self._frame_odom):
            node_frame = np.full(fe.num_nodes, -1, np.int64)
            fn = np.asarray(self._frame_node)
            node_frame[fn[fn >= 0]] = np.flatnonzero(fn >= 0)
            if np.all(node_frame >= 0):
                self._refined = None
                _, poses = self.trajectory()
                frames = (self._frame_scans, np.asarray(self._frame_odom, dtype=np.float64), poses, node_frame,
                          np.asarray(self._frame_breaks, dtype=np.int64))
        summary, self._refined = fe.refine_walls(frames)
        self.diagnostics.summary["wall_refinement"] = summary

    def extra_outputs(self, out_dir: Any) -> list[Any]:
        """``graph.g2o``: the optimised pose graph (g2o's VERTEX_SE2 / EDGE_SE2)."""
        from pathlib import Path

        from slam2d.io.pose_graph import write_g2o

        path = Path(out_dir) / "graph.g2o"
        write_g2o(path, self.frontend.graph)
        return [path]

    def pose_graph(self) -> PoseGraph:
        """The pose graph (nodes at their optimised poses): write it with ``slam2d.io.pose_graph``."""
        return self.frontend.graph

    def node_times(self) -> NDArray[np.float64]:
        """Timestamp of every graph node's scan."""
        return self.frontend.node_times()
