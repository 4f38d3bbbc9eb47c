"""The ``slam2d`` command: one entry point, one subcommand per job.

Options that configure a library object are generated from its parameter
dataclass (:mod:`slam2d.params`), so the CLI, the library and the docs cannot
disagree. A user mistake ends in one ``slam2d: error: ...`` line and exit
status 2; a traceback means a bug in slam2d.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from slam2d import __version__
from slam2d.errors import InputError, ProblemLog, Slam2dError
from slam2d.io.base import ProgressCallback, ReadOptions
from slam2d.params import add_arguments, from_arguments

__all__ = ["main", "build_parser"]

# One line per command: `slam2d --help` lists these without building (and importing) every command.
_HELP = {
    "info": "describe a recording and every problem found in it",
    "map": "build an occupancy map from a recording and known poses",
    "methods": "list the SLAM methods, or one method's parameters",
    "run": "run one SLAM method on a recording",
    "localize": "localize a recording in a fixed map (a run's, or any map_server map)",
    "evaluate": "measure a run's trajectory error, map quality and cost",
    "compare": "run several methods on the same data and write a comparison report",
    "simulate": "simulate a recording with exact ground truth in a built-in or custom world",
    "repeatability": "simulate the study's repeated static range measurements",
    "demo": "simulate the study's test space and compare the methods on it",
    "paper": "rerun the source study end to end in simulation and write one report",
    "calibrate": "calibrate the laser's range noise, the odometry's noise or its timing from data",
    "sweep": "run a parameter study (methods x parameters x datasets x seeds) on a local pool or a Dask cluster",
    "experiment": "rerun the source study's Section V experiments in simulation, with numbers",
    "compile": "compile every method's kernels now, so the first run is as fast as the second",
    "ros": "run a method live as a ROS 1 node (scan and tf in; map, tf map -> odom and pose out)",
}

EXIT_USER_ERROR = 2


# --------------------------------------------------------------------------- output helpers


def _console(stderr: bool = False):
    from rich.console import Console

    return Console(stderr=stderr, highlight=False, soft_wrap=True)


@contextmanager
def progress_bar(description: str) -> Iterator[ProgressCallback]:
    """A rich progress bar on a terminal; when stderr is not one (a log, a pipe), a plain line every 10 % or
    10 s once the phase has taken 2 s (a short one prints nothing), so a long command is never silent."""
    if not sys.stderr.isatty():
        yield _plain_progress(description)  # (rich's progress module is not even imported)
        return
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeRemainingColumn(),
        console=_console(stderr=True),
        transient=True,
    ) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total or None)

        yield update


def _plain_progress(description: str, *, quiet_for: float = 2.0, every: float = 10.0,
                    clock: Callable[[], float] | None = None) -> ProgressCallback:
    import time

    clock = clock or time.monotonic
    start = clock()
    state = {"said_at": None, "tenth": -1, "total": None}

    def update(done: int, total: int) -> None:
        now = clock()
        if now - start < quiet_for:
            return
        if total != state["total"]:  # another phase (bytes read, then frames run): count its tenths afresh
            state["tenth"], state["total"] = -1, total
        tenth = int(10 * done / total) if total else -1
        said = state["said_at"]
        if said is not None and tenth <= state["tenth"] and now - said < every:
            return
        state["said_at"], state["tenth"] = now, tenth
        share = f"{100 * done / total:.0f} % ({done} of {total})" if total else f"{done} done"
        print(f"{description}: {share}, {now - start:.0f} s", file=sys.stderr, flush=True)

    return update


def _add_out(p: argparse.ArgumentParser, command: str) -> None:
    """``--out`` and ``--overwrite`` of a command whose output folder is written whole (io.atomic.staged_folder)."""
    p.add_argument("--out", type=Path, required=True,
                   help=f"output folder: new, empty, or an earlier 'slam2d {command}' output (replaced whole "
                   "when the command is done; nothing is written on a failure)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace --out even when it holds other files (they are deleted)")
    p.set_defaults(staged=command)
    _add_max_memory(p)


def _add_max_memory(p: argparse.ArgumentParser) -> None:
    p.add_argument("--max-memory", type=_size, metavar="SIZE",
                   help="the most this run may hold, e.g. 2G or 500M (default: a map or particle set may take 75 %% "
                   "of the memory available when it grows); a setting that needs more stops with an error naming "
                   "it, before the memory is taken")


def _size(text: str) -> int:
    from slam2d.core.memory import parse_size

    try:
        return parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


# Staging folders of the running commands and the --out each becomes (for the paths shown to the user).
_STAGES: dict[Path, Path] = {}


def _shown(path: Path) -> Path:
    """``path`` as it will be when its command's output folder is in place."""
    for stage, final in _STAGES.items():
        if path == stage or stage in path.parents:
            return final / path.relative_to(stage)
    return path


def _print_written(out: Any, path: Path) -> None:
    out.print(f"  wrote {_shown(Path(path))}", markup=False)


def _report_problems(problems: ProblemLog, what: str) -> None:
    if problems:
        err = _console(stderr=True)
        err.print(f"[yellow]{what}: {problems.total()} problem(s) did not stop the run:[/yellow]")
        for line in problems.lines():
            err.print(f"  - {line}", markup=False)


def _read_options(args: argparse.Namespace) -> ReadOptions:
    return from_arguments(ReadOptions, args)


