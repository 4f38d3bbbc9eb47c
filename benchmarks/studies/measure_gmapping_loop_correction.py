#!/usr/bin/env python3
"""gmapping's ``loop_correction`` on a real log: the filter once per seed, then the correction with variants.

    NUMBA_NUM_THREADS=1 SLAM2D_THREADS=1 PYTHONPATH=src .venv/bin/python benchmarks/studies/measure_gmapping_loop_correction.py \
        ../shared/datasets/aces/aces.clf.gz --seeds 0-4 --set srt=0.05 --set stt=0.05

The filter is not changed by the correction (its nodes are the same bit for bit), so each seed's filter
runs once and the correction is redone on its best path for every variant: the loop search's distance and
range (``loop_correction_distance``, ``loop_correction_range``), and other choices of the steps'
information (the motion model's, as ``loop_correction`` uses; a constant one; the motion model with the
heading's standard deviation scaled; the motion model widened by the step's disagreement with the
odometry's) and of the back end (SPA with a Cauchy kernel). Prints the ATE (m) against the
``reference.tum`` beside the log, judged as ``slam2d evaluate --reference`` judges it, and the closures.

With ``--explain`` it prints instead, per seed, every closure's error against the reference (its
measured relative pose against the reference's between the two nodes' times) and the error of the
filter's own path over stretches of ``--stretch`` nodes (the relative pose from a stretch's first node
to its last, against the reference's): what a loop correction can and cannot repair.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from slam2d.backends import get_backend
from slam2d.core import se2
from slam2d.eval.evaluate import load_reference
from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
from slam2d.graph import frontend
from slam2d.io import open_recording
from slam2d.io.base import ReadOptions
from slam2d.methods.runner import build_method
from slam2d.sensors.motion_noise import gmapping_motion_std

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_particles import seed_list  # noqa: E402


def _motion(slam, steps, scale=(1.0, 1.0, 1.0)):
    p = slam.params
    scale = np.asarray(scale) * p.loop_correction_step_scale
    out = np.zeros((steps.shape[0], 3, 3))
    for k, s in enumerate(steps):
        std = np.maximum(gmapping_motion_std(s, p.srr, p.srt, p.str, p.stt) * scale, [0.01, 0.01, 0.005])
        out[k] = np.diag(1.0 / std**2)
    return out


def _constant(slam, steps, sxy=0.05, sth=0.01):
    return np.tile(np.diag([1.0 / sxy**2, 1.0 / sxy**2, 1.0 / sth**2]), (steps.shape[0], 1, 1))


def _odometry_disagreement(slam, steps):
    """The motion model's standard deviations of the odometry's step, widened by how far the path's step is from it."""
    p = slam.params
    odom = slam._node_odom[: slam._nodes]
    so = se2.relative(odom[:-1], odom[1:])
    dev = se2.relative(so, steps)
    out = np.zeros((steps.shape[0], 3, 3))
    for k in range(steps.shape[0]):
        m = gmapping_motion_std(so[k], p.srr, p.srt, p.str, p.stt)
        std = np.maximum(np.sqrt(m**2 + dev[k] ** 2), [0.01, 0.01, 0.005])
        out[k] = np.diag(1.0 / std**2)
    return out


VARIANTS = [
    ("loop_correction (defaults)", {}, None, None),
    ("steps: the motion model unscaled, closures unscaled", {"loop_correction_step_scale": 1.0,
                                                            "loop_correction_closure_scale": 1.0}, None, None),
    ("steps x 0.2, closures x 10", {"loop_correction_step_scale": 0.2, "loop_correction_closure_scale": 10.0},
     None, None),
    ("steps x 0.1, closures x 10", {"loop_correction_closure_scale": 10.0}, None, None),
    ("steps x 0.1, closures x 1000", {"loop_correction_closure_scale": 1000.0}, None, None),
    ("karto's loop search distance and range (4 m, 12 m)", {"loop_correction_distance": 4.0,
                                                           "loop_correction_range": 12.0}, None, None),
    ("distance 8 m, range 12 m", {"loop_correction_distance": 8.0, "loop_correction_range": 12.0}, None, None),
    ("distance 12 m, range 30 m", {"loop_correction_range": 30.0}, None, None),
    ("steps: constant 0.05 m, 0.01 rad", {}, _constant, None),
    ("steps: motion model, heading sd x 0.2 more", {}, lambda s, st: _motion(s, st, (1.0, 1.0, 0.2)), None),
    ("steps: odometry's motion model widened by the disagreement", {}, _odometry_disagreement, None),
    ("SPA with a Cauchy kernel (width 1)", {}, None, {"robust_kernel": "cauchy", "robust_delta": 1.0}),
]


