"""slam2d localize: the robot found and tracked in a fixed map, lost and found again, and the bad inputs."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.io.tum import read_tum
from slam2d.localization.localizer import LocalizationParams, Localizer
from slam2d.localization.run import localize_recording


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    """40 s of the simulated office: its true map (in the world's frame), recording and truth."""
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    out = tmp_path_factory.mktemp("office")
    write_outputs(simulate("office", SimulationParams(duration=40.0, seed=3)), out)
    return out


def _errors(trajectory, truth):
    t, p = read_tum(trajectory)
    tt, tp = read_tum(truth)
    k = np.searchsorted(tt, t).clip(0, len(tt) - 1)
    return np.hypot(p[:, 0] - tp[k, 0], p[:, 1] - tp[k, 1]), np.abs(np.angle(np.exp(1j * (p[:, 2] - tp[k, 2]))))


def test_found_without_an_initial_pose_and_tracked_in_the_true_map(office, tmp_path):
    # (the office is symmetric: one scan fits both wings; the search keeps both until the scans tell them apart)
    s = localize_recording(office / "truth-map.yaml", office / "recording.log.gz", tmp_path)
    rec = s.record
    assert rec["localized"] and rec["first_localized"]["time"] - rec["data_span_s"][0] < 15.0, rec["events"]
    assert rec["lost"] == 0 and "other places fit worse" in rec["events"][0]["why"]
    dist, heading = _errors(tmp_path / "trajectory.tum", office / "truth.tum")
    assert len(dist) == rec["localized_scans"] > 0.6 * rec["scans"]
    # (along a corridor longer than the URG-04LX's 5.6 m the walls do not say where along it the robot is:
    # tenths of a metre there even in the true map, as the accuracy bound in BENCHMARKS.md has it)
    assert np.median(dist) < 0.06 and dist.max() < 0.5 and np.median(heading) < np.radians(1.0)
    rows = (tmp_path / "localization.csv").read_text().splitlines()
    assert rows[0] == "time,state,x,y,theta,fit,spread_m,particles" and len(rows) == rec["scans"] + 1
    assert rows[1].split(",")[1] == "searching" and rows[1].split(",")[2] == ""  # no pose before it is found


@pytest.mark.parametrize("method", ["mcl", "match"])
def test_tracked_from_an_initial_pose(office, tmp_path, method):
    start = read_tum(office / "truth.tum")[1][0]
    s = localize_recording(office / "truth-map.yaml", office / "recording.log.gz", tmp_path,
                           params=LocalizationParams(method=method), initial_pose=start + [0.2, -0.1, 0.05])
    rec = s.record
    assert rec["first_localized"]["scan"] <= 3 and rec["lost"] == 0
    dist, heading = _errors(tmp_path / "trajectory.tum", office / "truth.tum")
    assert len(dist) > 0.95 * rec["scans"]
    assert np.median(dist) < 0.06 and dist.max() < 0.5 and np.median(heading) < np.radians(1.0)


def test_the_same_seed_gives_the_same_answer_and_another_seed_another_search(office, tmp_path):
    runs = [localize_recording(office / "truth-map.yaml", office / "recording.log.gz", tmp_path / str(i), seed=seed,
                               params=LocalizationParams(max_particles=1500))
            for i, seed in enumerate((5, 5, 6))]
    a, b, c = ((tmp_path / str(i) / "localization.csv").read_text() for i in range(3))
    assert a == b and a != c
    assert runs[2].record["localized"]


def test_a_kidnapping_keeps_the_odometry_and_the_clock_going(office):
    from slam2d.io import open_recording
    from slam2d.sim.faults import kidnapped

    frames = list(open_recording(office / "recording.log.gz").frames())
    at, resume = len(frames) // 3, len(frames) // 2
    moved, shift = kidnapped(frames, at, resume)
    assert len(moved) == at + len(frames) - resume
    steps = [np.hypot(*(moved[k].odometry[:2] - moved[k - 1].odometry[:2])) for k in range(1, len(moved))]
    assert max(steps) < 0.2 and np.allclose(np.diff([f.timestamp for f in moved]), 0.1, atol=0.02)
    # the scans after it are the later ones, re-stamped by the shift
    assert moved[at].scan.timestamp - shift == frames[resume].scan.timestamp
    assert np.array_equal(moved[at].scan.ranges, frames[resume].scan.ranges, equal_nan=True)
    with pytest.raises(ValueError):
        kidnapped(frames, 0, 5)


def test_a_map_without_the_robot_never_localizes_says_so_and_writes_what_it_has(office, tmp_path, capsys):
    from slam2d.io.map_server import write_map

    box = np.zeros((60, 60), np.int8)  # a 3 m x 3 m empty room: nothing the office's scans could fit
    box[0, :] = box[-1, :] = box[:, 0] = box[:, -1] = 100
    write_map(tmp_path / "box.yaml", box, 0.05, (0.0, 0.0, 0.0))
    code = main(["localize", str(tmp_path / "box.yaml"), str(office / "recording.log.gz"), "--out", str(tmp_path / "o"),
                 "--max-particles", "500"])
    err = capsys.readouterr().err
    assert code == 1 and "never localized" in err and "box.yaml" in err
    assert not (tmp_path / "o" / "trajectory.tum").exists()  # no confident trajectory
    rec = json.loads((tmp_path / "o" / "localization.json").read_text())
    assert rec["localized"] is False and rec["localized_scans"] == 0 and rec["scans"] > 100
    assert "searching" in (tmp_path / "o" / "localization.csv").read_text()


def test_localize_cli_writes_its_folder_and_refuses_bad_input(office, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["localize", str(office / "truth-map.yaml"), str(office / "recording.log.gz"), "--out", str(out),
                 "--method", "match", "--seed", "2"]) == 0
    assert {p.name for p in out.iterdir() if not p.name.startswith(".")} == {"trajectory.tum", "localization.csv",
                                                                             "localization.json"}
    assert json.loads((out / "localization.json").read_text())["method"] == "match"
    capsys.readouterr()
    # a map_server YAML whose image is missing
    (tmp_path / "noimage.yaml").write_text((office / "truth-map.yaml").read_text().replace("truth-map.pgm", "gone.pgm"))
    bad = [
        ([str(tmp_path / "noimage.yaml")], "gone.pgm"),
        ([str(tmp_path)], "map.yaml"),  # a folder that is no run folder
        ([str(office / "truth-map.yaml"), "--initial-pose", "1,2"], "X,Y,THETA"),
        ([str(office / "truth-map.yaml"), "--min-particles", "900", "--max-particles", "800"], "min_particles"),
    ]
    for args, said in bad:
        code = main(["localize", args[0], str(office / "recording.log.gz"), "--out", str(tmp_path / "x"), *args[1:]])
        err = capsys.readouterr().err
        assert code == 2 and said in err and "Traceback" not in err, (args, err)
        assert not (tmp_path / "x").exists()


def test_particles_stay_within_their_bounds_and_the_pose_follows_the_odometry_between_updates(office):
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    grid = read_map(office / "truth-map.yaml").to_grid()
    loc = Localizer(grid, LocalizationParams(min_particles=50, max_particles=2000), seed=1)
    assert len(loc.particles) == 2000  # a search starts with them all
    counts = []
    for frame in list(open_recording(office / "recording.log.gz").frames())[:150]:
        r = loc.feed(frame)
        counts.append(r.particles)
    assert max(counts) <= 2000 and min(counts) >= 50
    # a frame without odometry or returns: said, not a crash
    f = dataclasses.replace(frame, odometry=None)
    assert loc.feed(f).state in ("localized", "searching", "lost")



def test_scans_far_off_the_map_make_the_robot_lost_within_three_scans(office):
    """Scans that fit under half the usual floor (here: scans of a round hall, as when the robot was carried off)
    make the robot lost at the third, not after ``lost_after`` (10): by then the match can slide to a place that
    fits as well (the office's corridor repeats every 6 m)."""
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    grid = read_map(office / "truth-map.yaml").to_grid()
    frames = list(open_recording(office / "recording.log.gz").frames())[:100]
    loc = Localizer(grid, LocalizationParams(method="match"), seed=1)
    loc.restart(read_tum(office / "truth.tum")[1][0])
    assert [loc.feed(f).state for f in frames][-1] == "localized"
    last = frames[-1]
    # a round hall 9 m across: every range 4.5 m, a scan no place of the office's corridors and rooms fits
    elsewhere = [dataclasses.replace(last, index=100 + k, scan=dataclasses.replace(
        last.scan, timestamp=last.timestamp + 0.1 * (k + 1), ranges=np.full_like(last.scan.ranges, 4.5)))
        for k in range(4)]
    results = [loc.feed(f) for f in elsewhere]
    assert [r.state for r in results] == ["localized", "localized", "lost", "lost"], [r.fit for r in results]
    assert max(r.fit for r in results[:3]) < 0.25 and "under half" in loc.events[-1]["why"]


def test_a_robot_carried_into_a_twin_of_its_corridor_is_noticed_and_found_again(tmp_path, monkeypatch):
    """benchmarks/localization.py's kidnapping of corridor-loop: drive 2 (from half-way along the loop, backwards,
    seed 2) carried 6.6 m at its middle scan, from the east corridor heading south to the south-east corner heading
    west, odometry unaware. The match once slid onto a twin that fitted the scans as well (localized 5-17 m off for
    the rest of the drive, never lost); it may no longer move the pose that far against the odometry (_REACH), so
    the scans miss the map and it is lost at once, and found again."""
    import yaml

    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map
    from slam2d.sim.faults import kidnapped
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    world = yaml.safe_load((Path(__file__).resolve().parents[1] / "src" / "slam2d" / "sim" / "worlds"
                            / "corridor-loop.yaml").read_text())
    path, k, first_start = world["path"], len(world["path"]) // 2, world["start"][:2]
    world["start"] = [*path[k][:2], math.atan2(path[k - 1][1] - path[k][1], path[k - 1][0] - path[k][0])]
    world["path"] = path[k - 1::-1] + [first_start]
    (tmp_path / "drive2.yaml").write_text(yaml.safe_dump(world))
    write_outputs(simulate(str(tmp_path / "drive2.yaml"), SimulationParams(seed=2)), tmp_path / "d2")
    frames = list(open_recording(tmp_path / "d2" / "recording.log.gz").frames())
    tt, tp = read_tum(tmp_path / "d2" / "truth.tum")
    at = len(frames) // 2
    before = tp[np.argmin(np.abs(tt - frames[at - 1].timestamp))]
    later = [tp[np.argmin(np.abs(tt - f.timestamp))] for f in frames]
    resume = next(k for k in range(at + 10, len(frames))  # as benchmarks/localization.py picks it
                  if math.hypot(*(later[k][:2] - before[:2])) >= 4.0
                  and abs(math.remainder(later[k][2] - before[2], math.tau)) > 1.0)
    moved, shift = kidnapped(frames, at, resume)

    def truth(k):
        return tp[np.argmin(np.abs(tt - (moved[k].timestamp - (shift if k >= at else 0.0))))]

    assert math.hypot(*(truth(at)[:2] - truth(at - 1)[:2])) > 6.0
    loc = Localizer(read_map(tmp_path / "d2" / "truth-map.yaml").to_grid(), LocalizationParams(method="match"), seed=0)
    start = at - 60  # tracked from a given pose for 60 scans before the kidnapping
    loc.restart(truth(start), said=False)
    results = {k: loc.feed(moved[k]) for k in range(start, at + 220)}
    assert all(results[k].state == "localized" for k in range(start + 5, at))
    error = {k: math.hypot(*(r.pose[:2] - truth(k)[:2])) for k, r in results.items() if r.pose is not None}
    lost = [k for k in range(at, at + 220) if results[k].state == "lost"]
    # the match may not follow it there (the odometry says it drove on): its scans miss the map, lost at once
    assert lost and lost[0] < at + 10, "never noticed it was carried off"
    found = next((k for k in range(lost[0], at + 220) if results[k].state == "localized"), None)
    assert found is not None and found < at + 200, "not found again"
    # found in the right place, and tracked there from then on
    assert max(error[k] for k in range(found, at + 220)) < 0.3
    # a robot believed at a twin of its place (put down there: the scans fit it as well) is lost when the twin's
    # corridor ends, and found again where it is; with the misfit rules out of the way (scans that fit a twin at
    # under the lost floor but over half of it), the doubt check finds it
    import slam2d.localization.localizer as localizer

    monkeypatch.setattr(localizer, "_FAR_MISFITS", 10_000)
    points = moved[resume := at + 5].scan.points_in_base()
    beams = loc._beams(points, loc.p.match_beams)
    twins = [h for h in loc._unseen_rivals(-math.inf, *loc._beams(points, loc.p.beams), *beams,
                                           [(np.asarray(moved[resume].odometry), *beams)], [])
             if math.hypot(*(h["pose"][:2] - truth(resume)[:2])) > 4.0]
    assert twins, "no twin of the place to put the robot down in"
    twin = Localizer(read_map(tmp_path / "d2" / "truth-map.yaml").to_grid(),
                     LocalizationParams(method="match", lost_after=10_000), seed=0)
    twin.restart(twins[0]["pose"], said=False)
    after = {k: twin.feed(moved[k]) for k in range(resume, len(moved))}
    doubted = [e for e in twin.events if e["state"] == "lost"]
    assert doubted and "fit the last" in doubted[0]["why"], twin.events
    # once doubted, no place is reported but the right one. Found there again before the drive ends only sometimes
    # (the search's last lead over a twin 18 m off: 4.2 one day, 2.4 after a change elsewhere moved the doubt by one
    # update): the whole-map check proposes one place per metre of a corridor, matched where the prior holds it,
    # 0.8-2.7 m from the true place, which it scores 10 under it (docs/commands/localize.md, "How it fails")
    doubt = min(k for k, r in after.items() if r.state == "lost")
    assert all(math.hypot(*(r.pose[:2] - truth(k)[:2])) < 0.3 for k, r in after.items()
               if k > doubt and r.state == "localized"), twin.events


@pytest.mark.parametrize("method", ["match", "mcl"])
def test_off_a_partial_map_the_pose_follows_the_odometry_and_is_placed_again_when_back(office, method):
    """The office's map with everything south of y = 6 m unknown: the robot drives down into that part and back.
    Off the map its pose follows the odometry (state off_map); back on it, it is searched for near there and
    localized again (before: "carried off", lost for the remaining 70 % of the scans)."""
    from slam2d.grids.occupancy import OccupancyGrid
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    grid = read_map(office / "truth-map.yaml").to_grid()
    occupancy = grid.occupancy().copy()
    ys = grid.origin[1] + (np.arange(occupancy.shape[0]) + 0.5) * grid.resolution
    occupancy[ys < 6.0, :] = -1
    partial = OccupancyGrid.from_occupancy(occupancy, grid.resolution, grid.origin)
    tt, tp = read_tum(office / "truth.tum")
    loc = Localizer(partial, LocalizationParams(method=method), seed=1)
    loc.restart(tp[0])
    frames = list(open_recording(office / "recording.log.gz").frames())
    results = [loc.feed(f) for f in frames]
    states = [r.state for r in results]
    assert "lost" not in states and "off_map" in states
    first_off = states.index("off_map")
    assert states[first_off:].count("localized") > 0.5 * len(states[first_off:])  # placed again, most of the rest
    assert any(e["why"].startswith("back on the map after") for e in loc.events)
    k = np.searchsorted(tt, [f.timestamp for f in frames]).clip(0, len(tt) - 1)
    error = np.array([math.hypot(*(r.pose[:2] - tp[j, :2])) if r.pose is not None else np.nan
                      for r, j in zip(results, k)])
    localized = np.array([s == "localized" for s in states])
    off_map = np.array([s == "off_map" for s in states])
    assert np.nanmax(error[localized]) < 0.5 and np.median(error[localized]) < 0.1, error[localized].max()
    assert np.nanmax(error[off_map]) < 1.0  # odometry over a few metres


@pytest.mark.parametrize("anchor_off", [1.0, 5.0])
def test_back_on_the_map_a_place_is_taken_only_near_where_the_odometry_took_the_robot(office, anchor_off):
    """Searching near where the odometry took a robot back on the map (as after a stretch off it): the particles gather
    on the true place at once, which is taken only within _DRIFT_RADIUS (3 m after no travel) of the odometry's pose."""
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    tt, tp = read_tum(office / "truth.tum")
    frames = list(open_recording(office / "recording.log.gz").frames())
    loc = Localizer(read_map(office / "truth-map.yaml").to_grid(), LocalizationParams(method="match"), seed=0)
    start = 100
    truth = tp[min(np.searchsorted(tt, frames[start].timestamp), len(tt) - 1)]
    loc.restart(truth, said=False)  # the particles around the true place ...
    anchor = truth + np.array([0.0, anchor_off, 0.0])  # ... the odometry's pose this far off it
    assert loc._known_share(anchor, *loc._beams(frames[start].scan.points_in_base(), 180)) > 0.5
    loc.drifted = (anchor, 0.0)
    states = [loc.feed(f).state for f in frames[start:start + 30]]
    if anchor_off < 3.0:
        assert "localized" in states
    else:
        assert "localized" not in states


def test_back_on_the_map_the_particles_must_gather_on_a_place_over_several_updates(office):
    """Searching near where the odometry took a robot back on the map after a drive off it (metres of spread), a place
    is taken when the particles gathered on it at _CONFIRM_UPDATES filter updates in a row, as a search confirms its
    place; around a given initial pose, at the first. (fr079's second half in gmapping's map of its first took a
    place 6 m off where they gathered once, after 30 m off the map: 15 scans there, ATE 0.81 m.)"""
    from slam2d.core import se2
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map
    from slam2d.localization.localizer import _CONFIRM_UPDATES

    tt, tp = read_tum(office / "truth.tum")
    frames = list(open_recording(office / "recording.log.gz").frames())
    grid = read_map(office / "truth-map.yaml").to_grid()
    start = 100
    truth = tp[min(np.searchsorted(tt, frames[start].timestamp), len(tt) - 1)]
    updates_until_found = {}
    for drifted in (False, True):
        loc = Localizer(grid, LocalizationParams(method="match"), seed=0)
        loc.restart(truth, said=False)
        if drifted:
            loc.drifted = (truth.copy(), 0.0)
        updates, last = 0, None
        for f in frames[start:start + 60]:
            odom = np.asarray(f.odometry, dtype=np.float64)
            if last is None or loc.p.is_update(se2.relative(last, odom).reshape(3)):
                updates, last = updates + 1, odom
            if loc.feed(f).state == "localized":
                break
        updates_until_found[drifted] = updates
    assert updates_until_found[False] == 1
    assert _CONFIRM_UPDATES <= updates_until_found[True] < 60, updates_until_found


def test_match_brings_a_scan_onto_the_maps_walls_from_a_pose_near_it(office):
    """Localizer.match (the tracked pose's match; benchmarks/localization.py measures a map's offset with it) in the
    true map, along the office's first corridor (x along it): from 5 cm across it or 0.6 degrees off, back on the
    true pose, though the start already has every endpoint within two cells of a wall (before, a match that fitted
    no better by that share was dropped and the pose kept its error); along it, the odometry's prior holds it."""
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    tt, tp = read_tum(office / "truth.tum")
    frame = list(open_recording(office / "recording.log.gz").frames())[100]
    truth = tp[min(np.searchsorted(tt, frame.timestamp), len(tt) - 1)]
    loc = Localizer(read_map(office / "truth-map.yaml").to_grid(), seed=0)
    for off in (np.array([0.0, 0.05, 0.0]), np.array([0.0, 0.0, 0.01])):
        pose, fit = loc.match(frame.scan, truth + off)
        assert fit == 1.0 and abs(pose[1] - truth[1]) < 0.01 and abs(pose[2] - truth[2]) < 0.003, (off, pose - truth)
    pose, _ = loc.match(frame.scan, truth + np.array([0.05, 0.0, 0.0]))
    assert abs(pose[0] - truth[0] - 0.05) < 0.01  # along the corridor the walls say nothing


@pytest.mark.slow
def test_fr079_second_half_in_gmappings_map_takes_no_far_place_back_on_it(tmp_path):
    """fr079's second half with ``mcl`` in gmapping's map of its first half: back on the map after 30 m off it, the
    particles gathered once 6 m off (15 scans there, ATE 0.81 m) before they had to agree over several updates."""
    rec, error, _ = _second_half_in_the_first_halfs_map("fr079", tmp_path, maker="gmapping", method="mcl")
    assert rec["localized"] and any(e["why"].startswith("back on the map after") for e in rec["events"])
    assert error.max() < 1.0 and float(np.sqrt(np.mean(error ** 2))) < 0.15, (error.max(), np.median(error))


@pytest.mark.slow
def test_fr079_second_half_reports_no_far_place_after_leaving_the_first_halfs_map(tmp_path):
    """fr079's second half drives a hall and rooms its first half never saw. Off the map the pose follows the
    odometry; back on it the robot is looked for near where the odometry took it, not in a room alike 20 m away
    (before: 10-25 m off for the last 150 scans, ATE 4.6 m; then, matching the few beams that reached the map,
    1-3 m off in a mapped room while it drove the hall, ATE 0.575 m)."""
    rec, error, _ = _second_half_in_the_first_halfs_map("fr079", tmp_path)
    assert rec["localized"] and any(e["state"] == "off_map" for e in rec["events"])  # it does leave the map
    # (the map's own error there, karto's first half against the reference, is 0.04-0.19 m)
    rmse = float(np.sqrt(np.mean(error ** 2)))
    assert error.max() < 1.0 and np.median(error) < 0.15 and rmse < 0.25, (error.max(), np.median(error), rmse)


def _second_half_in_the_first_halfs_map(name, tmp_path, maker="karto", method="match"):
    """A real log's second half localized (``method``) in ``maker``'s map of its first half: the record, and each
    localized pose's position and heading error against the log's reference, in the map's frame."""
    from conftest import dataset_file

    from slam2d.core import se2
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen
    from slam2d.methods.runner import run_method

    log, reference = dataset_file(f"{name}/{name}.clf.gz"), dataset_file(f"{name}/reference.tum")
    frames = list(open_recording(log).frames())
    half = len(frames) // 2
    write_carmen(tmp_path / "first.log", frames[:half])
    write_carmen(tmp_path / "second.log", frames[half:])
    run_method(maker, tmp_path / "first.log", tmp_path / maker)
    rt, rp = read_tum(reference)
    to_reference = absolute_trajectory_error(associate(*read_tum(tmp_path / maker / "trajectory.tum"), rt, rp))
    rec = localize_recording(tmp_path / maker, tmp_path / "second.log", tmp_path / "out",
                             params=LocalizationParams(method=method)).record
    t, p = read_tum(tmp_path / "out" / "trajectory.tum")
    p = se2.compose(np.asarray(to_reference["alignment"]), p)
    k = np.searchsorted(rt, t).clip(0, len(rt) - 1)
    heading = np.degrees(np.abs(np.angle(np.exp(1j * (p[:, 2] - rp[k, 2])))))
    return rec, np.hypot(p[:, 0] - rp[k, 0], p[:, 1] - rp[k, 1]), heading


def test_intel_second_half_turning_at_the_maps_edge_keeps_its_heading_and_comes_back(tmp_path):
    """intel (one scan every 3 s) turns in place at the edge of its first half's map: the matcher's best start turned
    the pose 30-85 degrees a scan against the odometry, it left the map facing backwards and followed the odometry,
    drifting off, for its last 373 of 455 scans (61 localized)."""
    rec, error, heading = _second_half_in_the_first_halfs_map("intel", tmp_path)
    # (measured: 196 localized, median 0.064 m, the worst heading 51 degrees)
    assert rec["localized_scans"] > 150 and np.median(error) < 0.1 and heading.max() < 90.0
    assert any("from where the odometry took it" in e["why"] for e in rec["events"])  # found off the map (_rejoin)


def _search_history(office, n):
    """A fresh localizer in the office's true map holding the first ``n`` scans' filter updates as a search would,
    the frames, and the true pose at scan ``n``."""
    from slam2d.core import se2
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map

    loc = Localizer(read_map(office / "truth-map.yaml").to_grid(), seed=0)
    frames = list(open_recording(office / "recording.log.gz").frames())
    last = None
    for frame in frames[: n + 1]:
        odom = np.asarray(frame.odometry, dtype=np.float64)
        d = se2.relative(last, odom) if last is not None else None
        if d is None or loc.p.is_update(d):
            loc.search_scans.append((odom, *loc._beams(frame.scan.points_in_base(), loc.p.match_beams)))
            last = odom
    tt, tp = read_tum(office / "truth.tum")
    truth = tp[min(np.searchsorted(tt, frames[n].timestamp), len(tt) - 1)]
    return loc, frames, truth


def test_a_place_found_late_is_scored_on_the_earlier_scans_along_its_traced_path(office):
    loc, _, truth = _search_history(office, 200)
    assert len(loc.search_scans) > 50
    own = loc._path_score(truth)
    # the true place, traced back through the noisy odometry and matched at each step, fits nearly every scan (the
    # scans' share of its score, ``loose``) and slides little from the odometry (the rest; measured -0.07 a step)
    scans_only = loc._path_score(truth, loose=True)
    assert scans_only > -0.05 * len(loc.search_scans)
    assert own - scans_only > -0.15 * len(loc.search_scans)
    # the same place two metres off, or turned half a turn, does not: the scans before it count against it
    for offset in ([2.0, 0.0, 0.0], [-2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, math.pi]):
        assert loc._path_score(truth + np.array(offset)) < own - 3.0


def test_a_place_whose_traced_path_runs_through_the_maps_walls_is_refused(office):
    """The true place's path traced back through the odometry keeps off the walls; the same place turned a quarter turn
    drives through them (the corridor it came along runs across it), and a search refuses such a place whatever its
    scan fits (_THROUGH_WALLS). Turned the other way it leaves the building between two poses: only poses on walls
    count (1 % of them), not the steps between them."""
    from slam2d.localization.localizer import _THROUGH_WALLS

    loc, _, truth = _search_history(office, 200)
    assert loc._through_walls(truth, loc.search_scans) == 0.0
    assert loc._through_walls(truth + np.array([0.0, 0.0, math.pi / 2]), loc.search_scans) > _THROUGH_WALLS
    assert 0.0 < loc._through_walls(truth + np.array([0.0, 0.0, -math.pi / 2]), loc.search_scans) < _THROUGH_WALLS


def test_mines_second_half_in_a_map_without_its_room_is_never_placed(tmp_path):
    """Mines exp2's second half drives a room its first half never saw (karto and gmapping on the whole log agree);
    the first half's rooms of rough rock walls look alike, and the search placed it 13 m off there, its scans fitting
    81-91 % for 79 scans. Its paths traced back ran through the map's walls (6-11 % of their poses): now refused, it
    is never placed and says so."""
    from conftest import dataset_file

    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen
    from slam2d.methods.runner import run_method

    frames = list(open_recording(dataset_file("mines-exp2/mines-exp2.clf.gz")).frames())
    half = len(frames) // 2
    write_carmen(tmp_path / "first.log", frames[:half])
    write_carmen(tmp_path / "second.log", frames[half:])
    run_method("karto", tmp_path / "first.log", tmp_path / "karto")
    rec = localize_recording(tmp_path / "karto", tmp_path / "second.log", tmp_path / "out",
                             params=LocalizationParams(method="match")).record
    assert not rec["localized"] and rec["localized_scans"] == 0
    assert any("runs through the map's walls" in e["why"] for e in rec["events"])


def test_a_twin_that_fits_the_scans_by_sliding_against_the_odometry_pays_for_it(office):
    """At scan 60 a place 2 m along the corridor fits the scans along its traced path as well as the true place (within
    the search's margin), matched at every step; but its path slid from the odometry's prediction all along."""
    import slam2d.localization.localizer as localizer

    loc, frames, truth = _search_history(office, 60)
    points = frames[60].scan.points_in_base()
    rivals = loc._unseen_rivals(-math.inf, *loc._beams(points, loc.p.beams), *loc._beams(points, loc.p.match_beams),
                                loose=True)  # scored on the scans alone
    own_scans, own = loc._path_score(truth, loose=True), loc._path_score(truth)
    twins = [r for r in rivals if 1.0 < math.hypot(*(r["pose"][:2] - truth[:2]))
             and r["score"] > own_scans - localizer._HYPOTHESIS_MARGIN]
    assert twins, "no place that fits the scans as well"
    sliding = [r for r in twins if loc._path_score(r["pose"]) < own - localizer._HYPOTHESIS_MARGIN]
    assert sliding, [(r["pose"], r["score"], loc._path_score(r["pose"])) for r in twins]
    # (loose and the search's own score trace the same path: the search's prior is as loose)
    assert (localizer._SEARCH_PRIOR_XY, localizer._SEARCH_PRIOR_TH) == (localizer._PRIOR_XY, localizer._PRIOR_TH)


def test_the_whole_map_check_finds_the_true_place_the_particles_never_tried(office):
    loc, frames, truth = _search_history(office, 120)
    points = frames[120].scan.points_in_base()
    rivals = loc._unseen_rivals(-math.inf, *loc._beams(points, loc.p.beams), *loc._beams(points, loc.p.match_beams))
    near = [r for r in rivals if math.hypot(r["pose"][0] - truth[0], r["pose"][1] - truth[1]) < 0.3]
    assert near and abs(math.remainder(near[0]["pose"][2] - truth[2], math.tau)) < 0.05
    # ... and scores it best of all the places it found
    assert max(rivals, key=lambda r: r["score"]) is near[0]


def test_the_scans_before_a_found_place_are_traced_back_to_it(office):
    """What `slam2d run --resume` maps the scans before the new recording was found with."""
    from slam2d.core import se2

    loc, frames, truth = _search_history(office, 200)
    traced = loc.traced_back(frames[:201], truth)
    tt, tp = read_tum(office / "truth.tum")
    true = tp[np.searchsorted(tt, [f.timestamp for f in frames[:201]]).clip(0, len(tt) - 1)]
    err = np.hypot(*(traced[:, :2] - true[:, :2]).T)
    # (measured: median 2 mm, 95 % within 0.08 m, the worst 0.15 m, in a corridor along which nothing tells)
    assert traced.shape == (201, 3) and np.allclose(traced[-1], truth)
    assert np.median(err) < 0.02 and np.percentile(err, 95) < 0.1 and err.max() < 0.3
    # matched to the map at each step: the odometry alone, from the same place, strays further
    odom = np.array([f.odometry for f in frames[:201]])
    dead = se2.compose(se2.compose(truth, se2.inverse(odom[-1])), odom)
    assert np.hypot(*(dead[:, :2] - true[:, :2]).T).max() > 2 * err.max()
    # a scan without odometry cannot be traced back
    assert loc.traced_back([*frames[:50], dataclasses.replace(frames[50], odometry=None), *frames[51:60]],
                           truth) is None


def test_a_match_beyond_reach_is_taken_only_when_it_fits_clearly_better(office, monkeypatch):
    """A tracked pose 0.45 m off (held along a corridor) whose scan the walls place: no match within reach fits, the
    one beyond does and is taken; unless it must lead the best within by more than it does (_BEYOND_LEAD)."""
    import slam2d.localization.localizer as lz
    from slam2d.io import open_recording
    from slam2d.io.map_server import load_map_grid

    grid, _ = load_map_grid(office / "truth-map.yaml")
    frames = list(open_recording(office / "recording.log.gz").frames())
    tt, tp = read_tum(office / "truth.tum")
    frame = frames[len(frames) // 3]
    truth = tp[int(np.argmin(np.abs(tt - frame.timestamp)))]
    loc = Localizer(grid, LocalizationParams(method="match"))
    mx, my = loc._beams(frame.scan.points_in_base(), loc.p.match_beams)
    for offset in ([0.45, 0.0, 0.0], [0.0, 0.45, 0.0]):
        off = truth + offset
        within_fit = loc._refine(off, mx, my, wide=False, reach=(0.2, 0.15))
        if np.hypot(*(within_fit[0][:2] - truth[:2])) < 0.1 and loc._fit(off, mx, my) < 0.6:
            break
    else:
        pytest.skip("no pose off along a wall where the walls tell the truth apart")
    pose, fit = within_fit
    assert fit >= lz._FOUND_FIT and np.hypot(*(pose[:2] - off[:2])) > 0.2  # taken beyond the reach
    monkeypatch.setattr(lz, "_BEYOND_LEAD", 1.0)  # no match can lead by a whole scan
    pose, fit = loc._refine(off, mx, my, wide=False, reach=(0.2, 0.15))
    assert np.hypot(*(pose[:2] - off[:2])) < 0.2 + 1e-9  # refused: the pose stays within reach


def test_only_a_scan_that_fits_the_map_well_anchors_a_resumed_mapping_method():
    import slam2d.localization.localizer as lz
    from slam2d.localization.localizer import ScanResult, map_anchor

    pose = np.array([1.0, 2.0, 0.3])
    assert map_anchor(ScanResult(0.0, "localized", pose, lz._ANCHOR_FIT + 0.05, math.nan, 0)) is pose
    # (intel's second half resumed with every localized scan as an anchor: 3.9 m off; with those fitting 0.8: 0.09 m)
    assert map_anchor(ScanResult(0.0, "localized", pose, lz._ANCHOR_FIT - 0.05, math.nan, 0)) is None
    assert map_anchor(ScanResult(0.0, "searching", None, 0.95, math.nan, 0)) is None