def _seed(text: str) -> int:
    """``--seed``: a whole number >= 0 (numpy's generators refuse negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative; a seed is a whole number >= 0")
    return value


# --------------------------------------------------------------------------- info


def _add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info",
        help=_HELP["info"],
        description="Read a CARMEN log (plain or gzipped), a ROS 1 bag or a ROS 2 bag once and report "
        "its scans, beams, field of view, range limits, rate, time span, odometry source, topics, "
        "and every problem found (gaps, time going backwards, corrupt records).",
    )
    p.add_argument("file", type=Path, help="the recording: .log/.clf(.gz), .bag, or a ROS 2 bag folder")
    p.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    add_arguments(p.add_argument_group("reading"), ReadOptions)
    p.set_defaults(handler=cmd_info)


def cmd_info(args: argparse.Namespace) -> int:
    import math

    from slam2d.io import open_recording
    from slam2d.io.inspect import summarize
    from slam2d.sensors.recording_profile import measure_profile

    recording = open_recording(args.file, _read_options(args))
    frames: list = []
    with progress_bar(f"reading {args.file.name}") as progress:
        summary = summarize(recording, progress, keep=frames)
    # what the auto defaults resolve from: the laser's reach, the step between scans, the odometry against the scans
    profile = measure_profile(frames)
    if args.json:
        from slam2d.io.atomic import json_text

        print(json_text({**summary.as_dict(), "profile": profile.as_dict() if profile else None}))
        return 0

    from rich.table import Table

    out = _console()
    t = Table(title=f"{summary.path}", show_header=False, title_justify="left")
    t.add_column("what", style="bold")
    t.add_column("value")
    deg = math.degrees
    rows = [
        ("format", f"{summary.format}, {summary.file_bytes / 1e6:.2f} MB"),
        ("scans", f"{summary.scans}"),
        ("beams", f"{summary.beams_min}" + (f"-{summary.beams_max}" if summary.beams_max != summary.beams_min else "")),
        ("field of view", f"{summary.field_of_view_deg:.2f} deg at {summary.angular_resolution_deg:.4f} deg per beam"),
        ("range limits", f"{summary.range_min:g} to {summary.range_max:g} m (longest return {summary.longest_return:.2f} m, "
         f"{100 * summary.no_return_fraction:.1f} % no return)"),
        ("rate", f"{summary.rate_hz:.2f} Hz (median)"),
        ("time span", f"{summary.start:.3f} to {summary.end:.3f} s ({summary.duration:.1f} s)"),
        ("odometry", f"{summary.odometry_source}; {summary.frames_with_odometry} of {summary.scans} scans, "
         f"path {summary.odometry_path_length:.1f} m"),
        ("laser mount", "x {:.3f} m, y {:.3f} m, yaw {:.1f} deg".format(
            summary.laser_mount[0], summary.laser_mount[1], deg(summary.laser_mount[2]))),
    ]
    if profile is not None:
        rows.append(("laser reach", f"{profile.longest_return:.1f} m (99th percentile of returns)"))
        if profile.step_m is not None:
            rows.append(("step between scans", f"{profile.step_m:.3f} m, {deg(profile.step_rad):.1f} deg (median, "
                                               "odometry)"))
        if profile.odometry_heading_per_m is not None:
            rows.append(("odometry vs scans", f"heading error {profile.odometry_heading_per_m:.3f} rad/m + "
                         f"{profile.odometry_heading_per_rad:.3f} rad/rad over {profile.pairs} scan pairs; "
                         f"{profile.odometry_gaps} pairs show a turn or shift it missed"))
        for note in profile.notes:
            rows.append(("odometry vs scans", note))
    for k, v in rows:
        t.add_row(k, v)
    out.print(t)
    if summary.streams:
        st = Table(title="streams", title_justify="left")
        for col in ("name", "type", "count", "used as"):
            st.add_column(col)
        for s in summary.streams:
            st.add_row(s["name"], s["type"], str(s["count"]), s.get("used_as", ""))
        out.print(st)
    if summary.notes:
        out.print("inferred by the reader:")
        for line in summary.notes:
            out.print(f"  - {line}", markup=False)
    if summary.problems:
        out.print(f"[yellow]problems found ({len(summary.problems)}):[/yellow]")
        for line in summary.problems:
            out.print(f"  - {line}", markup=False)
    else:
        out.print("[green]no problems found[/green]")
    return 0


# --------------------------------------------------------------------------- map


def _add_map(sub: argparse._SubParsersAction) -> None:
    from slam2d.grids.occupancy import GridParams

    p = sub.add_parser(
        "map",
        help=_HELP["map"],
        description="Build a map_server map (PGM + YAML, plus a PNG preview) from the scans of DATA "
        "placed at the poses of a TUM trajectory (one pose per scan, or interpolated between poses). "
        "Without --poses the scans are placed along the recording's raw odometry, which shows how "
        "far the odometry drifts.",
    )
    p.add_argument("data", type=Path, help="the recording: .log/.clf(.gz), .bag, or a ROS 2 bag folder")
    _add_out(p, "map")
    p.add_argument("--poses", type=Path, help="TUM trajectory of the robot base (t x y z qx qy qz qw)")
    p.add_argument(
        "--max-pose-gap", type=float, default=1.0, metavar="S",
        help="scans further than this from the nearest given pose are skipped [s] (default: 1.0)",
    )
    p.add_argument(
        "--mode", choices=("trinary", "scale"), default="trinary",
        help="map_server image mode (default: trinary, as map_saver writes)",
    )
    add_arguments(p.add_argument_group("grid"), GridParams)
    add_arguments(p.add_argument_group("reading"), ReadOptions)
    p.set_defaults(handler=cmd_map)


class _FrameCache:
    """A recording's frames, read once and replayed from memory while they fit in ``max_beams``.

    ``slam2d map`` passes over the frames two or three times (odometry, mapping, agreement);
    reading fr079 again costs as much as mapping it. A recording larger than the budget (about
    160 MB of ranges) is read again on each pass instead.
    """

    def __init__(self, recording: Any, max_beams: int = 20_000_000) -> None:
        self.recording = recording
        self.max_beams = max_beams
        self._frames: list[Any] | None = None  # every frame, once a pass kept them all

    def frames(self, progress: ProgressCallback | None = None) -> Iterator[Any]:
        if self._frames is not None:
            yield from self._frames
            return
        kept: list[Any] | None = []
        beams = 0
        for frame in self.recording.frames(progress):
            if kept is not None:
                beams += frame.scan.num_beams
                if beams > self.max_beams:
                    kept = None
                else:
                    kept.append(frame)
            yield frame
        if kept is not None:
            self._frames = kept


def cmd_map(args: argparse.Namespace) -> int:
    import numpy as np

    from slam2d.eval.map_metrics import scan_agreement
    from slam2d.grids.mapping import map_from_poses
    from slam2d.grids.occupancy import GridParams
    from slam2d.io import open_recording

    if not args.max_pose_gap >= 0:
        raise InputError(f"{args.max_pose_gap} s must be a time >= 0", field="--max-pose-gap")
    grid_params = from_arguments(GridParams, args)
    recording = open_recording(args.data, _read_options(args))
    cache = _FrameCache(recording)
    with progress_bar(f"mapping {args.data.name}") as progress:
        if args.poses is not None:
            from slam2d.io.tum import read_tum

            times, poses = read_tum(args.poses)
            source = str(args.poses)
        else:
            # The odometry trajectory first, so that mapping and the agreement check below
            # place every scan the same way.
            stamped = [(f.timestamp, f.odometry) for f in cache.frames(progress) if f.odometry is not None]
            times = np.array([t for t, _ in stamped], dtype=np.float64)
            poses = np.array([p for _, p in stamped], dtype=np.float64).reshape(-1, 3)
            source = f"odometry ({recording.odometry_source})"
        if len(times) == 0:
            raise InputError(f"no poses to place scans at: {source} is empty", path=args.poses or args.data)
        try:
            grid, stats = map_from_poses(
                cache.frames(progress), times, poses, params=grid_params,
                max_pose_gap=args.max_pose_gap,
            )
        except InputError as exc:  # e.g. a corrupt pose that would grow the map without bound
            raise exc.in_file(args.poses or args.data) from None
    if stats.scans_used == 0:
        raise InputError(
            f"no scan could be placed: none lies within {args.max_pose_gap} s of a pose from {source}",
            path=args.data,
        )
    if not grid.observed.any():
        raise InputError(f"the map is empty: no beam of the {stats.scans_used} scans placed has a return",
                         path=args.data)
    agreement = scan_agreement(grid, cache.frames(), times, poses, max_pose_gap=args.max_pose_gap)
    from slam2d.report.map_outputs import write_map_outputs

    written = write_map_outputs(
        grid, args.out, mode=args.mode,
        extra={"poses": source, "scan_agreement": agreement, "stats": stats.as_dict()},
    )
    out = _console()
    out.print(
        f"mapped {stats.scans_used} scans ({stats.scans_skipped} skipped) from {args.data} with poses from {source}; "
        f"{100 * agreement['fraction']:.1f} % of beam endpoints fall on occupied cells",
        markup=False,
    )
    for path in written:
        _print_written(out, path)
    _report_problems(recording.problems, str(args.data))
    return 0


# --------------------------------------------------------------------------- methods


def _add_methods(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "methods",
        help=_HELP["methods"],
        description="Without a name: every registered method with a one-line summary. With a name: the "
        "method's parameters (name, default, unit, meaning) as 'slam2d run' and 'slam2d compare' take them "
        "with --set NAME=VALUE, and the values it logs per update. The advanced parameters (features most runs "
        "leave off, tuning knobs of slam2d's additions) are counted, and listed with --all.",
    )
    p.add_argument("name", nargs="?", help="a method name")
    p.add_argument("--all", action="store_true",
                   help="also list the advanced parameters, a table per feature they belong to")
    p.set_defaults(handler=cmd_methods)


def cmd_methods(args: argparse.Namespace) -> int:
    from rich.table import Table

    from slam2d.methods import available, get_method
    from slam2d.params import advanced_groups, describe

    out = _console()
    if args.name is None:
        t = Table(title="methods", title_justify="left")
        t.add_column("name", style="bold")
        t.add_column("odometry")
        t.add_column("summary")
        for name, cls in available().items():
            t.add_row(name, cls.odometry_role(), cls.summary)
        out.print(t)
        out.print("details: slam2d methods NAME", markup=False)
        return 0
    cls = get_method(args.name)
    params = describe(cls.Params)
    groups = advanced_groups(cls.Params)
    # a name is what the user types: never cut it (the other columns fold instead)
    width = max(len(p.name) for p in params if args.all or not p.advanced)

    def table(title: str, rows: list) -> Table:
        t = Table(title=title, title_justify="left")
        t.add_column("parameter", no_wrap=True, min_width=width)
        for col in ("default", "unit", "meaning"):
            t.add_column(col, overflow="fold")
        for prm in rows:
            t.add_row(prm.name, str(prm.default), prm.unit or "-", prm.help)
        return t

    out.print(table(f"{cls.name}: {cls.summary}", [p for p in params if not p.advanced]))
    count = sum(map(len, groups.values()))
    if groups and args.all:
        for group, members in groups.items():
            out.print(table(f"advanced: {group}", members))
    elif groups:
        out.print(f"and {count} advanced parameters ({', '.join(groups)}): 'slam2d methods {cls.name} --all' "
                  "lists them", markup=False)
    if cls.DIAGNOSTICS:
        d = Table(title="logged per update (diagnostics.json)", title_justify="left")
        d.add_column("name")
        d.add_column("meaning")
        for k, v in cls.DIAGNOSTICS.items():
            d.add_row(k, v)
        out.print(d)
    return 0


# --------------------------------------------------------------------------- run


def _settings(items: list[str] | None) -> dict[str, str]:
    """``--set NAME=VALUE`` options as a dict (later ones win)."""
    values: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"{item!r} is not NAME=VALUE", field="--set")
        values[name.strip()] = value.strip()
    return values


def _add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help=_HELP["run"],
        description="Run METHOD (see 'slam2d methods') over every scan of DATA and write OUT/trajectory.tum, "
        "OUT/map.yaml + map.pgm + preview.png, OUT/diagnostics.json (time and values per update) and "
        "OUT/run.json (method, parameters (the advanced ones where changed), seed, input SHA-256, versions, "
        "peak memory) and OUT/session/ "
        "(what the method needs to go on another day). '--params OUT/run.json' repeats a run exactly; "
        "'--resume OUT' maps DATA into OUT's map.",
    )
    p.add_argument("method", help="method name (see 'slam2d methods')")
    p.add_argument("data", type=Path, help="the recording: .log/.clf(.gz), .bag, or a ROS 2 bag folder")
    _add_out(p, "run")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", dest="settings",
                   help="a method parameter, e.g. --set resolution=0.05 or --set max_range=4.5m (repeatable; "
                   "'slam2d methods METHOD --all' lists them all)")
    p.add_argument("--params", type=Path, metavar="FILE",
                   help="YAML file of parameters (name: value), a slam_toolbox or slam_gmapping YAML (read "
                   "under slam2d's names and units), or a run.json to repeat; --set wins")
    p.add_argument("--seed", type=_seed, help="random seed (default: the --params file's, else 0)")
    p.add_argument("--resume", type=Path, metavar="RUN",
                   help="go on mapping in RUN's map (a run folder with its session/): DATA's start is found in "
                   "it, and mapping goes on in its frame with its settings and seed")
    p.add_argument("--initial-pose", metavar="X,Y,THETA",
                   help="with --resume: where DATA starts in RUN's map [m, m, rad] (default: search the whole map)")
    _add_sensor_model_option(p)
    add_arguments(p.add_argument_group("reading"), ReadOptions)
    p.set_defaults(handler=cmd_run)


def _command_line() -> str:
    import shlex

    return " ".join(["slam2d", *map(shlex.quote, sys.argv[1:])])


def cmd_run(args: argparse.Namespace) -> int:
    from slam2d.methods.runner import build_method, resume_run, run_method

    if args.resume is None and args.initial_pose is not None:
        raise InputError("is for --resume (where the recording starts in the saved map)", field="--initial-pose")
    if args.resume is not None:
        from slam2d.localization.run import parse_pose

        for flag, given in (("--set", args.settings), ("--params", args.params), ("--seed", args.seed),
                            ("--sensor-model", args.sensor_model)):
            if given:
                raise InputError("cannot go with --resume: the session's settings and seed are used", field=flag)
        initial = parse_pose(args.initial_pose) if args.initial_pose is not None else None
        with progress_bar(f"{args.method} on {args.data.name}, resuming {args.resume.name}") as progress:
            summary = resume_run(args.method, args.resume, args.data, args.out, initial_pose=initial,
                                 read_options=_read_options(args), progress=progress, command=_command_line())
        out = _console()
        resumed = summary.record["resumed"]
        traced = (f"traced back to its first scan at ({', '.join(f'{v:.2f}' for v in resumed['placed_at'])})"
                  if resumed["found_at_scan"] and not resumed["scans_before_placed"] else
                  f"its first {resumed['scans_before_placed']} scans left out (no odometry to trace them back)"
                  if resumed["scans_before_placed"] else "")
        out.print(f"{args.method}: {resumed['session_frames']} scans of {args.resume} replayed; {args.data.name} "
                  f"found at ({', '.join(f'{v:.2f}' for v in resumed['found_at'])}) at scan "
                  f"{resumed['found_at_scan'] + 1}{', ' + traced if traced else ''}; {summary.frames} scans mapped in "
                  f"{summary.seconds:.1f} s", markup=False)
        for path in summary.written:
            _print_written(out, path)
        return 0

    build = {"settings": _settings(args.settings), "params_file": args.params, "seed": args.seed,
             "sensor_model": args.sensor_model}
    slam = build_method(args.method, **build)  # every setting checked before the recording is read
    options = _read_options(args)
    with progress_bar(f"{slam.name} on {args.data.name}") as progress:
        # by name: run_method resolves the auto parameters from the recording
        summary = run_method(args.method, args.data, args.out, read_options=options, progress=progress,
                             command=_command_line(), **build)
    out = _console()
    rec = summary.record
    for name, how in rec.get("auto", {}).items():
        out.print(f"auto {name} = {how['value']}: {how['from']}", markup=False)
    for warning in rec.get("warnings", []):
        _console(stderr=True).print(f"warning: {warning}", markup=False)
    span = rec["data_span_s"]
    duration = (span[1] - span[0]) if span[0] is not None else 0.0
    out.print(
        f"{slam.name}: {summary.frames} scans ({summary.poses} placed) in {summary.seconds:.1f} s "
        f"({duration / summary.seconds if summary.seconds > 0 else float('inf'):.1f}x real time), "
        f"peak memory {rec['peak_rss_mb']:.0f} MB, seed {slam.seed}",
        markup=False,
    )
    if rec.get("compile_s"):
        out.print(f"  (and {rec['compile_s']:.1f} s compiling kernels on their first use: once per install, "
                  "not counted above)", markup=False)
    for path in summary.written:
        _print_written(out, path)
    return 0


# --------------------------------------------------------------------------- localize


def _add_localize(sub: argparse._SubParsersAction) -> None:
    from slam2d.localization.localizer import LocalizationParams

    p = sub.add_parser(
        "localize",
        help=_HELP["localize"],
        description="Localize the robot of DATA in a fixed map: a run folder's map.yaml or any map_server map "
        "(one made by another tool works too). The map never changes. Without --initial-pose the robot is "
        "searched for over the map's free space. Writes OUT/trajectory.tum (the poses while localized, in the "
        "map's frame), OUT/localization.csv (every scan: state, pose, fit to the map's walls, particle spread) "
        "and OUT/localization.json (when it was localized, lost and found again; time per scan). Exits 1, "
        "having written what it has, when the robot was never localized.",
    )
    p.add_argument("map", type=Path, metavar="RUN_OR_MAP", help="a run folder (its map.yaml) or a map_server YAML")
    p.add_argument("data", type=Path, help="the recording: .log/.clf(.gz), .bag, or a ROS 2 bag folder")
    _add_out(p, "localize")
    p.add_argument("--initial-pose", metavar="X,Y,THETA",
                   help="where the robot starts in the map's frame [m, m, rad] (default: search the whole map)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed of the particle filter (default: 0)")
    add_arguments(p.add_argument_group("localization"), LocalizationParams)
    add_arguments(p.add_argument_group("reading"), ReadOptions)
    p.set_defaults(handler=cmd_localize)


def cmd_localize(args: argparse.Namespace) -> int:
    from slam2d.localization.localizer import LocalizationParams
    from slam2d.localization.run import localize_recording, parse_pose

    params = from_arguments(LocalizationParams, args)
    initial = parse_pose(args.initial_pose) if args.initial_pose is not None else None
    with progress_bar(f"localizing {args.data.name}") as progress:
        summary = localize_recording(args.map, args.data, args.out, params=params, seed=args.seed,
                                     initial_pose=initial, read_options=_read_options(args), progress=progress,
                                     command=_command_line())
    rec = summary.record
    out = _console()
    for e in rec["events"]:
        out.print(f"  {e['time'] - rec['data_span_s'][0]:.1f} s in: {e['state']} ({e['why']})", markup=False)
    cpu = rec["cpu_ms_per_scan"]
    if rec["localized"]:
        first = rec["first_localized"]
        out.print(f"{params.method}: localized {rec['localized_scans']} of {rec['scans']} scans (from scan "
                  f"{first['scan']}, {100 * first['fraction_of_scans']:.0f} % in), lost {rec['lost']} times"
                  + (f", off the map {rec['off_map_scans']} scans (poses from the odometry)" if rec["off_map_scans"] else "")
                  + "; "
                  f"{cpu['median']:.1f} ms CPU per scan (median)", markup=False)
    for path in summary.written:
        _print_written(out, path)
    if not rec["localized"]:
        _console(stderr=True).print(
            f"slam2d: {params.method} never localized the robot in {rec['map']}: no place in the map fits the "
            f"scans well and for long enough (is this the right map? try --initial-pose X,Y,THETA)", markup=False)
        return 1
    return 0


# --------------------------------------------------------------------------- evaluate


def _add_truth_options(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--truth", type=Path, metavar="DIR",
                   help="ground-truth folder as 'slam2d simulate' writes it (truth.tum, truth-map.yaml)")
    g.add_argument("--reference", type=Path, metavar="POSES.tum",
                   help="reference trajectory (TUM), e.g. a dataset's reference.tum (not independent truth)")
    p.add_argument("--truth-map", type=Path, metavar="MAP.yaml",
                   help="ground-truth map (map_server YAML) to use with --reference, or instead of a truth folder's")
    p.add_argument("--relations", type=Path, metavar="FILE",
                   help="Freiburg .relations file (t1 t2 x y z roll pitch yaw) for the Kümmerle et al. 2009 metric")
    p.add_argument("--tolerance", type=float, default=0.1, metavar="M",
                   help="distance within which a map obstacle matches a true one, for precision and recall "
                   "[m] (default: 0.1)")


def _load_truth_options(args: argparse.Namespace) -> tuple[Any, Any]:
    from slam2d.eval.evaluate import load_reference, load_truth

    if not args.tolerance > 0:
        raise InputError(f"{args.tolerance} m must be positive", field="--tolerance")
    truth = None
    if args.truth is not None:
        truth = load_truth(args.truth)
        if args.truth_map is not None:
            from slam2d.io.map_server import read_map

            truth.map, truth.map_path = read_map(args.truth_map).to_grid(), args.truth_map
    elif args.reference is not None:
        truth = load_reference(args.reference, truth_map=args.truth_map)
    elif args.truth_map is not None:
        from slam2d.eval.evaluate import GroundTruth
        from slam2d.io.map_server import read_map

        truth = GroundTruth("truth", args.truth_map, None, None, read_map(args.truth_map).to_grid(), args.truth_map)
    relations = None
    if args.relations is not None:
        from slam2d.io.relations import read_relations

        relations = read_relations(args.relations)
    return truth, relations


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help=_HELP["evaluate"],
        description="Evaluate RUN (a folder 'slam2d run' wrote, or a TUM trajectory): ATE after the best SE(2) "
        "alignment and RPE per frame and per metre against --truth or --reference; the Kümmerle et al. 2009 "
        "relation metric with --relations; map error against a ground-truth map in both directions, with "
        "precision and recall; without any reference, how far the run's map disagrees with itself (read from "
        "the recording run.json names) and map quality (Filatov et al. 2017); time per scan, real-time factor "
        "and peak memory. Writes RUN/evaluation.json (or --out) and prints a summary. Several runs of one "
        "recording are also ranked, as 'slam2d compare' does (--out then takes the comparison's JSON).",
    )
    p.add_argument("run", type=Path, nargs="+", help="a run folder, or a TUM trajectory file; several to rank them")
    _add_truth_options(p)
    p.add_argument("--out", type=Path, help="where to write the JSON (default: RUN/evaluation.json for a folder; "
                   "with several runs, the comparison, which is not written without it)")
    p.add_argument("--json", action="store_true", help="print the evaluation (or the comparison) as JSON")
    p.set_defaults(handler=cmd_evaluate)


def cmd_evaluate(args: argparse.Namespace) -> int:
    from slam2d.eval.evaluate import METRIC_COLUMNS, evaluate_run, load_run, recording_frames
    from slam2d.io.atomic import json_text, write_json_atomic

    if args.out is not None and args.out.is_dir():
        raise InputError("is a folder; --out takes the name of the JSON file to write", path=args.out, field="--out")
    if len(set(args.run)) != len(args.run):
        raise InputError("a run is listed twice", field="run")
    truth, relations = _load_truth_options(args)
    runs = [load_run(path) for path in args.run]  # every folder checked before any is judged
    digests = {run.run["data"]["sha256"] for run in runs
               if isinstance(run.run.get("data"), dict) and run.run["data"].get("sha256")}
    if len(digests) > 1:
        raise InputError("these runs read different recordings (run.json's data.sha256 differ): only runs of one "
                         "recording can be ranked", field="run")
    sources, notes, hashed = [], {}, {}
    for path, run in zip(args.run, runs):
        frames, why_not = (recording_frames(run, hashed) if run.run
                           else (None, "a bare trajectory names no recording"))
        sources.append(frames)
        if frames is None:
            notes[path] = f"{path}: no reference-free measures: {why_not}"
    for path, run, frames in zip(args.run, runs, sources):
        if run.map_image is None and frames is None and (truth is None or not truth.has_trajectory) \
                and relations is None:
            raise InputError("nothing to evaluate: a bare trajectory needs --truth, --reference or --relations, "
                             "and a run folder its recording", path=path)
    # each run's evaluation.json in its folder; --out takes a single run's evaluation, or several runs' comparison
    targets = {path: args.out if len(runs) == 1 and args.out is not None
               else (path / "evaluation.json" if path.is_dir() else None) for path in args.run}
    evaluations = {}
    for path, run, frames in zip(args.run, runs, sources):
        evaluations[path] = evaluate_run(run, truth, relations=relations, tolerance=args.tolerance, frames=frames)
        if targets[path] is not None:
            write_json_atomic(targets[path], evaluations[path])
    document = None
    if len(runs) > 1:
        from slam2d.eval.compare import comparison_document, verdict

        names = _run_names(args.run, runs)
        by_name = {names[path]: e for path, e in evaluations.items()}
        document = comparison_document({"paths": [str(p) for p in args.run]}, by_name, verdict(by_name))
        if args.out is not None:
            write_json_atomic(args.out, document)
    if args.json:
        print(json_text(document if document is not None else evaluations[args.run[0]]))
        return 0
    from rich.table import Table

    out = _console()
    for path in args.run:
        t = Table(title=f"{path}", show_header=False, title_justify="left")
        t.add_column("metric", style="bold")
        t.add_column("value")
        t.add_column("meaning")
        for col in METRIC_COLUMNS:
            value = col.value(evaluations[path])
            if value is not None:
                t.add_row(col.label, f"{value:.{col.digits}f} {col.unit}".rstrip(), col.help)
        out.print(t)
        if path in notes:
            out.print(notes[path], markup=False)
    if truth is not None and truth.kind == "reference":
        out.print("trajectory errors are against a reference trajectory, not independent ground truth", markup=False)
    if document is not None:
        out.print(f"verdict: {document['verdict']}", markup=False)
        out.print("ranking, most self-consistent first: " + ", ".join(document["ranking"]), markup=False)
        if args.out is not None:
            _print_written(out, args.out)
    elif targets[args.run[0]] is not None:
        _print_written(out, targets[args.run[0]])
    return 0


def _run_names(paths: list[Path], runs: list[Any]) -> dict[Path, str]:
    """A name per run for the ranking: its method, or its folder's name where methods repeat."""
    methods = [str(run.run.get("method") or path.name) for path, run in zip(paths, runs)]
    unique = len(set(methods)) == len(methods)
    return {path: (m if unique else str(path)) for path, m in zip(paths, methods)}


