"""``slam2d compile``: the warm-up covers every method, and fails loudly."""

from __future__ import annotations

from pathlib import Path

import pytest

from slam2d.cli import main
from slam2d.methods import get_method, method_names
from slam2d.methods.warm_up import warm_up_commands


def test_every_method_is_warmed_up_in_each_odometry_mode(tmp_path):
    simulate, runs, evaluate = warm_up_commands(tmp_path)
    assert simulate[:2] == ["simulate", "corridor-loop"]
    seen = {(a[1], "use_odometry=true" in a) for a in runs}
    for name in method_names():
        assert (name, False) in seen
        assert ((name, True) in seen) == get_method(name).optional_odometry
    # every run reads the recording with the missed turn, and writes its own folder
    assert {a[2] for a in runs} == {str(tmp_path / "missed-turn.log.gz")}
    assert len({a[a.index("--out") + 1] for a in runs}) == len(runs)
    known = next(a for a in runs if a[1] == "known-poses")
    assert f"poses={tmp_path / 'recording' / 'truth.tum'}" in known
    # karto first (the longest compilation), lago after it (it reuses karto's cached kernels)
    names = [a[1] for a in runs]
    assert names[0] == "karto" and names.index("lago") > names.index("karto")
    assert evaluate[0] == "evaluate"


def test_compile_refuses_zero_jobs(capsys):
    assert main(["compile", "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err


def test_a_failing_run_stops_the_warm_up_with_its_error(monkeypatch):
    import slam2d.methods.warm_up as warm_up

    def fake(args):
        import subprocess

        code = 1 if args[0] == "run" and args[1] == "karto" else 0
        return args, 0.0, subprocess.CompletedProcess(args, code, "", "Traceback\nValueError: broken kernel\n")

    monkeypatch.setattr(warm_up, "_slam2d", fake)
    monkeypatch.setattr(warm_up, "_write_missed_turn", lambda sim, log: None)
    with pytest.raises(warm_up.Slam2dError, match="(?s)run karto.*broken kernel"):
        warm_up.warm_up(1, say=lambda line: None)


@pytest.mark.slow
def test_compile_runs_every_method(capsys):
    assert main(["compile", "--jobs", "2"]) == 0
    out = capsys.readouterr().out
    for name in method_names():
        assert f"compiled {name}" in out
    assert "every kernel compiled and cached" in out
