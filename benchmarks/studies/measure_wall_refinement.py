#!/usr/bin/env python3
"""karto's wall bundle adjustment (`wall_refinement`) on the simulated URG-04LX recordings: several settings per karto run.

    .venv/bin/python benchmarks/studies/measure_wall_refinement.py [--world office] [--laser urg-04lx] [--seeds 0,1,2] \
        [--base "key=value ..."] [--from-truth] [--oracle] ["key=value ..." ...]

Per seed, karto runs once (the `karto-sim-lasers` recordings, written once under --cache as
benchmarks/studies/measure_gmapping_proposal.py writes them; `--base` settings, `wall_end_landmarks` false unless
given) with the refinement held back; then the refinement runs on the finished graph once per
setting (each a quoted list of key=value, "" = the defaults), from the same poses, exactly as
`GraphSlam.finish` runs it. Printed per seed: karto's ATE / map error (m, judged as `slam2d
evaluate --truth`), then per setting ATE / map error, walls, and the refinement's CPU seconds; at
the end the mean ATE per setting. The same numbers as benchmarks/studies/measure_wall_end_revisits.py gives with
`wall_refinement=true` and the setting, at one karto run per seed.

With ``--from-truth`` each setting also runs from the *true* poses of the frames (instead of karto's)
and prints that ATE: what the refinement's own optimum is worth with the readings it uses, apart
from where it starts.

Diagnostics of the association (a setting's ``freeze=A,B,...``, not a parameter; docs/methods/what-was-tried.md,
*karto, is it the wall refinement's association?*): ``walls`` / ``ends`` make the segment-to-wall / end-to-landmark association
once, in the first round (at the start poses), and keep it for every round; ``oracle-walls`` / ``oracle-ends``
take it from the simulator's truth instead (each segment on the true straight line most of its beams lie on at
the true poses, each wall-end sighting at the true wall end within 0.1 m of it); ``report`` prints how the
refinement's own association at the true poses compares with the truth's.

A setting's ``ends_model=bearing`` (not a parameter) gives every wall-end sighting the oracle's model of it: a
bearing over the beam gap, perpendicular to the ray, instead of the detector's point covariance; ``ends_model=across:S``
scales the point's across-wall sigma by S.

``--oracle`` (no karto run; docs/methods/what-was-tried.md, *karto, which inputs hold the last centimetres*):
per seed the oracle smoother (:func:`slam2d.eval.accuracy_bound.oracle_smoother`) on the recording, with all its
readings and restricted (its ``beam_mask`` / ``edge_mask``) to the beams of the refinement's segments and the wall
ends its detector finds (karto's parameters and each setting), and why the detector misses the true wall ends it
misses, with what each kind is worth added back.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from slam2d.eval.evaluate import evaluate_run, load_run, load_truth
from slam2d.graph import wall_refinement as wr
from slam2d.io.tum import write_tum
from slam2d.methods.runner import build_method, run_method
from slam2d.report.map_outputs import write_map_outputs

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_proposal import cached_recording  # noqa: E402


def _oracle(world_name: str, true_frames: np.ndarray):
    """Associations from the simulator's truth (diagnostics, ``freeze=oracle-walls,oracle-ends``): each segment's
    wall is the true straight line (collinear walls of the world as one) that most of its beams, placed at the
    true frame poses, lie on (none when under 80 % of them do); each wall-end sighting's landmark is the true
    wall end point within 0.1 m of it (none: a detection where no wall ends). Also a function printing how the
    refinement's own association at the true poses compares with them."""
    from slam2d.eval.accuracy_bound import _hit_surfaces
    from slam2d.graph.wall_refinement import associate_ends, associate_segments, place_points
    from slam2d.sim.world import load_world

    w = load_world(world_name)
    seg = np.asarray(w.segments, np.float64)
    circles = np.asarray(w.circles, np.float64).reshape(-1, 3)
    t = np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0]) + 0.5 * np.pi
    t = np.mod(t, np.pi)
    dd = np.cos(t) * seg[:, 0] + np.sin(t) * seg[:, 1]
    _, line = np.unique(np.round(np.stack([t, dd], 1), 4), axis=0, return_inverse=True)
    line = np.concatenate([line.ravel(), line.max() + 1 + np.arange(circles.shape[0])])  # a circle is its own
    verts, vert_id = np.unique(np.round(np.concatenate([seg[:, :2], seg[:, 2:]]), 4), axis=0, return_inverse=True)

    def surfaces(pts):
        sf = np.empty(pts.shape[0], np.int64)
        al = np.empty(pts.shape[0])
        _hit_surfaces(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), seg, circles, sf, al)
        return sf

    def seg_lines(segs):
        bl = line[surfaces(place_points(true_frames[segs.node], segs.q))]
        ns = segs.seg_node.size
        out = np.full(ns, -1, np.int64)
        order = np.argsort(segs.segment, kind="stable")
        bounds = np.searchsorted(segs.segment[order], np.arange(ns + 1))
        for k in range(ns):
            v = bl[order[bounds[k]: bounds[k + 1]]]
            if v.size:
                vals, cnt = np.unique(v, return_counts=True)
                if cnt.max() >= 0.8 * v.size:
                    out[k] = vals[np.argmax(cnt)]
        return out

    def walls(segs):
        out = seg_lines(segs)
        _, idx = np.unique(out[out >= 0], return_inverse=True)
        res = np.full(out.size, -1, np.int64)
        res[out >= 0] = idx.ravel()
        return res

    def end_points(e):
        world = place_points(true_frames[e.node], e.z)
        dist = np.hypot(world[:, None, 0] - verts[None, :, 0], world[:, None, 1] - verts[None, :, 1])
        near = np.argmin(dist, 1)
        return np.where(dist[np.arange(near.size), near] < 0.1, near, -1)

    def report(segs, e, p):
        """The refinement's association at the true poses against the truth's."""
        tl = seg_lines(segs)
        sw = associate_segments(segs, true_frames, p)
        cnt = np.bincount(segs.segment, minlength=sw.size)
        mixed = wrong = 0
        for k in np.unique(sw[sw >= 0]):
            mine = sw == k
            vals, c = np.unique(tl[mine], return_counts=True)
            major = vals[np.argmax(np.bincount(np.searchsorted(vals, tl[mine]), cnt[mine]))]
            bad = mine & (tl != major)
            wrong += int(cnt[bad].sum())
            mixed += int(bad.any())
        used = int(cnt[sw >= 0].sum())
        txt = (f"walls at the truth: {int(sw.max()) + 1} walls, {used} beams, {wrong} beams "
               f"({100.0 * wrong / max(used, 1):.1f} %) on segments not on the wall's main true line, in {mixed} walls; "
               f"segments on no single true line {int((tl < 0).sum())} of {tl.size}")
        if e is not None and len(e):
            lm = associate_ends(e, true_frames, p.wall_refinement_end_gate, p.wall_refinement_minimum_nodes)
            tv = end_points(e)
            on = lm >= 0
            mixed_l = wrong_l = 0
            for k in np.unique(lm[on]):
                v = tv[lm == k]
                vals, c = np.unique(v, return_counts=True)
                major = vals[np.argmax(c)]
                wrong_l += int((v != major).sum())
                mixed_l += int((v != major).any())
            txt += (f"; ends at the truth: {int(on.sum())} sightings used in {int(lm.max()) + 1} landmarks, "
                    f"{int((on & (tv < 0)).sum())} of them at no true wall end, {wrong_l} not at their landmark's "
                    f"main true end (in {mixed_l} landmarks); true-end sightings {int((tv >= 0).sum())} of {len(e)}")
        return txt

    def ends(e):
        tv = end_points(e)
        # One sighting per frame and end (the nearest), ends seen from 3 frames or more.
        lm = np.full(tv.size, -1, np.int64)
        world = place_points(true_frames[e.node], e.z)
        err = np.where(tv >= 0, np.hypot(*(world - verts[np.maximum(tv, 0)]).T), np.inf)
        order = np.lexsort((err, tv, e.node))
        seen = set()
        for i in order:
            if tv[i] >= 0 and (int(e.node[i]), int(tv[i])) not in seen:
                seen.add((int(e.node[i]), int(tv[i])))
                lm[i] = tv[i]
        vals, cnt = np.unique(lm[lm >= 0], return_counts=True)
        keep = vals[cnt >= 3]
        res = np.full(lm.size, -1, np.int64)
        ok = np.isin(lm, keep)
        res[ok] = np.searchsorted(keep, lm[ok])
        return res

    return walls, ends, report