# --------------------------------------------------------------------------- compare


def _add_compare(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help=_HELP["compare"],
        description="Run every method of --methods on DATA in parallel processes, evaluate each run the same "
        "way (see 'slam2d evaluate') and write OUT/report.html (self-contained), OUT/report.md, "
        "OUT/comparison.json (the verdict: which map to trust, ranked from the runs alone, without a reference; "
        "with --reference or --truth also the ranking by ATE) and OUT/runs/METHOD/ (each run's files). A method "
        "that fails is reported as failed; the others go on.",
    )
    p.add_argument("data", type=Path, help="the recording: .log/.clf(.gz), .bag, or a ROS 2 bag folder")
    p.add_argument("--methods", required=True, help="comma-separated method names (see 'slam2d methods')")
    _add_out(p, "compare")
    _add_truth_options(p)
    p.add_argument("--set", action="append", metavar="[METHOD.]NAME=VALUE", dest="settings",
                   help="a parameter for every method that has it, or for one method (repeatable)")
    p.add_argument("--params", type=Path, metavar="FILE",
                   help="YAML file with one section per method: METHOD: {NAME: VALUE, ...}; --set wins")
    p.add_argument("--seed", type=_seed, help="random seed for every method (default: 0)")
    p.add_argument("--jobs", type=int, metavar="N",
                   help="methods run at once (default: one per core); --jobs 1 times each method alone")
    _add_sensor_model_option(p)
    add_arguments(p.add_argument_group("reading"), ReadOptions)
    p.set_defaults(handler=cmd_compare)


