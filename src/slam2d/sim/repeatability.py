"""The study's static repeatability experiment, simulated: a target plate, N readings per set-up.

The study put a target of one material in front of a Hokuyo URG-04LX at 1, 2,
3, 3.5 and 4 m, square to the beam ("90 deg") or turned by 45 degrees, and
recorded 500 readings per set-up (5 materials x 5 distances x 2 angles = 50
set-ups). Here the geometry is done for real: a flat plate
(:data:`PLATE_WIDTH` wide) of the material stands so that the laser's central
beam meets its centre at the set-up's distance and angle, and the laser
simulator measures full sweeps of it; the central beam's reading is the
experiment's datum.

A dropout (no return) is kept as a row whose range is NaN (an empty field in
the CSV): the count of lost readings is part of the result, and statistics
skip them (:meth:`RepeatabilityRows.summary`).

Each set-up draws from its own random stream, seeded by ``seed`` and the
set-up itself, so a set-up gives the same readings whichever other set-ups are
simulated with it, and :func:`write_setup_log` reproduces its rows exactly.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slam2d.core import Frame, make_scan
from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path
from slam2d.sensors.range_noise import MATERIALS, RangeNoiseModel, StudyModel, material_index
from slam2d.sim.laser import LaserSimulator, LaserSpec, laser_preset
from slam2d.sim.world import World

__all__ = [
    "PLATE_WIDTH",
    "STUDY_DISTANCES",
    "STUDY_ANGLES_DEG",
    "Setup",
    "RepeatabilityRows",
    "SetupSummary",
    "study_setups",
    "target_world",
    "repeated_measurements",
    "write_repeatability_csv",
    "read_repeatability_csv",
    "write_setup_log",
    "format_summary",
]

#: Width of the simulated target plate, metres (the study does not say; wide
#: enough that only the central beams meet it at 1 m, narrow enough to be a plate).
PLATE_WIDTH = 1.0
#: The study's distances (m) and angles between the beam and the target surface (deg).
STUDY_DISTANCES: tuple[float, ...] = (1.0, 2.0, 3.0, 3.5, 4.0)
STUDY_ANGLES_DEG: tuple[float, ...] = (90.0, 45.0)

CSV_HEADER = ("material", "angle_deg", "distance_m", "repetition", "range_m")


@dataclass(frozen=True)
class Setup:
    """One set-up of the experiment.

    ``angle_deg`` is the study's angle between the beam and the target's
    surface: 90 is square to the beam (incidence 0), 45 is turned by 45 degrees.
    """

    material: str
    angle_deg: float
    distance: float

    @property
    def incidence(self) -> float:
        """Angle between the beam and the surface normal, radians."""
        return math.radians(90.0 - self.angle_deg)

    def seed_key(self, seed: int) -> list[int]:
        """Entropy for this set-up's random stream: the seed and the set-up itself."""
        return [
            int(seed),
            material_index(self.material),
            int(round(self.angle_deg * 1000)),
            int(round(self.distance * 1e6)),
        ]


@dataclass(frozen=True)
class SetupSummary:
    """Statistics of one set-up's readings (NaN rows skipped)."""

    material: str
    angle_deg: float
    distance: float
    count: int  # readings attempted
    returns: int  # readings with a return
    mean: float  # m
    std: float  # m, sample standard deviation (n - 1)


@dataclass(frozen=True)
class RepeatabilityRows:
    """The experiment's readings as columns, one row per reading (a tidy table)."""

    material: NDArray[np.str_]
    angle_deg: NDArray[np.float64]
    distance: NDArray[np.float64]
    repetition: NDArray[np.int64]
    range: NDArray[np.float64]  # m; NaN: no return

    def __len__(self) -> int:
        return int(self.range.shape[0])

    def summary(self) -> list[SetupSummary]:
        """One :class:`SetupSummary` per set-up, in the order the set-ups first appear."""
        keys = list(zip(self.material.tolist(), self.angle_deg.tolist(), self.distance.tolist(), strict=True))
        order: dict[tuple[str, float, float], list[int]] = {}
        for i, key in enumerate(keys):
            order.setdefault(key, []).append(i)
        out = []
        for (material, angle, distance), rows in order.items():
            r = self.range[rows]
            ok = r[~np.isnan(r)]
            out.append(
                SetupSummary(
                    material, angle, distance, len(rows), int(ok.size),
                    float(ok.mean()) if ok.size else math.nan,
                    float(ok.std(ddof=1)) if ok.size > 1 else math.nan,
                )
            )
        return out


