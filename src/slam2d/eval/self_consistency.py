"""How far a trajectory's map disagrees with itself, without a reference: cross-validated scan consistency.

Every trajectory is judged by one mapper (same cells, same range limit, same
beams), so two methods are compared on their poses, not on how each draws its
map. Each scan is then checked against the map of all the *other* scans, less
those taken within ``exclude`` metres of travel of it: a scan agreeing with a
map it (or its neighbours, which share its drift) helped build proves
nothing, while a place seen again later says whether the two visits were put
in the same spot.

Per beam with a return, against that map:

* ``confirmed``: a wall other scans saw lies within ``tolerance`` cells of its end;
* ``contradicted``: its end lands where other scans looked through (free, at
  least ``min_views`` times) and no wall of theirs is near: a wall drawn twice,
  a corridor bent;
* ``through``: the beam itself passes through a wall the other scans agree
  on (hit at least ``min_views`` times and more often than looked through),
  more than ``tolerance`` cells before its end.

A scan's inconsistency is ``(contradicted + through) / (confirmed +
contradicted + through)``: judged only where at least ``min_beams`` beams
could be judged (a scan of a place nobody else saw is not judged).

Counting is one pass of compiled ray casting per scan to build the map, then,
sliding along the trajectory, one to take a scan out of the map as it comes
within ``exclude`` and one to put it back as it leaves: about three casts per
scan.

Two errors no scan contradicts are caught by comparing runs of the same scans
(:func:`rank_runs`): a map that shrank evenly (:func:`travel_scale`, against the
wheels) and a place drawn twice (the map's area). The settings were chosen by
``benchmarks/verdict.py`` (docs/evaluation.md, "Which map to trust").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.grids.raycast import end_coords, first_crossings, step
from slam2d.io.tum import poses_at_scans

#: what a beam says against the other scans' map (``labels`` of :func:`cross_validated_consistency`)
UNJUDGED, CONFIRMED, CONTRADICTED, THROUGH = 0, 1, 2, 3

__all__ = ["ConsistencyParams", "ScanRays", "place_scans", "cross_validated_consistency", "travel_scale",
           "judge_trajectory", "rank_runs", "verdict_sentence"]


@dataclass(frozen=True)
class ConsistencyParams:
    """How the scans are judged (one set for every method, so the judgment is the same)."""

    resolution: float = 0.1  # m: cell size of the judging map
    max_range: float = 10.0  # m: beams are cut here (a longer one counts as free up to it, no wall)
    beam_step: int = 2  # every k-th beam
    exclude: float = 5.0  # m: scans within this much travel of the judged scan are left out of its map
    tolerance: int = 1  # cells: a wall this near a beam's end confirms it
    min_views: int = 2  # scans that saw a cell free (or a wall) before it counts as free (or wall)
    min_beams: int = 10  # beams a scan needs judged to be judged


@dataclass
class ScanRays:
    """Every placed scan's laser position and beam ends in the map frame (one judging map's worth)."""

    index: NDArray[np.int64]  # (S,) the frame index of each placed scan
    origin: NDArray[np.float64]  # (S, 2) laser positions
    start: NDArray[np.int64]  # (S + 1,) offsets into ends
    ends: NDArray[np.float64]  # (B, 2) beam ends
    hit: NDArray[np.bool_]  # (B,) a return within max_range (else the beam is cut there: free only)
    travel: NDArray[np.float64]  # (S,) metres travelled along the trajectory to each scan
    poses: NDArray[np.float64]  # (S, 3) the trajectory's pose at each placed scan
    odometry: NDArray[np.float64] | None  # (S, 3) the frames' odometry there (None where a frame has none)


def place_scans(frames: Iterable[Any], pose_times: ArrayLike, poses: ArrayLike, params: ConsistencyParams,
                max_pose_gap: float = 1.0) -> ScanRays:
    """The scans at the trajectory's poses, beams thinned and cut as ``params`` says."""
    index, origins, ends, hits, starts, placed, odometry = [], [], [], [], [0], [], []
    for k, (frame, pose) in enumerate(poses_at_scans(frames, pose_times, poses, max_pose_gap)):
        if pose is None:
            continue
        scan = frame.scan
        laser = se2.compose(pose, scan.mount)
        ranges = np.asarray(scan.ranges, dtype=np.float64)[:: params.beam_step]
        angles = (scan.angle_min + scan.angle_increment * np.arange(scan.num_beams))[:: params.beam_step]
        keep = np.isfinite(ranges) & (ranges >= scan.range_min)  # no return: not used (glass, black, too far)
        hit = keep & (ranges < params.max_range)
        length = np.minimum(ranges, params.max_range)  # a return beyond max_range: free up to it
        a = laser[2] + angles[keep]
        d = length[keep]
        ends.append(np.column_stack([laser[0] + d * np.cos(a), laser[1] + d * np.sin(a)]))
        hits.append(hit[keep])
        starts.append(starts[-1] + int(keep.sum()))
        origins.append(laser[:2])
        placed.append(pose)
        odometry.append(frame.odometry)
        index.append(k)
    if not index:
        empty = np.zeros((0, 2))
        return ScanRays(np.zeros(0, np.int64), empty, np.zeros(1, np.int64), empty, np.zeros(0, bool), np.zeros(0),
                        np.zeros((0, 3)), None)
    placed = np.asarray(placed, dtype=np.float64)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(placed[:, :2], axis=0).T))])
    odom = None if any(o is None for o in odometry) else np.asarray(odometry, dtype=np.float64)
    return ScanRays(np.asarray(index, np.int64), np.asarray(origins), np.asarray(starts, np.int64),
                    np.concatenate(ends), np.concatenate(hits), travel, placed, odom)


