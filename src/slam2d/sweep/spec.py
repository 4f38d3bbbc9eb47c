"""Sweep specification: read a YAML spec, check it, and name every mistake by key path and line.

A spec says which methods to run with which parameter values, on which
datasets, with which seeds, and which metrics to collect::

    name: resolution-study
    seeds: [0, 1]                     # method seeds (or a count: 3 = 0, 1, 2)
    methods:
      odometry:
        grid:                         # every combination is run
          resolution: [0.02, 0.05, 0.1]
          p_hit: {from: 0.6, to: 0.9, num: 4}
        random:                       # plus (times) random samples, reproducible with their seed
          samples: 5
          seed: 1
          params:
            p_miss: {from: 0.1, to: 0.45}
        set: {max_range: 20}          # the same for every run
    datasets:
      - world: paper-arena            # simulated, one recording per seed
        duration: 20
        seeds: [0, 1, 2]
        odometry_noise: {srr: [0.05, 0.2]}   # lists here are swept too
      - file: ../../shared/datasets/intel/intel.clf.gz    # relative to this file
        reference: ../../shared/datasets/intel/reference.tum
    metrics: [ate, map_error, time_per_scan]
    objective: ate                    # what "best" means (default: the first metric with a direction)

:func:`load_spec` checks the structure, the datasets, the metrics and the
values' shapes; :func:`check_methods` checks the method names and every
parameter against the method's parameter dataclass. The second is separate
because methods register at run time (a method may live on another branch or
in a plug-in): a spec naming a method that is not installed is well formed,
but cannot run.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from slam2d.errors import InputError

__all__ = ["Metric", "METRICS", "ParamAxis", "MethodSweep", "DatasetSpec", "SweepSpec", "load_spec",
           "parse_spec", "check_methods"]


# --------------------------------------------------------------------------- metrics

@dataclass(frozen=True)
class Metric:
    """A metric a sweep can collect: a short name for a column of :data:`~slam2d.eval.evaluate.METRIC_COLUMNS`."""

    name: str
    key: tuple[str, ...]

    @property
    def column(self) -> Any:
        from slam2d.eval.evaluate import METRIC_COLUMNS

        (col,) = [c for c in METRIC_COLUMNS if c.key == self.key]
        return col

    @property
    def unit(self) -> str:
        return self.column.unit

    @property
    def better(self) -> str | None:
        return self.column.better

    @property
    def help(self) -> str:
        return self.column.help

    def value(self, evaluation: dict[str, Any] | None) -> float | None:
        return self.column.value(evaluation)


_METRIC_KEYS = {
    "ate": ("trajectory", "ate", "translation_m", "rmse"),
    "ate_rot": ("trajectory", "ate", "rotation_deg", "rmse"),
    "rpe": ("trajectory", "rpe_per_metre", "translation_percent", "mean"),
    "rpe_rot": ("trajectory", "rpe_per_frame", "rotation_deg", "rmse"),
    "relations": ("relations", "translation_abs_m", "mean"),
    "relations_rot": ("relations", "rotation_abs_deg", "mean"),
    "map_error": ("map_truth", "truth_to_map_m", "mean"),
    "ghost_walls": ("map_truth", "map_to_truth_m", "mean"),
    "precision": ("map_truth", "precision"),
    "recall": ("map_truth", "recall"),
    "occupied_fraction": ("map_quality", "occupied_fraction"),
    "uncertain_fraction": ("map_quality", "uncertain_fraction"),
    "corners": ("map_quality", "corners"),
    "enclosed_areas": ("map_quality", "enclosed_areas"),
    "time_per_scan": ("cost", "wall_s_per_scan", "median"),
    "time_per_scan_p95": ("cost", "wall_s_per_scan", "p95"),
    "real_time_factor": ("cost", "real_time_factor"),
    "peak_memory": ("cost", "peak_rss_mb"),
}

#: Every metric a spec may name, by its name in the spec and the results table.
METRICS: dict[str, Metric] = {name: Metric(name, key) for name, key in _METRIC_KEYS.items()}
DEFAULT_METRICS = ("ate", "map_error", "time_per_scan")

#: Cost metrics: they depend on the machine and the load, not on the seeds.
COST_METRICS = frozenset({"time_per_scan", "time_per_scan_p95", "real_time_factor", "peak_memory"})


# --------------------------------------------------------------------------- the parsed spec

@dataclass(frozen=True)
class ParamAxis:
    """One swept parameter: explicit ``values`` (a grid axis) or a ``low``-``high`` range (random)."""

    name: str
    where: str  # key path in the spec, for messages
    values: tuple[Any, ...] = ()
    low: float | None = None
    high: float | None = None
    log: bool = False
    integer: bool = False
    choices: tuple[Any, ...] = ()


@dataclass
class MethodSweep:
    """What to run of one method: grid axes, random ranges (with a sample count and seed), fixed values."""

    method: str
    grid: list[ParamAxis] = field(default_factory=list)
    random: list[ParamAxis] = field(default_factory=list)
    samples: int = 0
    random_seed: int = 0
    fixed: dict[str, Any] = field(default_factory=dict)
    where: str = ""

    @property
    def swept(self) -> list[str]:
        """Names of the parameters this sweep varies, in spec order."""
        return [a.name for a in self.grid] + [a.name for a in self.random if a.name not in {g.name for g in self.grid}]


@dataclass
class DatasetSpec:
    """A recording (``file``) or a simulated world (``world``) with seeds and swept simulation settings."""

    name: str
    where: str
    file: Path | None = None
    truth: Path | None = None
    reference: Path | None = None
    truth_map: Path | None = None
    relations: Path | None = None
    world: str | None = None
    seeds: tuple[int, ...] = (0,)
    duration: float | None = None
    simulation: dict[str, Any] = field(default_factory=dict)  # name -> value or tuple of values (swept)
    odometry_noise: dict[str, Any] = field(default_factory=dict)

    @property
    def simulated(self) -> bool:
        return self.world is not None


@dataclass
class SweepSpec:
    path: Path
    name: str
    methods: list[MethodSweep]
    datasets: list[DatasetSpec]
    seeds: tuple[int, ...]
    metrics: list[Metric]
    objective: Metric
    text: str = ""
    lines: dict[str, int] = field(default_factory=dict)

    def error(self, message: str, where: str) -> InputError:
        """An :class:`InputError` naming the spec file, the line of ``where`` (if known) and the key path."""
        return InputError(message, path=self.path, where=_line(self.lines, where), field=where)


# --------------------------------------------------------------------------- reading

def _key_lines(node: Any, prefix: str, out: dict[str, int]) -> None:
    """Key path -> line number (1-based) for every node of a composed YAML document."""
    out.setdefault(prefix, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            name = str(key.value)
            path = f"{prefix}.{name}" if prefix else name
            out[path] = key.start_mark.line + 1
            _key_lines(value, path, out)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _key_lines(item, f"{prefix}[{i}]", out)


def _line(lines: dict[str, int], where: str) -> int | None:
    """The line of ``where`` or of its closest ancestor that has one."""
    path = where
    while path:
        if path in lines:
            return lines[path]
        cut = max(path.rfind("."), path.rfind("["))
        path = path[:cut] if cut > 0 else ""
    return None


def load_spec(path: str | Path) -> SweepSpec:
    """Read and check a sweep spec (everything but the method names and parameters: see :func:`check_methods`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such sweep spec" if not path.exists() else "is not a file", path=path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError("is not text (a YAML sweep spec was expected)", path=path) from None
    return parse_spec(text, path)


def parse_spec(text: str, path: str | Path) -> SweepSpec:
    path = Path(path)
    try:
        node = yaml.compose(text)
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(f"not valid YAML: {getattr(exc, 'problem', None) or exc}", path=path,
                         where=mark.line + 1 if mark is not None else None) from None
    lines: dict[str, int] = {}
    if node is not None:
        _key_lines(node, "", lines)
    p = _Parser(path, lines)
    if not isinstance(doc, dict):
        raise p.err("a sweep spec is a mapping with 'methods', 'datasets' and optionally 'seeds', 'metrics', "
                    "'objective', 'name'", "")
    p.known(doc, "", {"name", "description", "methods", "datasets", "seeds", "metrics", "objective"})
    for required in ("methods", "datasets"):
        if required not in doc:
            raise p.err(f"'{required}' is missing", "")
    methods = p.methods(doc["methods"])
    datasets = p.datasets(doc["datasets"])
    seeds = p.seeds(doc.get("seeds", [0]), "seeds")
    metrics = p.metrics(doc.get("metrics", list(DEFAULT_METRICS)))
    objective = p.objective(doc.get("objective"), metrics)
    p.count_runs(methods, datasets, seeds)
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise p.err("must be a non-empty string", "name")
    return SweepSpec(path, name, methods, datasets, seeds, metrics, objective, text, lines)


class _Parser:
    def __init__(self, path: Path, lines: dict[str, int]) -> None:
        self.path = path
        self.lines = lines

    def err(self, message: str, where: str) -> InputError:
        return InputError(message, path=self.path, where=_line(self.lines, where), field=where or None)

    def count(self, value: int, where: str) -> None:
        """A count of values, samples or seeds; one this large is a typo, not a study."""
        if value > _MAX_COUNT:
            raise self.err(f"{value} is more than {_MAX_COUNT}", where)

    def count_runs(self, methods: list[MethodSweep], datasets: list[DatasetSpec], seeds: tuple[int, ...]) -> None:
        settings = sum(math.prod(len(a.values) for a in m.grid) * (m.samples if m.random else 1) for m in methods)
        recordings = sum(math.prod(len(v) for sec in (d.simulation, d.odometry_noise) for v in sec.values()
                                   if isinstance(v, tuple)) * len(d.seeds) for d in datasets)
        runs = settings * recordings * len(seeds)
        if runs > _MAX_RUNS:
            raise self.err(f"{settings} settings x {recordings} recordings x {len(seeds)} seeds is {runs} runs, "
                           f"more than {_MAX_RUNS}", "methods")

    def known(self, doc: dict[str, Any], where: str, keys: set[str]) -> None:
        for k in doc:
            if k not in keys:
                at = f"{where}.{k}" if where else str(k)
                raise self.err(f"unknown key {k!r}; expected one of: {', '.join(sorted(keys))}", at)

    # ----- methods

    def methods(self, raw: Any) -> list[MethodSweep]:
        if isinstance(raw, list):  # shorthand: a list of names, every method with its defaults
            for i, name in enumerate(raw):
                if not isinstance(name, str):
                    raise self.err("a method name was expected", f"methods[{i}]")
            raw = {name: None for name in raw}
        if not isinstance(raw, dict) or not raw:
            raise self.err("expected a mapping of method names to their sweeps (or a list of names)", "methods")
        return [self.method(str(name), section) for name, section in raw.items()]

    def method(self, name: str, section: Any) -> MethodSweep:
        where = f"methods.{name}"
        sweep = MethodSweep(name, where=where)
        if section is None:
            return sweep
        if not isinstance(section, dict):
            raise self.err("expected a mapping with 'grid', 'random' and/or 'set'", where)
        self.known(section, where, {"grid", "random", "set"})
        grid = section.get("grid") or {}
        if not isinstance(grid, dict):
            raise self.err("expected a mapping of parameter names to lists of values or {from, to, num}",
                           f"{where}.grid")
        for pname, spec in grid.items():
            sweep.grid.append(self.grid_axis(str(pname), spec, f"{where}.grid.{pname}"))
        if "random" in section:
            self.random(sweep, section["random"], f"{where}.random")
        fixed = section.get("set") or {}
        if not isinstance(fixed, dict):
            raise self.err("expected a mapping of parameter names to values", f"{where}.set")
        for pname, value in fixed.items():
            if isinstance(value, (list, dict)):
                raise self.err("a fixed value was expected (sweep lists under 'grid')", f"{where}.set.{pname}")
        sweep.fixed = {str(k): v for k, v in fixed.items()}
        names = [a.name for a in sweep.grid] + [a.name for a in sweep.random]
        for pname in sweep.fixed:
            if pname in names:
                raise self.err("is both swept and set; keep one", f"{where}.set.{pname}")
        for a in sweep.random:
            if a.name in {g.name for g in sweep.grid}:
                raise self.err("is both on the grid and random; keep one", a.where)
        return sweep

    def grid_axis(self, name: str, spec: Any, where: str) -> ParamAxis:
        if isinstance(spec, list):
            if not spec:
                raise self.err("the list of values is empty", where)
            for i, v in enumerate(spec):
                if isinstance(v, (list, dict)):
                    raise self.err("a plain value was expected", f"{where}[{i}]")
            if len(set(map(repr, spec))) != len(spec):
                raise self.err("a value is listed twice", where)
            return ParamAxis(name, where, values=tuple(spec))
        if isinstance(spec, dict):
            self.known(spec, where, {"from", "to", "num", "scale", "type"})
            for k in ("from", "to", "num"):
                if k not in spec:
                    raise self.err(f"'{k}' is missing (a range is {{from, to, num}}, optionally scale: log, "
                                   "type: int)", where)
            low, high, log, integer = self.range(spec, where)
            num = spec["num"]
            if not isinstance(num, int) or isinstance(num, bool) or num < 1:
                raise self.err(f"{num!r} must be a whole number >= 1", f"{where}.num")
            self.count(num, f"{where}.num")
            values = _spaced(low, high, num, log)
            if integer:
                values = sorted({int(round(v)) for v in values})
            else:
                values = [float(f"{v:.6g}") for v in values]  # readable values in the table and the plots
            return ParamAxis(name, where, values=tuple(values), low=low, high=high, log=log, integer=integer)
        # a single value on the grid is a one-point axis
        return ParamAxis(name, where, values=(spec,))

    def range(self, spec: dict[str, Any], where: str) -> tuple[float, float, bool, bool]:
        low, high = spec["from"], spec["to"]
        for k, v in (("from", low), ("to", high)):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise self.err(f"{v!r} is not a finite number", f"{where}.{k}")
        if high < low:
            raise self.err(f"'to' ({high}) is below 'from' ({low})", where)
        scale = spec.get("scale", "linear")
        if scale not in ("linear", "log"):
            raise self.err(f"{scale!r} is not one of: linear, log", f"{where}.scale")
        if scale == "log" and low <= 0:
            raise self.err("a log scale needs 'from' > 0", f"{where}.from")
        kind = spec.get("type", "int" if isinstance(low, int) and isinstance(high, int) else "float")
        if kind not in ("int", "float"):
            raise self.err(f"{kind!r} is not one of: int, float", f"{where}.type")
        return float(low), float(high), scale == "log", kind == "int"

    def random(self, sweep: MethodSweep, raw: Any, where: str) -> None:
        if not isinstance(raw, dict):
            raise self.err("expected a mapping with 'samples', 'seed' and 'params'", where)
        self.known(raw, where, {"samples", "seed", "params"})
        samples = raw.get("samples")
        if not isinstance(samples, int) or isinstance(samples, bool) or samples < 1:
            raise self.err(f"{samples!r} must be a whole number >= 1", f"{where}.samples")
        self.count(samples, f"{where}.samples")
        seed = raw.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise self.err(f"{seed!r} must be a whole number >= 0", f"{where}.seed")
        params = raw.get("params")
        if not isinstance(params, dict) or not params:
            raise self.err("expected a mapping of parameter names to {from, to} ranges or {choices: [...]}",
                           f"{where}.params")
        sweep.samples, sweep.random_seed = samples, seed
        for pname, spec in params.items():
            at = f"{where}.params.{pname}"
            if not isinstance(spec, dict):
                raise self.err("expected {from, to} (optionally scale: log, type: int) or {choices: [...]}", at)
            if "choices" in spec:
                self.known(spec, at, {"choices"})
                choices = spec["choices"]
                if not isinstance(choices, list) or not choices:
                    raise self.err("expected a non-empty list", f"{at}.choices")
                sweep.random.append(ParamAxis(str(pname), at, choices=tuple(choices)))
                continue
            self.known(spec, at, {"from", "to", "scale", "type"})
            for k in ("from", "to"):
                if k not in spec:
                    raise self.err(f"'{k}' is missing", at)
            low, high, log, integer = self.range(spec, at)
            sweep.random.append(ParamAxis(str(pname), at, low=low, high=high, log=log, integer=integer))

    # ----- datasets

    def datasets(self, raw: Any) -> list[DatasetSpec]:
        if not isinstance(raw, list) or not raw:
            raise self.err("expected a list of datasets ({file: ...} or {world: ...})", "datasets")
        out = [self.dataset(item, f"datasets[{i}]") for i, item in enumerate(raw)]
        names = [d.name for d in out]
        for i, n in enumerate(names):
            if names.index(n) != i:
                raise self.err(f"the name {n!r} is used twice; give one of them a 'name'", f"datasets[{i}]")
        return out

    def _file(self, value: Any, where: str, *, folder: bool = False) -> Path:
        if not isinstance(value, str) or not value:
            raise self.err("expected a path", where)
        p = Path(value).expanduser()
        if not p.is_absolute():
            p = (self.path.parent / p).resolve()
        if not p.exists():
            raise self.err(f"{p} does not exist (relative paths are relative to the spec file)", where)
        if folder and not p.is_dir():
            raise self.err(f"{p} is not a folder", where)
        return p

    def dataset(self, item: Any, where: str) -> DatasetSpec:
        if not isinstance(item, dict):
            raise self.err("expected a mapping with 'file' or 'world'", where)
        if ("file" in item) == ("world" in item):
            raise self.err("give exactly one of 'file' (a recording) and 'world' (a simulated world)", where)
        name = item.get("name")
        if name is not None and (not isinstance(name, str) or not name.strip() or "/" in name):
            raise self.err("must be a non-empty string without '/'", f"{where}.name")
        if "file" in item:
            self.known(item, where, {"file", "name", "truth", "reference", "truth_map", "relations"})
            if "truth" in item and "reference" in item:
                raise self.err("give 'truth' (a simulation folder) or 'reference' (a TUM file), not both", where)
            f = self._file(item["file"], f"{where}.file")
            d = DatasetSpec(name or _recording_name(f), where, file=f)
            if "truth" in item:
                d.truth = self._file(item["truth"], f"{where}.truth", folder=True)
                if not (d.truth / "truth.tum").is_file():
                    raise self.err(f"{d.truth} holds no truth.tum (a folder 'slam2d simulate' wrote)",
                                   f"{where}.truth")
            for k in ("reference", "truth_map", "relations"):
                if k in item:
                    setattr(d, k, self._file(item[k], f"{where}.{k}"))
            return d
        self.known(item, where, {"world", "name", "seeds", "duration", "simulation", "odometry_noise"})
        world = item["world"]
        if not isinstance(world, str) or not world:
            raise self.err("expected a built-in world name or a world YAML file", f"{where}.world")
        if world.endswith((".yaml", ".yml")):
            world = str(self._file(world, f"{where}.world"))
        else:
            from slam2d.sim.world import builtin_world_names

            if world not in builtin_world_names():
                raise self.err(f"unknown world {world!r}; built-in: {', '.join(builtin_world_names())}",
                               f"{where}.world")
        d = DatasetSpec(name or Path(world).stem, where, world=world)
        d.seeds = self.seeds(item.get("seeds", [0]), f"{where}.seeds")
        if "duration" in item:
            dur = item["duration"]
            if not isinstance(dur, (int, float)) or isinstance(dur, bool) or not dur > 0:
                raise self.err(f"{dur!r} must be a positive number of seconds", f"{where}.duration")
            d.duration = float(dur)
        from slam2d.sensors.motion_noise import OdometryNoise
        from slam2d.sim.simulate import SimulationParams

        for key, cls, skip in (("simulation", SimulationParams, {"seed", "duration"}), ("odometry_noise", OdometryNoise, set())):
            section = item.get(key) or {}
            at = f"{where}.{key}"
            if not isinstance(section, dict):
                raise self.err("expected a mapping of setting names to a value or a list of values", at)
            names = {f.name for f in dataclasses.fields(cls)} - skip
            for k, v in section.items():
                if k not in names:
                    raise self.err(f"unknown setting {k!r}; valid: {', '.join(sorted(names))}", f"{at}.{k}")
                values = v if isinstance(v, list) else [v]
                if not values:
                    raise self.err("the list of values is empty", f"{at}.{k}")
                for i, one in enumerate(values):  # every value must make a valid setting
                    try:
                        _build(cls, {k: one})
                        if key == "simulation" and k in ("robot", "laser"):
                            from slam2d.sim.laser import laser_preset
                            from slam2d.sim.robot import robot_preset

                            (robot_preset if k == "robot" else laser_preset)(one)
                    except InputError as exc:
                        raise self.err(exc.message, f"{at}.{k}" + (f"[{i}]" if isinstance(v, list) else "")) from None
                section[k] = tuple(values) if isinstance(v, list) else v
            setattr(d, key, dict(section))
        return d

    def seeds(self, raw: Any, where: str) -> tuple[int, ...]:
        if isinstance(raw, int) and not isinstance(raw, bool):
            if raw < 1:
                raise self.err(f"{raw} must be >= 1 (a count) or a list of seeds", where)
            self.count(raw, where)
            return tuple(range(raw))
        if not isinstance(raw, list) or not raw:
            raise self.err("expected a list of seeds or a count", where)
        for i, s in enumerate(raw):
            if not isinstance(s, int) or isinstance(s, bool) or s < 0:
                raise self.err(f"{s!r} is not a whole number >= 0", f"{where}[{i}]")
        if len(set(raw)) != len(raw):
            raise self.err("a seed is listed twice", where)
        return tuple(raw)

    # ----- metrics

    def metrics(self, raw: Any) -> list[Metric]:
        if isinstance(raw, str):
            raw = [raw]
        if not isinstance(raw, list) or not raw:
            raise self.err("expected a list of metric names", "metrics")
        out = []
        for i, name in enumerate(raw):
            if name not in METRICS:
                raise self.err(f"unknown metric {name!r}; available: {', '.join(METRICS)}", f"metrics[{i}]")
            if METRICS[name] in out:
                raise self.err(f"{name!r} is listed twice", f"metrics[{i}]")
            out.append(METRICS[name])
        return out

    def objective(self, raw: Any, metrics: list[Metric]) -> Metric:
        if raw is None:
            for m in metrics:
                if m.better is not None:
                    return m
            raise self.err("no metric has a direction (lower or higher is better); name an 'objective'", "metrics")
        if raw not in METRICS:
            raise self.err(f"unknown metric {raw!r}; available: {', '.join(METRICS)}", "objective")
        m = METRICS[raw]
        if m not in metrics:
            raise self.err(f"{raw!r} is not one of the metrics collected ({', '.join(x.name for x in metrics)})",
                           "objective")
        if m.better is None:
            raise self.err(f"{raw!r} has no direction (neither lower nor higher is clearly better)", "objective")
        return m


# Limits on a spec's sizes: a count or a run total beyond them is a typo (a run takes seconds at least).
_MAX_COUNT = 100_000
_MAX_RUNS = 1_000_000


def _spaced(low: float, high: float, num: int, log: bool) -> list[float]:
    import numpy as np

    if num == 1:
        return [low]
    return list(np.geomspace(low, high, num) if log else np.linspace(low, high, num))


def _recording_name(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".clf", ".log", ".bag"):
        name = name.removesuffix(suffix)
    return name or path.name


def _build(cls: type, values: dict[str, Any]) -> Any:
    from slam2d.params import from_mapping

    return from_mapping(cls, values)


# --------------------------------------------------------------------------- methods (at run time)

def check_methods(spec: SweepSpec) -> None:
    """Check every method name against the registry and every parameter value against the method's parameters.

    Each grid value, each random range's ends and the fixed values are checked
    (types, units, choices, ranges); an error names the spec file, the line
    and the key path (``methods.gmapping.grid.sigma[3]``).
    """
    from slam2d.methods.registry import available
    from slam2d.params import describe, from_mapping

    registered = available()
    for sweep in spec.methods:
        cls = registered.get(sweep.method) or registered.get(sweep.method.replace("_", "-"))
        if cls is None:
            raise spec.error(f"unknown method {sweep.method!r}; available: {', '.join(registered)}", sweep.where)
        names = {p.name for p in describe(cls.Params)}

        def check(values: dict[str, Any], where: str) -> None:
            try:
                from_mapping(cls.Params, values)
            except InputError as exc:
                raise spec.error(exc.message, where) from None

        for pname in [a.name for a in sweep.grid + sweep.random] + list(sweep.fixed):
            if pname.replace("-", "_") not in names:
                axis = next((a for a in sweep.grid + sweep.random if a.name == pname), None)
                at = axis.where if axis else f"{sweep.where}.set.{pname}"
                raise spec.error(f"{sweep.method} has no parameter {pname!r}; valid: {', '.join(sorted(names))}", at)
        check(dict(sweep.fixed), f"{sweep.where}.set")
        for axis in sweep.grid:
            for i, v in enumerate(axis.values):
                check({**sweep.fixed, axis.name: v}, f"{axis.where}[{i}]" if len(axis.values) > 1 or axis.low is not None else axis.where)
        for axis in sweep.random:
            ends = list(axis.choices) if axis.choices else [axis.low, axis.high]
            for v in ends:
                if axis.integer and v is not None:
                    v = int(round(v))
                check({**sweep.fixed, axis.name: v}, axis.where)
