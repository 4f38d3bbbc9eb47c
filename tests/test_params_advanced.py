"""Advanced parameters: listed after the others by feature, and recorded in a run only when changed."""

from __future__ import annotations

import json
from dataclasses import dataclass

import pytest

from slam2d.cli import main
from slam2d.methods import available, get_method
from slam2d.params import advanced_groups, as_dict, as_record, describe, from_mapping, markdown_table, param


@dataclass
class Feature:
    feature: bool = param(False, help="a feature most runs leave off", advanced=True, group="the feature")
    feature_gain: float = param(2.0, unit="m", help="its knob", advanced=True, group="the feature")


@dataclass
class Example(Feature):
    resolution: float = param(0.05, unit="m", low=0.001, help="cell size")
    smoothing: int = param(3, help="a slam2d addition's knob", advanced=True, group="smoothing")
    seed_like: int = param(0, help="a plain one")


def test_param_keeps_advanced_and_group():
    info = {p.name: p for p in describe(Example)}
    assert info["feature_gain"].advanced and info["feature_gain"].group == "the feature"
    assert not info["resolution"].advanced and info["resolution"].group == ""
    with pytest.raises(ValueError, match="needs its group"):
        param(1, help="ungrouped", advanced=True)


def test_listing_puts_own_then_inherited_then_advanced_by_group():
    # declaration order is feature, feature_gain, resolution, smoothing, seed_like (the base class's first)
    assert [p.name for p in describe(Example)] == ["resolution", "seed_like", "smoothing", "feature", "feature_gain"]
    assert {g: [p.name for p in ps] for g, ps in advanced_groups(Example).items()} == {
        "smoothing": ["smoothing"], "the feature": ["feature", "feature_gain"]}


def test_markdown_table_folds_the_advanced_ones_by_group():
    table = markdown_table(Example, names="settings")
    main_table, advanced = table.split("**Advanced**")
    assert "`resolution`" in main_table and "`feature`" not in main_table
    assert "<details><summary>the feature (2)</summary>" in advanced and "| `feature_gain` | `2.0` | m |" in advanced
    assert advanced.count("<details>") == advanced.count("</details>") == 2


def test_a_record_holds_the_advanced_ones_only_where_changed():
    assert as_record(Example()) == {"resolution": 0.05, "seed_like": 0}
    changed = Example(feature=True, resolution=0.1)
    assert as_record(changed) == {"resolution": 0.1, "seed_like": 0, "feature": True}
    assert from_mapping(Example, as_record(changed)) == changed


@pytest.mark.parametrize("name", list(available()))
def test_a_trimmed_record_builds_the_same_parameters(name):
    """A run.json without the advanced parameters (and an older one with every parameter) loads into the same
    parameters: from_mapping fills in the defaults."""
    cls = get_method(name).Params
    full = as_dict(cls())
    trimmed = as_record(cls())
    assert set(trimmed) == {p.name for p in describe(cls) if not p.advanced}
    assert from_mapping(cls, trimmed) == from_mapping(cls, full) == cls()


def test_gmapping_lists_its_own_parameters_before_the_refinements():
    from slam2d.methods.gmapping import GMappingParams

    params = describe(GMappingParams)
    assert params[0].name == "particles"
    for p in params:
        if p.name.startswith(("loop_correction", "wall_refinement")):
            assert p.advanced and p.group == p.name.split("_")[0] + " " + p.name.split("_")[1], p.name
    first_advanced = next(k for k, p in enumerate(params) if p.advanced)
    assert not any(p.advanced for p in params[:first_advanced]) and all(p.advanced for p in params[first_advanced:])


@pytest.mark.parametrize("name, most", [("karto", 37), ("lago", 37), ("gmapping", 35), ("hector", 20),
                                        ("coreslam", 20), ("crsm", 20), ("known-poses", 20), ("odometry", 20)])
def test_each_method_shows_few_parameters(name, most):
    assert sum(not p.advanced for p in describe(get_method(name).Params)) <= most


def test_methods_lists_the_advanced_ones_only_with_all(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["methods", "gmapping"]) == 0
    out = capsys.readouterr().out.split("logged per update")[0]
    assert " particles " in out and " loop_correction_distance " not in out and " islands " not in out
    n = sum(p.advanced for p in describe(get_method("gmapping").Params))
    assert f"and {n} advanced parameters (" in out and "'slam2d methods gmapping --all' lists them" in out
    assert main(["methods", "gmapping", "--all"]) == 0
    every = capsys.readouterr().out.split("logged per update")[0]
    assert " loop_correction_distance " in every and "advanced: loop correction" in every
    assert "advanced parameters (" not in every
    # the advanced tables come after the method's own, a feature at a time
    assert every.index(" particles ") < every.index("advanced: islands") < every.index("advanced: loop correction")


def test_run_json_records_advanced_parameters_only_where_changed(tmp_path):
    # (karto, not gmapping: a process that ran gmapping's OpenMP kernels cannot fork children that run them, and the
    # demo test forks gmapping in this process when they share a worker; numba terminates such a child)
    from slam2d.methods.runner import build_method
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    write_outputs(simulate("paper-arena", SimulationParams(seed=3, duration=15.0)), tmp_path / "d")
    data = str(tmp_path / "d" / "recording.log.gz")
    out = tmp_path / "r"
    assert main(["run", "karto", data, "--out", str(out), "--set", "minimum_travel_distance=0.3",
                 "--set", "loop_retry_distance=0.5"]) == 0
    record = json.loads((out / "run.json").read_text())
    params = record["params"]
    cls = get_method("karto").Params
    assert params["minimum_travel_distance"] == 0.3 and params["loop_retry_distance"] == 0.5
    assert {p.name for p in describe(cls) if p.advanced and p.name in params} == {"loop_retry_distance"}
    session = json.loads((out / "session" / "session.json").read_text())
    assert session["params"] == params
    # read back (--params run.json, as resume and compare do): the defaults fill in the rest
    again = build_method("karto", params_file=out / "run.json")
    assert again.params == from_mapping(cls, {**as_dict(cls()), **params})
    assert again.params.loop_retry_distance == 0.5 and again.params.wall_refinement_edge_scale == 1.0
    rerun = tmp_path / "again"
    assert main(["run", "karto", data, "--out", str(rerun), "--params", str(out / "run.json")]) == 0
    assert (rerun / "trajectory.tum").read_bytes() == (out / "trajectory.tum").read_bytes()
    assert json.loads((rerun / "run.json").read_text())["params"] == params


def test_markdown_table_can_leave_the_advanced_ones_out_or_give_them_alone():
    """The method pages show the parameters most runs set; their advanced ones go on a reference page of their own,
    a heading and a table per group (docs/generate.py)."""
    main_only = markdown_table(Example, names="settings", advanced="omit")
    assert "`resolution`" in main_only and "`feature`" not in main_only and "Advanced" not in main_only
    sections = markdown_table(Example, names="settings", advanced="sections")
    assert "`resolution`" not in sections and "`smoothing`" in sections and "<details>" not in sections
    assert sections.index("## smoothing") < sections.index("`smoothing`") < sections.index("## the feature")
    assert "| `feature_gain` | `2.0` | m |" in sections.split("## the feature")[1]
    with pytest.raises(ValueError, match="advanced"):
        markdown_table(Example, advanced="hidden")
