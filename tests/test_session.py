"""Sessions: every run keeps what its method needs to go on; --resume maps a new recording into the old map."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from slam2d.cli import main
from slam2d.io.tum import read_tum


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Two drives through the simulated office: the world's own path, and one that starts half-way along it, backwards."""
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    root = tmp_path_factory.mktemp("drives")
    write_outputs(simulate("office", SimulationParams(duration=40.0, seed=3)), root / "d1")
    world = yaml.safe_load((root / "d1" / "world.yaml").read_text())
    world["start"] = [14.0, 7.25, math.pi]  # in the part the first drive mapped, driving the other way
    world["path"] = [[1.5, 7.25], [14.0, 7.25]]
    (root / "world2.yaml").write_text(yaml.safe_dump(world))
    write_outputs(simulate(str(root / "world2.yaml"), SimulationParams(duration=30.0, seed=4)), root / "d2")
    assert main(["run", "karto", str(root / "d1" / "recording.log.gz"), "--out", str(root / "k1")]) == 0
    return root


def test_every_run_writes_a_session_that_reads_back_as_its_frames(drives):
    from slam2d import __version__
    from slam2d.io import open_recording
    from slam2d.io.session import read_session

    session = read_session(drives / "k1", version=__version__, method="karto")
    run = json.loads((drives / "k1" / "run.json").read_text())
    assert session.record["params"] == run["params"] and session.record["seed"] == run["seed"]
    frames = list(open_recording(drives / "d1" / "recording.log.gz").frames())
    back = [f for f, *_ in session.frames()]
    assert len(back) == len(frames) == run["scans"]
    for a, b in zip(frames[::50], back[::50]):
        assert a.timestamp == b.timestamp and np.allclose(a.odometry, b.odometry)
        assert np.allclose(a.scan.ranges, b.scan.ranges, equal_nan=True, atol=1e-6)  # float32 ranges
        assert np.array_equal(a.scan.mount, b.scan.mount) and a.scan.angle_increment == b.scan.angle_increment


