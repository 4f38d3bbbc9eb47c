"""``slam2d compare``: every method on the same data, in parallel processes, evaluated the same way.

:func:`compare` runs each method in its own process (a crash or an exception
in one is reported as that method's failure and does not stop the others),
evaluates every finished run against the truth or reference it is given
(:func:`slam2d.eval.evaluate.evaluate_run`), and returns a
:class:`Comparison`, which :func:`slam2d.report.comparison.write_report`
turns into ``report.html`` and ``report.md``.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slam2d.errors import InputError

__all__ = ["MethodOutcome", "Comparison", "compare", "comparison_document", "run_all", "verdict"]


@dataclass
class MethodOutcome:
    """One method's run in a comparison.

    ``status`` is ``"ok"`` or ``"failed"``. A failed run has ``error`` (one
    line: what went wrong) and ``details`` (the traceback or the exit status);
    its ``run_dir`` may hold nothing. A finished run's ``run_dir`` holds what
    ``slam2d run`` writes (``trajectory.tum``, ``map.yaml`` + ``map.pgm``,
    ``preview.png``, ``diagnostics.json``, ``run.json``) and
    ``evaluation.json``, whose content is also in ``evaluation`` (the schema is
    documented in :func:`slam2d.eval.evaluate.evaluate_run`).
    """

    method: str
    status: str
    run_dir: Path
    params: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    error: str | None = None
    details: str | None = None
    evaluation: dict[str, Any] | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def alignment(self) -> list[float] | None:
        """The SE(2) transform [x, y, theta] from the run's map frame into the truth's frame, if known."""
        if not self.evaluation:
            return None
        return self.evaluation.get("alignment")


@dataclass
class Comparison:
    """Everything a report shows: the data, the truth it was judged against, one outcome per method."""

    data: Path
    outcomes: list[MethodOutcome]
    truth: Any = None  # slam2d.eval.evaluate.GroundTruth or None
    relations: Path | None = None
    wall_s: float = 0.0  # the whole comparison, runs and evaluation
    command: str = ""
    recording: dict[str, Any] = field(default_factory=dict)  # scans, duration_s, format, sha256 of the data
    verdict: dict[str, Any] | None = None  # verdict() of the finished runs

    @property
    def methods(self) -> list[str]:
        return [o.method for o in self.outcomes]


# --------------------------------------------------------------------------- running the comparison

_POLL_S = 0.05


def _split_settings(
    methods: list[str], settings: Mapping[str, Any], per_method_files: Mapping[str, Any] | None
) -> dict[str, dict[str, Any]]:
    """Per-method parameter values from ``name=value`` (every method that has it) and ``method.name=value``."""
    from slam2d.methods import get_method
    from slam2d.params import describe

    out: dict[str, dict[str, Any]] = {m: dict((per_method_files or {}).get(m, {})) for m in methods}
    names = {m: {p.name for p in describe(get_method(m).Params)} for m in methods}
    for key, value in settings.items():
        if "." in key:
            method, name = key.split(".", 1)
            if method not in out:
                raise InputError(
                    f"{method!r} is not one of the methods compared ({', '.join(methods)})", field=f"--set {key}"
                )
            out[method][name] = value
            continue
        targets = [m for m in methods if key.replace("-", "_") in names[m]]
        if not targets:
            raise InputError(
                f"no method compared has a parameter {key!r} (use METHOD.NAME=VALUE for one method)",
                field=f"--set {key}",
            )
        for m in targets:
            out[m][key] = value
    return out


def _child(method: str, data: str, run_dir: str, settings: dict[str, Any], seed: int | None,
           options: dict[str, Any], command: str, sensor_model: Any = None) -> None:
    """Body of a method's process: run it; on any failure leave ``error.json`` and exit 1."""
    import traceback

    from slam2d.errors import Slam2dError
    from slam2d.io.atomic import write_json_atomic
    from slam2d.io.base import ReadOptions
    from slam2d.methods.runner import run_method

    out = Path(run_dir)
    try:
        run_method(method, data, out, settings=settings, seed=seed, read_options=ReadOptions(**options),
                   command=command, sensor_model=sensor_model)
    except BaseException as exc:  # report everything, bugs included: the others go on
        line = str(exc) if isinstance(exc, Slam2dError) else f"{type(exc).__name__}: {exc}"
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "error.json", {"error": line, "details": traceback.format_exc()}, indent=None)
        os._exit(1)
    os._exit(0)


def _process_context() -> Any:
    # fork: a child starts at once with everything imported (and with methods
    # registered at run time, such as a test's); spawn where there is no fork.
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


