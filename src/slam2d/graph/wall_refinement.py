"""Wall bundle adjustment: karto's finished trajectory refined against straight walls and wall ends (``wall_refinement``).

Along a corridor longer than the laser's reach the correlative matches are flat along it and
the odometry decides (docs/methods/what-was-tried.md, *karto, why the simulated worlds stay at 0.1 m*); the
accuracy bound (docs/accuracy_bound.md) reaches 1-3 cm by solving every range reading against
the wall it hit and every wall end's bearing, jointly with the walls and the odometry. This is
that estimator without the truth, run once on the finished run (``GraphSlam.refine_walls``), over
every placed frame (``wall_refinement_frames``) or over the graph's nodes:

1. **Lines per scan** (:func:`extract_segments`, compiled): the returns, in beam order, are cut
   where neighbours are more than ``wall_refinement_break_distance`` apart, then split recursively
   at the point farthest from the chord while it is more than ``wall_refinement_split_distance``
   off (split-and-merge); a piece of at least ``wall_refinement_minimum_points`` beams whose
   total-least-squares line fits with an RMS under ``wall_refinement_fit_rms`` is a segment.
2. **Walls** (:func:`associate_segments`): every segment, placed by its scan's current pose,
   joins the wall (an infinite line ``n(alpha) . p = d``) of the longest segments already taken
   whose angle is within ``wall_refinement_angle_gate``, both of whose end points are within
   ``wall_refinement_offset_gate`` of the line, and whose extent along the line is within
   ``wall_refinement_overlap_gap`` of the segment's; otherwise it starts a wall. Walls seen from
   fewer than ``wall_refinement_minimum_nodes`` scans are dropped.
3. **Wall ends** (:func:`scan_wall_ends`, :func:`associate_ends`): the wall-end detector of
   ``wall_end_landmarks`` with its own incidence limits, each end joining the nearest landmark
   within ``wall_refinement_end_gate`` (never two ends of one scan).
4. **Joint least squares** (:func:`refine_walls`): unknowns are the poses (local perturbations, as
   SPA's), the walls' ``(alpha, d)`` and the wall ends' points. Residuals: each beam of a segment
   on a wall, its point-to-line distance over ``wall_refinement_range_sigma`` (Huber at
   ``wall_refinement_robust_delta`` sigmas); each wall-end sighting with its covariance (Huber
   too); and what ties the poses (``wall_refinement_edges``): the pose graph's own edges (and,
   over all frames, the odometry between consecutive frames with a GMapping-style noise model,
   :func:`odometry_graph`), or that odometry alone, or it and the loop closures' edges. Levenberg-Marquardt steps with a sparse solve (scipy);
   the association is redone with the new poses between rounds (``wall_refinement_iterations``).
   The graph's fixed node is the gauge.

It changes nothing during the run: the finished poses are replaced, so the returned trajectory
and map follow them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit
from numpy.typing import NDArray

from slam2d.backends.graph import PoseGraph, edge_jacobians
from slam2d.backends.landmarks import PointObservations, landmark_positions, point_errors, point_jacobians
from slam2d.backends.spa import robust_objective, robust_weights
from slam2d.core import se2
from slam2d.graph.wall_geometry import floored_sigmas, place_points, tls_line, usable_returns
from slam2d.params import param
from slam2d.sensors.beam_model import beam_sigmas

__all__ = ["WallRefinementParams", "refine_path", "Segments", "extract_segments", "scan_segments", "associate_segments",
           "EndSightings", "scan_wall_ends", "associate_ends", "odometry_graph", "refine_walls", "WallRefinementResult"]

_DEG = math.pi / 180.0

# Diagnostics only (benchmarks/studies/measure_wall_refinement.py, a setting's ``freeze=walls,ends``), not a
# parameter: the associations named here ("walls": segments to walls, "ends": wall-end sightings to landmarks) are made once,
# in refine_walls' first round, and kept for every later round instead of being redone at the new poses.
_FREEZE: set[str] = set()
# Diagnostics only, likewise: associations given from outside (e.g. the simulator's truth), ``"walls"``: a function of
# the Segments giving every segment's wall, ``"ends"``: of the EndSightings giving every sighting's landmark (-1: none);
# used for every round.
_GIVEN: dict[str, Any] = {}


# a feature most runs leave off: its parameters are listed after the method's own, under its name
_ADVANCED = {"advanced": True, "group": "wall refinement"}


@dataclass
class WallRefinementParams:
    """The wall bundle adjustment's parameters (not in Karto)."""

    wall_refinement: bool = param(
        False,
        help="after the run, refine the poses (every placed frame, or the graph's nodes) jointly with straight "
        "walls fitted to their scans and the wall ends they see (every beam on a wall against its line, every "
        "end against its point, and the odometry or the pose graph's edges) by a batch least squares; the "
        "trajectory and map follow (not in Karto; docs/methods/what-was-tried.md, karto: URG-04LX wall ends and the "
        "wall refinement)",
        **_ADVANCED,
    )
    wall_refinement_frames: bool = param(
        True,
        help="refine every placed frame (its scan, and the odometry between consecutive frames), not only the "
        "graph's nodes: several times the readings (wall_refinement); needs odometry on every frame, else "
        "the nodes alone are refined",
        **_ADVANCED,
    )
    wall_refinement_iterations: int = param(
        5, unit="rounds", low=1, help="rounds of association then Levenberg-Marquardt steps (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_steps: int = param(
        3, unit="steps", low=1, help="Levenberg-Marquardt steps per association round (wall_refinement)", **_ADVANCED
    )
    wall_refinement_minimum_points: int = param(
        10, unit="beams", low=3, help="fewest beams of a line segment (wall_refinement)", **_ADVANCED
    )
    wall_refinement_break_distance: float = param(
        0.2, unit="m", low=0.0,
        help="neighbouring returns farther apart than this are on different segments (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_split_distance: float = param(
        0.04, unit="m", low=0.0,
        help="a run of returns is split at its point farthest from the chord while it is this far off "
        "(wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_fit_rms: float = param(
        0.02, unit="m", low=0.0, help="largest RMS distance of a segment's returns from its line (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_angle_gate: float = param(
        4.0 * _DEG, unit="rad", low=0.0,
        help="a segment joins a wall whose direction is within this of its own (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_offset_gate: float = param(
        0.1, unit="m", low=0.0,
        help="... and whose line passes within this of both of the segment's end points (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_overlap_gap: float = param(
        1.0, unit="m", low=0.0,
        help="... and whose extent along the line is at most this far from the segment's (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_minimum_nodes: int = param(
        3, unit="scans", low=2,
        help="walls and wall ends seen from fewer scans are not used (wall_refinement)", **_ADVANCED
    )
    wall_refinement_range_sigma: float = param(
        0.04, unit="m", low=1e-6,
        help="least sigma of a beam's distance from its wall (a sensor model's per-beam range sigma is used when "
        "larger) (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_robust_delta: float = param(
        2.0, unit="sigma", low=1e-6,
        help="Huber kernel width of a beam's point-to-line residual (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_ends: bool = param(
        True,
        help="detect the wall ends of every refined scan (wall_end_landmarks' detector and parameters, but "
        "wall_refinement_end_incidence and wall_refinement_end_open_incidence), associate them over all scans "
        "within wall_refinement_end_gate and add them as points to the refinement (wall_refinement); off: "
        "with wall_end_landmarks on, that tracker's landmarks are used, else none",
        **_ADVANCED,
    )
    wall_refinement_end_incidence: float = param(
        85.0 * _DEG, unit="rad", low=0.0, high=math.pi / 2,
        help="largest incidence of a wall end (wall_refinement_ends; wall_end_maximum_incidence for the refinement): "
        "the jambs far ahead along a corridor are seen at grazing incidence, and at 80 deg each is lost before the "
        "next is seen, which leaves the stretch between them to the odometry",
        **_ADVANCED,
    )
    wall_refinement_end_open_incidence: float = param(
        80.0 * _DEG, unit="rad", low=0.0, high=math.pi / 2,
        help="largest incidence of a wall end with no return after it (wall_refinement_ends; "
        "wall_end_open_incidence for the refinement)",
        **_ADVANCED,
    )
    wall_refinement_end_jump: float = param(
        0.3, unit="m", low=0.0,
        help="least range step from a wall end's beam to the next two (wall_refinement_ends; wall_end_jump for the "
        "refinement): a box 0.25 m in front of a wall is missed at 0.3 m",
        **_ADVANCED,
    )
    wall_refinement_end_run: int = param(
        5, unit="beams", low=2,
        help="returns without a jump on the near wall before its end (wall_refinement_ends; wall_end_run for the "
        "refinement): a lost return among them (a grazing wall far ahead) loses the end",
        **_ADVANCED,
    )
    wall_refinement_end_two_pass: bool = param(
        False,
        help="refine first with wall_end_landmarks' jump and run (wall_end_jump, wall_end_run), then again from those "
        "poses with wall_refinement_end_jump and wall_refinement_end_run (wall_refinement_ends): the ends the second "
        "detector adds (a box close in front of a wall, a jamb far ahead after a lost return) are associated at the "
        "first pass's poses, not at the run's, where they can join the wrong landmark "
        "(docs/methods/what-was-tried.md, karto: which inputs hold the last centimetres)",
        **_ADVANCED,
    )
    wall_refinement_end_gate: float = param(
        0.15, unit="m", low=0.0,
        help="a wall end joins the nearest landmark (mean of its sightings) within this, never two of one scan "
        "(wall_refinement_ends)",
        **_ADVANCED,
    )
    wall_refinement_edges: str = param(
        "graph", choices=("graph", "odometry", "odometry+loops"),
        help="what ties the poses besides the walls (wall_refinement): graph = the pose graph's edges (scan "
        "matches, loop closures; over all frames, plus the odometry between consecutive frames with the "
        "wall_refinement_odometry_* noise model), odometry = that odometry alone, odometry+loops = it and the "
        "loop closures' edges",
        **_ADVANCED,
    )
    wall_refinement_odometry_srr: float = param(
        0.1, unit="m/m", low=0.0, help="odometry noise: translation from translation (GMapping srr) (wall_refinement_edges)",
        **_ADVANCED,
    )
    wall_refinement_odometry_srt: float = param(
        0.2, unit="rad/m", low=0.0, help="odometry noise: rotation from translation (GMapping srt) (wall_refinement_edges)",
        **_ADVANCED,
    )
    wall_refinement_odometry_str: float = param(
        0.1, unit="m/rad", low=0.0, help="odometry noise: translation from rotation (GMapping str) (wall_refinement_edges)",
        **_ADVANCED,
    )
    wall_refinement_odometry_stt: float = param(
        0.2, unit="rad/rad", low=0.0, help="odometry noise: rotation from rotation (GMapping stt) (wall_refinement_edges)",
        **_ADVANCED,
    )
    wall_refinement_edge_scale: float = param(
        1.0, low=0.0,
        help="factor on the information of the edges that tie the poses (wall_refinement_edges) (wall_refinement)",
        **_ADVANCED,
    )
    wall_refinement_carry_damping: bool = param(
        False,
        help="keep the Levenberg-Marquardt damping from one association round to the next instead of restarting "
        "each round at 1e-4 (wall_refinement): the along-track modes of a long chain of frames are far weaker than "
        "the diagonal the damping scales, so restarted they barely move in 3 steps a round and the solve stops "
        "short of its optimum (docs/methods/what-was-tried.md, karto: is it the wall refinement's association?)",
        **_ADVANCED,
    )