def travel_scale(rays: ScanRays, window: float = 2.0) -> float | None:
    """How far the trajectory says the robot went per metre the odometry says, over stretches of ``window`` m
    of odometry travel (straight-line distances: heading drift within a stretch does not count).

    Self-consistency cannot see a map that shrank evenly (a corridor longer than the laser's reach, along
    which the scans slide); the wheels can. None without odometry or with under two stretches.
    """
    if rays.odometry is None or rays.odometry.shape[0] < 2:
        return None
    odo = rays.odometry[:, :2]
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odo, axis=0).T))])
    marks = np.unique(np.searchsorted(along, np.arange(0.0, along[-1], window)))
    if marks.shape[0] < 3:
        return None
    moved = np.hypot(*np.diff(rays.poses[marks, :2], axis=0).T).sum()
    wheels = np.hypot(*np.diff(odo[marks], axis=0).T).sum()
    return float(moved / wheels) if wheels > 0 else None


@njit(cache=True)
def _count_scan(hits, passes, stamp, stamp_id, origin_x, origin_y, resolution, sx, sy, ex, ey, is_hit, sign):
    """Add ``sign`` to the wall count of each beam end's cell and the free count of each cell a beam
    crosses before it (once per cell per call; a cell that is a wall for one beam is not free for another)."""
    rows, cols = hits.shape
    u0 = (sx - origin_x) / resolution
    v0 = (sy - origin_y) / resolution
    for i in range(ex.shape[0]):
        if not is_hit[i]:
            continue
        u1, v1 = end_coords(u0, v0, ex[i], ey[i], origin_x, origin_y, resolution, True)
        col, row = int(math.floor(u1)), int(math.floor(v1))
        if 0 <= row < rows and 0 <= col < cols and stamp[row, col] != stamp_id:
            stamp[row, col] = stamp_id
            hits[row, col] += sign
    start_col, start_row = int(math.floor(u0)), int(math.floor(v0))
    for i in range(ex.shape[0]):
        u1, v1 = end_coords(u0, v0, ex[i], ey[i], origin_x, origin_y, resolution, is_hit[i])
        end_col, end_row = int(math.floor(u1)), int(math.floor(v1))
        du, dv = u1 - u0, v1 - v0
        step_c = 1 if du > 0.0 else -1
        step_r = 1 if dv > 0.0 else -1
        t_max_x, t_delta_x, t_max_y, t_delta_y = first_crossings(u0, v0, du, dv, start_col, start_row)
        col, row = start_col, start_row
        for _ in range(abs(end_col - col) + abs(end_row - row) + 1):
            at_end = col == end_col and row == end_row
            if at_end and is_hit[i]:
                break
            if 0 <= row < rows and 0 <= col < cols and stamp[row, col] != stamp_id:
                stamp[row, col] = stamp_id
                passes[row, col] += sign
            if at_end:
                break
            col, row, t_max_x, t_max_y = step(col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x,
                                              t_max_y, t_delta_y)


