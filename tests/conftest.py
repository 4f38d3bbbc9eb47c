"""Shared fixtures: where the real datasets are, and skipping when they are absent."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

# Property tests check correctness, not time: a per-example deadline only flakes on a loaded
# machine (CI shares 2 cores), so it is off for every test unless one sets its own.
settings.register_profile("slam2d", deadline=None)
settings.load_profile("slam2d")

PROJECT_ROOT = Path(__file__).resolve().parents[1]
DATASETS = PROJECT_ROOT.parent / "shared" / "datasets"


@pytest.fixture(scope="session")
def datasets() -> Path:
    """``../shared/datasets``; tests using it skip with a reason when it is missing."""
    if not DATASETS.is_dir():
        pytest.skip(f"real datasets not found at {DATASETS} (CI has them; see README)")
    return DATASETS


def dataset_file(relative: str) -> Path:
    """A file under ``../shared/datasets``, skipping the calling test when it is missing."""
    path = DATASETS / relative
    if not path.exists():
        pytest.skip(f"dataset file {path} not found (CI has ../shared/datasets)")
    return path


@pytest.fixture(scope="session")
def paper_arena(tmp_path_factory) -> Path:
    """One pass of the study's arena as ``slam2d simulate paper-arena`` makes it (seed 0), with exact truth.

    Simulated once per test process and shared, read-only, by the methods' arena tests.
    """
    from slam2d.cli import main

    out = tmp_path_factory.mktemp("paper-arena")
    assert main(["simulate", "paper-arena", "--out", str(out)]) == 0
    return out


def run_ate(method: str, sim: Path, out: Path, *options: str) -> float:
    """``slam2d run METHOD`` on a simulation's recording, then ``slam2d evaluate``: the ATE RMSE in metres."""
    import json

    from slam2d.cli import main

    assert main(["run", method, str(sim / "recording.log.gz"), "--out", str(out), *options]) == 0
    assert main(["evaluate", str(out), "--truth", str(sim), "--json"]) == 0
    return json.loads((out / "evaluation.json").read_text())["trajectory"]["ate"]["translation_m"]["rmse"]


def recording_frames(path: Path) -> list:
    """Every frame of a recording, read with the default options."""
    from slam2d.io import open_recording

    return list(open_recording(path).frames())
