"""``slam2d paper``: the source study rerun end to end in simulation, into one report.

Section III (:mod:`slam2d.experiments.section3`), Section IV (:mod:`slam2d.experiments.section4`)
and, when this build has it, Section V (``slam2d.experiments.section5``, imported lazily) each
return :class:`~slam2d.experiments.ExperimentResult` objects; :mod:`slam2d.report.paper` renders
them all the same way.

Everything is written into a staging folder beside ``--out`` and moved into place at the end,
so an interrupted or failed run leaves no half-written report. An existing ``--out`` is replaced
only when it holds an earlier ``slam2d paper`` output (its ``paper.json``); any other existing
folder or file is refused.
"""

from __future__ import annotations

import importlib
import os
import platform
import resource
import shutil
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import Any

from slam2d.errors import InputError
from slam2d.io.atomic import json_text, swap_into_place
from slam2d.report.paper import SectionRun, write_paper_report

__all__ = ["PaperRun", "run_paper", "check_out_dir", "MARKER", "QUICK_SKIPS"]

MARKER = "paper.json"
SECTION5_MODULE = "slam2d.experiments.section5"
#: What --quick leaves out, in the report's words.
QUICK_SKIPS = ("Section III drives one lap on one seed instead of two laps on three seeds (so no mean or spread over "
               "seeds); Section IV is the same as the full run (500 readings per set-up cost about 3 s); Section V, "
               "when this build has it, is called with quick=True and its own text says what that leaves out.")


@dataclass
class PaperRun:
    """What :func:`run_paper` did."""

    out: Path
    sections: list[SectionRun]
    wall_s: float
    cpu_s: float
    written: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[SectionRun]:
        return [s for s in self.sections if s.status == "failed"]


def check_out_dir(out: Path) -> None:
    """Refuse an --out we must not or cannot write, before any work."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder; give a new folder or an earlier 'slam2d paper' output",
                         path=out, field="--out")
    if out.is_dir() and any(out.iterdir()) and not _replaceable(out):
        raise InputError(f"is a folder that is not empty and holds no {MARKER} (not an earlier 'slam2d paper' "
                         "output); it is not replaced: give a new or empty folder", path=out, field="--out")
    parent = out.resolve().parent
    probe = parent
    while not probe.exists():  # the nearest existing ancestor must let us create the folder
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f"cannot write into {probe}", path=out, field="--out")


def _replaceable(out: Path) -> bool:
    """An earlier ``slam2d paper`` output, or an earlier ``slam2d demo`` one (what ``make demo`` used to write)."""
    if (out / MARKER).is_file():
        return True
    demo = {"paper-arena", "compare"}
    return ({p.name for p in out.iterdir()} <= demo and (out / "paper-arena" / "simulation.json").is_file()
            and (out / "compare" / "report.html").is_file())


def _cpu() -> float:
    """CPU seconds of this process and of every child process it has waited for."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _timed(section: SectionRun, body: Callable[[], list[Any]]) -> SectionRun:
    wall0, cpu0 = time.perf_counter(), _cpu()
    try:
        section.results = list(body())
    except InputError:
        raise
    except Exception as exc:  # a bug in one section is reported; the others stand
        section.status, section.note = "failed", f"{type(exc).__name__}: {exc}"
        section.details = traceback.format_exc()
    section.wall_s, section.cpu_s = time.perf_counter() - wall0, _cpu() - cpu0
    return section


def _section5(folder: Path, quick: bool, seed: int) -> SectionRun:
    title = "the stochastic model verified (GMapping with and without it, entropy, Fig. 11)"
    try:
        module = importlib.import_module(SECTION5_MODULE)
    except ModuleNotFoundError as exc:
        if exc.name != SECTION5_MODULE:
            raise
        return SectionRun("V", title, status="not run", note=(
            f"{SECTION5_MODULE} is not part of this build, so Section V (Figs. 8-10: GMapping with and without the "
            "model on the can, the broken wall and the rebound; the entropy experiment; Fig. 11) was not run. Nothing "
            "is shown for it, and none of the study's Section V findings is confirmed or refuted here."))
    section = SectionRun("V", title, folder=folder)
    folder.mkdir(parents=True, exist_ok=True)
    return _timed(section, lambda: module.run_section5(folder, quick=quick, seed=seed))


