"""Parameter dataclasses drive the CLI; atomic writes never leave partial files."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path, write_text_atomic
from slam2d.params import add_arguments, describe, from_arguments, from_mapping, markdown_table, param


@dataclass
class Example:
    resolution: float = param(0.05, unit="m", help="cell size", low=0.001, high=1.0)
    particles: int = param(30, help="number of particles", low=1)
    mode: str = param("fast", help="how to run", choices=("fast", "exact"))
    topic: str | None = param(None, help="a topic")
    verbose: bool = param(False, help="talk more")


def parse(*argv):
    parser = argparse.ArgumentParser()
    add_arguments(parser, Example)
    return from_arguments(Example, parser.parse_args(list(argv)))


def test_defaults_and_overrides():
    assert parse() == Example()
    got = parse("--resolution", "0.1", "--particles", "5", "--mode", "exact", "--topic", "/scan", "--verbose")
    assert got == Example(0.1, 5, "exact", "/scan", True)


@pytest.mark.parametrize(
    "argv, needle",
    [
        (("--resolution", "abc"), "resolution: 'abc' is not a valid float"),
        (("--particles", "2.5"), "particles: '2.5' is not a valid int"),
        (("--resolution", "0"), "resolution: 0.0 m is below the minimum 0.001 m"),
        (("--resolution", "2"), "above the maximum"),
        (("--mode", "slow"), "mode: 'slow' is not one of: fast, exact"),
    ],
)
def test_bad_values_name_the_parameter(argv, needle):
    with pytest.raises(InputError) as err:
        parse(*argv)
    assert needle in str(err.value)


def test_nan_is_not_a_value_of_any_range():
    # NaN compares false with both ends of a range, so it used to pass every check (and crash later).
    for argv in (["--resolution", "nan"], ["--resolution", "NaN"]):
        with pytest.raises(InputError, match="is not a number") as info:
            parse(*argv)
        assert info.value.field == "resolution"
    with pytest.raises(InputError, match="resolution: nan m is not a number"):
        from_mapping(Example, {"resolution": float("nan")}, path="p.yaml")


def test_yaml_booleans_are_not_numbers():
    for name in ("resolution", "particles"):
        with pytest.raises(InputError, match="True is not a valid") as info:
            from_mapping(Example, {name: True}, path="p.yaml")
        assert info.value.field == name and info.value.path == "p.yaml"
    assert from_mapping(Example, {"verbose": True}).verbose is True


def test_help_carries_units_and_defaults():
    parser = argparse.ArgumentParser()
    add_arguments(parser, Example)
    text = parser.format_help()
    assert "--resolution" in text and "[m]" in text and "default: 0.05" in text
    assert "one of: fast, exact" in text


def test_markdown_table_lists_every_field():
    table = markdown_table(Example)
    for p in describe(Example):
        assert f"`--{p.name.replace('_', '-')}`" in table
    assert "| `--resolution` | `0.05` | m |" in table


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "map.pgm"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_replaces_file_and_folder(tmp_path):
    target = tmp_path / "a.txt"
    write_text_atomic(target, "one")
    write_text_atomic(target, "two")
    assert target.read_text() == "two"
    folder = tmp_path / "bag"
    for content in ("first", "second"):
        with atomic_path(folder) as tmp:
            tmp.mkdir()
            (tmp / "x").write_text(content)
    assert (folder / "x").read_text() == "second"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "bag"]


def test_atomic_write_never_replaces_a_folder_with_a_file(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "precious.txt").write_text("keep me")
    with pytest.raises(InputError, match="is a folder") as info:
        write_text_atomic(folder, "{}")
    assert info.value.path == str(folder)
    assert (folder / "precious.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]  # no temporary file left
