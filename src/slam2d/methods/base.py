"""The interface every SLAM method implements, and the diagnostics it keeps.

A method is built from its parameter dataclass (``Params``; fields made with
:func:`slam2d.params.param`, so the CLI options and the docs table come from
it), a seed, and optionally a per-beam sensor model. It is then fed one
:class:`~slam2d.core.frames.Frame` at a time with :meth:`SlamMethod.feed`,
and at any point exposes

* :attr:`~SlamMethod.pose`: the current pose estimate of the robot base,
* :meth:`~SlamMethod.trajectory`: the estimated pose at every frame it placed,
* :meth:`~SlamMethod.map`: the current occupancy grid,
* :attr:`~SlamMethod.diagnostics`: per-update wall and CPU time, plus the
  values the method reports (match scores, effective particle counts, ...).

A method subclass implements :meth:`~SlamMethod.update` (one frame),
:meth:`~SlamMethod.current_pose` and :meth:`~SlamMethod.map`, and registers
itself with :func:`slam2d.methods.registry.register`. Graph methods that
revise the past override :meth:`~SlamMethod.trajectory` and
:meth:`~SlamMethod.finish`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.compile_time import compile_clock
from slam2d.core.frames import Frame
from slam2d.grids.occupancy import OccupancyGrid
from slam2d.params import as_dict, auto_fields, validate

__all__ = ["SlamMethod", "Diagnostics"]

log = logging.getLogger(__name__)


class Diagnostics:
    """What a method did, update by update: a table of numeric series plus totals.

    ``series`` maps a name to one value per update; every update has
    ``timestamp`` (s), ``wall_s`` and ``cpu_s`` (the time :meth:`SlamMethod.update`
    took), and whatever the method returned for it. A value a method did not
    report for an update is NaN. ``counters`` count events (``match_failures``,
    ``resamples``...); ``summary`` holds scalars set once (``finish_wall_s``,
    peak memory...).
    """

    BUILT_IN = ("timestamp", "wall_s", "cpu_s")

    def __init__(self) -> None:
        self.series: dict[str, list[float]] = {name: [] for name in self.BUILT_IN}
        self.counters: Counter[str] = Counter()
        self.summary: dict[str, Any] = {}

    def __len__(self) -> int:
        return len(self.series["timestamp"])

    def record(self, timestamp: float, wall_s: float, cpu_s: float, values: Mapping[str, float] | None) -> None:
        n = len(self)
        self.series["timestamp"].append(float(timestamp))
        self.series["wall_s"].append(float(wall_s))
        self.series["cpu_s"].append(float(cpu_s))
        for name, value in (values or {}).items():
            column = self.series.get(name)
            if column is None:
                column = self.series[name] = [math.nan] * n
            column.append(float(value))
        for column in self.series.values():
            if len(column) == n:
                column.append(math.nan)

    def count(self, name: str, n: int = 1) -> None:
        self.counters[name] += n

    def last_values(self) -> dict[str, float | int]:
        """The last update's values (those it reported) and every counter: what a live node publishes."""
        last = {k: col[-1] for k, col in self.series.items() if col and not math.isnan(col[-1])}
        return {**last, **self.counters}

    def array(self, name: str) -> NDArray[np.float64]:
        return np.asarray(self.series[name], dtype=np.float64)

    def as_dict(self) -> dict[str, Any]:
        return {
            "updates": len(self),
            "series": {k: [None if math.isnan(v) else v for v in col] for k, col in self.series.items()},
            "counters": dict(self.counters),
            "summary": dict(self.summary),
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> Diagnostics:
        d = cls()
        d.series = {
            k: [math.nan if v is None else float(v) for v in col] for k, col in doc.get("series", {}).items()
        }
        for name in cls.BUILT_IN:
            d.series.setdefault(name, [])
        d.counters = Counter(doc.get("counters", {}))
        d.summary = dict(doc.get("summary", {}))
        return d


class SlamMethod(ABC):
    """Base of every SLAM method: feed frames, read pose, trajectory, map and diagnostics."""

    #: Registry name, as typed on the command line (``gmapping``, ``known-poses``).
    name: ClassVar[str]
    #: The parameter dataclass.
    Params: ClassVar[type]
    #: One line for listings.
    summary: ClassVar[str] = ""
    #: Whether the method reads the frames' odometry (odometry-free methods ignore it).
    uses_odometry: ClassVar[bool] = True
    #: True when odometry is optional: the method works without it and uses it when a parameter says so.
    optional_odometry: ClassVar[bool] = False
    #: Whether results depend on the seed.
    stochastic: ClassVar[bool] = False
    #: How the odometry guard checks (a ``GapCheck``; None: its defaults), when ``odometry_gap_check`` is on.
    gap_check: ClassVar[Any] = None
    #: Per-update values the method reports, name -> "meaning [unit]" (for the docs and the report).
    DIAGNOSTICS: ClassVar[dict[str, str]] = {}
    #: Values every method that reads odometry may report (``odometry_gap_check``).
    COMMON_DIAGNOSTICS: ClassVar[dict[str, str]] = {
        "odometry_recovery": "1 where the odometry was corrected before this scan: the scans showed a turn or "
        "shift it missed [-]",
        "compile_s": "seconds numba spent compiling kernels first used in this update, taken out of wall_s and "
        "cpu_s (a fresh install's first run only) [s]",
    }

    def __init__(self, params: Any = None, *, seed: int = 0, sensor_model: Any = None, profile: Any = None) -> None:
        self.params = params if params is not None else self.Params()
        if not isinstance(self.params, self.Params):
            raise TypeError(f"{self.name}: params must be a {self.Params.__name__}, got {type(self.params).__name__}")
        validate(self.params)
        # The ``auto`` parameters, resolved from the recording's profile (or to the original's defaults):
        # name -> {"value": ..., "from": why}; run.json records it.
        self.auto: dict[str, dict[str, Any]] = self._resolve_auto(profile)
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        # A per-beam range noise model (sigma(range, incidence)); None: the method's own default.
        self.sensor_model = sensor_model
        self.diagnostics = Diagnostics()
        self._times: list[float] = []
        self._poses: list[NDArray[np.float64]] = []
        self.frames_fed = 0
        # what reading the parameters said (a ROS node's file: keys dropped or converted), for run.json's warnings
        self.param_notes: list[str] = []
        self._gap_guard = None
        if getattr(self.params, "odometry_gap_check", False):
            from slam2d.matching.odometry_gaps import OdometryGapGuard

            self._gap_guard = OdometryGapGuard(self.gap_check)

    # ----------------------------------------------------------------- what a method implements

    @classmethod
    def auto_values(cls, params: Any, profile: Any) -> dict[str, tuple[Any, str]]:
        """The values of the ``auto`` parameters this recording calls for: name -> (value, why).

        ``profile`` is a :class:`~slam2d.sensors.recording_profile.RecordingProfile`. A name left out
        falls back to the original's default. Methods with ``auto`` parameters override this.
        """
        return {}

    @abstractmethod
    def update(self, frame: Frame) -> Mapping[str, float] | None:
        """Process one frame; return the values to log for this update (or None)."""

    @abstractmethod
    def current_pose(self) -> NDArray[np.float64] | None:
        """The current estimate of the robot base pose, or None while the method has none."""

    @abstractmethod
    def map(self) -> OccupancyGrid:
        """The current map."""

    def written_map(self) -> Any:
        """The map a run folder writes: :meth:`map`, or what stands for it with less memory.

        It needs ``observed``, ``occupancy()``, ``occupied()``, ``crop_to_observed()``, ``resolution``,
        ``origin`` and ``shape``. CoreSLAM and CRSM hand over their integer maps, cropped, without the
        float grid of :meth:`map` (260 MB more for crsm's diverged fr101 map).
        """
        return self.map()

    def relocate(self, pose: NDArray[np.float64]) -> None:
        """Put the robot down at ``pose`` (map frame) before the next frame: a resumed session's new recording
        starts there. The next frame's odometry is not read as motion from the last one."""
        self._relocate(np.asarray(pose, dtype=np.float64).reshape(3))
        if self._gap_guard is not None:
            from slam2d.matching.odometry_gaps import OdometryGapGuard

            self._gap_guard = OdometryGapGuard(self.gap_check)

    def anchor_to_map(self, pose: NDArray[np.float64]) -> None:
        """The next frame's pose in the saved map of a resumed session, as localization in that map finds it.
        A graph method ties the frame's node to it (karto, lago); the others do not use it."""
        self._anchor_to_map(np.asarray(pose, dtype=np.float64).reshape(3))

    def _anchor_to_map(self, pose: NDArray[np.float64]) -> None:  # noqa: B027 - optional hook
        pass

    @classmethod
    def can_relocate(cls) -> bool:
        """Whether :meth:`relocate` is implemented (``slam2d run --resume`` needs it)."""
        return cls._relocate is not SlamMethod._relocate

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        raise NotImplementedError(f"{self.name} cannot go on from a saved session")

    def finish(self) -> None:  # noqa: B027 - optional hook
        """Called once after the last frame (a final optimisation, picking the best particle...)."""

    def extra_outputs(self, out_dir: Any) -> list[Any]:
        """Write method-specific files into a run folder (a pose graph...); return their paths."""
        return []

    # ----------------------------------------------------------------- what every method gets

    def _resolve_auto(self, profile: Any) -> dict[str, dict[str, Any]]:
        pending = auto_fields(self.params)
        if not pending:
            return {}
        chosen = self.auto_values(self.params, profile) if profile is not None else {}
        if profile is None:
            fallback_why = "the original's default: the recording was not measured (a live feed, or no profile given)"
        else:
            fallback_why = "the original's default: " + ("; ".join(profile.notes) or "the recording cannot tell")
        values, out = {}, {}
        for p in pending:
            value, why = chosen.get(p.name, (p.fallback, fallback_why))
            values[p.name] = value
            out[p.name] = {"value": value, "from": why}
        self.params = dataclasses.replace(self.params, **values)
        validate(self.params)
        return out

    def feed(self, frame: Frame) -> None:
        """Process one frame, timing the update and recording the pose it ends at."""
        compile0 = compile_clock()
        wall0 = time.perf_counter()
        cpu0 = time.process_time()
        recovered = False
        if self._gap_guard is not None and self._uses_odometry_now():
            frame, recovered = self._check_odometry(frame)
        values = self.update(frame)
        if recovered:
            values = {**(values or {}), "odometry_recovery": 1.0}
        cpu = time.process_time() - cpu0
        wall = time.perf_counter() - wall0
        compiled = compile_clock()
        if compiled != compile0:  # a kernel compiled in this update (its first use): not the method's time
            wall -= compiled[0] - compile0[0]
            cpu -= compiled[1] - compile0[1]
            values = {**(values or {}), "compile_s": compiled[0] - compile0[0]}
        self.frames_fed += 1
        pose = self.current_pose()
        if pose is not None:
            self._times.append(frame.timestamp)
            self._poses.append(np.array(pose, dtype=np.float64).reshape(3))
        self.diagnostics.record(frame.timestamp, wall, cpu, values)

    def _uses_odometry_now(self) -> bool:
        return self.uses_odometry and (not self.optional_odometry or bool(getattr(self.params, "use_odometry", True)))

    def _check_odometry(self, frame: Frame) -> tuple[Frame, bool]:
        """The frame with its odometry corrected where the scans show it missed a turn or a shift."""
        odom = self.usable_odometry(frame)
        if odom is None:
            return frame, False
        guard = self._gap_guard
        refined, reverted = guard.refined, guard.reverted
        corrected, recovered = guard.correct(frame.scan.points_in_base(), odom)
        if guard.refined > refined:
            self.diagnostics.count("odometry_increments_refined")
        if guard.reverted > reverted:
            self.diagnostics.count("odometry_corrections_reverted")
        if recovered:
            self.diagnostics.count("odometry_recoveries")
            c = guard.last_correction
            log.info("%s: odometry corrected by %.2f m, %.1f deg at t=%.3f (the scans show a turn or shift it missed)",
                     self.name, math.hypot(c[0], c[1]), math.degrees(c[2]), frame.timestamp)
        return dataclasses.replace(frame, odometry=corrected), recovered

    def run(self, frames: Iterable[Frame]) -> SlamMethod:
        """Feed every frame, then :meth:`finish` (timed into ``diagnostics.summary['finish_wall_s']``)."""
        for frame in frames:
            self.feed(frame)
        self.timed_finish()
        return self

    def timed_finish(self) -> None:
        """:meth:`finish`, timed into ``diagnostics.summary['finish_wall_s']`` (compilation not counted)."""
        compile0 = compile_clock()[0]
        wall0 = time.perf_counter()
        self.finish()
        self.diagnostics.summary["finish_wall_s"] = time.perf_counter() - wall0 - (compile_clock()[0] - compile0)

    def odometry_step(
        self, last: NDArray[np.float64], odom: NDArray[np.float64], max_step: float, timestamp: float,
    ) -> tuple[NDArray[np.float64], float, bool]:
        """The odometry increment between two scans: ``(delta, length, is_motion)``.

        ``delta`` is ``odom`` relative to ``last`` (the robot frame at ``last``), ``length`` its
        translation. An increment longer than ``max_step`` metres, or not finite, is a reset or a
        corrupt reading rather than motion: it is counted as ``odometry_jumps``, warned, and
        ``is_motion`` is False. What to do then is the caller's choice (keep going with it, or
        predict no motion); nothing here stops the run.
        """
        with np.errstate(invalid="ignore"):  # a non-finite reading is reported below, not by numpy
            delta = se2.relative(last, odom)
        length = math.hypot(float(delta[0]), float(delta[1]))
        if length <= max_step and bool(np.all(np.isfinite(delta))):  # a non-finite step is a jump too
            return delta, length, True
        self.diagnostics.count("odometry_jumps")
        log.warning("%s: odometry jumps %.2f m at t=%.3f; continuing", self.name, length, timestamp)
        return delta, length, False

    @staticmethod
    def usable_odometry(frame: Frame) -> NDArray[np.float64] | None:
        """The frame's odometry pose as floats, or None when it has none or it is not finite."""
        odom = frame.odometry
        if odom is None:
            return None
        odom = np.asarray(odom, dtype=np.float64)
        return odom if bool(np.all(np.isfinite(odom))) else None

    @property
    def pose(self) -> NDArray[np.float64] | None:
        """The current pose estimate ``[x, y, theta]`` of the robot base, or None."""
        return self.current_pose()

    def trajectory(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(timestamps (N,), poses (N, 3))``: the estimate at every frame that got a pose."""
        if not self._times:
            return np.zeros(0), np.zeros((0, 3))
        return np.array(self._times), np.stack(self._poses)

    @classmethod
    def odometry_role(cls) -> str:
        """How the method treats odometry, for listings: ``"required"``, ``"optional"`` or ``"ignored"``."""
        if cls.optional_odometry:
            return "optional"
        return "required" if cls.uses_odometry else "ignored"

    def parameters(self) -> dict[str, Any]:
        """Every parameter value, by name."""
        return as_dict(self.params)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.frames_fed} frames fed, seed {self.seed})"
