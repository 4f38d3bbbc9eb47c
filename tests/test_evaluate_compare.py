"""`slam2d evaluate` and `slam2d compare`: metrics on runs, methods side by side, failures contained."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.core import se2
from slam2d.eval.evaluate import METRIC_COLUMNS, evaluate_run, load_run, load_truth
from slam2d.io.relations import relations_from_trajectory, write_relations
from slam2d.io.tum import read_tum, write_tum


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "paper-arena", "--out", str(out), "--duration", "25", "--seed", "11"]) == 0
    return out


@pytest.fixture(scope="module")
def runs(sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    data = str(sim / "recording.log.gz")
    assert main(["run", "odometry", data, "--out", str(out / "odometry")]) == 0
    assert main(["run", "known-poses", data, "--out", str(out / "known"), "--set", f"poses={sim / 'truth.tum'}"]) == 0
    return out


# --------------------------------------------------------------------------- evaluate


def test_known_poses_scores_zero_trajectory_error_and_a_sharp_map(sim, runs):
    truth = load_truth(sim)
    ev = evaluate_run(load_run(runs / "known"), truth)
    assert ev["trajectory"]["ate"]["translation_m"]["rmse"] < 1e-9
    assert ev["trajectory"]["rpe_per_frame"]["translation_m"]["max"] < 1e-9
    assert np.allclose(ev["alignment"], 0.0, atol=1e-9)
    # the map drawn at the true poses lies on the true walls (range noise only)
    assert ev["map_truth"]["truth_to_map_m"]["median"] < 0.05
    assert ev["map_truth"]["precision"] > 0.9
    assert ev["cost"]["scans"] > 200 and ev["cost"]["real_time_factor"] > 1


def test_odometry_scores_worse_than_known_poses(sim, runs):
    truth = load_truth(sim)
    odo = evaluate_run(load_run(runs / "odometry"), truth)
    known = evaluate_run(load_run(runs / "known"), truth)
    assert odo["trajectory"]["ate"]["translation_m"]["rmse"] > 0.01
    assert odo["map_truth"]["map_to_truth_m"]["mean"] > known["map_truth"]["map_to_truth_m"]["mean"]
    assert odo["map_truth"]["precision"] < known["map_truth"]["precision"]


def test_a_moved_trajectory_scores_zero_after_alignment_and_the_shift_before(sim, runs, tmp_path):
    t, p = read_tum(sim / "truth.tum")
    moved = se2.compose(np.array([2.0, -1.0, 0.0]), p)  # a pure 2.236 m shift
    write_tum(tmp_path / "moved.tum", t, moved)
    ev = evaluate_run(load_run(tmp_path / "moved.tum"), load_truth(sim))
    ate = ev["trajectory"]["ate"]
    assert ate["translation_m"]["rmse"] < 1e-9
    assert ate["before_alignment"]["translation_m"]["rmse"] == pytest.approx(np.hypot(2.0, 1.0), abs=1e-9)


def test_relations_built_from_the_truth_score_zero_on_the_truth(sim, runs, tmp_path):
    t, p = read_tum(sim / "truth.tum")
    pairs = np.stack([np.arange(0, len(t) - 10, 7), np.arange(10, len(t), 7)[: len(range(0, len(t) - 10, 7))]], 1)
    rel = write_relations(tmp_path / "r.relations", *_rel_arrays(relations_from_trajectory(t, p, pairs)))
    assert main(["evaluate", str(runs / "known"), "--relations", str(rel), "--out", str(tmp_path / "e.json")]) == 0
    ev = json.loads((tmp_path / "e.json").read_text())
    assert ev["relations"]["used"] == len(pairs)
    assert ev["relations"]["translation_abs_m"]["mean"] < 1e-9


def _rel_arrays(rel):
    return rel.t1, rel.t2, rel.motion


def test_evaluate_command_writes_json_and_prints_a_table(sim, runs, capsys):
    assert main(["evaluate", str(runs / "odometry"), "--truth", str(sim)]) == 0
    text = capsys.readouterr().out
    assert "ATE" in text and "Map error" in text and "Time/scan" in text
    ev = json.loads((runs / "odometry" / "evaluation.json").read_text())
    for col in METRIC_COLUMNS:
        if col.key[0] in ("relations",):
            continue
        assert col.value(ev) is not None, col.label


def test_evaluate_against_a_map_only_aligns_by_icp(sim, runs, tmp_path):
    assert main(["evaluate", str(runs / "known"), "--truth-map", str(sim / "truth-map.yaml"),
                 "--out", str(tmp_path / "e.json")]) == 0
    ev = json.loads((tmp_path / "e.json").read_text())
    assert ev["alignment_source"] == "map" and "trajectory" not in ev
    assert np.hypot(*ev["alignment"][:2]) < 0.05 and abs(ev["alignment"][2]) < 0.01


def test_evaluate_bad_input(sim, runs, tmp_path, capsys):
    no_traj = tmp_path / "truthless"
    no_traj.mkdir()
    shutil.copy(sim / "truth-map.yaml", no_traj)
    assert main(["evaluate", str(runs / "known"), "--truth", str(no_traj)]) == 2
    err = capsys.readouterr().err
    assert "truth.tum is missing" in err and str(no_traj) in err

    t, p = read_tum(sim / "truth.tum")
    write_tum(tmp_path / "late.tum", t + 500.0, p)
    assert main(["evaluate", str(runs / "known"), "--reference", str(tmp_path / "late.tum")]) == 2
    err = capsys.readouterr().err
    assert "do not overlap in time" in err and err.count("\n") == 1

    assert main(["evaluate", str(tmp_path / "nothing"), "--truth", str(sim)]) == 2
    assert "no such file" in capsys.readouterr().err


# --------------------------------------------------------------------------- compare


def test_compare_both_baselines_with_truth(sim, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", str(sim / "recording.log.gz"), "--methods", "odometry,known-poses",
                 "--truth", str(sim), "--out", str(out)]) == 0
    for m in ("odometry", "known-poses"):
        assert (out / "runs" / m / "run.json").is_file()
        assert (out / "runs" / m / "evaluation.json").is_file()
    html = (out / "report.html").read_text()
    md = (out / "report.md").read_text()
    assert "odometry" in html and "known-poses" in html and "known-poses" in md
    known = json.loads((out / "runs" / "known-poses" / "run.json").read_text())
    assert known["params"]["poses"].endswith("truth.tum")  # filled in from --truth


def test_a_method_that_raises_midway_fails_alone(sim, tmp_path, capsys):
    from dataclasses import dataclass

    from slam2d.grids.occupancy import GridParams, OccupancyGrid
    from slam2d.methods import SlamMethod
    from slam2d.methods.registry import _REGISTRY, register

    @dataclass
    class BrokenParams(GridParams):
        pass

    class Broken(SlamMethod):
        name = "test-broken"
        Params = BrokenParams

        def __init__(self, params=None, **kw):
            super().__init__(params, **kw)
            self.grid = OccupancyGrid(self.params)

        def update(self, frame):
            if frame.index == 50:
                raise RuntimeError("matcher diverged at scan 50")

        def current_pose(self):
            return np.zeros(3)

        def map(self):
            return self.grid

    register(Broken)
    try:
        out = tmp_path / "cmp"
        status = main(["compare", str(sim / "recording.log.gz"), "--methods", "test-broken,odometry",
                       "--truth", str(sim), "--out", str(out)])
        assert status == 0  # one method finished
        printed = capsys.readouterr().out
        assert "test-broken: FAILED" in printed and "matcher diverged at scan 50" in printed
        assert (out / "runs" / "odometry" / "run.json").is_file()
        assert not (out / "runs" / "test-broken" / "run.json").exists()
        html = (out / "report.html").read_text()
        assert "matcher diverged at scan 50" in html and "failed" in html.lower()
    finally:
        _REGISTRY.pop("test-broken", None)


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["--methods", "odometry,gmaping"], ["unknown method 'gmaping'", "known-poses"]),
        (["--methods", "odometry", "--set", "nope=1"], ["no method compared has a parameter 'nope'"]),
        (["--methods", "odometry", "--set", "hector.resolution=1"], ["'hector' is not one of the methods"]),
        (["--methods", "odometry", "--set", "resolution=-3"], ["resolution", "below the minimum"]),
        (["--methods", "odometry,odometry"], ["listed twice"]),
        (["--methods", "known-poses"], ["known-poses needs a trajectory"]),
        (["--methods", "odometry", "--truth", "TRUTHLESS"], ["truth.tum is missing"]),
        (["--methods", "odometry", "--reference", "LATE"], ["do not overlap in time"]),
    ],
)
def test_compare_bad_input(sim, tmp_path, capsys, extra, expected):
    truthless = tmp_path / "truthless"
    truthless.mkdir()
    t, p = read_tum(sim / "truth.tum")
    write_tum(tmp_path / "late.tum", t + 500.0, p)
    subst = {"TRUTHLESS": str(truthless), "LATE": str(tmp_path / "late.tum")}
    argv = ["compare", str(sim / "recording.log.gz"), "--out", str(tmp_path / "cmp"), *[subst.get(a, a) for a in extra]]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("slam2d: error:") and "\n" not in err, err
    for piece in expected:
        assert piece in err, err
    assert not (tmp_path / "cmp" / "report.html").exists()


def test_a_bare_trajectory_without_truth_is_an_error(sim, capsys):
    assert main(["evaluate", str(sim / "truth.tum")]) == 2
    assert "nothing to evaluate" in capsys.readouterr().err
