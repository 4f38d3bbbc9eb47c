"""Simulated lasers: exact geometry, noise statistics, dropouts, distortion, the repeatability experiment."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from slam2d.errors import InputError
from slam2d.io import open_recording
from slam2d.sensors.range_noise import MATERIALS, ConstantSigma, StudyModel, dropout_probability, material_index
from slam2d.sim.laser import LASER_PRESETS, LaserSimulator, LaserSpec, cast_rays, laser_preset
from slam2d.sim.repeatability import (
    CSV_HEADER,
    Setup,
    read_repeatability_csv,
    repeated_measurements,
    target_world,
    write_repeatability_csv,
    write_setup_log,
)
from slam2d.sim.world import World, load_world

EXACT = 1e-9
DEG = math.pi / 180


def make_world(segments=(), circles=(), segment_material=None, circle_material=None) -> World:
    segs = np.array(segments, dtype=np.float64).reshape(-1, 4)
    circ = np.array(circles, dtype=np.float64).reshape(-1, 3)
    sm = np.zeros(len(segs), dtype=np.int64) if segment_material is None else np.asarray(segment_material)
    cm = np.zeros(len(circ), dtype=np.int64) if circle_material is None else np.asarray(circle_material)
    return World("test", "", segs, sm, circ, cm, source="test")


def plate(distance: float, incidence: float, width: float = 1.0) -> list[float]:
    """A wall whose centre is ``distance`` along +x, its normal turned by ``incidence``."""
    t = np.array([-math.sin(incidence), math.cos(incidence)]) * width / 2
    c = np.array([distance, 0.0])
    return [*(c - t), *(c + t)]


def narrow_laser(beams: int = 2000) -> LaserSpec:
    """A laser whose beams all point (within 0.2 mrad) straight ahead: many samples of one geometry."""
    inc = 1e-7
    return LaserSpec("narrow", beams, -inc * (beams // 2), inc, 0.0, 100.0, 10.0)


# ---------------------------------------------------------------- presets and specs


def test_presets():
    urg = laser_preset("urg-04lx")
    assert urg.beams == 682
    assert urg.angle_increment == pytest.approx(2 * math.pi / 1024)
    assert math.degrees(urg.beams * urg.angle_increment) == pytest.approx(239.77, abs=0.005)
    assert (urg.range_min, urg.range_max, urg.rate) == (0.02, 5.6, 10.0)
    assert urg.angles[urg.central_beam] == 0.0
    sick = laser_preset("SICK-LMS")
    assert sick.beams == 361 and math.degrees(sick.field_of_view) == pytest.approx(180.0)
    assert sick.range_max == 80.0
    rp = laser_preset("rplidar-a1")
    assert math.degrees(rp.beams * rp.angle_increment) == pytest.approx(360.0) and rp.range_max == 12.0
    assert {"urg-04lx", "sick-lms", "rplidar-a1"} <= set(LASER_PRESETS)
    # a copy: changing it does not change the preset
    urg.range_max = 4.0
    assert laser_preset("urg-04lx").range_max == 5.6


def test_unknown_preset_lists_the_presets():
    with pytest.raises(InputError, match=r"laser: unknown laser 'lms9000'; presets: urg-04lx.*sick-lms.*rplidar-a1"):
        laser_preset("lms9000")


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(range_min=-0.1), "range_min"),
        (dict(range_max=0.01), "range_max"),
        (dict(range_max=math.inf), "range_max"),
        (dict(angle_increment=-0.01), "angle_increment"),
        (dict(angle_increment=0.0), "angle_increment"),
        (dict(beams=0), "beams"),
        (dict(beams=5000), "beams"),
        (dict(rate=0.0), "rate"),
        (dict(angle_min=math.nan), "angle_min"),
        (dict(range_min="near"), "range_min"),
    ],
)
def test_bad_laser_spec_names_the_field(change, field):
    values = dict(name="mine", beams=682, angle_min=-2.0, angle_increment=2 * math.pi / 1024,
                  range_min=0.02, range_max=5.6, rate=10.0)
    values.update(change)
    with pytest.raises(InputError) as err:
        LaserSpec(**values)
    assert err.value.field == field
    assert "\n" not in str(err.value) and "'mine'" in str(err.value)


# ---------------------------------------------------------------- exact geometry


def test_perpendicular_and_oblique_beams_on_a_wall():
    world = make_world([[2.0, -3.0, 2.0, 3.0]], segment_material=[2])
    angles = np.radians(np.linspace(-50, 50, 101))
    r, inc, mat = cast_rays(world, [0.0, 0.0, 0.0], angles)
    np.testing.assert_allclose(r, 2.0 / np.cos(angles), rtol=0, atol=EXACT)
    np.testing.assert_allclose(inc, np.abs(angles), rtol=0, atol=EXACT)
    assert np.all(mat == 2)
    assert r[50] == 2.0 and inc[50] == 0.0


@pytest.mark.parametrize("incidence_deg", [0.0, 30.0, 45.0, 60.0])
@pytest.mark.parametrize("heading", [0.0, 1.0, -2.5])
def test_hit_on_a_turned_plate_from_a_turned_laser(incidence_deg, heading):
    inc = math.radians(incidence_deg)
    d = 2.7
    # build the plate in the laser's frame, then move laser and plate by the same rigid motion
    seg = np.array(plate(d, inc, 2.0)).reshape(2, 2)
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, -s], [s, c]])
    offset = np.array([1.5, -0.7])
    seg_world = seg @ rot.T + offset
    world = make_world([seg_world.reshape(-1)], segment_material=[4])
    r, got_inc, mat = cast_rays(world, [offset[0], offset[1], heading], [0.0])
    assert abs(r[0] - d) < EXACT
    assert abs(got_inc[0] - inc) < EXACT
    assert mat[0] == 4


def test_circle_hits():
    world = make_world(circles=[[3.0, 0.0, 0.5]], circle_material=[1])
    r, inc, mat = cast_rays(world, [0.0, 0.0, 0.0], [0.0])
    assert abs(r[0] - 2.5) < EXACT and abs(inc[0]) < EXACT and mat[0] == 1
    # a beam offset sideways by r sin(phi) meets the outline at incidence phi
    for phi in np.radians([10.0, 30.0, 45.0, 70.0]):
        h = 0.5 * math.sin(phi)
        r, inc, _ = cast_rays(world, [0.0, h, 0.0], [0.0])
        assert abs(r[0] - (3.0 - 0.5 * math.cos(phi))) < EXACT
        assert abs(inc[0] - phi) < EXACT
    # a beam passing just beside misses
    r, inc, mat = cast_rays(world, [0.0, 0.5 + 1e-6, 0.0], [0.0])
    assert r[0] == math.inf and math.isnan(inc[0]) and mat[0] == -1


def test_a_beam_that_misses_everything_has_no_return():
    world = make_world([[2.0, -1.0, 2.0, 1.0]], circles=[[3.0, 0.0, 0.2]])
    r, inc, mat = cast_rays(world, [0.0, 0.0, 0.0], [math.pi, math.pi / 2, math.atan2(1.0 + 1e-9, 2.0)])
    assert np.all(np.isinf(r)) and np.all(np.isnan(inc)) and np.all(mat == -1)
    sim = LaserSimulator(laser_preset("urg-04lx"), world, ConstantSigma(0.0), dropouts=False)
    ranges = sim.measure([0.0, 0.0, math.pi], None, np.random.default_rng(0))
    behind = np.abs(se2_wrap(sim.angles + math.pi)) > 0.6  # beams that do not see the wall
    assert np.all(np.isnan(ranges[behind]))


def se2_wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_nearest_of_several_walls_and_circles():
    world = make_world(
        [[3.0, -1, 3.0, 1], [1.0, -1, 1.0, 1], [2.0, -1, 2.0, 1]],
        circles=[[0.6, 0.0, 0.1]],
        segment_material=[0, 1, 2],
        circle_material=[3],
    )
    r, _, mat = cast_rays(world, [0.0, 0.0, 0.0], [0.0, 0.3])
    assert abs(r[0] - 0.5) < EXACT and mat[0] == 3  # the circle in front of every wall
    assert abs(r[1] - 1.0 / math.cos(0.3)) < EXACT and mat[1] == 1  # misses the circle: nearest wall


def dense_cast(origin, directions, segments):
    """An independent reference: all ray-segment intersections solved as one N x M array."""
    p = origin[:2]
    d = np.stack([np.cos(directions), np.sin(directions)], axis=-1)
    a = segments[:, :2]
    e = segments[:, 2:] - a
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    ap = a - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[None, :, 0] * e[None, :, 1] - ap[None, :, 1] * e[None, :, 0]) / denom
        u = (ap[None, :, 0] * d[:, None, 1] - ap[None, :, 1] * d[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.where(hit, t, np.inf).min(axis=1)


def test_matches_an_independent_whole_array_caster_on_random_worlds():

    rng = np.random.default_rng(42)
    for _ in range(20):
        segs = rng.uniform(-5, 5, size=(30, 4))
        world = make_world(segs)
        pose = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-3, 3)])
        angles = np.linspace(-3.1, 3.1, 500)
        r, inc, _ = cast_rays(world, pose, angles)
        expected = dense_cast(pose, pose[2] + angles, segs)
        np.testing.assert_allclose(r, expected, rtol=1e-12)
        hit = np.isfinite(r)
        assert np.all((inc[hit] >= 0) & (inc[hit] <= math.pi / 2))


def test_laser_inside_a_circle_sees_its_far_side():
    world = make_world(circles=[[0.0, 0.0, 1.0]])
    r, inc, _ = cast_rays(world, [0.25, 0.0, 0.0], [0.0, math.pi])
    np.testing.assert_allclose(r, [0.75, 1.25], atol=EXACT)
    np.testing.assert_allclose(inc, [0.0, 0.0], atol=EXACT)


# ---------------------------------------------------------------- noise statistics


def std_bounds(n: int, alpha: float = 1e-6) -> tuple[float, float]:
    """Bounds of sample std / sigma for n normal samples: (n-1) s^2 / sigma^2 ~ chi2(n-1)."""
    lo = math.sqrt(stats.chi2.ppf(alpha / 2, n - 1) / (n - 1))
    hi = math.sqrt(stats.chi2.ppf(1 - alpha / 2, n - 1) / (n - 1))
    return lo, hi


def residuals(world, noise, *, sweeps: int = 10, seed: int = 7, dropouts: bool = False):
    sim = LaserSimulator(narrow_laser(), world, noise, dropouts=dropouts)
    truth, inc, mat = sim.cast([0.0, 0.0, 0.0])
    rng = np.random.default_rng(seed)
    ranges = np.concatenate([sim.measure([0.0, 0.0, 0.0], None, rng) for _ in range(sweeps)])
    return ranges - np.tile(truth, sweeps), inc, mat


# sigma expected from the study's numbers: Fig. 6/7 cubics x Table I ratio (see the docs)
FIG6 = np.poly1d([0.000037032, 0.000037966, -0.001034868, 0.00479271])
FIG7 = np.poly1d([0.000424014, -0.002317497, 0.004646225, 0.001744066])
RATIO90 = {"varnished-wood": 4.3872, "white-textile": 4.5669, "white-paper": 5.3563, "cardboard": 6.0059}
RATIO45 = {"varnished-wood": 5.5417, "white-textile": 5.7235, "white-paper": 7.4447, "cardboard": 8.5790}


def study_sigma(material: str, d: float, incidence_deg: float) -> float:
    def ratio(table, m):
        value = 1.5 * table["cardboard"] if m == "black-metal" else table[m]
        return value / np.mean(list(table.values()))

    s0 = FIG6(d) * ratio(RATIO90, material)
    s45 = FIG7(d) * ratio(RATIO45, material)
    return s0 + (s45 - s0) * incidence_deg / 45.0


@pytest.mark.parametrize(
    "material, distance, incidence_deg",
    [
        ("varnished-wood", 1.0, 0.0),
        ("white-paper", 2.5, 45.0),
        ("cardboard", 4.0, 0.0),
        ("black-metal", 3.0, 45.0),
        ("white-textile", 3.5, 22.5),
        ("white-paper", 2.0, 30.0),
    ],
)
def test_noise_std_matches_the_study_model(material, distance, incidence_deg):
    world = make_world([plate(distance, math.radians(incidence_deg), 2.0)], segment_material=[material_index(material)])
    res, inc, _ = residuals(world, StudyModel())
    assert np.allclose(inc, math.radians(incidence_deg), atol=1e-3)
    n = res.size
    sigma = study_sigma(material, distance, incidence_deg)
    lo, hi = std_bounds(n)
    s = res.std(ddof=1)
    assert lo * sigma <= s <= hi * sigma, f"std {s:.6f} m vs sigma {sigma:.6f} m (n={n})"
    assert abs(res.mean()) < 5.0 * sigma / math.sqrt(n), "noise is unbiased"
    assert stats.normaltest(res).pvalue > 1e-6, "noise is Gaussian"


@pytest.mark.parametrize("sigma, distance", [(0.0041, 2.0), (0.01, 30.0)])
def test_constant_sigma_noise(sigma, distance):
    world = make_world([plate(distance, 0.3, 4.0)], segment_material=[4])
    res, _, _ = residuals(world, ConstantSigma(sigma))
    lo, hi = std_bounds(res.size)
    assert lo * sigma <= res.std(ddof=1) <= hi * sigma


def test_zero_sigma_gives_exact_ranges():
    world = make_world([plate(2.0, 0.4)])
    res, _, _ = residuals(world, ConstantSigma(0.0), sweeps=1)
    assert np.all(np.abs(res) < EXACT)


@pytest.mark.parametrize("material, incidence_deg", [("white-paper", 80.0), ("black-metal", 0.0), ("cardboard", 75.0)])
def test_dropout_rate_matches_the_probability(material, incidence_deg):
    m = material_index(material)
    world = make_world([plate(2.0, math.radians(incidence_deg), 3.0)], segment_material=[m])
    res, inc, _ = residuals(world, ConstantSigma(0.0), sweeps=20, dropouts=True)
    n = res.size
    p = float(dropout_probability(math.radians(incidence_deg), m))
    lost = np.isnan(res).sum()
    assert abs(lost - n * p) <= 5.0 * math.sqrt(n * p * (1 - p)) + 1, f"{lost} of {n} lost, expected p={p}"
    assert 0 < p < 1


def test_no_dropouts_when_disabled():
    world = make_world([plate(2.0, math.radians(85.0), 3.0)], segment_material=[4])
    res, _, _ = residuals(world, ConstantSigma(0.0), sweeps=2, dropouts=False)
    assert not np.any(np.isnan(res))


def test_range_limits_make_no_returns():
    urg = laser_preset("urg-04lx")
    exact = ConstantSigma(0.0)
    far = LaserSimulator(urg, make_world([plate(5.7, 0.0, 20.0)]), exact, dropouts=False)
    assert np.all(np.isnan(far.measure([0, 0, 0], None, np.random.default_rng(0))))
    near = LaserSimulator(urg, make_world([plate(0.015, 0.0, 0.001)]), exact, dropouts=False)
    r = near.measure([0, 0, 0], None, np.random.default_rng(0))
    assert np.isnan(r[urg.central_beam])
    ok = LaserSimulator(urg, make_world([plate(5.5, 0.0, 0.5)]), exact, dropouts=False)
    assert ok.measure([0, 0, 0], None, np.random.default_rng(0))[urg.central_beam] == pytest.approx(5.5)


# ---------------------------------------------------------------- distortion, determinism


def test_motion_distortion_skews_a_scan_taken_while_moving_sideways():
    # The laser faces +x and slides toward +y (sideways) during the sweep; a wall at y = D
    # on its left. Seen from the start pose, each beam's point is pulled in by how far the
    # laser had moved when that beam was measured: the wall looks tilted.
    urg = laser_preset("urg-04lx")
    D, slide = 2.0, 0.05
    world = make_world([[-20.0, D, 20.0, D]])
    start, end = np.array([0.0, 0.0, 0.0]), np.array([0.0, slide, 0.0])
    sim = LaserSimulator(urg, world, ConstantSigma(0.0), dropouts=False, distortion=True)
    r = sim.measure(start, end, np.random.default_rng(0))
    a = sim.angles
    seen = np.isfinite(r)
    frac = np.arange(urg.beams) / (urg.beams - 1)
    y_from_start = r * np.sin(a)
    np.testing.assert_allclose(y_from_start[seen], D - slide * frac[seen], atol=EXACT)
    first, last = np.flatnonzero(seen)[[0, -1]]
    skew = y_from_start[first] - y_from_start[last]
    assert skew == pytest.approx(slide * (last - first) / (urg.beams - 1), abs=EXACT)
    assert skew > 0.02
    # without distortion the wall is straight, wherever pose_end says the laser went
    flat = LaserSimulator(urg, world, ConstantSigma(0.0), dropouts=False, distortion=False)
    r0 = flat.measure(start, end, np.random.default_rng(0))
    seen0 = np.isfinite(r0)
    assert seen0.sum() > 250  # beams within 5.6 m of the wall
    np.testing.assert_allclose((r0 * np.sin(a))[seen0], D, atol=EXACT)


def test_distortion_from_turning():
    # Turning by w during the sweep: beam i is cast at heading + w * i/(N-1).
    urg = laser_preset("urg-04lx")
    world = make_world(circles=[[0.0, 0.0, 3.0]])  # the laser at the centre: every beam 3 m
    turn = 0.2
    sim = LaserSimulator(urg, world, ConstantSigma(0.0), dropouts=False, distortion=True)
    poses = sim.beam_poses([0.0, 0.0, 0.0], [0.0, 0.0, turn])
    frac = np.arange(urg.beams) / (urg.beams - 1)
    np.testing.assert_allclose(poses[:, 2], se2_wrap(sim.angles + turn * frac), atol=EXACT)
    r = sim.measure([0.0, 0.0, 0.0], [0.0, 0.0, turn], np.random.default_rng(0))
    np.testing.assert_allclose(r, 3.0, atol=EXACT)


def test_same_seed_same_ranges():
    world = load_world("paper-arena")
    sim = LaserSimulator(laser_preset("urg-04lx"), world)
    pose = [*world.start[:2], 0.3]
    a = sim.measure(pose, None, np.random.default_rng(5))
    b = sim.measure(pose, None, np.random.default_rng(5))
    c = sim.measure(pose, None, np.random.default_rng(6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c, equal_nan=True)
    assert np.isfinite(a).sum() > 600, "the arena's walls are all within 5.6 m"


def test_scan_of_a_built_in_world_matches_its_geometry():
    world = load_world("paper-arena")
    urg = laser_preset("urg-04lx")
    sim = LaserSimulator(urg, world, ConstantSigma(0.0), dropouts=False)
    pose = np.array([*world.start[:2], 0.0])
    r = sim.measure(pose, None, np.random.default_rng(0))
    ok = np.isfinite(r)
    pts = np.stack([pose[0] + r[ok] * np.cos(sim.angles[ok]), pose[1] + r[ok] * np.sin(sim.angles[ok])], -1)
    # every endpoint lies on some wall
    segs = world.segments
    a, b = segs[:, :2], segs[:, 2:]
    ab = b - a
    t = np.clip(((pts[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    dist = np.linalg.norm(pts[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)
    assert dist.max() < 1e-9


# ---------------------------------------------------------------- performance


def office_sized_world(n_segments: int = 200) -> World:
    """A 30 x 20 m office with about 200 wall segments (the built-in office has fewer)."""
    rng = np.random.default_rng(3)
    segs = [[0, 0, 30, 0], [30, 0, 30, 20], [30, 20, 0, 20], [0, 20, 0, 0]]
    while len(segs) < n_segments:
        x, y = rng.uniform(1, 27), rng.uniform(1, 17)
        length = rng.uniform(0.5, 3)
        segs.append([x, y, x + length, y] if len(segs) % 2 else [x, y, x, y + length])
    return make_world(segs)


# ---------------------------------------------------------------- the repeatability experiment


def test_target_geometry_is_exact():
    for angle in (90.0, 45.0, 60.0):
        for d in (1.0, 2.0, 3.0, 3.5, 4.0):
            world = target_world(Setup("cardboard", angle, d))
            r, inc, mat = cast_rays(world, [0.0, 0.0, 0.0], [0.0])
            assert abs(r[0] - d) < EXACT
            assert abs(inc[0] - math.radians(90.0 - angle)) < EXACT
            assert mat[0] == material_index("cardboard")


def test_repeated_measurements_shape_and_order():
    rows = repeated_measurements(repetitions=12, seed=1)
    assert len(rows) == 50 * 12
    summary = rows.summary()
    assert len(summary) == 50
    assert {(s.material, s.angle_deg, s.distance) for s in summary} == {
        (m, a, d) for m in MATERIALS for a in (90.0, 45.0) for d in (1.0, 2.0, 3.0, 3.5, 4.0)
    }
    assert (summary[0].material, summary[0].angle_deg, summary[0].distance) == ("varnished-wood", 90.0, 1.0)
    np.testing.assert_array_equal(rows.repetition[:24], np.tile(np.arange(12), 2))
    ok = ~np.isnan(rows.range)
    assert np.all(np.abs(rows.range[ok] - rows.distance[ok]) < 0.1)


def test_repeated_measurements_statistics():
    rows = repeated_measurements(
        ["varnished-wood", "black-metal"], [1.0, 4.0], [90, 45], repetitions=3000, seed=2, dropouts=False
    )
    lo, hi = std_bounds(3000)
    for s in rows.summary():
        sigma = study_sigma(s.material, s.distance, 90.0 - s.angle_deg)
        assert lo * sigma <= s.std <= hi * sigma, s
        assert abs(s.mean - s.distance) < 5 * sigma / math.sqrt(3000)


def test_repeated_measurements_are_deterministic_per_setup():
    a = repeated_measurements(["cardboard", "white-paper"], [2.0, 3.0], [45], 30, seed=9)
    b = repeated_measurements(["white-paper"], [3.0], [45], 30, seed=9)
    np.testing.assert_array_equal(a.range[-30:], b.range)
    c = repeated_measurements(["white-paper"], [3.0], [45], 30, seed=10)
    assert not np.array_equal(b.range, c.range, equal_nan=True)


def test_dropouts_are_nan_rows():
    rows = repeated_measurements(["black-metal"], [2.0], [90], 1000, seed=0)
    lost = int(np.isnan(rows.range).sum())
    assert len(rows) == 1000 and 3 <= lost <= 50  # p = 2 % for black metal
    assert rows.summary()[0].returns == 1000 - lost


def test_csv_round_trip(tmp_path):
    rows = repeated_measurements(["black-metal", "white-textile"], [1.0, 3.5], [90, 45], 200, seed=4)
    assert np.isnan(rows.range).any()
    path = write_repeatability_csv(tmp_path / "repeat.csv", rows)
    lines = path.read_text().splitlines()
    assert lines[0] == "material,angle_deg,distance_m,repetition,range_m" == ",".join(CSV_HEADER)
    assert len(lines) == 1 + len(rows)
    assert any(line.endswith(",") for line in lines[1:]), "a no-return is an empty range"
    back = read_repeatability_csv(path)
    np.testing.assert_array_equal(back.material, rows.material)
    np.testing.assert_array_equal(back.angle_deg, rows.angle_deg)
    np.testing.assert_array_equal(back.distance, rows.distance)
    np.testing.assert_array_equal(back.repetition, rows.repetition)
    np.testing.assert_array_equal(back.range, rows.range)  # bit for bit, NaN where NaN
    assert [p.name for p in tmp_path.iterdir()] == ["repeat.csv"], "no temporary file left behind"


@pytest.mark.parametrize(
    "text, line, field",
    [
        ("material,angle_deg,distance_m,repetition\ncardboard,90,1,0\n", 1, "header"),
        ("material,angle_deg,distance_m,repetition,range_m\ncardboard,90,1,0,1.0\nsteel,90,1,1,1.0\n", 3, "material"),
        ("material,angle_deg,distance_m,repetition,range_m\ncardboard,ninety,1,0,1.0\n", 2, "angle_deg"),
        ("material,angle_deg,distance_m,repetition,range_m\ncardboard,90,1,0.5,1.0\n", 2, "repetition"),
        ("material,angle_deg,distance_m,repetition,range_m\ncardboard,90,1,0\n", 2, "row"),
    ],
)
def test_bad_csv_names_file_line_and_field(tmp_path, text, line, field):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        read_repeatability_csv(path)
    assert err.value.where == line and err.value.field == field
    assert str(err.value).startswith(f"{path}:{line}: {field}: ")


def test_setup_log_is_readable_and_matches_the_rows(tmp_path):
    setup = Setup("white-paper", 45.0, 3.0)
    path = write_setup_log(tmp_path / "paper-45-3m.log.gz", setup, 25, seed=3)
    rec = open_recording(path)
    frames = list(rec.frames())
    assert len(frames) == 25 and not rec.problems
    urg = laser_preset("urg-04lx")
    scan = frames[0].scan
    assert scan.num_beams == 682 and scan.range_max == 5.6 and scan.range_min == 0.02
    assert scan.angle_min == pytest.approx(urg.angle_min) and scan.angle_increment == pytest.approx(urg.angle_increment)
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(25) / 10.0)
    assert all(np.array_equal(f.odometry, np.zeros(3)) for f in frames)
    rows = repeated_measurements([setup.material], [setup.distance], [setup.angle_deg], 25, seed=3)
    central = np.array([f.scan.ranges[urg.central_beam] for f in frames])
    np.testing.assert_array_equal(central, rows.range)
    # only beams toward the plate return: its ends are at atan2(+-0.354, 3 -+ 0.354)
    half = 0.5 * math.sqrt(0.5)
    seen = scan.angles[scan.valid]
    assert seen.min() >= math.atan2(-half, 3 + half) and seen.max() <= math.atan2(half, 3 - half)
    assert seen.max() - seen.min() > math.radians(13)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(materials=["steel"]), "materials"),
        (dict(distances=[-1.0]), "distances"),
        (dict(distances=[6.0]), "distances"),
        (dict(distances=["far"]), "distances"),
        (dict(angles_deg=[0.0]), "angles_deg"),
        (dict(angles_deg=[120.0]), "angles_deg"),
        (dict(repetitions=0), "repetitions"),
    ],
)
def test_bad_experiment_arguments(kwargs, field):
    kwargs.setdefault("repetitions", 2)
    with pytest.raises(InputError) as err:
        repeated_measurements(**kwargs)
    assert err.value.field == field


def test_setup_log_out_of_range_leaves_no_file(tmp_path):
    with pytest.raises(InputError, match="distances: 7.0 m is outside the urg-04lx laser's range"):
        write_setup_log(tmp_path / "far.log", Setup("cardboard", 90.0, 7.0), 5)
    assert list(tmp_path.iterdir()) == []
