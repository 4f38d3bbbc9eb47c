"""The method interface, the registry, the two baselines and `slam2d run`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.errors import InputError
from slam2d.io.tum import read_tum, write_tum
from slam2d.methods import SlamMethod, available, get_method
from slam2d.methods.base import Diagnostics
from slam2d.methods.runner import build_method, run_method
from slam2d.params import from_mapping
from tests.conftest import recording_frames


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A 20 s simulated recording of the study's arena, with exact truth."""
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "paper-arena", "--out", str(out), "--duration", "20", "--seed", "3"]) == 0
    return out


# --------------------------------------------------------------------------- registry and parameters


def test_registry_lists_the_baselines():
    methods = available()
    assert {"odometry", "known-poses"} <= set(methods)
    for name, cls in methods.items():
        assert issubclass(cls, SlamMethod)
        assert cls.name == name and cls.summary


def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(InputError) as err:
        get_method("gmaping")
    assert "gmaping" in str(err.value) and "odometry" in str(err.value) and "known-poses" in str(err.value)


def test_parameters_from_settings_convert_units_and_reject_mistakes():
    cls = get_method("odometry")
    p = from_mapping(cls.Params, {"resolution": "10cm", "max-range": "4.5", "p_hit": 0.8})
    assert p.resolution == pytest.approx(0.1) and p.max_range == 4.5 and p.p_hit == 0.8
    cases = {
        "nope": ("unknown parameter 'nope'", "resolution"),  # lists the valid names
        "resolution=abc": ("not a valid float",),
        "resolution=-1": ("below the minimum",),
        "resolution=5deg": ("unit 'deg'", "in m"),
        "grow_margin=2.5": ("not a valid int",),
    }
    for text, expected in cases.items():
        name, _, value = text.partition("=")
        with pytest.raises(InputError) as err:
            from_mapping(cls.Params, {name: value or "1"})
        for piece in expected:
            assert piece in str(err.value), (text, str(err.value))


# --------------------------------------------------------------------------- the interface


def test_diagnostics_pad_missing_values_with_nan():
    d = Diagnostics()
    d.record(0.0, 0.1, 0.1, {"score": 1.0})
    d.record(1.0, 0.1, 0.1, None)
    d.record(2.0, 0.1, 0.1, {"neff": 3.0})
    assert len(d) == 3
    assert d.series["score"][0] == 1.0 and math.isnan(d.series["score"][1]) and math.isnan(d.series["score"][2])
    assert math.isnan(d.series["neff"][0]) and d.series["neff"][2] == 3.0
    back = Diagnostics.from_dict(json.loads(json.dumps(d.as_dict())))
    assert np.allclose(back.array("score"), d.array("score"), equal_nan=True)


def test_odometry_baseline_follows_the_odometry(sim):
    frames = recording_frames(sim / "recording.log.gz")
    slam = get_method("odometry")().run(frames)
    times, poses = slam.trajectory()
    assert len(times) == len(frames)
    expected = np.stack([f.odometry for f in frames])
    assert np.allclose(poses, expected)
    assert np.array_equal(slam.pose, expected[-1])
    assert slam.map().occupied().sum() > 100
    diag = slam.diagnostics
    assert len(diag) == len(frames)
    assert np.all(diag.array("wall_s") >= 0) and np.all(np.isfinite(diag.array("cpu_s")))
    assert np.all(diag.array("cells_updated") > 0)


def test_known_poses_follows_the_truth_and_counts_scans_without_pose(sim, tmp_path):
    frames = recording_frames(sim / "recording.log.gz")
    t, p = read_tum(sim / "truth.tum")
    half = len(t) // 2
    write_tum(tmp_path / "half.tum", t[:half], p[:half])
    slam = build_method("known-poses", settings={"poses": str(tmp_path / "half.tum"), "max_pose_gap": "0.5"})
    slam.run(frames)
    times, poses = slam.trajectory()
    assert np.allclose(times, t[:half]) and np.allclose(poses, p[:half])
    assert slam.diagnostics.counters["frames_without_pose"] == len(frames) - half


def test_known_poses_needs_a_trajectory():
    with pytest.raises(InputError, match="poses=FILE.tum"):
        build_method("known-poses")


def test_a_method_class_plugs_in_without_touching_the_cli(sim, tmp_path):
    """A method registered at run time is found by name by `slam2d run`."""
    from dataclasses import dataclass

    from slam2d.grids.occupancy import GridParams, OccupancyGrid
    from slam2d.methods.registry import _REGISTRY, register

    @dataclass
    class StillParams(GridParams):
        pass

    class Still(SlamMethod):
        name = "test-still"
        Params = StillParams
        summary = "stays at the origin"

        def __init__(self, params=None, **kw):
            super().__init__(params, **kw)
            self.grid = OccupancyGrid(self.params)

        def update(self, frame):
            self.grid.integrate(frame.scan, np.zeros(3))
            return {"score": float(self.rng.random())}

        def current_pose(self):
            return np.zeros(3)

        def map(self):
            return self.grid

    register(Still)
    try:
        assert main(["run", "test-still", str(sim / "recording.log.gz"), "--out", str(tmp_path / "r"),
                     "--seed", "5"]) == 0
        diag = json.loads((tmp_path / "r" / "diagnostics.json").read_text())
        scores = diag["series"]["score"]
        assert scores[0] == np.random.default_rng(5).random()  # the seed reaches the method
    finally:
        _REGISTRY.pop("test-still", None)