def _refinement_inputs(sim, p):
    """The beams and wall ends the wall refinement uses on a simulated recording, as ``(scans, beams)`` masks for
    :func:`slam2d.eval.accuracy_bound.oracle_smoother`: ``beams``, the returns on its extracted segments (every
    scan's, as ``refine_path`` extracts them: no sensor model, karto's range threshold) whose wall is kept at the
    *true* poses (seen from enough scans); ``detected``, the nearer beam of every wall end its detector reports
    (``scan_wall_ends``' settings); ``ends``, those of them that join a landmark at the true poses (seen from enough
    scans)."""
    from slam2d.graph.wall_refinement import (associate_ends, associate_segments, floored_sigmas, scan_segments,
                                              scan_wall_ends)
    from slam2d.matching.wall_ends import detect_wall_ends

    truth = np.asarray(sim.truth)[np.asarray(sim.scan_indices)]
    scans = list(sim.scans)
    n, b = len(scans), scans[0].num_beams
    segs = scan_segments(scans, [None] * n, p, p.range_threshold)
    on = associate_segments(segs, truth, p)[segs.segment] >= 0
    # each segment beam's index, from its point (base frame) through the laser's mount
    m = np.asarray(scans[0].mount, np.float64)
    c, s_ = np.cos(m[2]), np.sin(m[2])
    dx, dy = segs.q[:, 0] - m[0], segs.q[:, 1] - m[1]
    bearing = np.arctan2(-s_ * dx + c * dy, c * dx + s_ * dy)
    ang = np.asarray(scans[0].angles)
    beam = np.clip(np.rint((bearing - ang[0]) / (ang[1] - ang[0])).astype(np.int64), 0, b - 1)
    beams = np.zeros((n, b), bool)
    beams[segs.node[on], beam[on]] = True
    # the detector's nearer beam per sighting, in scan_wall_ends' order
    near = []
    for scan in scans:
        sig = floored_sigmas(None, np.arange(scan.num_beams), p.wall_end_range_sigma)  # as scan_wall_ends
        near.append(detect_wall_ends(scan, sig, jump=p.wall_refinement_end_jump, run=p.wall_refinement_end_run,
                                     max_incidence=p.wall_refinement_end_incidence,
                                     open_incidence=p.wall_refinement_end_open_incidence,
                                     max_range=p.wall_end_maximum_range, bearing_sigma=p.wall_end_bearing_sigma).beams)
    e = scan_wall_ends(scans, [None] * n, p)
    k = np.concatenate(near)
    assert k.size == len(e)
    detected = np.zeros((n, b), bool)
    detected[e.node, k] = True
    lm = associate_ends(e, truth, p.wall_refinement_end_gate, p.wall_refinement_minimum_nodes)
    ends = np.zeros((n, b), bool)
    ends[e.node[lm >= 0], k[lm >= 0]] = True
    return beams, detected, ends