def study_setups(
    materials: Iterable[str] = MATERIALS,
    distances: Iterable[float] = STUDY_DISTANCES,
    angles_deg: Iterable[float] = STUDY_ANGLES_DEG,
) -> list[Setup]:
    """Every combination, material-major then angle then distance (the study's 50 by default).

    Raises :class:`~slam2d.errors.InputError` naming the field for an unknown
    material, a distance that is not positive, or an angle outside (0, 90].
    """
    mats = [str(m) for m in materials]
    for m in mats:
        try:
            material_index(m)
        except ValueError as exc:
            raise InputError(str(exc), field="materials") from None
    dists = [_number(d, "distances") for d in distances]
    angles = [_number(a, "angles_deg") for a in angles_deg]
    for d in dists:
        if not (math.isfinite(d) and d > 0.0):
            raise InputError(f"{d} m is not a distance > 0", field="distances")
    for a in angles:
        if not (0.0 < a <= 90.0):
            raise InputError(f"{a} deg is not an angle in (0, 90] between the beam and the target", field="angles_deg")
    if not (mats and dists and angles):
        raise InputError("needs at least one material, distance and angle", field="materials")
    return [Setup(m, a, d) for m in mats for a in angles for d in dists]


def _number(value: object, field: str) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{value!r} is not a number", field=field) from None


def target_world(setup: Setup, plate_width: float = PLATE_WIDTH) -> World:
    """A world holding only the target plate, for a laser at the origin looking along +x.

    The plate's centre is at ``(distance, 0)`` and its normal is turned by the
    set-up's incidence, so a beam along +x meets the centre at exactly that
    distance and incidence.
    """
    a = setup.incidence
    half = 0.5 * plate_width
    tangent = np.array([-math.sin(a), math.cos(a)])
    centre = np.array([setup.distance, 0.0])
    p0, p1 = centre - half * tangent, centre + half * tangent
    return World(
        name=f"target-{setup.material}-{setup.angle_deg:g}deg-{setup.distance:g}m",
        description=f"a {plate_width:g} m plate of {setup.material} at {setup.distance:g} m, "
        f"{setup.angle_deg:g} deg to the beam",
        segments=np.array([[p0[0], p0[1], p1[0], p1[1]]]),
        segment_material=np.array([material_index(setup.material)]),
        circles=np.zeros((0, 3)),
        circle_material=np.zeros(0, dtype=np.int64),
        source="built-in:repeatability-target",
    )


def _laser_pose(laser: LaserSpec) -> NDArray[np.float64]:
    """Laser pose at the origin that points the central beam exactly along +x."""
    return np.array([0.0, 0.0, -float(laser.angles[laser.central_beam])])


def _sweeps(
    setup: Setup, repetitions: int, laser: LaserSpec, noise: RangeNoiseModel, seed: int, dropouts: bool
) -> Iterable[NDArray[np.float64]]:
    """The full sweeps of one set-up, one per repetition."""
    if setup.distance >= laser.range_max or setup.distance < laser.range_min:
        raise InputError(
            f"{setup.distance} m is outside the {laser.name} laser's range "
            f"[{laser.range_min}, {laser.range_max}) m",
            field="distances",
        )
    simulator = LaserSimulator(laser, target_world(setup), noise, dropouts=dropouts)
    rng = np.random.default_rng(setup.seed_key(seed))
    pose = _laser_pose(laser)
    for _ in range(repetitions):
        yield simulator.measure(pose, None, rng)


# Refuse absurd reading counts before allocating them (the study took 50 x 500).
_MAX_READINGS = 10_000_000


