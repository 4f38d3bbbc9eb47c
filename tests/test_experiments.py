"""The study's Section V experiments (slam2d experiment ...) and the shape measures behind them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.experiments import ExperimentResult
from slam2d.experiments.section5 import EXPERIMENTS, STUDY, VARIANTS, run_experiment, run_section5
from slam2d.experiments.shapes import Shape, measure_shape, shape_distance, stations
from slam2d.grids.occupancy import OccupancyGrid


def _grid_with(cells_fn, resolution=0.05, size=80):
    occ = np.zeros((size, size), dtype=np.int16)
    cells_fn(occ)
    return OccupancyGrid.from_occupancy(occ, resolution, (0.0, 0.0))


# --------------------------------------------------------------------------- shapes


def test_thickness_counts_the_occupied_cells_across_a_wall():
    # a wall along x at y = 2.025 (the centre of row 40); drawn one and three cells thick
    wall = Shape.of("wall", [[0.5, 2.025, 3.5, 2.025]])

    def one(occ):
        occ[40, :] = 100

    def three(occ):
        occ[39:42, :] = 100

    thin = measure_shape(_grid_with(one), np.zeros(3), wall, half_width=0.2)
    thick = measure_shape(_grid_with(three), np.zeros(3), wall, half_width=0.2)
    assert thin["thickness_median_m"] == pytest.approx(0.05, abs=0.0126)
    assert thick["thickness_median_m"] == pytest.approx(0.15, abs=0.0126)
    assert thin["coverage"] == 1.0 and thin["map_to_shape_mean_m"] < 1e-9
    assert thick["map_to_shape_mean_m"] == pytest.approx(2 * 0.05 / 3)  # the two outer rows are 5 cm off


def test_a_shifted_map_is_as_far_from_the_shape_as_the_shift():
    wall = Shape.of("wall", [[0.5, 2.025, 3.5, 2.025]])

    def one(occ):
        occ[42, :] = 100  # 10 cm above the true wall

    grid = _grid_with(one)
    m = measure_shape(grid, np.zeros(3), wall, half_width=0.2)
    assert m["map_to_shape_mean_m"] == pytest.approx(0.1)
    assert m["shape_to_map_mean_m"] == pytest.approx(0.1, abs=0.003)  # stations fall between cell centres too
    # moving the map by the transform puts it back on the wall
    back = measure_shape(grid, np.array([0.0, -0.1, 0.0]), wall, half_width=0.2)
    assert back["map_to_shape_mean_m"] < 1e-9
    # outside half_width the wall is not seen at all
    assert measure_shape(grid, np.zeros(3), wall, half_width=0.05)["coverage"] == 0.0


def test_circle_stations_face_the_viewer_and_distances_are_exact():
    can = Shape.of("can", circles=[[1.0, 2.0, 0.1]])
    pts, normals = stations(can, spacing=0.01, end_margin=0.0, viewer=[1.0, 0.0], arc_deg=60)
    assert np.all(pts[:, 1] < 2.0)  # the side towards the viewer
    assert np.allclose(np.hypot(pts[:, 0] - 1.0, pts[:, 1] - 2.0), 0.1)
    assert np.allclose(np.hypot(*normals.T), 1.0)
    assert shape_distance(can, [[1.0, 2.3], [1.0, 2.0]]) == pytest.approx([0.2, 0.1])


# --------------------------------------------------------------------------- the experiments, quick


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("section5")
    return out, run_section5(out, quick=True, seed=0)


def test_run_section5_quick_writes_every_experiment(quick):
    out, results = quick
    assert [r.name for r in results] == list(EXPERIMENTS)
    for r in results:
        assert isinstance(r, ExperimentResult) and r.tables and r.figures and r.verdict and r.numbers
        assert "quick mode" in r.summary
        folder = out / r.name
        assert (folder / "summary.md").read_text().startswith(f"# {r.title}")
        record = json.loads((folder / "result.json").read_text())
        assert record["name"] == r.name and record["verdict"] == r.verdict
        for fig in r.figures:
            assert (folder / fig.path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        for k in range(len(r.tables)):
            assert (folder / "tables" / f"table-{k + 1}.csv").is_file()
    assert (out / "calibration" / "model.yaml").is_file()


def test_map_experiments_report_every_setting_and_the_truth(quick):
    _, results = quick
    for r in results[:3]:
        table = r.tables[0]
        assert [row[0] for row in table.rows][:len(VARIANTS)] == list(VARIANTS.values())
        assert table.rows[-1][0].startswith("the world rasterised")
        for v in VARIANTS:
            assert math.isfinite(r.numbers[f"{v}.ate_m"])
        assert r.numbers["default.max_pose_difference_m"] == 0.0
    can = results[0]
    # the robot stands still: a one-cell-thick wall across which the map has occupied cells, near the truth
    assert can.numbers["default.can.coverage"] > 0.5
    assert can.numbers["default.wall.map_to_shape_mean_m"] < 0.05
    assert can.numbers["default.ate_m"] < 0.01


def test_entropy_of_a_static_robot_is_ln_n_and_the_study_values_are_beside_it(quick):
    _, results = quick
    r = next(r for r in results if r.name == "entropy")
    assert r.numbers["ln_n"] == pytest.approx(math.log(30), abs=1e-15)
    # no motion -> no motion noise -> identical particles -> the entropy is ln N (up to rounding)
    for v in VARIANTS:
        assert r.numbers[f"{v}.mean_entropy"] == pytest.approx(math.log(30), abs=1e-12)
    # a creeping robot spreads its particles: the entropy falls below ln N
    assert r.numbers["creeping.default.distance_from_ln_n"] > 1e-9
    assert r.study["entropy_without_model"] == STUDY["entropy_without_model"]
    assert any(row[3] == STUDY["entropy_with_model"] for row in r.tables[0].rows)


def test_new_conditions_verify_the_calibrated_model(quick):
    _, results = quick
    r = next(r for r in results if r.name == "new-conditions")
    assert r.numbers["calibrated.share_inside"] >= 0.75
    assert r.numbers["constant.share_inside"] < r.numbers["calibrated.share_inside"]


def test_experiments_are_reproducible_with_the_seed(tmp_path):
    a = run_experiment("rebound", tmp_path / "a", quick=True, seed=3)
    b = run_experiment("rebound", tmp_path / "b", quick=True, seed=3)
    keys = [k for k in a.numbers if not k.endswith("cpu_s")]
    assert {k: a.numbers[k] for k in keys} == {k: b.numbers[k] for k in keys}
    assert (tmp_path / "a" / "tables" / "table-1.csv").read_text() == (tmp_path / "b" / "tables" / "table-1.csv").read_text()


# --------------------------------------------------------------------------- the command


def test_command_writes_its_outputs(tmp_path, capsys):
    assert main(["experiment", "can", "--out", str(tmp_path / "can"), "--quick", "--seed", "1"]) == 0
    assert "Fig. 8" in capsys.readouterr().out
    assert (tmp_path / "can" / "figures" / "maps.png").is_file()


def test_command_refuses_bad_input(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["experiment", "nope", "--out", str(tmp_path / "x")])
    assert exc.value.code != 0
    assert "invalid choice" in capsys.readouterr().err
    code = main(["experiment", "can", "--out", str(tmp_path / "x"), "--quick", "--seed", "-1"])
    assert code != 0 and "--seed" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    code = main(["experiment", "can", "--out", str(blocker), "--quick"])
    assert code != 0 and "a folder is needed here" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["experiment", "can", "--out", str(tmp_path / "y"), "--seed", "abc"])


# --------------------------------------------------------------------------- full runs


@pytest.mark.slow
def test_full_new_conditions_band_holds_for_the_calibrated_model_only(tmp_path):
    r = run_experiment("new-conditions", tmp_path, quick=False, seed=0)
    assert r.numbers["calibrated.share_inside"] >= 0.85
    assert r.numbers["study.share_inside"] >= 0.85  # the simulator's own model: the truth
    assert r.numbers["constant.share_inside"] <= 0.5


@pytest.mark.slow
def test_full_broken_wall_runs_five_recordings_per_setting(tmp_path):
    r = run_experiment("broken-wall", tmp_path, quick=False, seed=0)
    assert r.numbers["runs"] == 5 * len(VARIANTS)
    assert r.tables[0].rows[0][1] == 5
    for v in VARIANTS:
        assert r.numbers[f"{v}.ate_m"] < 0.2