@njit(cache=True)
def _judge_scan(hits, passes, origin_x, origin_y, resolution, sx, sy, ex, ey, is_hit, tolerance, min_views, label):
    """Label each beam of one scan against the counts: ``UNJUDGED``, ``CONFIRMED``, ``CONTRADICTED`` or
    ``THROUGH`` (see the module)."""
    rows, cols = hits.shape
    u0 = (sx - origin_x) / resolution
    v0 = (sy - origin_y) / resolution
    start_col, start_row = int(math.floor(u0)), int(math.floor(v0))
    for i in range(ex.shape[0]):
        if not is_hit[i]:
            continue
        u1, v1 = end_coords(u0, v0, ex[i], ey[i], origin_x, origin_y, resolution, True)
        end_col, end_row = int(math.floor(u1)), int(math.floor(v1))
        wall_near = False
        for r in range(max(end_row - tolerance, 0), min(end_row + tolerance + 1, rows)):
            for c in range(max(end_col - tolerance, 0), min(end_col + tolerance + 1, cols)):
                if hits[r, c] > 0:
                    wall_near = True
        if wall_near:
            label[i] = CONFIRMED
            continue
        # the beam's way: does it cross a wall the others agree on, well before its end?
        du, dv = u1 - u0, v1 - v0
        step_c = 1 if du > 0.0 else -1
        step_r = 1 if dv > 0.0 else -1
        t_max_x, t_delta_x, t_max_y, t_delta_y = first_crossings(u0, v0, du, dv, start_col, start_row)
        col, row = start_col, start_row
        crossed = False
        for _ in range(abs(end_col - col) + abs(end_row - row) + 1):
            if abs(col - end_col) <= tolerance and abs(row - end_row) <= tolerance:
                break
            if 0 <= row < rows and 0 <= col < cols:
                h = hits[row, col]
                if h >= min_views and h > passes[row, col]:
                    crossed = True
                    break
            col, row, t_max_x, t_max_y = step(col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x,
                                              t_max_y, t_delta_y)
        if crossed:
            label[i] = THROUGH
        elif 0 <= end_row < rows and 0 <= end_col < cols and passes[end_row, end_col] >= min_views:
            label[i] = CONTRADICTED


@njit(cache=True)
def _cross_validate(hits, passes, stamp, origin_x, origin_y, resolution, origins, start, ex, ey, is_hit, lo, hi,
                    tolerance, min_views, label):
    """Judge every scan ``i`` against the counts of all scans outside ``[lo[i], hi[i]]`` (a sliding window)."""
    n = origins.shape[0]
    stamp_id = 0
    for j in range(n):
        stamp_id += 1
        a, b = start[j], start[j + 1]
        _count_scan(hits, passes, stamp, stamp_id, origin_x, origin_y, resolution, origins[j, 0], origins[j, 1],
                    ex[a:b], ey[a:b], is_hit[a:b], 1)
    observed = 0  # cells any scan saw: the map's area
    for r in range(hits.shape[0]):
        for c in range(hits.shape[1]):
            if hits[r, c] > 0 or passes[r, c] > 0:
                observed += 1
    out_lo, out_hi = 0, -1  # the scans taken out of the counts now
    for i in range(n):
        while out_hi < hi[i]:  # scans coming within the window: out
            out_hi += 1
            if out_hi >= out_lo:
                stamp_id += 1
                a, b = start[out_hi], start[out_hi + 1]
                _count_scan(hits, passes, stamp, stamp_id, origin_x, origin_y, resolution, origins[out_hi, 0],
                            origins[out_hi, 1], ex[a:b], ey[a:b], is_hit[a:b], -1)
        while out_lo < lo[i]:  # scans left behind: back in
            if out_lo <= out_hi:
                stamp_id += 1
                a, b = start[out_lo], start[out_lo + 1]
                _count_scan(hits, passes, stamp, stamp_id, origin_x, origin_y, resolution, origins[out_lo, 0],
                            origins[out_lo, 1], ex[a:b], ey[a:b], is_hit[a:b], 1)
            out_lo += 1
        a, b = start[i], start[i + 1]
        _judge_scan(hits, passes, origin_x, origin_y, resolution, origins[i, 0], origins[i, 1], ex[a:b], ey[a:b],
                    is_hit[a:b], tolerance, min_views, label[a:b])
    return observed