def _per_method_file(path: Path | None, methods: list[str]) -> dict[str, dict[str, Any]]:
    if path is None:
        return {}
    from slam2d.methods import get_method
    from slam2d.methods.runner import read_params_file
    from slam2d.params import from_mapping

    doc, _ = read_params_file(path)
    out = {}
    for name, section in doc.items():
        if name not in methods:
            raise InputError(f"section {name!r} is not one of the methods compared ({', '.join(methods)})",
                             path=path, field=str(name))
        if not isinstance(section, dict):
            raise InputError("expected a mapping of parameter names to values", path=path, field=str(name))
        try:  # a mistyped name or value is named in this file, not only by method
            from_mapping(get_method(name).Params, section)
        except InputError as exc:
            raise InputError(exc.message, path=path, field=f"{name}.{exc.field}" if exc.field else str(name)) from None
        out[name] = section
    return out


def cmd_compare(args: argparse.Namespace) -> int:
    import time

    from slam2d.eval.compare import compare
    from slam2d.methods.registry import get_method

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for name in methods:  # every name checked before any method starts
        try:
            get_method(name)
        except InputError as exc:
            raise InputError(exc.message, field="--methods") from None
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"{args.jobs} must be at least 1", field="--jobs")
    truth, relations = _load_truth_options(args)
    out = _console()

    def done(outcome: Any, seconds: float) -> None:
        if outcome.ok:
            out.print(f"  {outcome.method}: finished in {seconds:.1f} s", markup=False)
        else:
            out.print(f"  {outcome.method}: FAILED after {seconds:.1f} s: {outcome.error}", markup=False)

    out.print(f"running {', '.join(methods)} on {args.data}", markup=False)
    comparison = compare(
        args.data, methods, args.out, truth=truth, relations=relations, settings=_settings(args.settings),
        per_method_params=_per_method_file(args.params, methods), seed=args.seed, read_options=_read_options(args),
        jobs=args.jobs, tolerance=args.tolerance, command=_command_line(), on_done=done,
        sensor_model=args.sensor_model,
    )
    from slam2d.report.comparison import write_report

    t0 = time.perf_counter()
    written = write_report(comparison, args.out)
    out.print(f"report written in {time.perf_counter() - t0:.1f} s", markup=False)
    for path in written:
        _print_written(out, path)
    failed = [o for o in comparison.outcomes if not o.ok]
    return 1 if len(failed) == len(comparison.outcomes) else 0


