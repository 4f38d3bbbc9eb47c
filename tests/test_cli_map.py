"""`slam2d map` made cheaper: one parser per command, one read of the recording, no matplotlib.

Each shortcut must leave the output as it was; these tests compare against the long way round.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from slam2d import cli
from slam2d.cli import main


@pytest.fixture(scope="module")
def paper_log(paper_arena):
    return paper_arena / "recording.log.gz", paper_arena / "truth.tum"


def _subparsers(parser):
    return next(a for a in parser._actions if a.dest == "command").choices


def test_one_commands_parser_is_that_command_of_the_whole_parser():
    whole = _subparsers(cli.build_parser())
    assert len(whole) == len(cli._COMMANDS)
    for name, full in whole.items():
        alone = _subparsers(cli.build_parser(name))
        assert list(alone) == [name]
        assert alone[name].format_help() == full.format_help()
    # anything else gets every command, so argparse can list them
    assert len(_subparsers(cli.build_parser("no-such-command"))) == len(whole)
    assert len(_subparsers(cli.build_parser(None))) == len(whole)


def test_map_imports_neither_the_experiments_nor_matplotlib_nor_scipy_ndimage(paper_log, tmp_path):
    log, truth = paper_log
    code = (
        "import sys; from slam2d.cli import main; "
        f"assert main(['map', {str(log)!r}, '--poses', {str(truth)!r}, '--out', {str(tmp_path / 'm')!r}]) == 0; "
        "print('LOADED:' + ' '.join(m for m in ('matplotlib', 'scipy.ndimage', 'scipy.spatial', 'slam2d.experiments.section5', "
        "'slam2d.sim.simulate', 'rich.progress') if m in sys.modules))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "LOADED:", proc.stdout
    assert (tmp_path / "m" / "preview.png").is_file()


def _outputs(folder):
    import json

    info = json.loads((folder / "map.json").read_text())
    info["stats"].pop("seconds")  # wall time
    return (folder / "map.pgm").read_bytes(), (folder / "map.yaml").read_text().replace(str(folder), ""), info


@pytest.mark.parametrize("poses", [True, False], ids=["poses", "odometry"])
def test_map_reads_the_recording_once_and_writes_what_three_reads_wrote(paper_log, tmp_path, monkeypatch, poses):
    from slam2d.io.carmen import CarmenLog

    log, truth = paper_log
    extra = ["--poses", str(truth)] if poses else []
    reads = []
    original = CarmenLog.frames
    monkeypatch.setattr(CarmenLog, "frames", lambda self, *a, **k: reads.append(1) or original(self, *a, **k))
    assert main(["map", str(log), *extra, "--out", str(tmp_path / "once")]) == 0
    assert len(reads) == 1
    # a budget too small for the recording: every pass reads it again, and the files are the same
    monkeypatch.setattr(cli._FrameCache.__init__, "__defaults__", (0,))
    assert main(["map", str(log), *extra, "--out", str(tmp_path / "again")]) == 0
    assert len(reads) == (3 if poses else 4)  # mapping and agreement (and the odometry pass)
    assert _outputs(tmp_path / "once") == _outputs(tmp_path / "again")


def test_poses_at_scans_is_interpolate_poses_scan_by_scan():
    from types import SimpleNamespace

    from slam2d.io.tum import interpolate_poses, poses_at_scans

    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0.0, 100.0, 300))
    p = rng.normal(size=(300, 3))
    shuffled = rng.permutation(300)  # unsorted trajectories are sorted first, as interpolate_poses does
    queries = np.concatenate([rng.uniform(-5.0, 105.0, 700), t[::7]])
    frames = [SimpleNamespace(scan=SimpleNamespace(timestamp=q)) for q in queries]
    out = list(poses_at_scans(frames, t[shuffled], p[shuffled], 0.5, chunk=64))
    assert [f for f, _ in out] == frames
    for q, (_, pose) in zip(queries, out):
        want, ok = interpolate_poses(t, p, q, 0.5)
        if ok[0]:
            assert pose is not None and np.array_equal(pose, want[0])
        else:
            assert pose is None


def test_preview_pixels_are_matplotlibs():
    matplotlib = pytest.importorskip("matplotlib")

    from slam2d.report.images import gray_pixels

    img = np.concatenate([np.linspace(0.0, 1.0, 100_001), [0.0, 1.0, 0.5, 1 / 3, 205 / 255]])
    want = matplotlib.colormaps["gray"](img, bytes=True)
    assert np.all(want[:, 0] == want[:, 1]) and np.all(want[:, 3] == 255)
    assert np.array_equal(gray_pixels(img), want[:, 0])


def test_by_time_sorts_stably_and_leaves_a_sorted_trajectory_alone():
    from slam2d.io.tum import by_time

    t = np.array([0.0, 2.0, 1.0, 1.0, 3.0])
    p = np.arange(15, dtype=np.float64).reshape(5, 3)
    ts, ps = by_time(t, p)
    assert np.array_equal(ts, [0.0, 1.0, 1.0, 2.0, 3.0])
    assert np.array_equal(ps[:, 0], [0.0, 6.0, 9.0, 3.0, 12.0])  # the two poses at t=1 in file order
    sorted_t = np.sort(t)
    assert by_time(sorted_t, p)[0] is sorted_t
