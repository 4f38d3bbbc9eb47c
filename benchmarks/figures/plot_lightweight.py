#!/usr/bin/env python3
"""Draw docs/images/coreslam-paper-arena.png and crsm-paper-arena.png (see docs/methods/), and
crsm-mines.png, crsm-mines-unknown.png, crsm-mines-turn.png and crsm-mines-s2s.png when ../shared/datasets is there
(``benchmarks/figures/plot_lightweight.py mines-unknown``, ``mines-turn`` or ``mines-s2s`` draws only that one).

Each arena picture: the method's map of the simulated paper-arena (no odometry
used), its trajectory against the true one, and the per-scan match score and
CPU time from its diagnostics. crsm-mines.png: the mines logs mapped (same
mapper, 5 cm) along hector's and crsm's trajectories, with scan_consistency.

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_lightweight.py``.
The pictures depend only on the code and the fixed seeds.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.eval.trajectory_metrics import align_se2  # noqa: E402
from slam2d.core import se2  # noqa: E402
from slam2d.io import open_recording  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.io.tum import read_tum  # noqa: E402
from slam2d.methods import get_method  # noqa: E402
from slam2d.sim.simulate import SimulationParams, simulate, write_outputs  # noqa: E402

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"


def draw(name: str, frames, t_truth, p_truth) -> None:
    slam = get_method(name)(seed=0).run(frames)
    t, p = slam.trajectory()
    truth = np.stack([np.interp(t, t_truth, p_truth[:, k]) for k in range(2)], axis=-1)
    aligned = se2.compose(align_se2(p[:, :2], truth), p)
    ate = float(np.sqrt(np.mean(np.sum((aligned[:, :2] - truth) ** 2, axis=1))))
    grid = slam.map().crop_to_observed(margin=10)
    fig, (ax, diag) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.2, 1]})
    x0, y0, x1, y1 = grid.extent()
    ax.imshow(1.0 - grid.probability(), cmap="gray", origin="lower", extent=(x0, x1, y0, y1), vmin=0, vmax=1)
    # draw the estimate in the map's frame, the truth moved onto it
    back = se2.inverse(align_se2(p[:, :2], truth))
    truth_in_map = se2.transform_points(back, truth)
    ax.plot(truth_in_map[:, 0], truth_in_map[:, 1], color="black", lw=1.5, label="true path")
    ax.plot(p[:, 0], p[:, 1], color="tab:red", lw=1.0, label=f"{name} (ATE {ate * 100:.1f} cm)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{name} on the simulated paper-arena, no odometry")
    ax.legend(loc="upper right", fontsize=8)
    d = slam.diagnostics
    diag.plot(d.array("score"), color="tab:blue", lw=1.0, label="score (diagnostics 'score')")
    diag.set_xlabel("scan")
    diag.set_ylabel("score")
    cpu = diag.twinx()
    cpu.plot(1e3 * d.array("cpu_s"), color="tab:orange", lw=0.8, label="CPU time per scan")
    cpu.set_ylabel("CPU ms per scan")
    cpu.set_ylim(0, max(10.0, float(np.nanpercentile(1e3 * d.array("cpu_s")[1:], 99)) * 1.2))
    diag.set_title("per scan")
    lines = diag.get_lines() + cpu.get_lines()
    diag.legend(lines, [line.get_label() for line in lines], loc="lower right", fontsize=8)
    fig.tight_layout()
    out = IMAGES / f"{name}-paper-arena.png"
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    print(f"wrote {out} (ATE {ate:.3f} m)")


def _map_panel(ax, frames, t, p, title: str, *, path: bool) -> None:
    """The scans mapped along trajectory ``(t, p)`` (5 cm log-odds), optionally with the path, titled."""
    from slam2d.grids.mapping import map_from_poses
    from slam2d.grids.occupancy import GridParams

    grid, _ = map_from_poses(frames, t, p, params=GridParams(resolution=0.05))
    grid = grid.crop_to_observed(margin=10)
    x0, y0, x1, y1 = grid.extent()
    ax.imshow(1.0 - grid.probability(), cmap="gray", origin="lower", extent=(x0, x1, y0, y1), vmin=0, vmax=1)
    if path:
        ax.plot(p[:, 0], p[:, 1], color="tab:red", lw=0.6)
    ax.set_title(title, fontsize=10)
    ax.set_xticks([])
    ax.set_yticks([])


def _save(fig, name: str, dpi: int) -> None:
    fig.tight_layout()
    out = IMAGES / name
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    print(f"wrote {out}")


def draw_mines() -> None:
    """hector, crsm with the original's 40 rays and crsm with its defaults on mines-exp1/2 (seed 0, no odometry)."""
    from slam2d.eval import scan_consistency
    from slam2d.methods.runner import build_method

    data = Path(__file__).resolve().parents[2].parent / "shared" / "datasets"
    if not (data / "mines-exp2").is_dir():
        print(f"no {data}: crsm-mines.png not drawn")
        return
    runs = (("hector", {}), ("crsm", {"desired_number_of_picked_rays": "40", "dense_refine_rounds": "0",
                                      "unknown_rays": "score", "turn_sigma": "0"}),
            ("crsm", {}))
    titles = ("hector", "crsm, the original's 40 rays and scoring", "crsm, defaults")
    fig, axes = plt.subplots(2, 3, figsize=(13, 9))
    for row, ds in enumerate(("mines-exp1", "mines-exp2")):
        frames = list(open_recording(data / ds / f"{ds}.clf.gz").frames())
        for col, ((name, settings), title) in enumerate(zip(runs, titles)):
            slam = build_method(name, settings=settings, seed=0)
            slam.run(frames)
            t, p = slam.trajectory()
            score = scan_consistency(frames, t, p)["mean"]
            _map_panel(axes[row, col], frames, t, p, f"{ds}: {title}\nscan_consistency {score:.3f}", path=True)
    _save(fig, "crsm-mines.png", 70)