# --------------------------------------------------------------------------- demo


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help=_HELP["demo"],
        description="Simulate a youBot with a Hokuyo URG-04LX driving through paper-arena (the source "
        "study's rectangular-walled room), write the recording and its ground truth, run 'info' on it, "
        "then 'compare' every method on it against the truth and write the report "
        "(OUT/compare/report.html).",
    )
    p.add_argument("--out", type=Path, default=Path("demo-out"), help="output folder (default: demo-out)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed of the simulated noise (default: 0)")
    p.set_defaults(handler=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    from slam2d.methods import method_names

    parser = build_parser()
    sim_dir = args.out / "paper-arena"
    status = main_args(parser.parse_args(["simulate", "paper-arena", "--out", str(sim_dir), "--seed", str(args.seed)]))
    if status:
        return status
    log = sim_dir / "recording.log.gz"
    status |= main_args(parser.parse_args(["info", str(log)]))
    status |= main_args(parser.parse_args([
        "compare", str(log), "--methods", ",".join(method_names()), "--truth", str(sim_dir),
        "--out", str(args.out / "compare"), "--seed", str(args.seed),
    ]))
    if not status:
        _console().print(f"open {args.out / 'compare' / 'report.html'} in a browser", markup=False)
    return status


# --------------------------------------------------------------------------- paper


def _add_paper(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "paper",
        help=_HELP["paper"],
        description="Rerun the source study in simulation: Section III (paper-arena with a youBot and a "
        "URG-04LX at limited speed, every method on the same recording, maps side by side, ATE, map error, "
        "Filatov metrics, speed, memory, and the study's ranking tested by stated rules), Section IV (the "
        "repeatability experiment: Table I, Figs. 5-7, eq. 1 beside the study's) and Section V when this build "
        "has it. Writes OUT/report.html (self-contained), OUT/report.md, OUT/paper.json (every number) and each "
        "section's files under OUT/section3/, OUT/section4/, OUT/section5/. The report is built in a staging "
        "folder and moved into place at the end; an existing OUT is replaced only if it is an earlier "
        "'slam2d paper' output.",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (new, empty, or an earlier paper output)")
    p.add_argument("--quick", action="store_true",
                   help="one lap on one seed in Section III instead of two laps on three seeds (about a minute)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulations (default: 0)")
    p.add_argument("--jobs", type=int, metavar="N", help="methods run at once (default: one per core)")
    p.set_defaults(handler=cmd_paper)


def cmd_paper(args: argparse.Namespace) -> int:
    from slam2d.experiments.paper import run_paper

    out = _console()
    err = _console(stderr=True)
    result = run_paper(args.out, quick=args.quick, seed=args.seed, jobs=args.jobs, command=_command_line(),
                       log=lambda msg: err.print(msg, markup=False))
    for s in result.sections:
        timing = f" (wall {s.wall_s:.1f} s, CPU {s.cpu_s:.1f} s)" if s.wall_s is not None else ""
        out.print(f"Section {s.key}: {s.status}{timing}", markup=False)
        for r in s.results:
            out.print(f"  {r.title}: {r.verdict}", markup=False)
        if s.status != "ok":
            out.print(f"  {s.note}", markup=False)
    out.print(f"total: wall {result.wall_s:.1f} s, CPU {result.cpu_s:.1f} s", markup=False)
    for path in result.written:
        _print_written(out, path)
    return 1 if result.failed else 0


# --------------------------------------------------------------------------- simulate


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    from slam2d.sensors.motion_noise import OdometryNoise
    from slam2d.sim.simulate import TRUTH_MAP_RESOLUTION, SimulationParams
    from slam2d.sim.world import builtin_world_names

    p = sub.add_parser(
        "simulate",
        help=_HELP["simulate"],
        description="Drive a simulated robot along a path in WORLD (a built-in name or a YAML world file) "
        "and write what it recorded: a CARMEN log (recording.log.gz), a ROS 2 bag (recording/; "
        "recording.bag with --ros1) with /scan, /odom, /tf and /tf_static, the true trajectory "
        "(truth.tum), the true occupancy map (truth-map.yaml + .pgm), the world (world.yaml) and every "
        "setting (simulation.json). The same settings and seed give the same bytes.",
    )
    p.add_argument("world", help=f"a built-in world ({', '.join(builtin_world_names())}) or a world YAML file")
    _add_out(p, "simulate")
    p.add_argument("--path", type=Path, help="YAML with 'waypoints: [[x, y], ...]' or "
                   "'commands: [[seconds, vx, vy, omega], ...]' (default: the world's own path)")
    p.add_argument("--ros1", action="store_true", help="write a ROS 1 bag instead of a ROS 2 bag")
    p.add_argument("--map-resolution", type=float, default=TRUTH_MAP_RESOLUTION, metavar="M",
                   help="cell size of the true occupancy map [m]; finer than the maps it judges, so their "
                   f"errors are measured on their own cells (default: {TRUTH_MAP_RESOLUTION})")
    add_arguments(p.add_argument_group("simulation"), SimulationParams)
    add_arguments(p.add_argument_group("odometry noise"), OdometryNoise)
    p.set_defaults(handler=cmd_simulate)


def cmd_simulate(args: argparse.Namespace) -> int:
    from slam2d.sensors.motion_noise import OdometryNoise
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    if not args.map_resolution > 0:
        raise InputError(f"{args.map_resolution} m must be positive", field="map_resolution")
    params = from_arguments(SimulationParams, args)
    noise = from_arguments(OdometryNoise, args)
    with progress_bar(f"simulating {args.world}"):
        sim = simulate(args.world, params, odometry_noise=noise, path=args.path)
    written = write_outputs(sim, args.out, ros1=args.ros1, map_resolution=args.map_resolution)
    out = _console()
    duration = float(sim.times[-1] - sim.times[0])
    out.print(
        f"simulated {duration:.1f} s in {sim.world.name}: {len(sim.scans)} scans from a {sim.laser.name} "
        f"on a {sim.robot.name}, seed {params.seed}",
        markup=False,
    )
    for path in written:
        _print_written(out, path)
    return 0


# --------------------------------------------------------------------------- repeatability


def _add_repeatability(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "repeatability",
        help=_HELP["repeatability"],
        description="The source study's repeatability experiment in simulation: a laser facing a flat target "
        "of each material at each distance and angle, measured N times. Writes repeatability.csv "
        "(material, angle_deg, distance_m, repetition, range_m), and with --scan-logs one CARMEN log of "
        "full scans per set-up.",
    )
    _add_out(p, "repeatability")
    p.add_argument("--materials", default=",".join(_materials()),
                   help="comma-separated materials (default: all five of the study)")
    p.add_argument("--distances", default="1,2,3,3.5,4", help="comma-separated distances [m] (default: 1,2,3,3.5,4)")
    p.add_argument("--angles", default="90,45",
                   help="comma-separated angles between beam and target [deg]; 90 = perpendicular (default: 90,45)")
    p.add_argument("--repetitions", type=int, default=500, help="measurements per set-up (default: 500)")
    p.add_argument("--laser", default="urg-04lx", help="laser preset (default: urg-04lx)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed (default: 0)")
    p.add_argument("--scan-logs", action="store_true", help="also write one CARMEN log of full scans per set-up")
    p.set_defaults(handler=cmd_repeatability)


def _materials() -> tuple[str, ...]:
    from slam2d.sensors.range_noise import MATERIALS

    return MATERIALS


def _number_list(text: str, field: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{text!r} is not a comma-separated list of numbers", field=field) from None
    if not values:
        raise InputError("the list is empty", field=field)
    return values


def cmd_repeatability(args: argparse.Namespace) -> int:
    from slam2d.sensors.range_noise import material_index
    from slam2d.sim.laser import laser_preset
    from slam2d.sim.repeatability import (
        format_summary, repeated_measurements, study_setups, write_repeatability_csv, write_setup_log,
    )

    materials = [m.strip() for m in args.materials.split(",") if m.strip()]
    for m in materials:
        try:
            material_index(m)
        except ValueError as exc:
            raise InputError(str(exc), field="materials") from None
    distances = _number_list(args.distances, "distances")
    angles = _number_list(args.angles, "angles")
    if any(d <= 0 for d in distances):
        raise InputError("distances must be positive", field="distances")
    if any(not 0 < a <= 90 for a in angles):
        raise InputError("angles must lie in (0, 90] degrees", field="angles")
    if args.repetitions < 1:
        raise InputError(f"{args.repetitions} must be at least 1", field="repetitions")
    laser = laser_preset(args.laser)
    rows = repeated_measurements(materials, distances, angles, args.repetitions, laser=laser, seed=args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    written = [write_repeatability_csv(args.out / "repeatability.csv", rows)]
    if args.scan_logs:
        for setup in study_setups(materials, distances, angles):
            name = f"{setup.material}-{setup.angle_deg:g}deg-{setup.distance:g}m.log.gz"
            written.append(write_setup_log(args.out / "setups" / name, setup, args.repetitions,
                                           laser=laser, seed=args.seed))
    out = _console()
    out.print(format_summary(rows), markup=False)
    for path in written:
        _print_written(out, path)
    return 0


# --------------------------------------------------------------------------- calibrate and --sensor-model


def _add_sensor_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sensor-model", metavar="MODEL",
                   help="range noise model the methods weigh beams with: a model file ('slam2d calibrate laser' "
                   "writes one), 'study' (the source study's URG-04LX model) or 'constant:SIGMA' in metres "
                   "(default: each method's own constant)")


def _add_calibrate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help=_HELP["calibrate"],
        description="Estimate sensor and motion models from data: 'laser' fits sigma against distance (and "
        "incidence) from repeated range measurements and writes a model file every method accepts "
        "(--sensor-model); 'verify' checks a model against new measurements; 'odometry' estimates GMapping's "
        "srr, srt, str, stt and the systematic scale errors against a reference trajectory; 'odometry-lag' "
        "how far the odometry leads the scans in time (coreslam's odometry_delay).",
    )
    csub = p.add_subparsers(dest="calibrate_command", metavar="WHAT", required=True)
    laser = csub.add_parser(
        "laser",
        help="range sigma per surface, angle and distance; fits; a sensor model file",
        description="Reduce repeated range measurements as the source study did, for any laser: DATA is a tidy "
        "CSV (material, angle_deg, distance_m, repetition, range_m, as 'slam2d repeatability' writes) or "
        "recordings of a laser standing still before a static scene (per-beam statistics over the scans, "
        "grouped by range and incidence). Writes OUT/report.html and OUT/report.md (sigma per surface and angle, "
        "Gaussian probability plots, fits of sigma against distance with the degree chosen by "
        "cross-validation, residuals and 95 %% bands, sigma at the reference distance) and OUT/model.yaml.",
    )
    laser.add_argument("data", type=Path, nargs="+", help="CSV file(s), or recording(s) of a static laser")
    _add_out(laser, "calibrate laser")
    laser.add_argument("--reference-distance", type=float, default=2.5, metavar="M",
                       help="distance at which to report one sigma [m] (default: 2.5, the study's)")
    laser.add_argument("--degree", default="cv",
                       help="polynomial degree of the fits, or 'cv' to choose it by leave-one-distance-out "
                       "cross-validation (default: cv)")
    laser.add_argument("--max-degree", type=int, default=5,
                       help="highest degree cross-validation may choose (default: 5; it can only compare degrees "
                       "up to the number of distances minus 2, so on the study's five distances at most the cubic)")
    laser.add_argument("--range-bin", type=float, default=0.25, metavar="M",
                       help="recordings: width of the range groups [m] (default: 0.25)")
    laser.add_argument("--incidence-bin", type=float, default=15.0, metavar="DEG",
                       help="recordings: width of the incidence groups [deg] (default: 15)")
    laser.set_defaults(handler=cmd_calibrate_laser)
    verify = csub.add_parser(
        "verify",
        help="measured repeatability under new conditions against a model's prediction",
        description="Compare the sigma measured in DATA (CSV or static recordings, as for 'calibrate laser') "
        "with MODEL's prediction at each set-up's distance, incidence and surface; count the set-ups inside "
        "the model's band (prediction +- z x the model's own uncertainty and the sampling error combined). "
        "Writes OUT/report.html, OUT/report.md and OUT/verification.json.",
    )
    verify.add_argument("model", help="a model file, 'study' or 'constant:SIGMA'")
    verify.add_argument("data", type=Path, nargs="+", help="CSV file(s), or recording(s) of a static laser")
    _add_out(verify, "calibrate verify")
    verify.add_argument("--z", type=float, default=1.96, help="half-width of the band in standard deviations "
                        "(default: 1.96, 95 %%)")
    verify.add_argument("--range-bin", type=float, default=0.25, metavar="M",
                        help="recordings: width of the range groups [m] (default: 0.25)")
    verify.add_argument("--incidence-bin", type=float, default=15.0, metavar="DEG",
                        help="recordings: width of the incidence groups [deg] (default: 15)")
    verify.set_defaults(handler=cmd_calibrate_verify)
    odo = csub.add_parser(
        "odometry",
        help="odometry noise (srr, srt, str, stt) and scale errors against a reference trajectory",
        description="Maximum-likelihood estimates, with 95 %% intervals, of the odometry noise model the "
        "simulator uses (GMapping's srr, srt, str, stt, see docs/robots.md) and of the systematic wheel radius "
        "and track width scales, from DATA's odometry (a recording, or a TUM file of odometry poses) against "
        "a reference trajectory. Writes OUT/gmapping-params.yaml (srr, srt, str, stt: 'slam2d run gmapping "
        "--params' reads it), OUT/odometry.yaml (every estimate with its interval), OUT/report.html and "
        "OUT/report.md.",
    )
    odo.add_argument("data", type=Path, help="a recording with odometry, or a TUM file of odometry poses")
    odo.add_argument("--reference", type=Path, required=True, metavar="POSES.tum",
                     help="reference trajectory (TUM), e.g. a simulation's truth.tum")
    _add_out(odo, "calibrate odometry")
    odo.add_argument("--linear-update", type=float, default=1.0, metavar="M",
                     help="translation over which srr is the spread per metre (GMapping linearUpdate; the "
                     "simulator's reference_distance) [m] (default: 1.0)")
    odo.add_argument("--angular-update", type=float, default=0.5, metavar="RAD",
                     help="rotation over which stt is the spread per radian (GMapping angularUpdate; the "
                     "simulator's reference_rotation) [rad] (default: 0.5)")
    odo.add_argument("--exact-reference", action="store_true",
                     help="the reference has no error of its own (a simulator's truth): do not estimate its noise")
    odo.add_argument("--max-gap", type=float, default=0.5, metavar="S",
                     help="longest gap between reference poses to interpolate across [s] (default: 0.5)")
    odo.set_defaults(handler=cmd_calibrate_odometry)
    lag = csub.add_parser(
        "odometry-lag",
        help="how far the odometry leads the scans in time, and the odometry_delay to set",
        description="Estimate from DATA alone (no reference) how far its odometry leads (or lags) its scans: "
        "the heading change from each scan to the next by registering the two scans, against the odometry's "
        "heading change read D seconds before the two stamps, fitted with a free scale over a grid of D. Prints "
        "the best D with its 95 %% interval, the rms per scan pair at D = 0 and at D, and the '--set "
        "odometry_delay=D' for coreslam. Refuses (exit 2) a recording without odometry or without turns; exits "
        "1 when the estimate is not reliable (the turns do not fix the timing, the registration failed, or the lag "
        "moves when the odometry's smoothing is halved or doubled).",
    )
    lag.add_argument("data", type=Path, help="a recording with odometry (CARMEN log, ROS 1 or 2 bag)")
    lag.add_argument("--max-lag", type=float, default=0.5, metavar="S",
                     help="search D from -S to +S [s] (default: 0.5)")
    lag.add_argument("--step", type=float, default=0.01, metavar="S",
                     help="grid step of D [s] (default: 0.01; refined tenfold around the best)")
    lag.add_argument("--json", action="store_true", help="print the estimate as JSON")
    add_arguments(lag.add_argument_group("reading"), ReadOptions)
    lag.set_defaults(handler=cmd_calibrate_odometry_lag)


def _degree(text: str) -> int | None:
    if text.strip().lower() == "cv":
        return None
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{text!r} is not a whole number or 'cv'", field="--degree") from None


def cmd_calibrate_laser(args: argparse.Namespace) -> int:
    from slam2d.io.atomic import write_text_atomic
    from slam2d.sensors.calibration.laser import calibrate_laser, load_laser_data
    from slam2d.sensors.calibration.model import dump_model_yaml, model_from_document
    from slam2d.sensors.calibration.report import laser_report

    data = load_laser_data(args.data, range_bin=args.range_bin, incidence_bin=args.incidence_bin)
    cal = calibrate_laser(data, reference_distance=args.reference_distance, degree=_degree(args.degree),
                          max_degree=args.max_degree)
    model_path = args.out / "model.yaml"
    doc = cal.model_document({"command": _command_line()})
    model_from_document(doc, model_path)  # what we write must read back
    args.out.mkdir(parents=True, exist_ok=True)
    header = f"slam2d sensor model (docs/sensor-model.md); use it with --sensor-model {model_path}"
    write_text_atomic(model_path, dump_model_yaml(doc, header))
    written = [model_path, *laser_report(cal, model_path, _command_line()).write(args.out)]
    out = _console()
    ref = cal.sigma_at_reference()
    out.print(f"{len(data.setups)} set-ups; sigma at {cal.reference_distance:g} m: "
              + ", ".join(f"{k} {1000 * v:.2f} mm" for k, v in ref.items()), markup=False)
    for path in written[:3]:
        _print_written(out, path)
    return 0


def cmd_calibrate_verify(args: argparse.Namespace) -> int:
    from slam2d.io.atomic import write_json_atomic
    from slam2d.sensors.calibration.laser import load_laser_data, verify_model
    from slam2d.sensors.calibration.model import sensor_model_from_spec
    from slam2d.sensors.calibration.report import verify_report

    model = sensor_model_from_spec(args.model)
    data = load_laser_data(args.data, range_bin=args.range_bin, incidence_bin=args.incidence_bin)
    ver = verify_model(model, data, z=args.z, source=args.model)
    written = verify_report(ver, model, data.sources, _command_line()).write(args.out)
    summary = {
        "model": args.model, "data": data.sources, "z": ver.z, "share_inside": ver.share_inside,
        "setups": [{"material": r.setup.material, "angle_deg": r.setup.angle_deg, "distance_m": r.setup.distance,
                    "measured_sigma_m": r.setup.sigma, "predicted_sigma_m": r.predicted,
                    "band_half_width_m": r.half_width, "inside": r.inside} for r in ver.rows],
    }
    write_json_atomic(args.out / "verification.json", summary)
    out = _console()
    out.print(f"{sum(r.inside for r in ver.rows)} of {len(ver.rows)} set-ups ({100 * ver.share_inside:.1f} %) "
              f"inside the model's band", markup=False)
    for path in [args.out / "verification.json", *written[:2]]:
        _print_written(out, path)
    return 0


def cmd_calibrate_odometry(args: argparse.Namespace) -> int:
    from slam2d.io.atomic import write_text_atomic
    from slam2d.sensors.calibration.model import dump_model_yaml
    from slam2d.sensors.calibration.odometry import calibrate_odometry, load_odometry_pairs
    from slam2d.sensors.calibration.report import odometry_report

    if not args.max_gap > 0:
        raise InputError(f"{args.max_gap} s must be positive", field="--max-gap")
    pairs = load_odometry_pairs(args.data, args.reference, max_gap=args.max_gap)
    cal = calibrate_odometry(pairs, reference_distance=args.linear_update, reference_rotation=args.angular_update,
                             exact_reference=args.exact_reference)
    args.out.mkdir(parents=True, exist_ok=True)
    params = cal.gmapping_params()
    lines = [f"# GMapping odometry noise from 'slam2d calibrate odometry' ({cal.intervals} intervals)",
             f"# linearUpdate {cal.reference_distance:g} m, angularUpdate {cal.reference_rotation:g} rad; "
             "95 % intervals in odometry.yaml"]
    lines += [f"{k}: {v!r}" for k, v in params.items()]
    gpath, fpath = args.out / "gmapping-params.yaml", args.out / "odometry.yaml"
    write_text_atomic(gpath, "\n".join(lines) + "\n")
    record = {**cal.as_dict(), "data": str(args.data), "reference": str(args.reference), "command": _command_line()}
    write_text_atomic(fpath, dump_model_yaml(record, "odometry calibration (docs/commands/calibrate.md)"))
    written = [gpath, fpath, *odometry_report(cal, [str(args.data), str(args.reference)], _command_line()).write(args.out)]
    out = _console()
    for k, e in cal.noise.items():
        ci = f"[{e.low:.4g}, {e.high:.4g}]" if e.identifiable else "not identifiable"
        out.print(f"  {k} = {e.value:.4g} {ci}", markup=False)
    for k in ("wheel_radius_scale", "track_width_scale"):
        e = getattr(cal, k)
        out.print(f"  {k} = {e.value:.4f} [{e.low:.4f}, {e.high:.4f}]", markup=False)
    for note in cal.notes:
        out.print(f"  note: {note}", markup=False)
    for path in written[:4]:
        _print_written(out, path)
    return 0


def cmd_calibrate_odometry_lag(args: argparse.Namespace) -> int:
    import math

    from slam2d.io import open_recording
    from slam2d.io.atomic import json_text
    from slam2d.sensors.calibration.odometry_lag import odometry_lag

    if not args.data.exists():
        raise InputError("no such file or folder", path=args.data)
    recording = open_recording(args.data, _read_options(args))
    with progress_bar(f"reading {args.data.name}") as progress:
        frames = list(recording.frames(progress))
    try:
        est = odometry_lag(frames, max_lag=args.max_lag, step=args.step)
    except InputError as exc:
        raise exc.in_file(args.data) from None
    out = _console()
    setting = est.setting()
    if args.json:
        out.print(json_text({**est.as_dict(), "data": str(args.data)}), markup=False)
    else:
        lo, hi = est.interval
        word = "leads" if est.lag >= 0 else "lags"
        out.print(f"odometry {word} the scans by {abs(est.lag):.3f} s (95 %: {lo:.3f} to {hi:.3f} s; positive = "
                  f"leads), from {est.pairs} scan pairs turning {math.degrees(est.turn):.0f} deg in all", markup=False)
        out.print(f"  heading change per scan pair, scans against scaled odometry: {est.rms_at_zero:.3f} deg rms "
                  f"read at the stamps, {est.rms_at_lag:.3f} deg read back by {est.lag:.3f} s "
                  f"({est.improvement:.2f} x smaller); scan turn / odometry turn {est.scale:.3f}", markup=False)
        for note in est.notes:
            out.print(f"  note: {note}", markup=False)
        if setting is not None:
            out.print(f"  use with coreslam: --set use_odometry=true --set {setting}", markup=False)
        elif est.confident:
            out.print("  nothing to set: keep odometry_delay=0", markup=False)
        else:
            out.print("  no odometry_delay recommended: the estimate is not reliable", markup=False)
    return 0 if est.confident else 1


# --------------------------------------------------------------------------- sweep


def _add_sweep(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help=_HELP["sweep"],
        description="Run every run a sweep spec (YAML: methods with parameter grids or seeded random ranges, "
        "datasets as files or simulated worlds with seeds, metrics) describes, evaluate each, and write "
        "OUT/results.parquet and OUT/results.csv (one row per run), OUT/plots/ (each metric against each swept "
        "value) and OUT/summary.html (the best settings per method with their spread over seeds). Runs go to a "
        "local process pool, or to a Dask cluster with --scheduler. Rerunning the same command skips the "
        "finished runs; a run whose worker dies is retried once.",
    )
    p.add_argument("spec", type=Path, help="the sweep spec (YAML; see docs/commands/sweep.md)")
    p.add_argument("--out", type=Path, required=True, help="output folder (created if missing; reused to resume)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="address of a running Dask scheduler (start one with 'dask scheduler' and 'dask worker', "
                   "formerly dask-scheduler and dask-worker); "
                   "default: a local process pool")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: one per core); with --scheduler, wait until N "
                   "workers have joined")
    p.add_argument("--retry-failed", action="store_true", help="rerun the runs that failed before (default: keep them)")
    p.add_argument("--dry-run", action="store_true", help="check the spec and list the runs; run nothing")
    p.set_defaults(handler=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from slam2d.sweep import check_methods, load_spec, run_sweep

    if args.workers is not None and args.workers < 1:
        raise InputError(f"{args.workers} must be at least 1", field="--workers")
    spec = load_spec(args.spec)
    out = _console()
    if args.dry_run:
        from slam2d.sweep.expand import expand

        check_methods(spec)
        data, runs = expand(spec, args.out)
        per_method = {m.method: sum(r.method == m.method for r in runs) for m in spec.methods}
        out.print(f"{spec.path}: {len(runs)} runs on {len(data)} recording(s) "
                  f"({', '.join(f'{m}: {n}' for m, n in per_method.items())}); "
                  f"metrics {', '.join(m.name for m in spec.metrics)}, best by {spec.objective.name}", markup=False)
        return 0

    def row_done(row: dict[str, Any], done: int, total: int) -> None:
        swept = ", ".join(f"{k}={v}" for k, v in row.get("swept", {}).items())
        sim = f" (simulation seed {row['dataset_seed']})" if row.get("dataset_seed") is not None else ""
        what = f"{row['method']} {swept} on {row['dataset']}{sim}, seed {row['seed']}".replace("  ", " ")
        if row["status"] == "ok":
            value = row["metrics"].get(spec.objective.name)
            shown = "-" if value is None else f"{value:.4g}"
            out.print(f"  [{done}/{total}] {what}: {spec.objective.name} {shown} ({row['task_s']:.1f} s)",
                      markup=False)
        else:
            out.print(f"  [{done}/{total}] {what}: FAILED: {row['error']}", markup=False)

    result = run_sweep(spec, args.out, scheduler=args.scheduler, workers=args.workers,
                       retry_failed=args.retry_failed, on_row=row_done,
                       on_note=lambda line: out.print(line, markup=False))
    failed = len(result.failed)
    out.print(f"{len(result.rows)} runs: {len(result.rows) - failed} finished, {failed} failed "
              f"({result.executed} run now, {result.reused} reused)", markup=False)
    for path in result.written:
        if path.parent == args.out or path.name == "summary.html":
            _print_written(out, path)
    return 1 if result.rows and failed == len(result.rows) else 0


# --------------------------------------------------------------------------- experiment (the study's Section V)


def _add_experiment(sub: argparse._SubParsersAction) -> None:
    from slam2d.experiments.section5 import EXPERIMENTS

    p = sub.add_parser(
        "experiment",
        help=_HELP["experiment"],
        description="The source study's Section V in simulation with exact ground truth: GMapping with and without "
        "the laser model (the study's constant 0.0041 m, a sigma(range, incidence) calibrated from simulated "
        "repeated measurements, and 0.0041 set as GMapping's own sigma parameter). can, broken-wall, rebound: "
        "obstacle thickness, distance to the true shape and ATE (Figs. 8-10); entropy: GMapping's published "
        "entropy over 10 runs per setting against ln N and the study's values; new-conditions: repeatability "
        "under conditions not used for the calibration against the model ('calibrate verify', Fig. 11); "
        "held-out: ATE and map error of each setting on several worlds and seeds. Writes OUT/summary.md, "
        "OUT/result.json, OUT/tables/*.csv and OUT/figures/*.png.",
    )
    p.add_argument("experiment", choices=list(EXPERIMENTS), metavar="EXPERIMENT",
                   help="one of: " + ", ".join(EXPERIMENTS))
    _add_out(p, "experiment")
    p.add_argument("--quick", action="store_true",
                   help="short recordings, fewer particles, seeds and runs (seconds, not minutes; indicative only)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the recordings and filters (default: 0)")
    p.set_defaults(handler=cmd_experiment)


def cmd_experiment(args: argparse.Namespace) -> int:
    from slam2d.experiments.section5 import run_experiment

    with progress_bar(f"experiment {args.experiment}"):
        result = run_experiment(args.experiment, args.out, quick=args.quick, seed=args.seed)
    out = _console()
    out.print(result.title, markup=False)
    out.print(result.verdict, markup=False)
    for name in ("summary.md", "result.json"):
        _print_written(out, args.out / name)
    return 0


# --------------------------------------------------------------------------- entry point

# --------------------------------------------------------------------------- compile


def _add_compile(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compile",
        help=_HELP["compile"],
        description="numba compiles each kernel on its first use and keeps it on disk. This runs every method "
        "once on a short simulated recording (with and without odometry where it is optional) so that "
        "compilation happens now, not in your first run. 'make' runs it after installing; run it again after "
        "upgrading slam2d or numba. Takes about a minute on two cores.",
    )
    p.add_argument("--jobs", type=int, default=None, help="runs at a time (default: the CPUs, at most 4)")
    p.set_defaults(handler=cmd_compile)


def cmd_compile(args: argparse.Namespace) -> int:
    from slam2d.methods.warm_up import warm_up

    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"must be 1 or more, got {args.jobs}", field="--jobs")
    took = warm_up(args.jobs, say=lambda line: print(line, flush=True))
    print(f"every kernel compiled and cached ({took:.0f} s)")
    return 0


# --------------------------------------------------------------------------- ros


def _add_ros(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ros",
        help=_HELP["ros"],
        description="Run METHOD as a ROS 1 node named slam2d, as slam_gmapping runs: it subscribes 'scan', reads "
        "the odometry from tf (odom_frame -> base_frame) and the laser's mount (base_frame -> the scan's frame), "
        "and publishes 'map' and 'map_metadata' (latched), tf map_frame -> odom_frame, '~pose' and "
        "'~diagnostics'; services 'dynamic_map' and '~save'. Every method parameter is also a private ROS "
        "parameter (_particles:=50; --set wins), and ROS remappings (scan:=/base_scan) pass through. On "
        "shutdown with --out (or _output:=DIR) the run folder is written as 'slam2d run' writes it. Needs ROS 1 "
        "(Debian: apt-get install ros-core python3-rospy python3-tf2-ros and the message packages).",
    )
    p.add_argument("method", help="method name (see 'slam2d methods')")
    p.add_argument("--out", type=Path, help="run folder written on shutdown and by ~save (as _output:=DIR)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out that is not a node's output")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", dest="settings",
                   help="a method parameter (repeatable); wins over the private ROS parameters")
    p.add_argument("--params", type=Path, metavar="FILE",
                   help="YAML file of parameters, a slam_toolbox or slam_gmapping YAML, or a run.json")
    p.add_argument("--seed", type=_seed, help="random seed (default: the --params file's, else 0)")
    _add_sensor_model_option(p)
    p.set_defaults(handler=cmd_ros)