def _pooled(judged: NDArray[np.int64], disagreeing: NDArray[np.int64]) -> float:
    total = judged.sum()
    return float(disagreeing.sum() / total) if total else math.nan


def cross_validated_consistency(rays: ScanRays, params: ConsistencyParams | None = None) -> dict[str, Any]:
    """Each scan judged against the map of the scans taken more than ``exclude`` m of travel away.

    Returns ``{"inconsistency", "judged_share", "judged", "disagreeing", "labels", "area_m2"}``: the pooled
    share of judged beams that disagree, the share of scans judged, per scan its judged and disagreeing
    beams (both 0 for a scan not judged: under ``min_beams``), each beam's label and the area the scans
    observed.
    """
    p = params or ConsistencyParams()
    n = rays.origin.shape[0]
    labels = np.zeros(rays.hit.shape[0], dtype=np.int8)
    if n == 0:
        none = np.zeros(0, dtype=np.int64)
        return {"inconsistency": float("nan"), "judged_share": 0.0, "judged": none, "disagreeing": none,
                "labels": labels, "area_m2": 0.0}
    lo_xy = np.minimum(rays.ends.min(axis=0), rays.origin.min(axis=0)) - 2 * p.resolution
    hi_xy = np.maximum(rays.ends.max(axis=0), rays.origin.max(axis=0)) + 2 * p.resolution
    shape = (int(math.ceil((hi_xy[1] - lo_xy[1]) / p.resolution)) + 1,
             int(math.ceil((hi_xy[0] - lo_xy[0]) / p.resolution)) + 1)
    hits = np.zeros(shape, dtype=np.int32)
    passes = np.zeros(shape, dtype=np.int32)
    stamp = np.zeros(shape, dtype=np.int32)
    lo = np.searchsorted(rays.travel, rays.travel - p.exclude, side="left")
    hi = np.searchsorted(rays.travel, rays.travel + p.exclude, side="right") - 1
    observed = _cross_validate(hits, passes, stamp, float(lo_xy[0]), float(lo_xy[1]), p.resolution, rays.origin,
                               rays.start, np.ascontiguousarray(rays.ends[:, 0]),
                               np.ascontiguousarray(rays.ends[:, 1]), rays.hit, lo.astype(np.int64),
                               hi.astype(np.int64), p.tolerance, p.min_views, labels)
    counts = np.zeros((n, 4), dtype=np.int64)  # per scan: unjudged, confirmed, contradicted, through
    np.add.at(counts, (np.repeat(np.arange(n), np.diff(rays.start)), labels), 1)
    judged = counts[:, CONFIRMED:].sum(axis=1)
    disagreeing = counts[:, CONTRADICTED:].sum(axis=1)
    ok = judged >= p.min_beams
    judged, disagreeing = np.where(ok, judged, 0), np.where(ok, disagreeing, 0)
    return {"inconsistency": _pooled(judged, disagreeing), "judged_share": float(ok.mean()), "judged": judged,
            "disagreeing": disagreeing, "labels": labels, "area_m2": observed * p.resolution ** 2}


#: most disagreeing beam ends kept for the report's pictures (evenly thinned beyond)
_MARKS = 3000


