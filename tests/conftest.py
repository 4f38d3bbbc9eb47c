"""Shared fixtures: where the real datasets are, and skipping when they are absent."""

from __future__ import annotations

from pathlib import Path

import pytest

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