def _check_repetitions(repetitions: int) -> int:
    if isinstance(repetitions, bool) or not isinstance(repetitions, (int, np.integer)) or repetitions < 1:
        raise InputError(f"{repetitions!r} must be a whole number >= 1", field="repetitions")
    return int(repetitions)


def repeated_measurements(
    materials: Sequence[str] = MATERIALS,
    distances: Sequence[float] = STUDY_DISTANCES,
    angles_deg: Sequence[float] = STUDY_ANGLES_DEG,
    repetitions: int = 500,
    *,
    laser: LaserSpec | None = None,
    noise: RangeNoiseModel | None = None,
    seed: int = 0,
    dropouts: bool = True,
) -> RepeatabilityRows:
    """Simulate the study's repeatability experiment: ``repetitions`` readings per set-up.

    ``laser`` defaults to the URG-04LX and ``noise`` to :class:`StudyModel`.
    The range recorded is the central beam's reading of each full sweep
    (NaN for a dropout). Rows come set-up by set-up (material, then angle,
    then distance), repetitions 0..N-1 within each.
    """
    repetitions = _check_repetitions(repetitions)
    laser = laser_preset("urg-04lx") if laser is None else laser
    noise = StudyModel() if noise is None else noise
    setups = study_setups(materials, distances, angles_deg)
    if len(setups) * repetitions > _MAX_READINGS:
        raise InputError(f"{repetitions} per set-up is {len(setups) * repetitions} readings for {len(setups)} "
                         f"set-ups, more than {_MAX_READINGS}", field="repetitions")
    central = laser.central_beam
    ranges = np.empty((len(setups), repetitions))
    for s, setup in enumerate(setups):
        for k, sweep in enumerate(_sweeps(setup, repetitions, laser, noise, seed, dropouts)):
            ranges[s, k] = sweep[central]
    n = repetitions
    return RepeatabilityRows(
        material=np.repeat(np.array([s.material for s in setups]), n),
        angle_deg=np.repeat(np.array([s.angle_deg for s in setups], dtype=np.float64), n),
        distance=np.repeat(np.array([s.distance for s in setups], dtype=np.float64), n),
        repetition=np.tile(np.arange(n, dtype=np.int64), len(setups)),
        range=ranges.reshape(-1),
    )


def _fmt(value: float) -> str:
    """Shortest text that reads back as the same float; empty for NaN."""
    return "" if math.isnan(value) else repr(float(value))


def write_repeatability_csv(path: str | Path, rows: RepeatabilityRows) -> Path:
    """Write the readings as a tidy CSV (one row per reading), atomically; return the path.

    Header: ``material,angle_deg,distance_m,repetition,range_m``. A no-return
    has an empty ``range_m``. Floats are written exactly (they read back bit
    for bit).
    """
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(CSV_HEADER)
        for m, a, d, k, r in zip(
            rows.material.tolist(), rows.angle_deg.tolist(), rows.distance.tolist(),
            rows.repetition.tolist(), rows.range.tolist(), strict=True,
        ):
            writer.writerow((m, _fmt(a), _fmt(d), k, _fmt(r)))
    return path