# ----------------------------------------------------------------------------- line extraction


@njit(cache=True)
def _split_and_fit(x, y, beam, break_distance, split_distance, min_points, max_rms):
    """Segments (start, end inclusive) of ordered points and their lines (alpha, d, rms)."""
    n = x.shape[0]
    starts = np.empty(n + 1, np.int64)
    ends = np.empty(n + 1, np.int64)
    alpha = np.empty(n + 1)
    dist = np.empty(n + 1)
    rms = np.empty(n + 1)
    m = 0
    stack = np.empty((n + 2, 2), np.int64)
    run_start = 0
    for k in range(1, n + 1):
        if k < n and math.hypot(x[k] - x[k - 1], y[k] - y[k - 1]) <= break_distance and beam[k] - beam[k - 1] <= 2:
            continue
        top = 0
        stack[0, 0] = run_start
        stack[0, 1] = k - 1
        top = 1
        while top > 0:
            top -= 1
            s = stack[top, 0]
            e = stack[top, 1]
            if e - s + 1 < min_points:
                continue
            dx = x[e] - x[s]
            dy = y[e] - y[s]
            length = math.hypot(dx, dy)
            best = -1
            bd = 0.0
            if length > 0.0:
                for j in range(s + 1, e):
                    d = abs((x[j] - x[s]) * dy - (y[j] - y[s]) * dx) / length
                    if d > bd:
                        bd = d
                        best = j
            if bd > split_distance and best > 0:
                stack[top, 0] = s
                stack[top, 1] = best
                top += 1
                stack[top, 0] = best
                stack[top, 1] = e
                top += 1
                continue
            a, cx, cy, r = tls_line(x, y, s, e)
            if r > max_rms:
                continue
            starts[m] = s
            ends[m] = e
            alpha[m] = a
            dist[m] = cx * math.cos(a) + cy * math.sin(a)
            rms[m] = r
            m += 1
        run_start = k
    return starts[:m], ends[:m], alpha[:m], dist[:m], rms[:m]