def _oracle_table(world: str, laser: str, seeds: list[int], settings: dict) -> None:
    """``--oracle``: the oracle smoother (the truth's associations, every reading solved as the accuracy bound
    counts it) on each seed's recording, with all its readings and restricted to the refinement's inputs."""
    from slam2d.eval.accuracy_bound import laser_information, oracle_smoother, setup_from_simulation
    from slam2d.sim.simulate import SimulationParams, simulate

    p = build_method("karto", settings={**settings, "wall_refinement": "true"}).params
    for seed in seeds:
        sim = simulate(world, SimulationParams(duration=120.0 if world == "office" else None, seed=seed, laser=laser))
        beams, detected, ends = _refinement_inputs(sim, p)
        info = laser_information(setup_from_simulation(sim))
        shape = beams.shape
        edge_beams = np.zeros(shape[0] * shape[1], bool)
        edge_beams[info.beam[info.beams_used:]] = True
        edge_beams = edge_beams.reshape(shape)
        none = np.zeros(shape, bool)
        # Why the detector misses a true wall end (a beam gap the oracle counts): its nearer beam returned nothing;
        # the next two beams are not both `wall_refinement_end_jump` farther; a return among the
        # `wall_refinement_end_run` beams before it is lost; else one of the later checks (incidence, open end,
        # continuation of the ranges).
        rng = np.stack([np.asarray(sc.ranges, np.float64) for sc in sim.scans])
        rr = np.where(np.isfinite(rng), rng, np.inf)
        gap_beam = info.beam[info.beams_used:]
        si, k = gap_beam // shape[1], gap_beam % shape[1]
        def at(j):
            return rr[si, np.clip(j, 0, shape[1] - 1)]
        side = np.where(at(k + 1) >= at(k - 1), 1, -1)
        missed = ~(detected[si, k] | detected[si, np.clip(k + 1, 0, shape[1] - 1)] | detected[si, np.clip(k - 1, 0, shape[1] - 1)])
        lost = ~np.isfinite(rr[si, k])
        small = ~lost & ~((at(k + side) > rr[si, k] + p.wall_refinement_end_jump)
                          & (at(k + 2 * side) > rr[si, k] + p.wall_refinement_end_jump))
        run = ~lost & ~small & ~np.all([np.isfinite(at(k - j * side)) for j in range(1, p.wall_refinement_end_run)], 0)
        why = {"near beam lost": missed & lost, "jump": missed & small, "lost return in the run": missed & run,
               "later checks": missed & ~lost & ~small & ~run}

        def plus(sel):
            m = ends.copy()
            m[si[sel], k[sel]] = True
            return m
        rows = [("(a) all beams, all ends", None, None), ("(b) segment beams, all ends", beams, None),
                ("(c) all beams, detected ends", None, ends), ("(c') all beams, no ends", None, none),
                ("(d) segment beams, detected ends", beams, ends), ("(d') segment beams, no ends", beams, none),
                ("(d) and the ends missed for the jump", beams, plus(why["jump"])),
                ("(d) and those missed for a lost return in the run", beams, plus(why["lost return in the run"])),
                ("(d) and those missed by the later checks", beams, plus(why["later checks"]))]
        out = []
        for name, bm, em in rows:
            r = oracle_smoother(sim, beam_mask=bm, edge_mask=em)
            out.append(f"{name} {r['ate_m']:.3f}")
        print(f"{world} {laser} seed {seed}: oracle ATE (m): " + ", ".join(out)
              + f"; beams {int(info.beams_used)} of which on segments {int(beams.sum())}; true wall-end gaps "
              f"{int(info.edges_used)}, detector's sightings {int(detected.sum())} ({int((detected & edge_beams).sum())} "
              f"at a true end gap's near beam), used {int(ends.sum())} ({int((ends & edge_beams).sum())}); true gaps "
              "missed: " + ", ".join(f"{k_} {int(v.sum())}" for k_, v in why.items()), flush=True)