def run_all(
    methods: list[str],
    data: Path,
    runs_dir: Path,
    *,
    settings: dict[str, dict[str, Any]],
    seed: int | None,
    options: dict[str, Any],
    jobs: int,
    command: str = "",
    on_done: Callable[[MethodOutcome, float], None] | None = None,
    sensor_model: Any = None,
) -> list[MethodOutcome]:
    """Run every method in its own process, ``jobs`` at a time; a failure is an outcome, not an exception.

    ``sensor_model`` (a model or its ``--sensor-model`` text) goes to every method.
    """
    import json

    ctx = _process_context()
    waiting = list(methods)
    running: dict[str, tuple[Any, float]] = {}
    outcomes: dict[str, MethodOutcome] = {}
    while waiting or running:
        while waiting and len(running) < jobs:
            m = waiting.pop(0)
            run_dir = runs_dir / m
            for stale in ("run.json", "error.json"):
                (run_dir / stale).unlink(missing_ok=True)
            proc = ctx.Process(
                target=_child, name=f"slam2d-{m}",
                args=(m, str(data), str(run_dir), settings.get(m, {}), seed, options, command, sensor_model),
            )
            proc.start()
            running[m] = (proc, time.perf_counter())
        time.sleep(_POLL_S)
        for m, (proc, started) in list(running.items()):
            if proc.is_alive():
                continue
            proc.join()
            del running[m]
            run_dir = runs_dir / m
            outcome = MethodOutcome(m, "ok", run_dir)
            if proc.exitcode == 0 and (run_dir / "run.json").is_file():
                record = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
                outcome.params = record.get("params", {})
                outcome.seed = record.get("seed", 0)
            else:
                outcome.status = "failed"
                err = run_dir / "error.json"
                if err.is_file():
                    doc = json.loads(err.read_text(encoding="utf-8"))
                    outcome.error, outcome.details = doc.get("error"), doc.get("details")
                elif proc.exitcode is not None and proc.exitcode < 0:
                    outcome.error = f"the process was killed by signal {-proc.exitcode}"
                else:
                    outcome.error = f"the process ended with exit status {proc.exitcode} and no report"
            outcomes[m] = outcome
            if on_done is not None:
                on_done(outcome, time.perf_counter() - started)
    return [outcomes[m] for m in methods]


def compare(
    data: str | Path,
    methods: list[str],
    out_dir: str | Path,
    *,
    truth: Any = None,
    relations: Any = None,
    settings: Mapping[str, Any] | None = None,
    per_method_params: Mapping[str, Mapping[str, Any]] | None = None,
    seed: int | None = None,
    read_options: Any = None,
    jobs: int | None = None,
    tolerance: float = 0.1,
    command: str = "",
    on_done: Callable[[MethodOutcome, float], None] | None = None,
    sensor_model: Any = None,
) -> Comparison:
    """Run ``methods`` on ``data`` in parallel processes and evaluate each run the same way.

    ``truth`` is a :class:`~slam2d.eval.evaluate.GroundTruth` (or None);
    ``relations`` a :class:`~slam2d.io.relations.Relations`. ``known-poses``
    maps along the truth's trajectory unless its ``poses`` is set. Runs go to
    ``out_dir/runs/METHOD/``. The truth is checked against the recording's
    time span before anything runs. ``sensor_model`` (a range noise model, or
    its ``--sensor-model`` text: a model file, ``study``, ``constant:SIGMA``)
    is handed to every method; a text is checked here before anything runs.
    """

    from slam2d.eval.evaluate import evaluate_run, load_run
    from slam2d.io import open_recording
    from slam2d.io.atomic import write_json_atomic
    from slam2d.io.base import ReadOptions
    from slam2d.methods import get_method
    from slam2d.methods.runner import input_digest
    from slam2d.params import as_dict, from_mapping

    started = time.perf_counter()
    data = Path(data)
    out_dir = Path(out_dir)
    if not methods:
        raise InputError("no methods to compare", field="--methods")
    if len(set(methods)) != len(methods):
        raise InputError(f"a method is listed twice: {', '.join(methods)}", field="--methods")
    for m in methods:
        get_method(m)  # unknown names fail here, listing the valid ones
    options = read_options if read_options is not None else ReadOptions()
    per_method = _split_settings(methods, settings or {}, per_method_params)
    recording = _recording_summary(data, options)
    if truth is not None and truth.has_trajectory:
        _check_overlap(recording, truth, data)
    if "known-poses" in methods and "poses" not in per_method["known-poses"]:
        if truth is None or not truth.has_trajectory:
            raise InputError(
                "known-poses needs a trajectory: give --truth or --reference, or --set known-poses.poses=FILE.tum",
                field="--methods",
            )
        source = truth.source / "truth.tum" if truth.source.is_dir() else truth.source
        per_method["known-poses"]["poses"] = str(source.resolve())
    for m in methods:  # a mistyped value fails here, before anything runs
        try:
            from_mapping(get_method(m).Params, per_method[m])
        except InputError as exc:
            raise InputError(f"{m}: {exc}") from None
    if isinstance(sensor_model, str):
        from slam2d.sensors.calibration.model import sensor_model_from_spec

        sensor_model_from_spec(sensor_model)  # a bad file fails here, once
    recording.update(input_digest(data))
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    n_jobs = max(1, min(len(methods), jobs if jobs else (os.cpu_count() or 1)))
    outcomes = run_all(methods, data, runs_dir, settings=per_method, seed=seed, options=as_dict(options),
                       jobs=n_jobs, command=command, on_done=on_done, sensor_model=sensor_model)
    def frames():  # read again for each run's reference-free measures: a long recording is not held in memory
        return open_recording(data, options).frames()

    for outcome in outcomes:
        if not outcome.ok:
            continue
        try:
            outcome.evaluation = evaluate_run(load_run(outcome.run_dir), truth, relations=relations,
                                              tolerance=tolerance, frames=frames)
        except InputError as exc:
            outcome.status, outcome.error = "failed", f"evaluation: {exc}"
            continue
        write_json_atomic(outcome.run_dir / "evaluation.json", outcome.evaluation)
    evaluations = {o.method: o.evaluation for o in outcomes if o.ok and o.evaluation is not None}
    judged = verdict(evaluations)
    judged["failed"] = [o.method for o in outcomes if not o.ok]
    write_json_atomic(out_dir / "comparison.json", comparison_document(recording, evaluations, judged))
    return Comparison(
        data=data, outcomes=outcomes, truth=truth, relations=getattr(relations, "path", None),
        wall_s=time.perf_counter() - started, command=command, recording=recording, verdict=judged,
    )