def explain(slam, reference, seed: int, stretch: int) -> None:
    """Closures against the reference, and the filter's path against it over stretches of nodes."""
    def at(t):
        return reference.poses[np.argmin(np.abs(reference.times - t))]

    summary = slam.correct_loops()
    print(f"seed {seed}: {summary['closure_count']} closures; error against the reference (m, m, deg):")
    for c in summary["closures"]:
        e = se2.relative(se2.relative(at(c["time_from"]), at(c["time_to"])), np.asarray(c["measurement"]))
        print(f"  {c['frm']:4d} -> {c['to']:4d} (t {c['time_from']:.0f} -> {c['time_to']:.0f} s, fine {c['response_fine']:.2f})"
              f": {e[0]:+.3f} {e[1]:+.3f} {np.degrees(e[2]):+.2f}")
    nodes = slam.best_nodes()
    times = np.asarray(slam._frame_times)[slam._node_frames()]
    ref = np.array([at(t) for t in times])
    print(f"seed {seed}: the filter's path over stretches of {stretch} nodes against the reference:")
    for i in range(0, nodes.shape[0] - 1, stretch):
        j = min(i + stretch, nodes.shape[0] - 1)
        e = se2.relative(se2.relative(ref[i], ref[j]), se2.relative(nodes[i], nodes[j]))
        length = float(np.hypot(*np.diff(ref[i:j + 1, :2], axis=0).T).sum())
        worst = max(range(i, j), key=lambda k: float(np.hypot(*se2.relative(se2.relative(ref[k], ref[k + 1]),
                                                                            se2.relative(nodes[k], nodes[k + 1]))[:2])))
        w = se2.relative(se2.relative(ref[worst], ref[worst + 1]), se2.relative(nodes[worst], nodes[worst + 1]))
        print(f"  nodes {i:4d}-{j:4d} (t {times[i]:.0f}-{times[j]:.0f} s, {length:5.1f} m): {np.hypot(*e[:2]):.2f} m "
              f"{np.degrees(e[2]):+.1f} deg; worst step {worst} (t {times[worst + 1]:.0f} s) {np.hypot(*w[:2]):.2f} m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--seeds", type=seed_list, default=seed_list("0-4"))
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a method parameter (repeatable)")
    ap.add_argument("--explain", action="store_true", help="closures' and the path's stretches' errors instead")
    ap.add_argument("--stretch", type=int, default=15, help="--explain: nodes a stretch")
    a = ap.parse_args()
    reference = load_reference(a.log.parent / "reference.tum")
    settings = dict(s.split("=", 1) for s in a.set)
    settings["loop_correction"] = "true"
    rows: dict[str, list[str]] = {"filter alone": []}
    for seed in a.seeds:
        slam = build_method("gmapping", settings=settings, seed=seed)
        for frame in open_recording(a.log, ReadOptions()).frames(None):
            slam.feed(frame)

        def ate():
            t, p = slam.trajectory()
            assoc = associate(t, p, reference.times, reference.poses, max_gap=0.5)
            return absolute_trajectory_error(assoc)["translation_m"]["rmse"]

        if a.explain:
            explain(slam, reference, seed, a.stretch)
            continue
        rows["filter alone"].append(f"{ate():.3f}")
        base = {k: getattr(slam.params, k) for k in ("loop_correction_distance", "loop_correction_range",
                                                     "loop_correction_step_scale", "loop_correction_closure_scale")}
        own_info = type(slam).step_information
        real_init = frontend.GraphFrontend.__init__
        for name, over, info, backend in VARIANTS:
            for k, v in {**base, **over}.items():
                setattr(slam.params, k, v)
            if info is not None:
                slam.step_information = lambda steps, f=info: f(slam, steps)
            if backend is not None:
                def init(self, *args, _opts=backend, **kw):
                    real_init(self, *args, **kw)
                    self.backend = get_backend("spa", **_opts)
                frontend.GraphFrontend.__init__ = init
            try:
                slam._refined = None
                summary = slam.correct_loops()
            finally:
                frontend.GraphFrontend.__init__ = real_init
                slam.step_information = own_info.__get__(slam)
            rows.setdefault(name, []).append(f"{ate():.3f} ({summary['closure_count']})")
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    if a.explain:
        return
    print(f"gmapping on {a.log.name}, {' '.join(a.set)} loop_correction=true; ATE (m) against reference.tum "
          "(closures), seeds " + ", ".join(map(str, a.seeds)))
    print("| variant | " + " | ".join(f"seed {s}" for s in a.seeds) + " |")
    print("|---|" + "---|" * len(a.seeds))
    for name, vals in rows.items():
        print(f"| {name} | " + " | ".join(vals) + " |")


if __name__ == "__main__":
    main()