_SCAN_WALL_ENDS = wr.scan_wall_ends


def _bearing_ends(scans, sigmas, p, **kw):
    """Diagnostics (a setting's ``ends_model=bearing``, not a parameter): the wall-end sightings of
    ``scan_wall_ends`` with the oracle's model of them: a bearing over the beam gap (``gap^2 / 12`` of the scan's
    angle increment) perpendicular to the ray from the laser, instead of the point's along-wall / across-wall
    covariance (nothing along the ray but a 10 m sigma, to keep it invertible)."""
    e = _SCAN_WALL_ENDS(scans, sigmas, p, **kw)
    if not len(e):
        return e
    m = np.asarray(scans[0].mount, np.float64)
    da = float(abs(scans[0].angles[1] - scans[0].angles[0]))
    d = e.z - m[:2]
    r = np.hypot(d[:, 0], d[:, 1])
    u = d / r[:, None]
    v = np.stack([-u[:, 1], u[:, 0]], 1)
    info = (v[:, :, None] * v[:, None, :]) / (r * r * da * da / 12.0)[:, None, None] + (u[:, :, None] * u[:, None, :]) / 100.0
    return wr.EndSightings(e.node, e.z, info)


def _across_ends(scale: float):
    """Diagnostics (``ends_model=across:S``, not a parameter): the detector's sightings with their across-wall
    sigma (the covariance's smaller axis) times S, the along-wall one kept."""
    def ends(scans, sigmas, p, **kw):
        e = _SCAN_WALL_ENDS(scans, sigmas, p, **kw)
        if not len(e):
            return e
        w, vec = np.linalg.eigh(e.information)  # ascending: the along-wall axis first, the across-wall one last
        w[:, 1] /= scale * scale
        return wr.EndSightings(e.node, e.z, np.einsum("kij,kj,klj->kil", vec, w, vec))
    return ends