def comparison_document(recording: dict[str, Any], evaluations: dict[str, dict[str, Any]],
                        judged: dict[str, Any]) -> dict[str, Any]:
    """``comparison.json``: the verdict first, then every run's measures (the per-scan curves and the
    disagreement points stay in each run's ``evaluation.json``)."""
    from slam2d.eval.evaluate import ATE

    measures = {}
    for name, e in evaluations.items():
        sc = e.get("self_consistency") or {}
        row = {k: sc.get(k) for k in ("inconsistency", "beams", "beams_judged", "scans", "scans_judged")}
        ate = ATE.value(e)
        if ate is not None:
            row["ate_rmse_m"] = ate
        measures[name] = row
    return {"format": 1, "verdict": judged["sentence"], "ranking": judged["reference_free"]["ranking"],
            "confidence": judged["reference_free"]["confidence"], "reference_free": judged["reference_free"],
            "reference": judged["reference"], "failed": judged.get("failed", []), "recording": recording,
            "measures": measures}


def verdict(evaluations: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The comparison's verdict from each run's evaluation (``evaluate_run`` with the recording's frames).

    ``reference_free``: :func:`~slam2d.eval.self_consistency.rank_runs` of their ``self_consistency``;
    ``reference``: the ranking by ATE where the evaluations have one (a reference or the truth), else
    None; ``sentence``: the verdict in words.
    """
    from slam2d.eval.evaluate import ATE
    from slam2d.eval.self_consistency import rank_runs, verdict_sentence

    measures = {name: e["self_consistency"] for name, e in evaluations.items() if e.get("self_consistency")}
    ranked = rank_runs(measures)
    ranked["not_judged"] = sorted(set(ranked["not_judged"]) | (set(evaluations) - set(measures)))
    ate = {name: ATE.value(e) for name, e in evaluations.items() if ATE.value(e) is not None}
    reference = None
    if ate:
        reference = {"measure": "ate_rmse_m", "ranking": sorted(ate, key=lambda n: (ate[n], n)), "ate_rmse_m": ate}
    return {"reference_free": ranked, "reference": reference, "sentence": verdict_sentence(ranked)}


def _recording_summary(data: Path, options: Any) -> dict[str, Any]:
    """Scans and time span of the recording (one quick read, which also checks the file)."""
    from slam2d.io import detect_format, open_recording

    recording = open_recording(data, options)
    first = last = None
    scans = 0
    for frame in recording.frames():
        scans += 1
        if first is None:
            first = frame.timestamp
        last = frame.timestamp
    if scans == 0:
        raise InputError("no laser scans in the recording", path=data)
    return {"path": str(data), "format": detect_format(data), "scans": scans, "start_s": first, "end_s": last,
            "duration_s": (last - first) if first is not None else 0.0}


def _check_overlap(recording: dict[str, Any], truth: Any, data: Path) -> None:
    t0, t1 = float(truth.times.min()), float(truth.times.max())
    if recording["end_s"] < t0 or recording["start_s"] > t1:
        raise InputError(
            f"the trajectories do not overlap in time: the recording spans {recording['start_s']:.3f}-"
            f"{recording['end_s']:.3f} s, the {truth.kind} {truth.source} spans {t0:.3f}-{t1:.3f} s",
            path=data, field="timestamp",
        )
