"""The `slam2d` command end to end: info, map, demo, and every bad input a user can give it."""

from __future__ import annotations

import gzip
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slam2d.cli import main
from tests.conftest import dataset_file


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A short simulated recording of the study's arena as a CARMEN log, with its true trajectory."""
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    d = tmp_path_factory.mktemp("room")
    sim = simulate("paper-arena", SimulationParams(seed=3, duration=40.0))
    write_outputs(sim, d)
    return d / "recording.log.gz", d / "truth.tum", len(sim.scans)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


#: a progress line, which a slow run (numba compiling in a fresh clone) writes before its error
_PROGRESS = re.compile(r": \d+ % \(\d+ of \d+\), \d+ s$")


def assert_one_line_error(code, err, *needles):
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if ln.strip() and not _PROGRESS.search(ln)]
    assert len(lines) == 1, err
    assert lines[0].startswith("slam2d: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_info_reports_the_recording(capsys, room):
    log, _, n = room
    code, out, err = run(capsys, "info", log, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["scans"] == n
    assert s["beams_min"] == s["beams_max"] == 682
    assert s["field_of_view_deg"] == pytest.approx(681 * 360 / 1024)  # first to last beam
    assert s["rate_hz"] == pytest.approx(10.0, rel=1e-3)
    assert s["frames_with_odometry"] == n
    assert s["laser_mount"][0] > 0.0  # the youBot's laser sits ahead of its centre
    assert s["problems"] == []
    # the profile the auto defaults resolve from
    p = s["profile"]
    assert p["scans"] == n and p["has_odometry"] and p["pairs"] >= 12
    assert 0.0 < p["longest_return"] <= 5.6 and p["step_m"] > 0.0
    assert p["odometry_heading_per_m"] is not None


def test_info_table_names_what_matters(capsys, room):
    log, _, _ = room
    code, out, _ = run(capsys, "info", log)
    assert code == 0
    for word in ("scans", "field of view", "range limits", "rate", "time span", "odometry", "no problems found",
                 "laser reach", "odometry vs scans"):
        assert word in out


def test_map_with_true_poses_is_sharp_and_complete(capsys, room, tmp_path):
    log, truth, n = room
    out_dir = tmp_path / "map"
    code, out, err = run(capsys, "map", log, "--poses", truth, "--out", out_dir)
    assert code == 0, err
    assert sorted(p.name for p in out_dir.iterdir()) == [
        ".slam2d-output.json", "map.json", "map.pgm", "map.yaml", "preview.png"]
    info = json.loads((out_dir / "map.json").read_text())
    assert info["stats"]["scans_used"] == n
    assert info["wall_thickness_cells"]["median"] <= 2
    from slam2d.io.map_server import read_map

    m = read_map(out_dir / "map.yaml")
    occupied = np.argwhere(m.occupancy == 100)
    assert len(occupied) > 100
    # the occupied cells span the arena's walls (within a cell or two)
    from slam2d.sim.world import load_world

    xmin, ymin, xmax, ymax = load_world("paper-arena").bounds()
    span = (occupied.max(axis=0) - occupied.min(axis=0)) * m.resolution
    assert span[1] == pytest.approx(xmax - xmin, abs=0.15) and span[0] == pytest.approx(ymax - ymin, abs=0.15)


def test_map_along_odometry_is_blurred_by_drift(capsys, room, tmp_path):
    log, truth, _ = room
    run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "truth")
    code, _, err = run(capsys, "map", log, "--out", tmp_path / "odom", "--max-pose-gap", "0.5")
    assert code == 0, err
    sharp = json.loads((tmp_path / "truth" / "map.json").read_text())["wall_thickness_cells"]
    blurred = json.loads((tmp_path / "odom" / "map.json").read_text())["wall_thickness_cells"]
    assert blurred["p90"] > sharp["p90"]


def test_demo_runs_end_to_end(capsys, tmp_path):
    code, out, err = run(capsys, "demo", "--out", tmp_path / "demo")
    assert code == 0, err
    from slam2d.methods import method_names

    for method in method_names():
        assert (tmp_path / "demo" / "compare" / "runs" / method / "run.json").is_file(), method
    html = (tmp_path / "demo" / "compare" / "report.html").read_text()
    assert all(method in html for method in method_names())
    assert "no problems found" in out


# ---------------------------------------------------------------- bad input, each a clear line


def test_missing_file(capsys, tmp_path):
    code, _, err = run(capsys, "info", tmp_path / "nope.log")
    assert_one_line_error(code, err, "nope.log", "no such file")


def test_directory_instead_of_file(capsys, tmp_path):
    code, _, err = run(capsys, "info", tmp_path)
    assert_one_line_error(code, err, str(tmp_path), "is a folder")


def test_empty_file(capsys, tmp_path):
    empty = tmp_path / "empty.log"
    empty.write_text("")
    code, _, err = run(capsys, "info", empty)
    assert_one_line_error(code, err, "empty.log", "empty")


def test_truncated_line_names_file_line_and_field(capsys, tmp_path):
    bad = tmp_path / "bad.log"
    bad.write_text(
        "ODOM 0 0 0 0 0 0 1.0 host 1.0\n"
        "FLASER 180 " + " ".join(["1.0"] * 100) + "\n"
    )
    code, _, err = run(capsys, "info", bad)
    assert_one_line_error(code, err, "bad.log:2", "FLASER")


def test_non_numeric_field(capsys, tmp_path):
    bad = tmp_path / "bad.log.gz"
    with gzip.open(bad, "wt") as f:
        f.write("ODOM 0 0 zero 0 0 0 1.0 host 1.0\n")
    code, _, err = run(capsys, "info", bad)
    assert_one_line_error(code, err, "bad.log.gz:1", "theta")


def test_skip_bad_records_counts_and_continues(capsys, room, tmp_path):
    log, _, n = room
    with gzip.open(log, "rt") as f:
        lines = f.readlines()
    lines.insert(5, "FLASER 3 1.0 oops\n")
    patched = tmp_path / "patched.log"
    patched.write_text("".join(lines))
    code, _, err = run(capsys, "info", patched)
    assert_one_line_error(code, err, "patched.log:6")
    code, out, err = run(capsys, "info", patched, "--skip-bad-records", "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["scans"] == n
    assert any("patched.log:6" in p or "6" in p for p in s["problems"])


def test_bad_parameter_value(capsys, room, tmp_path):
    log, truth, _ = room
    code, _, err = run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "m", "--resolution", "-1")
    assert_one_line_error(code, err, "resolution")
    assert not (tmp_path / "m").exists()


def test_bad_poses_file_writes_nothing(capsys, room, tmp_path):
    log, _, _ = room
    poses = tmp_path / "poses.tum"
    poses.write_text("0.0 1 2 0 0 0 0 1\n0.1 1 2 0 0 0 zero 1\n")
    code, _, err = run(capsys, "map", log, "--poses", poses, "--out", tmp_path / "m")
    assert_one_line_error(code, err, "poses.tum:2")
    assert not (tmp_path / "m").exists()


def test_poses_that_do_not_overlap_in_time(capsys, room, tmp_path):
    log, _, _ = room
    poses = tmp_path / "late.tum"
    poses.write_text("5000.0 0 0 0 0 0 0 1\n5001.0 1 0 0 0 0 0 1\n")
    code, _, err = run(capsys, "map", log, "--poses", poses, "--out", tmp_path / "m")
    assert_one_line_error(code, err, "no scan could be placed")
    assert not (tmp_path / "m" / "map.yaml").exists()


def test_unsupported_bag_version(capsys):
    bag = dataset_file("robustness/laser_scan_sparsifier_demo.bag")
    code, _, err = run(capsys, "info", bag)
    assert_one_line_error(code, err, "laser_scan_sparsifier_demo.bag", "unsupported bag version 1.2")


def test_corrupt_timestamps_are_caught(capsys):
    log = dataset_file("robustness/infinite-corridor-corrupt-timestamps.log.gz")
    code, _, err = run(capsys, "info", log)
    assert_one_line_error(code, err, "infinite-corridor-corrupt-timestamps.log.gz:", "timestamp")


def test_real_entry_point_prints_no_traceback(tmp_path):
    exe = Path(sys.executable).with_name("slam2d")
    proc = subprocess.run([str(exe), "info", str(tmp_path / "missing.bag")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0
    assert "Traceback" not in proc.stderr
    proc = subprocess.run([str(exe), "map", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0
    assert "--resolution" in proc.stdout and "[m]" in proc.stdout


@pytest.mark.parametrize(
    "rel, scans",
    [
        ("intel/intel.clf.gz", 910),
        ("aces/aces.clf.gz", 440),
        ("fr101/fr101.clf.gz", 292),
        ("csail/csail.clf.gz", 406),
        ("mines-exp1/mines-exp1.clf.gz", 756),
        ("mines-exp2/mines-exp2.clf.gz", 641),
        ("robustness/csail-robotlaser1-corrected.log", 686),
        ("robustness/laser_scan_matcher_demo.bag", None),
        pytest.param("fr079/fr079.clf.gz", 4791, marks=pytest.mark.slow),
    ],
)
def test_info_on_every_shared_dataset(capsys, rel, scans):
    path = dataset_file(rel)
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0, err
    s = json.loads(out)
    if scans is not None:
        assert s["scans"] == scans
    else:
        assert s["scans"] > 300
    assert s["duration"] > 0


def test_bag_without_the_requested_topic(capsys, room, tmp_path):
    from slam2d.io import open_recording
    from slam2d.io.rosbag import write_rosbag

    log, _, _ = room
    bag = write_rosbag(tmp_path / "room-ros2", open_recording(log).frames())
    code, out, err = run(capsys, "info", bag, "--json")
    assert code == 0, err
    assert json.loads(out)["odometry_source"].startswith("/odom")
    code, _, err = run(capsys, "info", bag, "--scan-topic", "/front_scan")
    assert_one_line_error(code, err, "room-ros2", "scan_topic", "no topic /front_scan", "/scan")
    code, _, err = run(capsys, "info", bag, "--scan-topic", "/odom")
    assert_one_line_error(code, err, "scan_topic", "nav_msgs/Odometry", "expected sensor_msgs/LaserScan")


def test_map_in_scale_mode_reads_back(capsys, room, tmp_path):
    from slam2d.io.map_server import read_map

    log, truth, _ = room
    code, _, err = run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "t")
    assert code == 0, err
    code, _, err = run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "s", "--mode", "scale")
    assert code == 0, err
    trinary = read_map(tmp_path / "t" / "map.yaml")
    scale = read_map(tmp_path / "s" / "map.yaml")
    assert scale.mode == "scale" and scale.image_path.name != "preview.png"
    assert scale.occupancy.shape == trinary.occupancy.shape
    # map_saver's trinary rule applied to the scale map's values gives the trinary map
    s = scale.occupancy.astype(int)
    assert np.array_equal(trinary.occupancy == 100, s >= 65)
    assert np.array_equal(trinary.occupancy == 0, (s >= 0) & (s <= 25))
    assert np.array_equal(trinary.occupancy == -1, (s < 0) | ((s > 25) & (s < 65)))
    assert (s > 25).any() and (s < 0).any()


# ---------------------------------------------------------------- bad input found by the input sweep


def _flaser_log(path: Path, xs) -> Path:
    """A tiny CARMEN log: one FLASER line (180 beams at 2 m) per odometry x in ``xs``, a second apart."""
    ranges = " ".join(["2.0"] * 180)
    path.write_text("".join(
        f"FLASER 180 {ranges} {x} 0 0 {x} 0 0 {k + 1.0} host {k + 1.0}\n" for k, x in enumerate(xs)
    ))
    return path


@pytest.mark.parametrize("value", ["nan", "NaN"])
def test_nan_parameter_is_refused_by_name(capsys, room, tmp_path, value):
    log, truth, _ = room
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r", "--set", f"resolution={value}")
    assert_one_line_error(code, err, "resolution", "is not a number")
    code, _, err = run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "m", "--resolution", value)
    assert_one_line_error(code, err, "resolution", "is not a number")
    code, _, err = run(capsys, "info", log, "--range-max", value)  # used to be ignored silently
    assert_one_line_error(code, err, "range_max", "is not a number")
    assert not (tmp_path / "r").exists() and not (tmp_path / "m").exists()


@pytest.mark.parametrize("command", [["run", "coreslam", "DATA", "--out", "OUT"], ["demo", "--out", "OUT"],
                                     ["repeatability", "--out", "OUT"]])
def test_negative_seed_is_a_usage_error(capsys, room, tmp_path, command):
    argv = [str(room[0]) if a == "DATA" else str(tmp_path / "o") if a == "OUT" else a for a in command]
    with pytest.raises(SystemExit) as info:
        main([*argv, "--seed", "-1"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--seed: -1 is negative" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_simulate_negative_seed(capsys, tmp_path):
    code, _, err = run(capsys, "simulate", "paper-arena", "--out", tmp_path / "s", "--seed", "-1", "--duration", "2")
    assert_one_line_error(code, err, "seed", "below the minimum 0")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("seed", ["abc", "1.5", "[1]", "true"])
def test_params_file_seed_must_be_a_whole_number(capsys, room, tmp_path, seed):
    params = tmp_path / "run.yaml"
    params.write_text(f"method: odometry\nseed: {seed}\nparams: {{}}\n")
    code, _, err = run(capsys, "run", "odometry", room[0], "--out", tmp_path / "r", "--params", params)
    assert_one_line_error(code, err, f"{params}: seed:", "is not a whole number >= 0")


@pytest.mark.parametrize("gap", ["-1", "nan"])
def test_map_max_pose_gap_must_be_a_time(capsys, room, tmp_path, gap):
    log, truth, _ = room
    code, _, err = run(capsys, "map", log, "--poses", truth, "--out", tmp_path / "m", "--max-pose-gap", gap)
    assert_one_line_error(code, err, "--max-pose-gap")
    assert not (tmp_path / "m").exists()


def test_a_corrupt_odometry_pose_names_the_recording(capsys, tmp_path):
    # within the readers' bound (1e7 m) but beyond the map's max_extent: the map refuses to grow there
    log = _flaser_log(tmp_path / "far.log", [0.0, 0.5, 1e6, 1.5])
    code, _, err = run(capsys, "map", log, "--out", tmp_path / "m")
    assert_one_line_error(code, err, f"{log}: max_extent: the map would grow to 1", "beyond the limit of 2000 m")
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r")
    assert_one_line_error(code, err, f"{log} (scan 3 at t=3.000 s): max_extent:")
    assert not (tmp_path / "m").exists() and not (tmp_path / "r").exists()


def test_evaluate_out_folder_is_refused_not_deleted(capsys, room, tmp_path):
    log, truth, _ = room
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r")
    assert code == 0, err
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "keep.txt").write_text("mine")
    code, _, err = run(capsys, "evaluate", tmp_path / "r", "--reference", truth, "--out", folder)
    assert_one_line_error(code, err, str(folder), "--out: is a folder")
    assert (folder / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("name, text", [("run.json", "[1, 2]\n"), ("diagnostics.json", '"text"\n'),
                                        ("diagnostics.json", '{"series": [1]}\n'),
                                        ("diagnostics.json", '{"series": {"wall_s": ["abc"]}}\n')])
def test_evaluate_run_folder_with_foreign_json(capsys, room, tmp_path, name, text):
    log, truth, _ = room
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r")
    assert code == 0, err
    (tmp_path / "r" / name).write_text(text)
    code, _, err = run(capsys, "evaluate", tmp_path / "r", "--reference", truth)
    assert_one_line_error(code, err, str(tmp_path / "r" / name))


@pytest.mark.parametrize("section, words", [("{nosuch: 1}", "odometry.nosuch: unknown parameter 'nosuch'"),
                                            ("{resolution: abc}", "odometry.resolution: 'abc' is not a valid float")])
def test_compare_params_file_errors_name_the_file(capsys, room, tmp_path, section, words):
    params = tmp_path / "per-method.yaml"
    params.write_text(f"odometry: {section}\n")
    code, _, err = run(capsys, "compare", room[0], "--methods", "odometry", "--out", tmp_path / "c",
                       "--params", params)
    assert_one_line_error(code, err, f"{params}: {words}")
    assert not (tmp_path / "c").exists()


def test_simulate_commands_file_errors_name_the_file(capsys, tmp_path):
    path = tmp_path / "drive.yaml"
    path.write_text("commands: [[5, 10, 0, 0]]\n")
    code, _, err = run(capsys, "simulate", "paper-arena", "--out", tmp_path / "s", "--path", path)
    assert_one_line_error(code, err, f"{path}: commands[0]: speed 10 m/s exceeds")
    assert not (tmp_path / "s").exists()


def test_simulate_help_names_the_built_in_worlds():
    from slam2d.cli import build_parser
    from slam2d.sim.world import builtin_world_names

    simulate = build_parser("simulate")._subparsers._group_actions[0].choices["simulate"]
    (world,) = [a for a in simulate._actions if a.dest == "world"]
    assert "--list-worlds" not in world.help  # an option that never existed
    assert all(name in world.help for name in builtin_world_names())


def test_a_truth_map_without_obstacles_is_named(capsys, room, tmp_path):
    log, truth, _ = room
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r")
    assert code == 0, err
    given = truth.parent / "truth-map.yaml"
    empty = tmp_path / "empty-map.yaml"  # the same image, read with a threshold nothing exceeds
    text = given.read_text().replace("occupied_thresh: 0.65", "occupied_thresh: 1.0")
    empty.write_text(text.replace("image: truth-map.pgm", f"image: {truth.parent / 'truth-map.pgm'}"))
    code, _, err = run(capsys, "evaluate", tmp_path / "r", "--truth-map", empty)
    assert_one_line_error(code, err, f"{empty}: truth: the ground-truth map has no occupied cells")


def test_a_run_json_whose_sensor_model_is_gone_is_named(capsys, room, tmp_path):
    params = tmp_path / "run.json"
    params.write_text('{"method": "odometry", "seed": 0, "params": {}, "sensor_model": {"spec": "gone.yaml"}}\n')
    code, _, err = run(capsys, "run", "odometry", room[0], "--out", tmp_path / "r", "--params", params)
    assert_one_line_error(code, err, f"{params}: sensor_model.spec: 'gone.yaml' is neither")
    assert "--sensor-model" not in err  # the user gave none


def test_an_output_folder_that_is_a_file_is_said_plainly(capsys, room, tmp_path):
    a_file = tmp_path / "results"
    a_file.write_text("not a folder")
    code, _, err = run(capsys, "run", "odometry", room[0], "--out", a_file)
    assert_one_line_error(code, err, f"{a_file}: --out: exists and is a file; a folder is needed here")
    code, _, err = run(capsys, "run", "odometry", room[0], "--out", a_file / "sub")
    assert_one_line_error(code, err, f"{a_file / 'sub'}: --out: a part of this path is a file, not a folder")
    assert a_file.read_text() == "not a folder"


def test_a_recording_without_returns_is_named_and_leaves_no_folder(capsys, tmp_path):
    log = tmp_path / "dark.log"  # every beam a no-return (0)
    zeros = " ".join(["0"] * 180)
    log.write_text("".join(f"FLASER 180 {zeros} {0.1 * k} 0 0 {0.1 * k} 0 0 {k + 1.0} h {k + 1.0}\n" for k in range(5)))
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r")
    assert_one_line_error(code, err, f"{log}: odometry mapped nothing: none of the 5 scans had a return")
    code, _, err = run(capsys, "map", log, "--out", tmp_path / "m")
    assert_one_line_error(code, err, f"{log}: the map is empty")
    assert not (tmp_path / "r").exists() and not (tmp_path / "m").exists()  # not a trajectory without its map


# ---------------------------------------------------------------- output folders are written whole


def test_a_users_folder_is_not_clobbered_and_overwrite_replaces_it_whole(capsys, room, tmp_path):
    mine = tmp_path / "u"
    mine.mkdir()
    (mine / "map.pgm").write_text("mine")
    code, _, err = run(capsys, "run", "odometry", room[0], "--out", mine)
    assert_one_line_error(code, err, f"{mine}: --out: is a folder that is not empty (not an earlier slam2d output)",
                          "--overwrite")
    assert (mine / "map.pgm").read_text() == "mine" and len(list(mine.iterdir())) == 1
    code, out, err = run(capsys, "run", "odometry", room[0], "--out", mine, "--overwrite")
    assert code == 0, err
    assert (mine / "map.pgm").read_bytes().startswith(b"P5") and (mine / "run.json").is_file()
    assert f"wrote {mine / 'run.json'}" in out and ".partial" not in out  # the final paths, not the staging one
    # an earlier output of another command is not one of this command's either
    code, _, err = run(capsys, "map", room[0], "--out", mine)
    assert_one_line_error(code, err, "an earlier 'slam2d run' output", "--overwrite")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left


def test_a_rerun_replaces_the_whole_run_folder(capsys, room, tmp_path):
    out = tmp_path / "r"
    assert run(capsys, "run", "karto", room[0], "--out", out)[0] == 0
    assert (out / "graph.g2o").is_file()
    assert run(capsys, "run", "odometry", room[0], "--out", out)[0] == 0  # an earlier 'run' output: replaced
    assert not (out / "graph.g2o").exists()  # not karto's graph beside odometry's run.json
    assert json.loads((out / "run.json").read_text())["method"] == "odometry"


def test_a_failure_while_writing_leaves_the_old_folder_as_it_was(capsys, room, tmp_path, monkeypatch):
    out = tmp_path / "r"
    assert run(capsys, "run", "odometry", room[0], "--out", out)[0] == 0
    before = {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    import slam2d.report.map_outputs as map_outputs

    def full_disk(grid, folder, *args, **kwargs):
        (Path(folder) / "map.pgm").write_bytes(b"half")
        raise OSError(28, "No space left on device", str(Path(folder) / "map.pgm"))

    monkeypatch.setattr(map_outputs, "write_map_outputs", full_disk)
    code, _, err = run(capsys, "run", "karto", room[0], "--out", out)
    assert_one_line_error(code, err, "No space left on device")
    assert {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # the old run whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]  # and no staging folder beside it


def test_run_json_is_strict_json_and_reruns(capsys, room, tmp_path):
    """No Infinity or NaN (not JSON: jq and browsers reject it); a parameter at infinity is the text "inf"."""
    out = tmp_path / "r"
    # (an advanced parameter is recorded only when changed: this one is, to infinity)
    assert run(capsys, "run", "karto", room[0], "--out", out, "--set", "loop_match_maximum_drift=inf")[0] == 0

    def refuse(name):
        raise AssertionError(f"{name} is not JSON")

    for name in ("run.json", "diagnostics.json", "map.json"):
        json.loads((out / name).read_text(), parse_constant=refuse)
    record = json.loads((out / "run.json").read_text())
    assert record["params"]["loop_match_maximum_drift"] == "inf"
    code, _, err = run(capsys, "run", "karto", room[0], "--out", tmp_path / "again", "--params", out / "run.json")
    assert code == 0, err
    again = json.loads((tmp_path / "again" / "run.json").read_text())
    assert again["params"] == record["params"]


def test_a_pose_beyond_any_map_is_named_not_a_traceback(capsys, tmp_path):
    """An odometry x of 1e308 overflowed the map's cell arithmetic (OverflowError traceback in run and map)."""
    ranges = " ".join(["2.0"] * 180)
    log = tmp_path / "far.log"
    x = [1e308 if k == 3 else 0.1 * k for k in range(6)]
    log.write_text("".join(f"FLASER 180 {ranges} {x[k]} 0 0 {x[k]} 0 0 {k + 1.0} h {k + 1.0}\n" for k in range(6)))
    for argv in (("run", "odometry", log, "--out", tmp_path / "r"), ("map", log, "--out", tmp_path / "m")):
        code, _, err = run(capsys, *argv)
        assert_one_line_error(code, err, f"{log}:4: FLASER odom_x: 1e+308 m is farther than any map")
    tum = tmp_path / "far.tum"
    tum.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 -1e300 0 0 0 0 1\n")
    code, _, err = run(capsys, "map", log, "--poses", tum, "--out", tmp_path / "m")
    assert_one_line_error(code, err, f"{tum}:2: y: -1e+300 m is farther than any map")
    assert not (tmp_path / "r").exists() and not (tmp_path / "m").exists()


def test_info_counts_nan_infinite_and_negative_ranges(capsys, tmp_path):
    log = tmp_path / "odd.log"
    lines = []
    for k in range(4):
        r = ["2.0"] * 180
        r[5], r[6], r[7] = "nan", "inf", "-1.5"
        lines.append(f"FLASER 180 {' '.join(r)} {0.1 * k} 0 0 {0.1 * k} 0 0 {k + 1.0} h {k + 1.0}\n")
    log.write_text("".join(lines))
    code, out, err = run(capsys, "info", log)
    assert code == 0, err
    assert "no problems found" not in out
    assert "4 x ranges NaN, infinite or negative (read as no return)" in out and "line 1: FLASER, 3 of 180" in out


def test_a_key_given_twice_in_a_params_file_is_refused(capsys, room, tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("max_range: 10\nresolution: 0.05\nmax_range: 20\n")
    code, _, err = run(capsys, "run", "gmapping", room[0], "--params", params, "--out", tmp_path / "r")
    assert_one_line_error(code, err, f"{params}:3:", "'max_range' is given twice (first at line 1)")


# ---------------------------------------------------------------- memory asked for before it is taken


def test_a_setting_that_needs_more_memory_than_the_machine_has_is_refused(capsys, room, tmp_path):
    """particles=10000 islands=64 allocated until the OOM killer came (64 x 2.5 GB of particle maps)."""
    code, _, err = run(capsys, "run", "gmapping", room[0], "--set", "particles=10000", "--set", "islands=64",
                       "--out", tmp_path / "r")
    assert_one_line_error(code, err, "islands, particles, delta: 64 filter(s) of 10000 particle maps",
                          "would need 150 GB, more than the", "--max-memory")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("argv, field", [
    (("map", "{log}", "--resolution", "0.01"), "resolution: a map of"),
    (("run", "coreslam", "{log}"), "resolution: a map of"),
    (("run", "gmapping", "{log}"), "particles, delta:"),
])
def test_max_memory_caps_what_a_run_may_hold(capsys, room, tmp_path, argv, field):
    # 1 MB less what the interpreter already holds leaves nothing: the first map is refused, by name
    argv = [a.format(log=room[0]) for a in argv]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "o", "--max-memory", "1M")
    assert_one_line_error(code, err, field, "--max-memory 1 MB less the")
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as exit_:  # argparse's usage error
        run(capsys, *argv, "--out", tmp_path / "o", "--max-memory", "lots")
    assert exit_.value.code == 2 and "'lots' is not a size" in capsys.readouterr().err


def test_sizes_parse():
    from slam2d.core.memory import format_size, parse_size

    assert parse_size("2G") == 2 * 1024**3 and parse_size("500MB") == 500 * 1024**2 and parse_size("1024") == 1024
    assert parse_size("1.5 g") == int(1.5 * 1024**3)
    for bad in ("", "-1G", "2X", "G"):
        with pytest.raises(ValueError):
            parse_size(bad)
    assert format_size(150 * 1024**3) == "150 GB" and format_size(1024**2) == "1 MB"


def test_max_memory_holds_for_its_command_only(capsys, room, tmp_path):
    from slam2d.core.memory import budget_override

    assert budget_override() is None
    run(capsys, "map", room[0], "--out", tmp_path / "o", "--max-memory", "1M")
    assert budget_override() is None  # the next command (in this process) has the default again


def test_files_name_the_final_folder_not_the_staging_one(capsys, room, tmp_path):
    """compare's report and each run's evaluation.json name the run folders: where they end up."""
    out = tmp_path / "cmp"
    code, _, err = run(capsys, "compare", room[0], "--methods", "odometry", "--truth", room[0].parent, "--out", out,
                       "--jobs", "1")
    assert code == 0, err
    for path in out.rglob("*"):
        if path.suffix in (".json", ".md", ".html"):
            assert ".partial-" not in path.read_text(encoding="utf-8"), path
    assert str(out.resolve() / "runs" / "odometry") in (out / "runs" / "odometry" / "evaluation.json").read_text()


def test_compare_checks_every_method_name_before_running_any(capsys, room, tmp_path):
    code, out, err = run(capsys, "compare", room[0], "--methods", "odometry,foo", "--out", tmp_path / "c")
    assert_one_line_error(code, err, "--methods: unknown method 'foo'; available:")
    assert "running" not in out and not (tmp_path / "c").exists()


def test_a_method_that_needs_odometry_warns_when_the_recording_has_none(capsys, room, tmp_path):
    code, _, err = run(capsys, "run", "karto", room[0], "--odometry", "none", "--out", tmp_path / "k")
    assert code == 0, err
    assert "warning: " in err and "scans had no odometry: karto needs it" in err and "hector" in err
    record = json.loads((tmp_path / "k" / "run.json").read_text())
    assert len(record["warnings"]) == 1
    code, _, err = run(capsys, "run", "hector", room[0], "--odometry", "none", "--out", tmp_path / "h")
    assert code == 0 and "warning" not in err  # hector needs none


def test_methods_never_cuts_a_parameter_name(capsys, monkeypatch):
    from slam2d.methods import get_method
    from slam2d.params import describe

    monkeypatch.setenv("COLUMNS", "80")
    code, out, _ = run(capsys, "methods", "karto", "--all")
    assert code == 0 and "…" not in out.split("logged per update")[0]
    for prm in describe(get_method("karto").Params):
        assert f" {prm.name} " in out, prm.name


def test_the_command_listing_is_the_full_parsers(capsys):
    """`slam2d --help` builds only a line per command (fast); it must list what the full parser has."""
    from slam2d.cli import build_parser

    def commands(parser):
        action = parser._subparsers._group_actions[0]
        return [(c.dest, c.help) for c in action._choices_actions]

    assert commands(build_parser(listing=True)) == commands(build_parser())
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "rerun the source study end to end" in capsys.readouterr().out


def test_progress_off_a_terminal_is_a_plain_line_every_tenth_after_a_quiet_start(capsys):
    import slam2d.cli as cli

    clock = iter([0.0, 0.5, 3.0, 3.1, 3.2, 15.0, 16.0])
    update = cli._plain_progress("karto on intel", quiet_for=2.0, every=10.0, clock=lambda: next(clock))
    for done in (10, 300, 310, 320, 330, 600):  # t = 0.5 (quiet), 3.0, 3.1, 3.2 (same tenth), 15.0 (10 s), 16.0
        update(done, 910)
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["karto on intel: 33 % (300 of 910), 3 s", "karto on intel: 36 % (330 of 910), 15 s",
                     "karto on intel: 66 % (600 of 910), 16 s"]


def test_compiling_kernels_is_reported_apart_not_as_the_methods_time(room, tmp_path):
    """A fresh kernel cache (a fresh install): the first run compiles, and says so apart from its own time."""
    import os

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    records = []
    for k in range(2):
        proc = subprocess.run([sys.executable, "-m", "slam2d", "run", "coreslam", str(room[0]),
                               "--out", str(tmp_path / f"r{k}")], capture_output=True, text=True, env=env)
        assert proc.returncode == 0, proc.stderr
        records.append((json.loads((tmp_path / f"r{k}" / "run.json").read_text()), proc.stdout))
    (first, out1), (second, out2) = records
    assert first["compile_s"] > 0 and "compiling kernels on their first use" in out1
    assert second["compile_s"] == 0 and "compiling kernels" not in out2
    diagnostics = json.loads((tmp_path / "r0" / "diagnostics.json").read_text())
    per_update = [v for v in diagnostics["series"]["compile_s"] if v is not None]
    assert per_update and sum(per_update) <= first["compile_s"] + 1e-6  # taken out of those updates' times