def extract_segments(points: NDArray[np.float64], beams: NDArray[np.int64] | None = None, *,
                     break_distance: float = 0.2, split_distance: float = 0.04, min_points: int = 10,
                     max_rms: float = 0.02):
    """Line segments of points in scan order: (start, end) inclusive indices, normal angle, offset, RMS.

    ``beams``: each point's beam index (a gap of more than two lost beams also cuts a run);
    the line of a segment is ``cos(alpha) x + sin(alpha) y = d``.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if beams is None:
        beams = np.arange(points.shape[0], dtype=np.int64)
    if points.shape[0] == 0:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros(0), np.zeros(0), np.zeros(0)
    return _split_and_fit(points[:, 0].copy(), points[:, 1].copy(), np.asarray(beams, np.int64),
                          float(break_distance), float(split_distance), int(min_points), float(max_rms))


@dataclass
class Segments:
    """The beams on segments of every node, and the segments.

    Per beam: ``node``, ``q`` its point (base frame), ``u`` its direction from the laser (base
    frame), ``sigma`` (m), ``segment``. Per segment: ``seg_node``, ``seg_alpha``, ``seg_d`` (its
    line in the base frame), ``seg_ends`` (2, 2) its first and last point (base frame), ``seg_count``.
    """

    node: NDArray[np.int64]
    q: NDArray[np.float64]
    u: NDArray[np.float64]
    sigma: NDArray[np.float64]
    segment: NDArray[np.int64]
    seg_node: NDArray[np.int64]
    seg_alpha: NDArray[np.float64]
    seg_d: NDArray[np.float64]
    seg_ends: NDArray[np.float64]
    seg_count: NDArray[np.int64]


def scan_segments(scans: list[Any], sigmas: list[NDArray[np.float64] | None], p: Any,
                  range_threshold: float = math.inf) -> Segments:
    """The segments of every node's scan (``sigmas``: per node the per-beam range sigma, NaN or None = none)."""
    node_l, q_l, u_l, s_l, seg_l = [], [], [], [], []
    sn, sa, sd, se, sc = [], [], [], [], []
    nseg = 0
    for i, scan in enumerate(scans):
        beams, local, pts = usable_returns(scan, range_threshold)
        if beams.size < p.wall_refinement_minimum_points:
            continue
        starts, ends, alpha, d, _ = extract_segments(
            pts, beams, break_distance=p.wall_refinement_break_distance,
            split_distance=p.wall_refinement_split_distance, min_points=p.wall_refinement_minimum_points,
            max_rms=p.wall_refinement_fit_rms)
        if starts.size == 0:
            continue
        cm, sm = math.cos(scan.mount[2]), math.sin(scan.mount[2])
        u = np.stack([cm * local[:, 0] - sm * local[:, 1], sm * local[:, 0] + cm * local[:, 1]], -1)
        sig = floored_sigmas(sigmas[i], beams, p.wall_refinement_range_sigma)
        # A split point is the end of both its pieces: it goes to the first.
        label = np.full(beams.size, -1, np.int64)
        for k in range(starts.size - 1, -1, -1):
            label[starts[k]: ends[k] + 1] = nseg + k
        on = label >= 0
        node_l.append(np.full(int(on.sum()), i, np.int64))
        q_l.append(pts[on])
        u_l.append(u[on])
        s_l.append(sig[on])
        seg_l.append(label[on])
        sn.append(np.full(starts.size, i, np.int64))
        sa.append(alpha)
        sd.append(d)
        se.append(np.stack([pts[starts], pts[ends]], 1))
        sc.append(ends - starts + 1)
        nseg += starts.size
    if not node_l:
        zi, zf = np.zeros(0, np.int64), np.zeros(0)
        return Segments(zi, np.zeros((0, 2)), np.zeros((0, 2)), zf, zi, zi, zf, zf, np.zeros((0, 2, 2)), zi)
    return Segments(np.concatenate(node_l), np.concatenate(q_l), np.concatenate(u_l), np.concatenate(s_l),
                    np.concatenate(seg_l), np.concatenate(sn), np.concatenate(sa), np.concatenate(sd),
                    np.concatenate(se), np.concatenate(sc).astype(np.int64))


