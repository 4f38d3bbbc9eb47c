"""The reference-free verdict: a map that disagrees with itself, shrank or was drawn twice ranks below the true one."""

from __future__ import annotations

import json

import numpy as np
import pytest

from _room import boxes_grid
from slam2d.core.frames import Frame
from slam2d.core.scan import make_scan
from slam2d.eval.self_consistency import (
    ConsistencyParams,
    cross_validated_consistency,
    judge_trajectory,
    place_scans,
    rank_runs,
    verdict_sentence,
)
from slam2d.grids import cast_rays

RES = 0.02
ORIGIN = (-0.5, -0.5)
ANGLES = np.radians(np.arange(-120.0, 120.0, 1.0))


def _room() -> np.ndarray:
    """A 10 m x 6 m room with two pillars and a wall stub, at 2 cm."""
    return boxes_grid((360, 560), ORIGIN, RES, [(0.0, 0.0, 10.1, 0.1), (0.0, 6.0, 10.1, 6.1), (0.0, 0.0, 0.1, 6.1),
                                                (10.0, 0.0, 10.1, 6.1), (3.0, 2.8, 3.4, 3.2), (7.0, 2.5, 7.2, 3.5),
                                                (5.0, 0.0, 5.1, 1.2)])


@pytest.fixture(scope="module")
def laps():
    """Two laps round the room (about 40 m), a scan every 0.2 m; the odometry is the true path."""
    occ = _room()
    s = np.linspace(0.0, 4.0 * np.pi, 200)
    path = np.column_stack([5.0 + 3.6 * np.cos(s), 3.0 + 1.9 * np.sin(s), s + np.pi / 2])
    frames = []
    for i, pose in enumerate(path):
        ranges = cast_rays(occ, *ORIGIN, RES, *pose, ANGLES, 5.6)
        frames.append(Frame(i, make_scan(0.1 * i, ranges, ANGLES[0], ANGLES[1] - ANGLES[0], 0.05, 5.6), pose.copy()))
    return frames, np.arange(len(path)) * 0.1, path


def test_the_true_path_agrees_with_itself(laps):
    frames, times, path = laps
    judged = judge_trajectory(frames, times, path)
    assert judged["scans"] == len(frames)
    assert judged["scans_judged"] > 0.9 * len(frames)  # the second lap meets the first everywhere
    assert judged["inconsistency"] < 0.01
    assert judged["travel_scale"] == pytest.approx(1.0, abs=1e-9)


def test_a_second_lap_drawn_aside_is_contradicted(laps):
    frames, times, path = laps
    moved = path.copy()
    moved[100:, :2] += [0.25, 0.15]  # the second lap drawn 0.3 m off: every wall twice
    good = judge_trajectory(frames, times, path)
    bad = judge_trajectory(frames, times, moved)
    assert bad["inconsistency"] > 10 * max(good["inconsistency"], 0.002)
    # the disagreeing beam ends are where the doubled walls are: near the room's walls, inside the room
    marks = np.asarray(bad["disagreements"])
    assert len(marks) > 100
    assert np.all((marks[:, 0] > -1.0) & (marks[:, 0] < 11.0) & (marks[:, 1] > -1.0) & (marks[:, 1] < 7.0))
    # and the per-scan curve puts the disagreement in the second lap (the first is judged against it too,
    # so both laps disagree; the scans of the first lap before the shift, though, agree among themselves)
    per = bad["per_scan"]
    assert sum(per["disagreeing"]) > 0 and len(per["frame"]) == len(frames)


def test_a_turn_that_bends_the_map_is_contradicted_more_the_larger_it_is(laps):
    frames, times, path = laps
    values = []
    for degrees in (0.0, 2.0, 6.0):
        bent = path.copy()
        c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
        rel = bent[100:, :2] - path[100, :2]
        bent[100:, :2] = path[100, :2] + rel @ np.array([[c, s], [-s, c]])
        bent[100:, 2] += np.radians(degrees)
        values.append(judge_trajectory(frames, times, bent)["inconsistency"])
    assert values[0] < values[1] < values[2]


def test_the_scans_near_in_travel_are_left_out(laps):
    """A scan judged against its neighbours proves nothing: with one lap only, nothing is judged."""
    frames, times, path = laps
    rays = place_scans(frames[:95], times[:95], path[:95], ConsistencyParams(exclude=25.0))
    result = cross_validated_consistency(rays, ConsistencyParams(exclude=25.0))
    assert result["judged_share"] == 0.0 and np.isnan(result["inconsistency"])