def _judge(slam, truth, out: Path) -> tuple[float, float]:
    out.mkdir(parents=True, exist_ok=True)
    t, p = slam.trajectory()
    write_tum(out / "trajectory.tum", t, p)
    write_map_outputs(slam.map(), out)
    e = evaluate_run(load_run(out), truth)
    return e["trajectory"]["ate"]["translation_m"]["rmse"], e["map_truth"]["truth_to_map_m"]["mean"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", default="/tmp/slam2d-proposal")
    ap.add_argument("--base", default="", help="karto settings of the run, key=value separated by spaces")
    ap.add_argument("--from-truth", action="store_true", help="also refine from the true frame poses")
    ap.add_argument("--oracle", action="store_true",
                    help="no karto run: the oracle smoother on each recording, all readings and the refinement's")
    ap.add_argument("settings", nargs="*", help='refinement settings, one quoted "key=value ..." each ("" = defaults)')
    a = ap.parse_args()
    base = dict(s.split("=", 1) for s in a.base.split())
    if a.oracle:
        for v in a.settings or [""]:
            _oracle_table(a.world, a.laser, [int(s) for s in a.seeds.split(",")],
                          {**base, **dict(s.split("=", 1) for s in v.split())})
        return
    base.setdefault("wall_end_landmarks", "false")
    variants = [dict(s.split("=", 1) for s in v.split()) for v in (a.settings or [""])]
    variant_names = [s or "defaults" for s in (a.settings or [""])]
    means: dict[int, list[float]] = {}
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = cached_recording(a.cache, a.world, a.laser, seed)
        truth = load_truth(sim_dir)
        run_dir = Path(a.cache) / f"run-refine-{a.world}-{a.laser}-{seed}"
        slam = build_method("karto", settings={**base, "wall_refinement": "true"})
        slam.refine_walls = lambda: None  # held back: run below, once per setting
        run_method(slam, sim_dir / "recording.log.gz", run_dir)
        del slam.refine_walls
        fe = slam.frontend
        poses0 = fe.graph.poses.copy()
        done = len(fe.optimizations)
        e = evaluate_run(load_run(run_dir), truth)
        line = [f"karto {e['trajectory']['ate']['translation_m']['rmse']:.3f} / "
                f"{e['map_truth']['truth_to_map_m']['mean']:.3f}"]
        times, _ = slam.trajectory()
        true_frames = truth.poses[np.clip(np.searchsorted(truth.times, times), 0, len(truth.times) - 1)]
        for k, v in enumerate(variants):
            v = dict(v)
            wr._FREEZE = set(v.pop("freeze", "").replace("+", ",").split(",")) - {""}
            model = v.pop("ends_model", "point")
            wr.scan_wall_ends = (_bearing_ends if model == "bearing" else
                                 _across_ends(float(model.split(":")[1])) if model.startswith("across:") else _SCAN_WALL_ENDS)
            oracle_w, oracle_e, report = _oracle(a.world, true_frames)
            wr._GIVEN = {}
            if "oracle-walls" in wr._FREEZE:
                wr._GIVEN["walls"] = oracle_w
            if "oracle-ends" in wr._FREEZE:
                wr._GIVEN["ends"] = oracle_e
            if "report" in wr._FREEZE:
                wr._GIVEN["report"] = report
            slam.params = fe.params = build_method("karto", settings={**base, **v, "wall_refinement": "true"}).params
            fe.graph.poses = poses0
            slam._refined = None
            del fe.optimizations[done:]
            cpu = time.process_time()
            slam.refine_walls()
            cpu = time.process_time() - cpu
            if "report_text" in wr._GIVEN:
                print(wr._GIVEN.pop("report_text"), flush=True)
            walls = slam.diagnostics.summary["wall_refinement"]["walls"]
            objective = slam.diagnostics.summary["wall_refinement"]["objective_after"]
            ate, err = _judge(slam, truth, Path(a.cache) / f"run-refine-variant-{a.world}-{seed}")
            means.setdefault(k, []).append(ate)
            text = f"[{variant_names[k]}] {ate:.3f} / {err:.3f} ({walls:.0f} walls, objective {objective:.6g}, cpu {cpu:.1f} s"
            if a.from_truth:
                # The same refinement started at the true poses of the frames (and of the nodes among them).
                node_frame = np.asarray(slam._frame_node)
                fe.graph.poses = true_frames[node_frame >= 0]
                slam._refined = None
                del fe.optimizations[done:]
                slam.trajectory = lambda: (times, true_frames.copy())
                slam.refine_walls()
                del slam.trajectory
                ate_t, _ = _judge(slam, truth, Path(a.cache) / f"run-refine-truth-{a.world}-{seed}")
                objective = slam.diagnostics.summary["wall_refinement"]["objective_after"]
                means.setdefault(-1 - k, []).append(ate_t)
                text += f"; from the truth {ate_t:.3f}, objective {objective:.6g}"
            line.append(text + ")")
        print(f"{a.world} {a.laser} seed {seed}: " + ", ".join(line), flush=True)
    for k, v in enumerate(variants):
        extra = f", from the truth {np.mean(means[-1 - k]):.3f}" if a.from_truth else ""
        print(f"mean ATE {np.mean(means[k]):.3f} m{extra}: {variant_names[k]}")


if __name__ == "__main__":
    main()