def test_a_resumed_drive_is_mapped_in_the_first_maps_frame(drives, tmp_path):
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate

    out = tmp_path / "k2"
    # (where it starts, roughly: the first map's frame is the world's here, both drives' odometry starting at the
    # true pose; a global search along this corridor, mapped only one way, settles 3 m off: BENCHMARKS.md has it)
    start = read_tum(drives / "d2" / "truth.tum")[1][0] + [0.2, -0.1, 0.05]
    assert main(["run", "karto", str(drives / "d2" / "recording.log.gz"), "--resume", str(drives / "k1"),
                 "--out", str(out), "--initial-pose", ",".join(map(str, start))]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["resumed"]["session_frames"] > 300 and run["resumed"]["found_at_scan"] <= 2
    # the scans before it was found are traced back and mapped too: every scan of the recording is in the run
    from slam2d.io import open_recording

    assert run["resumed"]["scans_before_placed"] == 0
    assert run["scans"] == len(list(open_recording(drives / "d2" / "recording.log.gz").frames()))
    # the first map's frame, as the first drive's trajectory against its truth fixes it
    first = absolute_trajectory_error(associate(*read_tum(drives / "k1" / "trajectory.tum"),
                                                *read_tum(drives / "d1" / "truth.tum")))
    frame = first["alignment"]
    from slam2d.core import se2

    t, p = read_tum(out / "trajectory.tum")
    ate = absolute_trajectory_error(associate(t, se2.compose(np.asarray(frame), p), *read_tum(drives / "d2" / "truth.tum")),
                                    align=False)["translation_m"]["rmse"]
    # as well placed as the first drive's own poses (0.30 m: 40 s of strong odometry noise along one corridor);
    # the full drives of BENCHMARKS.md's "Continue mapping" give 0.10 m
    assert ate < 1.2 * first["translation_m"]["rmse"]
    diag = json.loads((out / "diagnostics.json").read_text())
    assert diag["counters"]["relocations"] == 1
    # localization in the first map goes on: the new nodes are held where it places them (map anchors)
    assert diag["counters"]["map_anchors"] > 20
    # the joined map holds both drives: larger than the first one's
    assert json.loads((out / "map.json").read_text())["size_cells"] != json.loads(
        (drives / "k1" / "map.json").read_text())["size_cells"]
    # and its session holds both, with the relocation: it resumes again
    session = json.loads((out / "session" / "session.json").read_text())
    assert session["frames"]["count"] == run["resumed"]["session_frames"] + run["scans"]
    assert len(session["relocations"]) == 1
    assert len(session["map_anchors"]) >= diag["counters"]["map_anchors"]
    # replayed (relocation and map anchors included), the session rebuilds the joined run's poses
    from slam2d import __version__
    from slam2d.io.session import SessionRecorder, read_session
    from slam2d.methods.runner import build_method, replay_session

    saved = read_session(out, version=__version__, method="karto")
    slam = build_method("karto", settings=saved.record["params"], seed=int(saved.record["seed"]))
    replay_session(slam, saved, SessionRecorder())
    slam.timed_finish()
    assert np.abs(slam.trajectory()[1][-len(p):] - p).max() < 1e-3
    assert slam.diagnostics.counters["map_anchors"] == diag["counters"]["map_anchors"]
    again = tmp_path / "k3"
    assert main(["run", "karto", str(drives / "d2" / "recording.log.gz"), "--resume", str(out), "--out", str(again),
                 "--initial-pose", ",".join(str(v) for v in p[0])]) == 0
    assert json.loads((again / "run.json").read_text())["resumed"]["found_at_scan"] <= 2


def test_a_session_cut_short_edited_or_from_elsewhere_is_refused(drives, tmp_path, capsys):
    import shutil

    run = tmp_path / "k1"
    shutil.copytree(drives / "k1", run)
    data = str(drives / "d2" / "recording.log.gz")

    def refused(*args):
        code = main(["run", *args])
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err
        return err

    assert "session of karto, not of hector" in refused("hector", data, "--resume", str(run), "--out", str(tmp_path / "x"))
    assert "cannot go with --resume" in refused("karto", data, "--resume", str(run), "--set", "resolution=0.1",
                                                "--out", str(tmp_path / "x"))
    assert "--initial-pose" in refused("karto", data, "--initial-pose", "1,2,3", "--out", str(tmp_path / "x"))
    record = json.loads((run / "session" / "session.json").read_text())
    (run / "session" / "session.json").write_text(json.dumps({**record, "slam2d": "0.0.1"}))
    assert "written by slam2d 0.0.1" in refused("karto", data, "--resume", str(run), "--out", str(tmp_path / "x"))
    (run / "session" / "session.json").write_text(json.dumps(record))
    frames = (run / "session" / "frames.npz").read_bytes()
    (run / "session" / "frames.npz").write_bytes(frames[: len(frames) // 2])
    assert "cut short or edited" in refused("karto", data, "--resume", str(run), "--out", str(tmp_path / "x"))
    shutil.rmtree(run / "session")
    assert "has no session" in refused("karto", data, "--resume", str(run), "--out", str(tmp_path / "x"))
    assert not (tmp_path / "x").exists()


def test_a_session_never_unpickles(tmp_path):
    from slam2d import __version__
    from slam2d.errors import InputError
    from slam2d.io.session import SessionRecorder, read_session, write_session

    write_session(tmp_path / "session", SessionRecorder(), method="odometry", params={}, seed=0, version=__version__)
    # frames.npz replaced by one holding a Python object, its checksum updated: still refused
    import hashlib
    import io

    buffer = io.BytesIO()
    np.savez(buffer, time=np.array([object()], dtype=object))
    (tmp_path / "session" / "frames.npz").write_bytes(buffer.getvalue())
    record = json.loads((tmp_path / "session" / "session.json").read_text())
    record["frames"]["sha256"] = hashlib.sha256(buffer.getvalue()).hexdigest()
    (tmp_path / "session" / "session.json").write_text(json.dumps(record))
    with pytest.raises(InputError, match="cannot be read"):
        read_session(tmp_path, version=__version__)


def test_a_replayed_session_rebuilds_the_run_and_gmapping_goes_on_too(drives, tmp_path, capsys):
    from slam2d import __version__
    from slam2d.io.session import SessionRecorder, read_session
    from slam2d.methods.runner import build_method, replay_session

    assert main(["run", "gmapping", str(drives / "d1" / "recording.log.gz"), "--out", str(tmp_path / "g"),
                 "--set", "particles=5"]) == 0
    for run, method in ((tmp_path / "g", "gmapping"), (drives / "k1", "karto")):
        session = read_session(run, version=__version__, method=method)
        slam = build_method(method, settings=session.record["params"], seed=int(session.record["seed"]))
        replay_session(slam, session, SessionRecorder())
        slam.timed_finish()
        t, p = slam.trajectory()
        t0, p0 = read_tum(run / "trajectory.tum")
        # the same poses (ranges are kept as 32-bit floats: karto's correlation grids move by a tenth of a mm)
        assert np.array_equal(t, t0) and np.abs(p - p0).max() < 1e-3, method
    start = read_tum(drives / "d2" / "truth.tum")[1][0]
    assert main(["run", "gmapping", str(drives / "d2" / "recording.log.gz"), "--resume", str(tmp_path / "g"),
                 "--out", str(tmp_path / "g2"), "--initial-pose", ",".join(map(str, start))]) == 0
    diag = json.loads((tmp_path / "g2" / "diagnostics.json").read_text())
    assert diag["counters"]["relocations"] == 1
    # known-poses has no state to go on from
    code = main(["run", "known-poses", str(drives / "d2" / "recording.log.gz"), "--resume", str(tmp_path / "g"),
                 "--out", str(tmp_path / "x")])
    assert code == 2 and "not of known-poses" in capsys.readouterr().err


def test_a_map_anchor_far_from_where_the_matches_put_the_node_is_refused(drives):
    """Localization in the saved map can take a wrong place: an anchor more than MAP_ANCHOR_GATE from the
    node's matched pose is not believed (no edge, the node not moved); a near one ties the node to the gauge."""
    from slam2d import __version__
    from slam2d.graph.sequential import MAP_ANCHOR_GATE
    from slam2d.io import open_recording
    from slam2d.io.session import SessionRecorder, read_session
    from slam2d.methods.runner import build_method, replay_session

    saved = read_session(drives / "k1", version=__version__, method="karto")
    new = list(open_recording(drives / "d2" / "recording.log.gz").frames())
    truth = read_tum(drives / "d2" / "truth.tum")[1]

    def resumed(offset):
        slam = build_method("karto", settings=saved.record["params"], seed=int(saved.record["seed"]))
        replay_session(slam, saved, SessionRecorder())
        graph = slam.frontend.graph
        nodes, edges = graph.num_nodes, graph.num_edges
        slam.relocate(truth[0])
        slam.anchor_to_map(truth[0] + offset)
        slam.feed(new[0])
        return slam, graph, nodes, edges

    slam, graph, nodes, edges = resumed(np.array([MAP_ANCHOR_GATE + 0.5, 0.0, 0.0]))
    assert graph.num_nodes == nodes + 1 and graph.num_edges == edges + 1  # the relocation's edge alone
    assert slam.diagnostics.counters["map_anchors_refused"] == 1
    assert np.hypot(*(graph.poses[nodes][:2] - truth[0][:2])) < 0.3
    slam, graph, nodes, edges = resumed(np.array([0.1, 0.0, 0.0]))
    assert graph.num_edges == edges + 2 and slam.diagnostics.counters["map_anchors"] == 1
    anchor_edge = graph.num_edges - 1
    assert graph.edge_i[anchor_edge] == graph.fixed and graph.edge_j[anchor_edge] == nodes
    # the node's estimate is averaged with it: it moves towards the anchor
    assert graph.poses[nodes][0] > truth[0][0] + 0.02