def test_a_shrunk_map_and_a_map_drawn_twice_rank_below_the_true_one(laps):
    frames, times, path = laps
    shrunk = path.copy()
    shrunk[:, :2] = path[0, :2] + 0.93 * (path[:, :2] - path[0, :2])  # every step 7 % short: no scan contradicts it
    twice = path.copy()
    twice[100:, :2] += [12.0, 0.0]  # the second lap not recognised: drawn again beside the first
    measures = {name: judge_trajectory(frames, times, poses)
                for name, poses in (("true", path), ("shrunk", shrunk), ("twice", twice), ("true-again", path))}
    assert measures["shrunk"]["travel_scale"] == pytest.approx(0.93, abs=0.005)
    assert measures["twice"]["area_m2"] > 1.5 * measures["true"]["area_m2"]
    ranked = rank_runs(measures)
    assert set(ranked["ranking"][:2]) == {"true", "true-again"}
    assert ranked["scale_off"]["shrunk"] < -0.05 and "true" not in ranked["scale_off"]
    assert "twice" in ranked["area_off"]  # (its 12 m jump, which no wheel felt, also puts its scale off)
    # two identical runs cannot be told apart: a coin toss, and the sentence says so
    assert ranked["confidence"] == pytest.approx(0.5)
    assert "cannot be told apart" in verdict_sentence(ranked)


def test_the_confidence_is_reproducible_and_high_for_a_clear_win(laps):
    frames, times, path = laps
    moved = path.copy()
    moved[100:, :2] += [0.25, 0.15]
    measures = {"good": judge_trajectory(frames, times, path), "bad": judge_trajectory(frames, times, moved)}
    first, again = rank_runs(measures, seed=3), rank_runs(measures, seed=3)
    assert first == again
    assert first["ranking"] == ["good", "bad"] and first["confidence"] >= 0.99
    assert verdict_sentence(first).startswith("Trust good's map")


def test_the_verdict_sentence_for_nothing_and_for_one_run():
    assert verdict_sentence({"ranking": [], "inconsistency": {}}).startswith("No run could be judged")
    one = verdict_sentence({"ranking": ["karto"], "inconsistency": {"karto": 0.02}, "score": {"karto": 0.02}})
    assert "nothing to rank it against" in one
    assert rank_runs({"karto": {"beams_judged": 0}})["not_judged"] == ["karto"]


# --------------------------------------------------------------------------- the commands


def _run(tmp_path, sim, method, name):
    from slam2d.cli import main

    out = tmp_path / name
    assert main(["run", method, str(sim / "recording.log.gz"), "--out", str(out)]) == 0
    return out


def test_evaluate_ranks_runs_of_one_recording_and_refuses_runs_of_two(tmp_path, paper_arena, capsys):
    from slam2d.cli import main

    karto = _run(tmp_path, paper_arena, "karto", "karto")
    odometry = _run(tmp_path, paper_arena, "odometry", "odometry")
    out = tmp_path / "comparison.json"
    assert main(["evaluate", str(karto), str(odometry), "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["ranking"] == ["karto", "odometry"]
    assert document["reference"] is None and "karto" in document["verdict"]
    assert json.loads((karto / "evaluation.json").read_text())["self_consistency"]["scans_judged"] > 0
    # a run of another file (the same log compressed again: other bytes)
    import gzip

    copy = tmp_path / "copy.log.gz"
    copy.write_bytes(gzip.compress(gzip.decompress((paper_arena / "recording.log.gz").read_bytes()), compresslevel=1))
    other = tmp_path / "other"
    assert main(["run", "odometry", str(copy), "--out", str(other)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(karto), str(other)]) != 0
    err = capsys.readouterr().err
    assert "different recordings" in err and "data.sha256" in err


def test_evaluate_without_the_recording_says_so_and_goes_on(tmp_path, paper_arena, capsys):
    from slam2d.cli import main

    karto = _run(tmp_path, paper_arena, "karto", "karto")
    run = json.loads((karto / "run.json").read_text())
    run["data"]["path"] = str(tmp_path / "gone.log.gz")
    (karto / "run.json").write_text(json.dumps(run))
    capsys.readouterr()
    assert main(["evaluate", str(karto)]) == 0
    text = capsys.readouterr().out
    assert "no reference-free measures" in text and "gone.log.gz" in text
    assert "self_consistency" not in json.loads((karto / "evaluation.json").read_text())


def test_evaluate_a_folder_that_is_not_a_run(tmp_path, capsys):
    from slam2d.cli import main

    capsys.readouterr()
    assert main(["evaluate", str(tmp_path)]) != 0
    assert "trajectory.tum is missing" in capsys.readouterr().err


def test_compare_writes_the_verdict(tmp_path, paper_arena):
    from slam2d.cli import main

    out = tmp_path / "cmp"
    assert main(["compare", str(paper_arena / "recording.log.gz"), "--methods", "karto,odometry", "--out", str(out),
                 "--truth", str(paper_arena), "--jobs", "1"]) == 0
    document = json.loads((out / "comparison.json").read_text())
    assert set(document["ranking"]) == {"karto", "odometry"}
    assert document["reference"]["ranking"][0] == "karto"
    assert set(document["measures"]) == {"karto", "odometry"}
    report = (out / "report.md").read_text()
    assert "## Which map to trust" in report and document["verdict"] in report
    assert (out / "images" / "disagreement-along-run.png").is_file()