def run_paper(out: Path, *, quick: bool, seed: int = 0, jobs: int | None = None, command: str = "",
              log: Callable[[str], None] | None = None) -> PaperRun:
    """Run Sections III-V and write ``out/report.html``, ``out/report.md`` and ``out/paper.json``."""
    from slam2d.experiments.section3 import run_section3
    from slam2d.experiments.section4 import run_section4

    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0 or seed >= 2**32:
        raise InputError(f"{seed!r} is not a whole number from 0 to 2^32 - 1", field="--seed")
    if jobs is not None and jobs < 1:
        raise InputError(f"{jobs} must be at least 1", field="--jobs")
    out = Path(out)
    check_out_dir(out)
    say = log or (lambda _m: None)
    wall0, cpu0 = time.perf_counter(), _cpu()
    out.resolve().parent.mkdir(parents=True, exist_ok=True)
    stage = out.resolve().parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    try:
        s3 = SectionRun("III", "the SLAM methods on the study's test space", folder=stage / "section3",
                        note="Quick mode: one lap, one seed." if quick else "")
        _timed(s3, lambda: run_section3(stage / "section3", quick=quick, seed=seed, jobs=jobs, log=say))
        say("section IV: repeatability readings, Table I, fits")
        s4 = SectionRun("IV", "the URG-04LX repeatability model (Table I, Figs. 5-7, eq. 1)", folder=stage / "section4")
        _timed(s4, lambda: run_section4(stage / "section4", quick=quick, seed=seed))
        say("section V")
        s5 = _section5(stage / "section5", quick, seed)
        sections = [s3, s4, s5]
        for sec in sections:  # texts that name a file name it where it will be, not in the staging folder
            sec.results = [_relocated(r, str(stage), str(out.resolve())) for r in sec.results]
        wall, cpu = time.perf_counter() - wall0, _cpu() - cpu0
        facts = _facts(quick, seed, command, wall, cpu, sections)
        written = write_paper_report(sections, stage, title="The source study, rerun in simulation by slam2d",
                                     facts=facts, intro=_INTRO)
        (stage / MARKER).write_text(json_text(_record(sections, quick, seed, command, wall, cpu)) + "\n",
                                    encoding="utf-8")
        swap_into_place(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    for s in sections:  # the folders now live under out
        if s.folder is not None:
            s.folder = out / s.folder.relative_to(stage)
    written = [out / p.name for p in written] + [out / MARKER]
    return PaperRun(out, sections, time.perf_counter() - wall0, _cpu() - cpu0, written)


_INTRO = ("The study ('Verification of SLAM Methods Implemented in ROS') tested GMapping, Hector and Karto on a KUKA "
          "youBot with a Hokuyo URG-04LX in a room with rectangular walls (Sec. III), measured the laser's repeatability "
          "(Sec. IV) and verified a range noise model in GMapping (Sec. V). Here each experiment is rerun in simulation "
          "with exact ground truth; each section sets the study's numbers beside ours and says by which rule it "
          "calls a finding held or not. Simulation is not the study's room: the laser noise is the study's own model, "
          "the odometry noise and the room are ours, so a finding that fails here may still hold on the real robot, "
          "and the reverse.")


def _facts(quick: bool, seed: int, command: str, wall: float, cpu: float, sections: list[SectionRun]) -> list[tuple[str, str]]:
    import slam2d

    facts = [("Mode", "quick (--quick): " + QUICK_SKIPS if quick else "full"), ("Seed", str(seed))]
    if command:
        facts.append(("Command", command))
    facts += [
        ("Time", f"wall {wall:.1f} s, CPU {cpu:.1f} s (this process and its method processes) on "
                 f"{os.cpu_count()} cores; the machine may be shared, so wall time can be inflated: judge by CPU"),
        ("Per section", "; ".join(f"{s.key}: {s.status}" + (f", wall {s.wall_s:.1f} s, CPU {s.cpu_s:.1f} s"
                                                              if s.wall_s is not None else "") for s in sections)),
        ("slam2d", slam2d.__version__),
        ("Python", f"{platform.python_version()} on {platform.machine()}"),
        ("Date", datetime.now().astimezone().isoformat(timespec="seconds")),
    ]
    return facts


def _record(sections: list[SectionRun], quick: bool, seed: int, command: str, wall: float, cpu: float) -> dict[str, Any]:
    import slam2d

    return {
        "format": 1, "slam2d": slam2d.__version__, "command": command, "quick": quick, "seed": seed,
        "wall_s": wall, "cpu_s": cpu,
        "sections": [{"key": s.key, "title": s.title, "status": s.status, "note": s.note, "wall_s": s.wall_s,
                      "cpu_s": s.cpu_s, "results": [asdict(r) for r in s.results]} for s in sections],
    }


def _relocated(value: Any, old: str, new: str) -> Any:
    """``value`` (a result, table, figure, or plain data) with every ``old`` path prefix in its texts made ``new``."""
    if isinstance(value, str):
        return value.replace(old, new)
    if isinstance(value, list):
        return [_relocated(v, old, new) for v in value]
    if isinstance(value, tuple):
        return tuple(_relocated(v, old, new) for v in value)
    if isinstance(value, dict):
        return {k: _relocated(v, old, new) for k, v in value.items()}
    if is_dataclass(value) and not isinstance(value, type):
        return replace(value, **{f.name: _relocated(getattr(value, f.name), old, new) for f in fields(value)})
    return value