# ----------------------------------------------------------------------------- association


def associate_segments(segs: Segments, poses: NDArray[np.float64], p: Any) -> NDArray[np.int64]:
    """The wall of every segment (-1: none) at ``poses``; walls numbered 0.. and seen from enough nodes."""
    ns = segs.seg_node.size
    wall = np.full(ns, -1, np.int64)
    if ns == 0:
        return wall
    pose = poses[segs.seg_node]
    ends = np.stack([place_points(pose, segs.seg_ends[:, 0, :]), place_points(pose, segs.seg_ends[:, 1, :])], 1)
    alpha = segs.seg_alpha + pose[:, 2]
    order = np.argsort(-segs.seg_count, kind="stable")
    nw = _greedy_walls(ends, alpha, order, wall, p.wall_refinement_angle_gate, p.wall_refinement_offset_gate,
                       p.wall_refinement_overlap_gap)
    # Walls seen from too few nodes are dropped; the rest renumbered.
    ok = wall >= 0
    pairs = np.unique(np.stack([wall[ok], segs.seg_node[ok]], 1), axis=0)
    nodes_per = np.bincount(pairs[:, 0], minlength=nw)
    keep = nodes_per >= p.wall_refinement_minimum_nodes
    index = np.full(nw, -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    return np.where(ok, index[np.maximum(wall, 0)], -1)


@njit(cache=True)
def _greedy_walls(ends, alpha, order, wall, gate_a, gate_d, gap):
    """Segments, longest first, each joined to the existing wall that fits it best (angle, offset and overlap
    gates; the wall keeps its first segment's line and grows its extent along it) or starting a new one:
    fills ``wall`` and returns the number of walls. One compiled pass: the scan of the walls so far runs once
    per segment."""
    ns = order.size
    wa = np.zeros(ns)
    wn = np.zeros((ns, 2))
    wd = np.zeros(ns)
    lo = np.zeros(ns)
    hi = np.zeros(ns)
    nw = 0
    half_turn = 0.5 * math.pi
    for s in order:
        e0x, e0y, e1x, e1y = ends[s, 0, 0], ends[s, 0, 1], ends[s, 1, 0], ends[s, 1, 1]
        best = -1
        best_cost = math.inf
        best_lo = 0.0
        best_hi = 0.0
        for k in range(nw):
            da = abs((alpha[s] - wa[k] + math.pi) % (2.0 * math.pi) - math.pi)
            if da > half_turn:
                da = math.pi - da
            nx, ny = wn[k, 0], wn[k, 1]
            off = max(abs(e0x * nx + e0y * ny - wd[k]), abs(e1x * nx + e1y * ny - wd[k]))
            a0 = e0x * -ny + e0y * nx
            a1 = e1x * -ny + e1y * nx
            amin, amax = min(a0, a1), max(a0, a1)
            g = max(amin - hi[k], lo[k] - amax)
            if da < gate_a and off < gate_d and g < gap:
                cost = off / gate_d + da / gate_a
                if cost < best_cost:
                    best, best_cost, best_lo, best_hi = k, cost, amin, amax
        if best >= 0:
            wall[s] = best
            lo[best] = min(lo[best], best_lo)
            hi[best] = max(hi[best], best_hi)
            continue
        a = alpha[s]
        nx, ny = math.cos(a), math.sin(a)
        wa[nw] = a
        wn[nw, 0], wn[nw, 1] = nx, ny
        wd[nw] = ((e0x * nx + e0y * ny) + (e1x * nx + e1y * ny)) * 0.5
        a0 = e0x * -ny + e0y * nx
        a1 = e1x * -ny + e1y * nx
        lo[nw] = min(a0, a1)
        hi[nw] = max(a0, a1)
        wall[s] = nw
        nw += 1
    return nw


def _fit_lines(world: NDArray[np.float64], wall: NDArray[np.int64], count: int):
    """Total-least-squares (alpha, d) of each wall's points."""
    w = np.bincount(wall, minlength=count).astype(np.float64)
    cx = np.bincount(wall, world[:, 0], count) / w
    cy = np.bincount(wall, world[:, 1], count) / w
    ux, uy = world[:, 0] - cx[wall], world[:, 1] - cy[wall]
    sxx = np.bincount(wall, ux * ux, count)
    syy = np.bincount(wall, uy * uy, count)
    sxy = np.bincount(wall, ux * uy, count)
    alpha = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + 0.5 * math.pi
    d = cx * np.cos(alpha) + cy * np.sin(alpha)
    return alpha, d


@dataclass
class EndSightings:
    """Wall ends of every node: ``node`` (K,), ``z`` (K, 2) in the base frame, ``information`` (K, 2, 2)."""

    node: NDArray[np.int64]
    z: NDArray[np.float64]
    information: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.node.shape[0])


