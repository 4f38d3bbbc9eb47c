"""Expand a sweep spec into the concrete datasets and runs, each with a stable id.

A run's id is a hash of what determines its result (method, parameter values,
seed, dataset), so a rerun of the same spec finds the runs it already
finished, and editing the spec adds runs instead of confusing old ones with
new ones. The expansion is deterministic: random samples come from the spec's
own seed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slam2d.sweep.spec import DatasetSpec, MethodSweep, SweepSpec

__all__ = ["DataInstance", "RunTask", "expand", "settings_of", "digest"]


def digest(value: Any, length: int = 10) -> str:
    """A short stable hash of a JSON-able value."""
    text = json.dumps(value, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:length]


@dataclass
class DataInstance:
    """One recording a run reads: a file as given, or one simulation (world, settings, seed) to write first."""

    id: str
    name: str  # the spec's dataset name (a column of the table)
    recording: Path
    seed: int | None = None  # simulation seed
    swept: dict[str, Any] = field(default_factory=dict)  # simulation settings that vary in the spec
    truth: Path | None = None  # a truth folder (truth.tum, truth-map.yaml, simulation.json)
    reference: Path | None = None
    truth_map: Path | None = None
    relations: Path | None = None
    simulate: dict[str, Any] | None = None  # what prepare_dataset needs; None for a file

    def as_task(self) -> dict[str, Any]:
        return {"id": self.id, "recording": str(self.recording), "truth": _s(self.truth),
                "reference": _s(self.reference), "truth_map": _s(self.truth_map), "relations": _s(self.relations),
                "simulate": self.simulate}


def _s(p: Path | None) -> str | None:
    return None if p is None else str(p)


@dataclass
class RunTask:
    """One run: a method with parameter values and a seed, on one data instance."""

    id: str
    method: str
    settings: dict[str, Any]  # every value the spec gives (swept and fixed)
    swept: dict[str, Any]  # the swept ones, for the table's grouping
    seed: int
    data: DataInstance
    index: int = 0  # position in the expansion: the table's row order


def settings_of(sweep: MethodSweep) -> list[dict[str, Any]]:
    """Every parameter setting of a method's sweep: grid product times the random samples, plus fixed values."""
    import numpy as np

    grid_names = [a.name for a in sweep.grid]
    grid = [dict(zip(grid_names, combo, strict=True)) for combo in itertools.product(*(a.values for a in sweep.grid))]
    samples: list[dict[str, Any]] = [{}]
    if sweep.random:
        rng = np.random.default_rng(sweep.random_seed)
        samples = []
        for _ in range(sweep.samples):
            one: dict[str, Any] = {}
            for axis in sweep.random:
                if axis.choices:
                    one[axis.name] = axis.choices[int(rng.integers(len(axis.choices)))]
                    continue
                u = float(rng.random())
                if axis.log:
                    v = math.exp(math.log(axis.low) + u * (math.log(axis.high) - math.log(axis.low)))
                else:
                    v = axis.low + u * (axis.high - axis.low)
                one[axis.name] = int(round(v)) if axis.integer else float(f"{v:.6g}")
            samples.append(one)
    out = []
    for g in grid:
        for s in samples:
            out.append({**sweep.fixed, **g, **s})
    return out


def _data_instances(d: DatasetSpec, data_dir: Path) -> list[DataInstance]:
    if not d.simulated:
        return [DataInstance(
            id=f"{d.name}-{digest(str(d.file), 8)}", name=d.name, recording=d.file, truth=d.truth,
            reference=d.reference, truth_map=d.truth_map, relations=d.relations,
        )]
    swept_keys = [(sec, k) for sec in ("simulation", "odometry_noise")
                  for k, v in getattr(d, sec).items() if isinstance(v, tuple)]
    combos = itertools.product(*(getattr(d, sec)[k] for sec, k in swept_keys))
    out = []
    for combo in combos:
        chosen = dict(zip(swept_keys, combo, strict=True))
        sim = {k: chosen.get(("simulation", k), v) for k, v in d.simulation.items()}
        noise = {k: chosen.get(("odometry_noise", k), v) for k, v in d.odometry_noise.items()}
        for seed in d.seeds:
            what = {"world": d.world, "duration": d.duration, "simulation": sim, "odometry_noise": noise,
                    "seed": seed}
            ident = f"{d.name}-seed{seed}-{digest(what, 8)}"
            folder = data_dir / ident
            out.append(DataInstance(
                id=ident, name=d.name, recording=folder / "recording.log.gz", seed=seed,
                swept={k: v for (_, k), v in chosen.items()}, truth=folder, simulate={**what, "out": str(folder)},
            ))
    return out


def expand(spec: SweepSpec, out_dir: Path) -> tuple[list[DataInstance], list[RunTask]]:
    """The data instances and the runs of a spec, in a fixed order (method, setting, dataset, seed)."""
    data: list[DataInstance] = []
    for d in spec.datasets:
        data += _data_instances(d, out_dir / "data")
    runs: list[RunTask] = []
    seen: set[str] = set()
    for sweep in spec.methods:
        swept_names = sweep.swept
        for setting in settings_of(sweep):
            for inst in data:
                for seed in spec.seeds:
                    key = {"method": sweep.method, "settings": setting, "seed": seed, "data": inst.id}
                    ident = f"{sweep.method}-{digest(key)}"
                    if ident in seen:  # two random samples rounded to the same integers: one run
                        continue
                    seen.add(ident)
                    runs.append(RunTask(
                        id=ident, method=sweep.method, settings=dict(setting),
                        swept={k: setting[k] for k in swept_names}, seed=seed, data=inst, index=len(runs),
                    ))
    return data, runs