def draw_mines_unknown() -> None:
    """crsm-mines-unknown.png: hector, crsm scoring unknown cells as misses, unknown_rays=drop, and drop with 160
    rays on mines-exp1 (seed 2) and mines-exp2 (seed 0), each trajectory turned onto hector's (a rigid move: the
    map's shape is its own)."""
    from slam2d.eval import scan_consistency
    from slam2d.methods.runner import build_method

    data = Path(__file__).resolve().parents[2].parent / "shared" / "datasets"
    if not (data / "mines-exp2").is_dir():
        print(f"no {data}: crsm-mines-unknown.png not drawn")
        return
    # drawn without the turn test (turn_sigma=0), as measured in the section it illustrates
    runs = (("hector", {}, "hector"),
            ("crsm", {"unknown_rays": "score", "turn_sigma": "0"}, "crsm, unknown_rays=score"),
            ("crsm", {"unknown_rays": "drop", "turn_sigma": "0"}, "crsm, unknown_rays=drop (default)"),
            ("crsm", {"unknown_rays": "drop", "desired_number_of_picked_rays": "160", "turn_sigma": "0"},
             "drop, 160 rays"))
    fig, axes = plt.subplots(2, 4, figsize=(17, 9))
    for row, (ds, seed) in enumerate((("mines-exp1", 2), ("mines-exp2", 0))):
        frames = list(open_recording(data / ds / f"{ds}.clf.gz").frames())
        reference = None
        for col, (name, settings, title) in enumerate(runs):
            slam = build_method(name, settings=settings, seed=seed)
            slam.run(frames)
            t, p = slam.trajectory()
            score = scan_consistency(frames, t, p)["mean"]
            if reference is None:
                reference = p
            else:
                p = se2.compose(align_se2(p[:, :2], reference[:, :2]), p)
            seeded = "" if name == "hector" else f" (seed {seed})"
            _map_panel(axes[row, col], frames, t, p, f"{ds}: {title}{seeded}\nscan_consistency {score:.3f}",
                       path=False)
    _save(fig, "crsm-mines-unknown.png", 60)


def draw_mines_turn(scan_to_scan: bool = False) -> None:
    """crsm-mines-turn.png: hector, crsm without the turn test (turn_sigma=0) and with it against the still
    prediction (the default then) for seeds 0-2 on both mines logs, each trajectory turned onto hector's, with
    scan_consistency and the heading agreement. ``scan_to_scan``: crsm-mines-s2s.png, hector, the still
    prediction (seed 2) and the defaults (the scan-to-scan prediction) for seeds 0-2."""
    from slam2d.eval import scan_consistency
    from slam2d.eval.trajectory_metrics import heading_agreement
    from slam2d.methods.runner import build_method

    data = Path(__file__).resolve().parents[2].parent / "shared" / "datasets"
    if not (data / "mines-exp2").is_dir():
        print(f"no {data}: crsm-mines-turn.png not drawn")
        return
    still = {"turn_null": "still", "turn_sigma": "0.07"}
    if scan_to_scan:
        runs = [("hector", {}, 0, "hector"), ("crsm", still, 2, "crsm, still prediction, seed 2")] + [
            ("crsm", {}, seed, f"crsm, default (scan_to_scan), seed {seed}") for seed in (0, 1, 2)]
    else:
        runs = [("hector", {}, 0, "hector")] + [("crsm", {"turn_sigma": "0"}, 2, "crsm, turn_sigma=0, seed 2")] + [
            ("crsm", still, seed, f"crsm, still (turn_sigma=0.07), seed {seed}") for seed in (0, 1, 2)]
    fig, axes = plt.subplots(2, len(runs), figsize=(4.2 * len(runs), 9))
    for row, ds in enumerate(("mines-exp1", "mines-exp2")):
        frames = list(open_recording(data / ds / f"{ds}.clf.gz").frames())
        reference = None
        for col, (name, settings, seed, title) in enumerate(runs):
            slam = build_method(name, settings=settings, seed=seed)
            slam.run(frames)
            t, p = slam.trajectory()
            score = scan_consistency(frames, t, p)["mean"]
            if reference is None:
                reference = (t, p)
                label = f"scan_consistency {score:.3f}"
            else:
                h = heading_agreement(t, p, *reference)["heading_p95_deg"]
                label = f"scan_consistency {score:.3f}, heading p95 {h:.1f} deg"
                p = se2.compose(align_se2(p[:, :2], reference[1][:, :2]), p)
            _map_panel(axes[row, col], frames, t, p, f"{ds}: {title}\n{label}", path=False)
    _save(fig, "crsm-mines-s2s.png" if scan_to_scan else "crsm-mines-turn.png", 60)


def main() -> None:
    if sys.argv[1:] == ["mines-unknown"]:
        draw_mines_unknown()
        return
    if sys.argv[1:] == ["mines-turn"]:
        draw_mines_turn()
        return
    if sys.argv[1:] == ["mines-s2s"]:
        draw_mines_turn(scan_to_scan=True)
        return
    with tempfile.TemporaryDirectory() as tmp:
        sim = simulate("paper-arena", SimulationParams(seed=1))
        write_outputs(sim, Path(tmp))
        frames = list(open_recording(Path(tmp) / "recording.log.gz").frames())
        t_truth, p_truth = read_tum(Path(tmp) / "truth.tum")
    for name in ("coreslam", "crsm"):
        draw(name, frames, t_truth, p_truth)
    draw_mines()
    draw_mines_unknown()
    draw_mines_turn()
    draw_mines_turn(scan_to_scan=True)


if __name__ == "__main__":
    main()