def read_repeatability_csv(path: str | Path, *, any_material: bool = False) -> RepeatabilityRows:
    """Read a CSV written by :func:`write_repeatability_csv` (or any with the same columns).

    ``any_material`` accepts any surface name (a user's own measurements, for
    calibration); otherwise a material must be one of the simulator's. Streams the file; a bad header or value raises
    :class:`~slam2d.errors.InputError` naming the file, the line and the column.
    """
    path = Path(path)
    try:
        f = open(path, encoding="utf-8-sig", newline="")  # a spreadsheet may save a BOM
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", path=path) from None
    material: list[str] = []
    angle: list[float] = []
    distance: list[float] = []
    repetition: list[int] = []
    ranges: list[float] = []
    with f:
        reader = csv.reader(f)
        try:
            header = next(reader, None)
            if header is None:
                raise InputError("file is empty; expected the header " + ",".join(CSV_HEADER), path=path)
            columns = [h.strip() for h in header]
            missing = [c for c in CSV_HEADER if c not in columns]
            if missing:
                raise InputError(
                    f"missing column(s) {', '.join(missing)}; expected {','.join(CSV_HEADER)}",
                    path=path, where=1, field="header",
                )
            index = {c: columns.index(c) for c in CSV_HEADER}
            for row in reader:
                line = reader.line_num
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(columns):
                    raise InputError(
                        f"{len(row)} values for {len(columns)} columns", path=path, where=line, field="row"
                    )

                def value(column: str, kind: type, allow_empty: bool = False) -> object:
                    text = row[index[column]].strip()
                    if allow_empty and text == "":
                        return math.nan
                    try:
                        return kind(text)
                    except ValueError:
                        raise InputError(
                            f"{text!r} is not a {kind.__name__}", path=path, where=line, field=column
                        ) from None

                name = row[index["material"]].strip()
                if not name:
                    raise InputError("empty material name", path=path, where=line, field="material")
                if not any_material and name not in MATERIALS:
                    raise InputError(
                        f"unknown material {name!r}; valid materials: {', '.join(MATERIALS)}",
                        path=path, where=line, field="material",
                    )
                material.append(name)
                angle.append(value("angle_deg", float))  # type: ignore[arg-type]
                distance.append(value("distance_m", float))  # type: ignore[arg-type]
                repetition.append(value("repetition", int))  # type: ignore[arg-type]
                ranges.append(value("range_m", float, allow_empty=True))  # type: ignore[arg-type]
        except csv.Error as exc:
            raise InputError(f"not a valid CSV: {exc}", path=path, where=reader.line_num) from None
        except UnicodeDecodeError:
            raise InputError("is not UTF-8 text", path=path) from None
    return RepeatabilityRows(
        material=np.array(material, dtype=str),
        angle_deg=np.array(angle, dtype=np.float64),
        distance=np.array(distance, dtype=np.float64),
        repetition=np.array(repetition, dtype=np.int64),
        range=np.array(ranges, dtype=np.float64),
    )


def write_setup_log(
    path: str | Path,
    setup: Setup,
    repetitions: int = 500,
    *,
    laser: LaserSpec | None = None,
    noise: RangeNoiseModel | None = None,
    seed: int = 0,
    dropouts: bool = True,
    start_time: float = 0.0,
) -> Path:
    """Write one set-up as a CARMEN log of ``repetitions`` full scans; return the path.

    The robot stands still at the odometry origin (every scan's odometry is
    zero); the laser sits on it turned so its central beam meets the plate's
    centre. Scans are ``1 / laser.rate`` seconds apart from ``start_time``.
    With the same arguments the central beams equal the rows
    :func:`repeated_measurements` gives for this set-up. Gzipped when the name
    ends in ``.gz``; written atomically.
    """
    from slam2d.io.carmen import write_carmen

    repetitions = _check_repetitions(repetitions)
    laser = laser_preset("urg-04lx") if laser is None else laser
    noise = StudyModel() if noise is None else noise
    (setup,) = study_setups([setup.material], [setup.distance], [setup.angle_deg])
    mount = _laser_pose(laser)
    origin = np.zeros(3)

    def frames() -> Iterable[Frame]:
        for k, ranges in enumerate(_sweeps(setup, repetitions, laser, noise, seed, dropouts)):
            scan = make_scan(
                start_time + k / laser.rate, ranges, laser.angle_min, laser.angle_increment,
                laser.range_min, laser.range_max, mount=mount, frame_id="laser",
            )
            yield Frame(k, scan, origin)

    return write_carmen(path, frames())


def format_summary(rows: RepeatabilityRows) -> str:
    """The per-set-up statistics as a small text table (for reports and the docs)."""
    out = io.StringIO()
    out.write(f"{'material':<16}{'angle':>7}{'dist m':>8}{'n':>6}{'returns':>9}{'mean m':>10}{'std mm':>9}\n")
    for s in rows.summary():
        out.write(
            f"{s.material:<16}{s.angle_deg:>7g}{s.distance:>8g}{s.count:>6}{s.returns:>9}"
            f"{s.mean:>10.4f}{1000 * s.std:>9.3f}\n"
        )
    return out.getvalue()