def judge_trajectory(frames: Iterable[Any], pose_times: ArrayLike, poses: ArrayLike,
                     params: ConsistencyParams | None = None, *, max_pose_gap: float = 1.0) -> dict[str, Any]:
    """The reference-free measures of one trajectory on its recording, JSON-ready.

    ``inconsistency`` (the ranking's measure: the share of judged beams that contradict the other
    visits' map), ``beams`` and ``beams_judged``, ``scans`` and ``scans_judged``, ``per_scan`` (each
    placed scan's ``frame`` index, ``judged`` and ``disagreeing`` beams: the curve over time) and
    ``disagreements`` (map-frame ends of disagreeing beams, at most 3000, for pictures).
    """
    p = params or ConsistencyParams()
    rays = place_scans(frames, pose_times, poses, p, max_pose_gap)
    result = cross_validated_consistency(rays, p)
    bad = np.flatnonzero(result["labels"] >= CONTRADICTED)
    if bad.shape[0] > _MARKS:
        bad = bad[np.linspace(0, bad.shape[0] - 1, _MARKS).astype(np.int64)]
    return {
        "inconsistency": result["inconsistency"],
        "travel_scale": travel_scale(rays),
        "area_m2": result["area_m2"],
        "beams": int(rays.hit.sum()),
        "beams_judged": int(result["judged"].sum()),
        "scans": int(rays.index.shape[0]),
        "scans_judged": int(np.count_nonzero(result["judged"])),
        "per_scan": {"frame": rays.index.tolist(), "judged": result["judged"].tolist(),
                     "disagreeing": result["disagreeing"].tolist()},
        "disagreements": np.round(rays.ends[bad], 3).tolist(),
        "params": dataclasses.asdict(p),
    }


#: a run whose travel_scale differs from the runs' median by more than this has the difference added to its score
SCALE_TOLERANCE = 0.02
#: a run whose map covers this much more area than the smallest map of the runs in scale has the excess added
AREA_TOLERANCE = 0.05


def _off_median(values: dict[str, float], tolerance: float) -> dict[str, float]:
    """Each value's relative difference from the median of three or more, where it is over ``tolerance``."""
    if len(values) < 3:
        return {}
    median = float(np.median(list(values.values())))
    return {name: v / median - 1.0 for name, v in values.items() if abs(v / median - 1.0) > tolerance}


def _area_excess(measures: dict[str, dict[str, Any]], scale_off: dict[str, float]) -> dict[str, float]:
    """Each run's map area over the smallest of the runs in scale that placed at least 95 % of the scans the
    most placed, where that excess is over ``AREA_TOLERANCE``."""
    areas = {n: m["area_m2"] for n, m in measures.items() if m.get("area_m2")}
    most = max((m.get("scans") or 0 for m in measures.values()), default=0)
    bar = [a for n, a in areas.items() if n not in scale_off and (measures[n].get("scans") or 0) >= 0.95 * most]
    if len(areas) < 2 or not bar:
        return {}
    smallest = min(bar)
    return {n: a / smallest - 1.0 for n, a in areas.items() if a / smallest - 1.0 > AREA_TOLERANCE}


def rank_runs(measures: dict[str, dict[str, Any]], *, seed: int = 0, rounds: int = 400,
              block: int = 10) -> dict[str, Any]:
    """Rank runs of one recording by their ``judge_trajectory`` measures, most self-consistent first.

    Runs are ordered by ``score``: the ``inconsistency``, plus two differences from the other runs of the
    same scans, each counted where it is over its tolerance (with three or more runs; a map 4 % short is
    as wrong as 4 % of its beams contradicting it):

    * ``scale_off``: ``travel_scale`` against the runs' median (``SCALE_TOLERANCE``): the map shrank or
      stretched along corridors, which no scan contradicts;
    * ``area_off``: ``area_m2`` over the smallest of the runs that are in scale and placed (nearly) every
      scan (``AREA_TOLERANCE``; two or more runs): places the run did not recognise on coming back are
      drawn a second time elsewhere, where no other scan meets them. The same scans drawn consistently
      cover the same ground; a map that shrank covers less, which is why only runs in scale set the bar.

    ``ahead[name]`` is how often the first stays ahead of that run when the scans both judged are
    resampled in blocks of ``block`` consecutive scans (a block bootstrap: neighbouring scans share
    their errors), ``rounds`` times with ``seed``: 0.5 is a coin toss, 1.0 never overtaken;
    ``confidence`` is the second's. Runs with no judged beam are listed under ``not_judged``.
    """
    judged_runs = {name: m for name, m in measures.items() if m.get("beams_judged")}
    scale_off = _off_median({n: m["travel_scale"] for n, m in judged_runs.items() if m.get("travel_scale")},
                            SCALE_TOLERANCE)
    area_off = _area_excess(judged_runs, scale_off)
    penalty = {name: abs(scale_off.get(name, 0.0)) + abs(area_off.get(name, 0.0)) for name in judged_runs}
    score = {name: judged_runs[name]["inconsistency"] + penalty[name] for name in judged_runs}
    order = sorted(judged_runs, key=lambda name: (score[name], name))
    out: dict[str, Any] = {
        "measure": "score",
        "ranking": order,
        "score": {name: score[name] for name in order},
        "inconsistency": {name: judged_runs[name]["inconsistency"] for name in order},
        "scale_off": scale_off,
        "area_off": area_off,
        "not_judged": sorted(set(measures) - set(judged_runs)),
        "confidence": None,
    }
    if len(order) < 2:
        return out
    out["ahead"] = {name: _ahead(judged_runs[order[0]]["per_scan"], judged_runs[name]["per_scan"],
                                 penalty[order[0]], penalty[name], seed, rounds, block) for name in order[1:]}
    out["confidence"] = out["ahead"][order[1]]
    return out


