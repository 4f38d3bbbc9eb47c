"""The parameter files shipped in params/ are valid: each names its method and builds it."""

from __future__ import annotations

from pathlib import Path

import pytest

from slam2d.methods.runner import build_method, read_params_file
from slam2d.params import as_dict

PARAMS = Path(__file__).resolve().parents[1] / "params"
FILES = sorted(PARAMS.glob("*.yaml"))


def test_there_are_parameter_files():
    assert len(FILES) >= 5


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_parameter_file_builds_its_method(path):
    values, extras = read_params_file(path)
    assert path.stem.startswith(extras["method"] + "-"), "the file name starts with its method"
    slam = build_method(extras["method"], params_file=path)
    built = as_dict(slam.params)
    for name, value in values.items():
        # every value in the file reached the method, none was dropped or renamed
        assert built[name] == value, name
    # the header says what it is for and how to use it
    text = path.read_text()
    assert text.startswith("#") and "# Use: slam2d run " + extras["method"] in text


def test_a_file_for_another_method_is_refused(tmp_path):
    from slam2d.errors import InputError

    with pytest.raises(InputError, match="karto"):
        build_method("gmapping", params_file=PARAMS / "karto-short-range.yaml")