def scan_wall_ends(scans: list[Any], sigmas: list[NDArray[np.float64] | None], p: Any, *, jump: float | None = None,
                   run: int | None = None) -> EndSightings:
    """The wall ends of every scan (:func:`slam2d.matching.wall_ends.detect_wall_ends`, the WallEndParams but the
    incidence limits ``wall_refinement_end_incidence`` and ``wall_refinement_end_open_incidence``, the jump
    ``wall_refinement_end_jump`` and the run ``wall_refinement_end_run``, unless ``jump`` / ``run`` are given)."""
    from slam2d.matching.wall_ends import detect_wall_ends

    node, z, info = [], [], []
    for i, scan in enumerate(scans):
        sig = floored_sigmas(sigmas[i], np.arange(scan.num_beams), p.wall_end_range_sigma)
        ends = detect_wall_ends(scan, sig, jump=p.wall_refinement_end_jump if jump is None else jump,
                                run=p.wall_refinement_end_run if run is None else run,
                                max_incidence=p.wall_refinement_end_incidence,
                                open_incidence=p.wall_refinement_end_open_incidence,
                                max_range=p.wall_end_maximum_range, bearing_sigma=p.wall_end_bearing_sigma)
        if len(ends):
            node.append(np.full(len(ends), i, np.int64))
            z.append(ends.points)
            info.append(np.linalg.inv(ends.covariances))
    if not node:
        return EndSightings(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2)))
    return EndSightings(np.concatenate(node), np.concatenate(z), np.concatenate(info))


@njit(cache=True)
def _greedy_end_landmarks(node, world, gate, lm):
    """Sightings in node order; each node's sightings take the nearest landmark means within ``gate`` (the
    nearest pair first, one landmark per sighting and per node), the rest start new landmarks: fills ``lm``
    and returns the number of landmarks. One compiled pass over the nodes."""
    k = node.size
    total = np.zeros((k, 2))
    count = np.zeros(k)
    last = np.full(k, -1, np.int64)
    nl = 0
    i0 = 0
    while i0 < k:
        i1 = i0 + 1
        while i1 < k and node[i1] == node[i0]:
            i1 += 1
        m = i1 - i0
        this = node[i0]
        if nl:
            d = np.empty((m, nl))
            for a in range(m):
                for b in range(nl):
                    if last[b] == this:
                        d[a, b] = math.inf
                    else:
                        d[a, b] = math.hypot(world[i0 + a, 0] - total[b, 0] / count[b],
                                             world[i0 + a, 1] - total[b, 1] / count[b])
            for _ in range(m):
                best, ba, bb = math.inf, -1, -1
                for a in range(m):
                    for b in range(nl):
                        if d[a, b] < best:
                            best, ba, bb = d[a, b], a, b
                if not best < gate:
                    break
                lm[i0 + ba] = bb
                for b in range(nl):
                    d[ba, b] = math.inf
                for a in range(m):
                    d[a, bb] = math.inf
        for j in range(i0, i1):
            if lm[j] < 0:
                lm[j] = nl
                nl += 1
            total[lm[j], 0] += world[j, 0]
            total[lm[j], 1] += world[j, 1]
            count[lm[j]] += 1.0
            last[lm[j]] = this
        i0 = i1
    return nl