def cmd_ros(args: argparse.Namespace) -> int:
    from slam2d.methods.runner import build_method
    from slam2d.ros.node import run_node

    build = {"settings": _settings(args.settings), "params_file": args.params, "seed": args.seed,
             "sensor_model": args.sensor_model}
    build_method(args.method, **build)  # every setting checked before ROS starts
    if args.out is not None:
        from slam2d.io.atomic import check_output_folder

        check_output_folder(args.out, "ros", overwrite=args.overwrite)
    return run_node(args.method, build, command=_command_line(), output=args.out, overwrite=args.overwrite)


_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    _add_info, _add_map, _add_methods, _add_run, _add_localize, _add_evaluate, _add_compare, _add_simulate,
    _add_repeatability, _add_demo, _add_paper, _add_calibrate, _add_sweep, _add_experiment, _add_compile, _add_ros,
]


def build_parser(command: str | None = None, *, listing: bool = False) -> argparse.ArgumentParser:
    """The command line; with ``command`` (a command's name) only that command's parser.

    Each command's options come from parameter classes whose modules take time to import (the
    experiments, the simulator): ``slam2d map`` should not pay for ``slam2d experiment``'s. A name
    that is not a command gets the whole parser, so argparse lists the valid ones.
    """
    parser = argparse.ArgumentParser(
        prog="slam2d",
        description="2D laser SLAM methods behind one interface: read recordings, build and compare maps.",
    )
    parser.add_argument("--version", action="version", version=f"slam2d {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    by_name = {add.__name__.removeprefix("_add_"): add for add in _COMMANDS}
    if listing and command not in by_name:  # `slam2d --help`: the commands, a line each, nothing imported
        for name, text in _HELP.items():
            sub.add_parser(name, help=text)
        return parser
    for add in [by_name[command]] if command in by_name else _COMMANDS:
        add(sub)
    return parser


def _os_error_text(exc: OSError) -> str:
    """The system's words, said for an output folder where they are cryptic ("File exists" for a file)."""
    import errno

    if isinstance(exc, FileExistsError) and exc.filename and Path(exc.filename).exists() and not Path(
        exc.filename
    ).is_dir():
        return "exists and is a file; a folder is needed here"
    if exc.errno == errno.ENOTDIR:
        return "a part of this path is a file, not a folder"
    return str(exc.strerror or exc)


def _run_staged(args: argparse.Namespace) -> int:
    """Run the command into a staging folder that replaces ``--out`` whole when it is done."""
    from slam2d.io.atomic import check_output_folder, staged_folder

    final = args.out
    check_output_folder(final, args.staged, overwrite=args.overwrite)
    with staged_folder(final, args.staged) as stage:
        _STAGES[stage] = final
        args.out = stage
        try:
            return int(args.handler(args) or 0)
        finally:
            args.out = final
            del _STAGES[stage]


def main_args(args: argparse.Namespace) -> int:
    if getattr(args, "max_memory", None):
        from slam2d.core.memory import budget_override, set_budget

        before = budget_override()
        set_budget(args.max_memory)
        try:
            return _main_args(args)
        finally:  # for this command only (a test or a script may run several in one process)
            set_budget(before)
    return _main_args(args)


def _main_args(args: argparse.Namespace) -> int:
    try:
        if getattr(args, "staged", None):
            return _run_staged(args)
        return int(args.handler(args) or 0)
    except Slam2dError as exc:
        print(f"slam2d: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:  # an output folder we cannot write, a disk that is full
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"slam2d: error: {where}{_os_error_text(exc)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("slam2d: interrupted", file=sys.stderr)
        return 130


def main(argv: list[str] | None = None) -> int:
    from slam2d.core.memory import return_freed_memory

    return_freed_memory()  # peak memory near what is live (workers forked from here inherit it)
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "ros":  # ROS remappings and private parameters (name:=value) are rospy's to read
        argv = [a for a in argv if ":=" not in a]
    parser = build_parser(argv[0] if argv else None, listing=True)
    args = parser.parse_args(argv)
    return main_args(args)