# --------------------------------------------------------------------------- slam2d run


def test_run_writes_a_repeatable_run_folder(sim, tmp_path, capsys):
    data = sim / "recording.log.gz"
    first = tmp_path / "first"
    assert main(["run", "odometry", str(data), "--out", str(first), "--set", "resolution=0.1", "--seed", "7"]) == 0
    for name in ("trajectory.tum", "map.yaml", "map.pgm", "preview.png", "diagnostics.json", "run.json"):
        assert (first / name).is_file(), name
    record = json.loads((first / "run.json").read_text())
    assert record["method"] == "odometry" and record["seed"] == 7
    assert record["params"]["resolution"] == 0.1 and "p_hit" in record["params"]
    assert len(record["data"]["sha256"]) == 64 and record["data"]["bytes"] == data.stat().st_size
    assert {"slam2d", "python", "numpy", "numba"} <= set(record["versions"])
    assert record["scans"] == record["poses"] > 0 and record["peak_rss_mb"] > 0
    diag = json.loads((first / "diagnostics.json").read_text())
    assert len(diag["series"]["wall_s"]) == record["scans"]

    again = tmp_path / "again"
    assert main(["run", "odometry", str(data), "--out", str(again), "--params", str(first / "run.json")]) == 0
    assert json.loads((again / "run.json").read_text())["seed"] == 7
    assert json.loads((again / "run.json").read_text())["params"] == record["params"]
    for name in ("trajectory.tum", "map.pgm", "map.yaml"):
        assert (first / name).read_bytes() == (again / name).read_bytes(), name


def test_run_takes_a_yaml_parameter_file(sim, tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("resolution: 0.2\nmax_range: 300cm\n")
    assert main(["run", "odometry", str(sim / "recording.log.gz"), "--out", str(tmp_path / "r"),
                 "--params", str(params), "--set", "max_range=3.5"]) == 0
    record = json.loads((tmp_path / "r" / "run.json").read_text())
    assert record["params"]["resolution"] == 0.2 and record["params"]["max_range"] == 3.5


@pytest.mark.parametrize(
    "args, expected",
    [
        (["run", "gmaping", "DATA"], ["unknown method 'gmaping'", "odometry"]),
        (["run", "odometry", "DATA", "--set", "resolutoin=0.1"], ["unknown parameter 'resolutoin'", "resolution"]),
        (["run", "odometry", "DATA", "--set", "resolution=fine"], ["resolution", "not a valid float"]),
        (["run", "odometry", "DATA", "--set", "resolution=20"], ["resolution", "above the maximum 10.0 m"]),
        (["run", "odometry", "DATA", "--set", "resolution"], ["--set", "not NAME=VALUE"]),
        (["run", "odometry", "DATA", "--set", "max_range=3s"], ["max_range", "unit 's'"]),
        (["run", "known-poses", "DATA"], ["poses=FILE.tum"]),
        (["run", "odometry", "DATA", "--params", "BADYAML"], ["bad.yaml:2", "not valid YAML"]),
        (["run", "odometry", "DATA", "--params", "WRONGMETHOD"], ["for method 'known-poses'"]),
        (["run", "odometry", "missing.log", "--out", "X"], ["missing.log"]),
    ],
)
def test_run_bad_input_is_one_line(sim, tmp_path, capsys, args, expected):
    bad = tmp_path / "bad.yaml"
    bad.write_text("resolution: 0.1\n  max_range: [\n")
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"method": "known-poses", "params": {}}))
    subst = {"DATA": str(sim / "recording.log.gz"), "BADYAML": str(bad), "WRONGMETHOD": str(wrong)}
    argv = [subst.get(a, a) for a in args]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("slam2d: error:"), err
    for piece in expected:
        assert piece in err, err
    assert not (tmp_path / "out" / "run.json").exists()


def test_known_poses_without_overlap_places_nothing(sim, tmp_path, capsys):
    t, p = read_tum(sim / "truth.tum")
    write_tum(tmp_path / "late.tum", t + 1000.0, p)
    status = main(["run", "known-poses", str(sim / "recording.log.gz"), "--out", str(tmp_path / "r"),
                   "--set", f"poses={tmp_path / 'late.tum'}"])
    assert status == 2
    assert "placed none of the" in capsys.readouterr().err
    assert not (tmp_path / "r" / "run.json").exists()


def test_run_method_on_a_ros2_bag(sim, tmp_path):
    summary = run_method("odometry", sim / "recording", tmp_path / "r")
    assert summary.frames > 100 and summary.record["data"]["format"].startswith("ros2")


def test_an_unknown_parameter_suggests_the_closest_names_not_all_85():
    from slam2d.errors import InputError

    cls = get_method("gmapping")
    with pytest.raises(InputError, match=r"unknown parameter 'partciles'; did you mean 'particles'\?$"):
        from_mapping(cls.Params, {"partciles": "3"})
    with pytest.raises(InputError) as exc:
        from_mapping(cls.Params, {"qqq": "3"})
    assert "none of the" in str(exc.value) and "srr" not in str(exc.value)  # not a wall of 85 names