def associate_ends(ends: EndSightings, poses: NDArray[np.float64], gate: float, min_nodes: int) -> NDArray[np.int64]:
    """The landmark of every sighting (-1: none) at ``poses``: in node order, the nearest landmark whose mean is
    within ``gate`` and not seen from that node yet, else a new one; landmarks seen from fewer than
    ``min_nodes`` nodes dropped, the rest numbered 0.."""
    k = len(ends)
    lm = np.full(k, -1, np.int64)
    if k == 0:
        return lm
    world = place_points(poses[ends.node], ends.z)
    nl = _greedy_end_landmarks(np.asarray(ends.node, np.int64), world, float(gate), lm)
    seen = np.bincount(lm, minlength=nl)  # one sighting per node and landmark, so sightings = nodes
    keep = seen >= min_nodes
    index = np.full(nl, -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    return index[lm]


# ----------------------------------------------------------------------------- the joint solve


def odometry_graph(poses: NDArray[np.float64], odometry: NDArray[np.float64], p: Any, fixed: int = 0,
                   breaks: NDArray[np.int64] | None = None) -> PoseGraph:
    """A pose graph over ``poses`` with one edge per consecutive pair: the odometry increment, its covariance
    from the GMapping-style noise model (:func:`slam2d.sensors.motion_noise.step_variances`) plus a floor.
    ``breaks``: poses whose odometry does not follow on from the one before (a resumed session's new
    recording): no edge into them."""
    from slam2d.sensors.motion_noise import OdometryNoise, step_variances

    g = PoseGraph()
    g.add_nodes(poses)
    g.fixed = fixed
    if poses.shape[0] < 2:
        return g
    inc = se2.relative(odometry[:-1], odometry[1:])
    noise = OdometryNoise(srr=p.wall_refinement_odometry_srr, srt=p.wall_refinement_odometry_srt,
                          str=p.wall_refinement_odometry_str, stt=p.wall_refinement_odometry_stt)
    var = step_variances(inc, noise) + np.array([1e-6, 1e-6, 1e-8])
    info = np.zeros((inc.shape[0], 3, 3))
    info[:, np.arange(3), np.arange(3)] = 1.0 / var
    idx = np.arange(poses.shape[0] - 1)
    keep = np.ones(idx.size, dtype=bool)
    if breaks is not None and len(breaks):
        keep[np.asarray(breaks, dtype=np.int64) - 1] = False
    g.add_edges(idx[keep], idx[keep] + 1, inc[keep], info[keep])
    return g




@dataclass
class WallRefinementResult:
    poses: NDArray[np.float64]
    walls: int
    beams: int
    points: int
    cost_before: float
    cost_after: float
    rounds: list[dict[str, float]]
    dense_pairs: int = -1  # the dense stage's return-to-return pairs in its last round (-1: it did not run)

    def summary(self, segments: int, cpu_s: float) -> dict[str, float]:
        """What a method records in ``diagnostics.summary['wall_refinement']``."""
        out = {"walls": float(self.walls), "beams": float(self.beams), "segments": float(segments),
               "points": float(self.points), "poses": float(self.poses.shape[0]),
               "objective_before": self.cost_before, "objective_after": self.cost_after, "cpu_s": cpu_s}
        if self.dense_pairs >= 0:
            out["dense_pairs"] = float(self.dense_pairs)
        return out


def _sqrt_info(info: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per matrix ``S`` with ``S^T S = info`` (symmetric square root; PSD matrices allowed)."""
    info = 0.5 * (info + np.swapaxes(info, 1, 2))
    w, v = np.linalg.eigh(info)
    return np.einsum("kij,kj,klj->kil", v, np.sqrt(np.maximum(w, 0.0)), v)


def refine_walls(graph: PoseGraph, segs: Segments, p: Any, points: PointObservations | None = None,
                 point_count: int = 0, ends: EndSightings | None = None, extra: Any = None,
                 iterations: int | None = None, steps: int | None = None) -> WallRefinementResult:
    """Refine ``graph``'s poses jointly with the walls of ``segs`` and point landmarks.

    The points are either ``points`` (sightings with their landmarks, fixed; ``point_count``
    landmarks) or ``ends`` (sightings associated again every round, :func:`associate_ends`).
    ``extra``: one more block of pose residuals (e.g. :class:`slam2d.graph.dense_refinement.DenseTerm`:
    ``associate(poses)`` every round, ``objective(poses)``, ``rows(poses, first_row)``).
    ``iterations`` / ``steps``: rounds and LM steps per round (default ``wall_refinement_iterations`` /
    ``_steps``). The graph is not modified. Returns the refined poses and a summary per round.
    """
    x = np.array(graph.poses, dtype=np.float64)
    n = x.shape[0]
    fixed = int(graph.fixed)
    ei, ej = np.asarray(graph.edge_i, np.int64), np.asarray(graph.edge_j, np.int64)
    z = np.asarray(graph.measurements, np.float64)
    esq = (_sqrt_info(np.asarray(graph.information, np.float64) * p.wall_refinement_edge_scale) if ei.size
           else np.zeros((0, 3, 3)))
    delta = p.wall_refinement_robust_delta

    def point_setup(x_, lm_=None):
        """Observations renumbered over the observed landmarks, their start positions and square-root information
        (``lm_``: the sightings' landmarks when given, else associated at ``x_``)."""
        if ends is not None and len(ends):
            if lm_ is None:
                lm_ = associate_ends(ends, x_, p.wall_refinement_end_gate, p.wall_refinement_minimum_nodes)
            ok = lm_ >= 0
            obs_ = PointObservations(ends.node[ok], lm_[ok], ends.z[ok], ends.information[ok])
        elif points is not None and len(points):
            obs_ = points
        else:
            return None, np.zeros((0, 2)), np.zeros((0, 2, 2))
        if len(obs_) == 0:
            return None, np.zeros((0, 2)), np.zeros((0, 2, 2))
        used = np.unique(obs_.landmark)
        index = np.full(int(used.max()) + 1, -1, np.int64)
        index[used] = np.arange(used.size)
        obs_ = PointObservations(obs_.pose, index[obs_.landmark], obs_.z, obs_.information)
        pos, _ = landmark_positions(x_, obs_, used.size)
        return obs_, pos, _sqrt_info(obs_.information)

    def beam_terms(x_, wall_, alpha_, d_):
        on = wall_[segs.segment] >= 0
        k = segs.node[on]
        w = wall_[segs.segment[on]]
        q = segs.q[on]
        pose = x_[k]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        world = np.stack([pose[:, 0] + c * q[:, 0] - s * q[:, 1], pose[:, 1] + s * q[:, 0] + c * q[:, 1]], -1)
        na = np.stack([np.cos(alpha_[w]), np.sin(alpha_[w])], -1)
        res = (na * world).sum(1) - d_[w]
        # The range sigma as the distance's: a beam's perpendicular error is its range error times the
        # cosine of its incidence, but the range error grows with the incidence (the URG model), and
        # scaling by the cosine gave the grazing beams of a corridor's far walls too much weight
        # (office seeds 0-2 with the cosine, floored at 0.1: 0.082 m mean ATE; without: 0.066 m).
        sig = segs.sigma[on]
        return k, w, q, c, s, world, na, res / sig, sig

    def objective(x_, alpha_, d_, lm_, wall_, obs_, psq_):
        r = beam_terms(x_, wall_, alpha_, d_)[7]
        obj = float(robust_objective(r * r, "huber", delta).sum())
        if ei.size:
            e = se2.relative(z, se2.relative(x_[ei], x_[ej]))
            obj += float((np.einsum("kij,kj->ki", esq, e) ** 2).sum())
        if obs_ is not None:
            e = np.einsum("kij,kj->ki", psq_, point_errors(x_, lm_, obs_))
            obj += float(robust_objective((e * e).sum(1), "huber", delta).sum())
        if extra is not None:
            obj += extra.objective(x_)
        return obj

    rounds: list[dict[str, float]] = []
    cost_before = math.nan
    lam = 1e-4
    nw = 0
    if "report" in _GIVEN:  # the caller prints it (the library prints nothing)
        _GIVEN["report_text"] = _GIVEN.pop("report")(segs, ends, p)
    frozen_walls = _GIVEN["walls"](segs) if "walls" in _GIVEN else None
    frozen_ends = _GIVEN["ends"](ends) if "ends" in _GIVEN and ends is not None and len(ends) else None
    for _ in range(p.wall_refinement_iterations if iterations is None else iterations):
        seg_wall = associate_segments(segs, x, p) if frozen_walls is None else frozen_walls
        if "walls" in _FREEZE:
            frozen_walls = seg_wall
        nw = int(seg_wall.max()) + 1 if seg_wall.size and seg_wall.max() >= 0 else 0
        if frozen_ends is None and "ends" in _FREEZE and ends is not None and len(ends):
            frozen_ends = associate_ends(ends, x, p.wall_refinement_end_gate, p.wall_refinement_minimum_nodes)
        obs, lm, psq = point_setup(x, frozen_ends)
        nl = lm.shape[0]
        pairs = extra.associate(x) if extra is not None else 0
        if nw == 0 and nl == 0 and pairs == 0:
            break
        bw = seg_wall[segs.segment]
        on0 = bw >= 0
        alpha, d = _fit_lines(place_points(x[segs.node[on0]], segs.q[on0]), bw[on0], nw)
        nvar = 3 * n + 2 * nw + 2 * nl
        free = np.ones(nvar, bool)
        free[3 * fixed: 3 * fixed + 3] = False
        obj = objective(x, alpha, d, lm, seg_wall, obs, psq)
        if math.isnan(cost_before):
            cost_before = obj
        lam = min(lam, 1e-4) if p.wall_refinement_carry_damping else 1e-4
        for _ in range(p.wall_refinement_steps if steps is None else steps):
            rows, cols, vals, rhs = [], [], [], []
            # beams: d res / d local pose step = n^T R [I | (-q_y, q_x)], d res / d (alpha, d) = (n_perp . p, -1)
            k, w, q, c, s, world, na, r, sig = beam_terms(x, seg_wall, alpha, d)
            m = r.size
            sw = np.sqrt(robust_weights(r * r, "huber", delta)) / sig
            nr0 = na[:, 0] * c + na[:, 1] * s
            nr1 = -na[:, 0] * s + na[:, 1] * c
            jt = nr0 * (-q[:, 1]) + nr1 * q[:, 0]
            ja = -na[:, 1] * world[:, 0] + na[:, 0] * world[:, 1]
            rows.append(np.repeat(np.arange(m), 5))
            cols.append(np.stack([3 * k, 3 * k + 1, 3 * k + 2, 3 * n + 2 * w, 3 * n + 2 * w + 1], 1).ravel())
            vals.append((np.stack([nr0, nr1, jt, ja, -np.ones(m)], 1) * sw[:, None]).ravel())
            rhs.append(r * sig * sw)
            row0 = m
            if ei.size:
                e, A, B = edge_jacobians(x, ei, ej, z)
                me = ei.size
                rr = np.repeat((row0 + 3 * np.arange(me)[:, None] + np.arange(3)[None, :])[:, :, None], 3, 2).ravel()
                ci = 3 * ei[:, None] + np.arange(3)[None, :]
                cj = 3 * ej[:, None] + np.arange(3)[None, :]
                rows += [rr, rr]
                cols += [np.broadcast_to(ci[:, None, :], (me, 3, 3)).ravel(),
                         np.broadcast_to(cj[:, None, :], (me, 3, 3)).ravel()]
                vals += [(esq @ A).ravel(), (esq @ B).ravel()]
                rhs.append(np.einsum("kij,kj->ki", esq, e).ravel())
                row0 += 3 * me
            if obs is not None:
                e, jp, jl = point_jacobians(x, lm, obs)
                mp = len(obs)
                we = np.einsum("kij,kj->ki", psq, e)
                pw = np.sqrt(robust_weights((we * we).sum(1), "huber", delta))[:, None, None]
                rr = row0 + 2 * np.arange(mp)[:, None] + np.arange(2)[None, :]
                cp = 3 * obs.pose[:, None] + np.arange(3)[None, :]
                cl = 3 * n + 2 * nw + 2 * obs.landmark[:, None] + np.arange(2)[None, :]
                rows += [np.repeat(rr[:, :, None], 3, 2).ravel(), np.repeat(rr[:, :, None], 2, 2).ravel()]
                cols += [np.broadcast_to(cp[:, None, :], (mp, 2, 3)).ravel(),
                         np.broadcast_to(cl[:, None, :], (mp, 2, 2)).ravel()]
                vals += [(pw * (psq @ jp)).ravel(), (pw * (psq @ jl)).ravel()]
                rhs.append((pw[:, :, 0] * we).ravel())
                row0 += 2 * mp
            if pairs:
                rr, cc, vv, ee = extra.rows(x, row0)
                rows.append(rr)
                cols.append(cc)
                vals.append(vv)
                rhs.append(ee)
                row0 += ee.size
            J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(row0, nvar))[:, np.flatnonzero(free)]
            rvec = np.concatenate(rhs)
            H = (J.T @ J).tocsc()
            g = J.T @ rvec
            hd = H.diagonal()
            accepted = False
            while lam < 1e8:
                step = spla.spsolve(H + sp.diags(lam * (hd + 1e-9)), -g)
                if not np.all(np.isfinite(step)):
                    lam *= 10.0
                    continue
                full = np.zeros(nvar)
                full[free] = step
                x_new = se2.compose(x, full[: 3 * n].reshape(n, 3))
                a_new = alpha + full[3 * n: 3 * n + 2 * nw: 2]
                d_new = d + full[3 * n + 1: 3 * n + 2 * nw: 2]
                lm_new = lm + full[3 * n + 2 * nw:].reshape(nl, 2)
                obj_new = objective(x_new, a_new, d_new, lm_new, seg_wall, obs, psq)
                if obj_new <= obj:
                    x, alpha, d, lm, obj = x_new, a_new, d_new, lm_new, obj_new
                    lam = max(lam / 10.0, 1e-9)
                    accepted = True
                    break
                lam *= 10.0
            if not accepted:
                break
        rounds.append({"walls": float(nw), "beams": float(int(on0.sum())), "points": float(nl),
                       "sightings": float(len(obs) if obs is not None else 0), "pairs": float(pairs),
                       "objective": obj})
    last = rounds[-1] if rounds else {"beams": 0.0, "points": 0.0, "objective": math.nan}
    return WallRefinementResult(x, nw, int(last["beams"]), int(last["points"]), cost_before, last["objective"], rounds)


def refine_path(scans: list[Any], poses: NDArray[np.float64], p: Any, *, graph: PoseGraph | None = None,
                odometry: NDArray[np.float64] | None = None, odometry_breaks: NDArray[np.int64] | None = None,
                fixed: int = 0, extra_edges: tuple | None = None, sensor_model: Any = None, range_limit: float = math.inf,
                points: PointObservations | None = None, point_count: int = 0,
                detector: Any = None, dense: Any = None) -> tuple[WallRefinementResult, Segments]:
    """The wall bundle adjustment of a path of scans, as a method calls it after its run.

    ``poses`` (one per scan) are the starting estimate. They are tied by ``graph`` when given (its own
    edges), else by the odometry between consecutive scans (:func:`odometry_graph`, ``odometry`` one
    reading per scan, none into the ``odometry_breaks``, ``fixed`` the gauge) plus ``extra_edges`` ``(i, j, measurements, information)``.
    The per-beam range sigma comes from ``sensor_model`` (none: ``wall_refinement_range_sigma``);
    returns beyond ``range_limit`` are not fitted. With ``wall_refinement_ends`` the wall ends are
    detected with ``detector``'s wall-end settings (default ``p``) and associated over all scans;
    otherwise ``points`` (``point_count`` landmarks, e.g. a tracker's) are used, if any. With
    ``wall_refinement_end_two_pass`` a first refinement with ``detector``'s ``wall_end_jump`` and ``wall_end_run``
    gives the start of the one with the refinement's own.
    ``dense``: the :class:`slam2d.graph.dense_refinement.DenseRefinementParams` of a dense alignment run
    after it from its poses (:class:`slam2d.graph.dense_refinement.DenseTerm` as an extra block of the
    same solve, with the same edges, and the walls and ends when ``dense_refinement_walls``); None: none.
    Returns the result (the refined poses, or non-finite ones if the solve failed) and the segments.
    """
    sig = [beam_sigmas(s, sensor_model, 0.0) if sensor_model is not None else None for s in scans]
    segs = scan_segments(scans, sig, p, range_limit)
    det = p if detector is None else detector
    ends = scan_wall_ends(scans, sig, det) if p.wall_refinement_ends else None
    if graph is None:
        graph = odometry_graph(poses, odometry, p, int(fixed), odometry_breaks)
        if extra_edges is not None and len(extra_edges[0]):
            graph.add_edges(*extra_edges)
    if ends is not None:
        points, point_count = None, 0
    first = None
    if ends is not None and p.wall_refinement_end_two_pass:
        first = refine_walls(graph, segs, p, ends=scan_wall_ends(scans, sig, det, jump=det.wall_end_jump,
                                                                 run=det.wall_end_run))
        if np.all(np.isfinite(first.poses)):
            graph = graph.copy()
            graph.poses = first.poses
    res = refine_walls(graph, segs, p, points, point_count, ends)
    if first is not None:
        res = replace(res, cost_before=first.cost_before, rounds=first.rounds + res.rounds)
    if dense is None or not np.all(np.isfinite(res.poses)):
        return res, segs
    from slam2d.graph.dense_refinement import DenseTerm

    term = DenseTerm(scans, sig, dense, range_limit)
    g = graph.copy()
    g.poses = res.poses
    if dense.dense_refinement_walls:
        second = refine_walls(g, segs, p, points, point_count, ends, extra=term,
                              iterations=dense.dense_refinement_iterations, steps=dense.dense_refinement_steps)
    else:
        second = refine_walls(g, scan_segments([], [], p), p, extra=term,
                              iterations=dense.dense_refinement_iterations, steps=dense.dense_refinement_steps)
    pairs = int(second.rounds[-1]["pairs"]) if second.rounds else 0
    return WallRefinementResult(second.poses, res.walls, res.beams, res.points, res.cost_before, res.cost_after,
                                res.rounds + second.rounds, pairs), segs