def _ahead(first: dict[str, list], other: dict[str, list], first_penalty: float, other_penalty: float, seed: int,
           rounds: int, block: int) -> float | None:
    """How often ``first`` scores below ``other`` over block-resampled scans both judged (None: too few)."""
    a = {f: (j, d) for f, j, d in zip(first["frame"], first["judged"], first["disagreeing"]) if j}
    b = {f: (j, d) for f, j, d in zip(other["frame"], other["judged"], other["disagreeing"]) if j}
    common = sorted(set(a) & set(b))
    if len(common) < 2 * block:
        return None
    ja, da = (np.array([a[f][k] for f in common]) for k in (0, 1))
    jb, db = (np.array([b[f][k] for f in common]) for k in (0, 1))
    n_blocks = len(common) // block
    rng = np.random.default_rng(seed)
    ahead = 0.0
    for _ in range(rounds):
        starts = rng.integers(0, len(common) - block + 1, size=n_blocks)
        idx = (starts[:, None] + np.arange(block)[None, :]).ravel()
        x = _pooled(ja[idx], da[idx]) + first_penalty
        y = _pooled(jb[idx], db[idx]) + other_penalty
        ahead += 1.0 if x < y else (0.5 if x == y else 0.0)
    return ahead / rounds


#: a first place the resampling overturns less often than this is not called a win
CLEAR_WIN = 0.9


def verdict_sentence(ranked: dict[str, Any]) -> str:
    """One sentence: which run's map to trust, and how sure that is."""
    order, score = ranked["ranking"], ranked.get("score", ranked["inconsistency"])
    if not order:
        return ("No run could be judged: no scan meets the map of another part of its run "
                "(a recording that never comes back to a place, or no trajectory).")
    if len(order) == 1:
        return (f"Only {order[0]} could be judged (disagreement {100 * score[order[0]]:.1f} %): there is nothing "
                "to rank it against.")
    first, second = order[:2]
    confidence = ranked.get("confidence")
    numbers = f"disagreement {100 * score[first]:.1f} % against {100 * score[second]:.1f} % for {second}"
    ahead = ranked.get("ahead") or {}
    close = [name for name in order[1:] if ahead.get(name) is not None and ahead[name] < CLEAR_WIN]
    if confidence is None:
        return (f"{first}'s map disagrees with itself least ({numbers}), but too few scans were judged by both "
                f"to say how sure that is.")
    if confidence >= CLEAR_WIN:
        return (f"Trust {first}'s map: it disagrees with itself least ({numbers}, the next; {first} stayed ahead "
                f"in {100 * confidence:.0f} % of resamplings of the scans).")
    names = [first, *close]
    together = " and ".join(names) if len(names) == 2 else ", ".join(names[:-1]) + " and " + names[-1]
    return (f"{together} cannot be told apart on this recording ({numbers}; {first} stayed ahead of {second} in "
            f"only {100 * confidence:.0f} % of resamplings of the scans): look at {'both' if len(names) == 2 else 'these'}"
            " maps.")
