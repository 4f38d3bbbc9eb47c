"""``hold_flat_direction`` (gmapping ``flat_ratio``): a climb's slide along a direction its score does not fix is undone."""

from __future__ import annotations

import numpy as np

from slam2d.cli import main
from slam2d.grids.tiled import TiledMaps
from slam2d.matching.hill_climb import (
    BeamSet,
    _wall_end_step,
    along_terms,
    hold_flat_direction,
    match_particles,
    wall_ends,
)
from slam2d.methods.gmapping import GMapping, GMappingParams
from tests._room import box_ranges
from tests.conftest import recording_frames


def _corridor(angles, reach=4.0):
    """Ranges from the origin to two endless walls at y = +-1 (nothing along the corridor within ``reach``)."""
    s = np.sin(angles)
    with np.errstate(divide="ignore"):
        r = np.where(np.abs(s) > 1e-9, 1.0 / np.abs(s), np.inf)
    return np.where(r < reach, r, np.nan)


def _room(angles):
    """Ranges from (0, 0) to the walls of a 4 x 3 m room centred 0.3 m ahead."""
    return box_ranges(angles, (-1.7, -1.5, 2.3, 1.5))


def _mapped(ranges, angles, n, poses_x):
    maps = TiledMaps(n, 0.05, (-6, -6, 6, 6))
    for x in poses_x:  # mapped from a few poses, so cells have a stable mean hit point
        maps.register(np.arange(n), np.tile([x, 0.0, 0.0], (n, 1)), np.broadcast_to(ranges, (n, ranges.size)), angles,
                      max_range=4.0, usable_range=4.0, generate_map=False)
    use = np.isfinite(ranges)
    return maps, BeamSet(np.nan_to_num(ranges), angles, use, np.full(ranges.size, 0.05), np.full(ranges.size, 0.075))


def _climb_and_hold(maps, beams, start, ratio):
    n = start.shape[0]
    out, score, like, ok = np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n, bool)
    common = (maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], 0.05, 1)
    match_particles(*common, start, np.zeros(3), beams.ex, beams.ey, beams.div_score,
                    beams.div_like, 0.05, 0.05, 5, 0.0, 0.0, np.zeros((n, 3)), 0.0, out, score, like, ok)
    climbed = out.copy()
    flat = np.zeros(n, dtype=np.int64)
    hold_flat_direction(*common, np.arange(n, dtype=np.int64), start, out, ok, np.zeros(3), beams.ex, beams.ey,
                        beams.div_score, beams.div_like, 0.05, ratio, np.zeros(0), np.zeros((0, 5)),
                        0.0, np.zeros((n, 3)), np.zeros((n, 3)), like,
                        flat)
    return climbed, out, like, flat, ok


def test_the_climb_along_an_endless_corridor_is_undone_and_the_rest_kept():
    """Along the corridor the climb slides on the cells' ripple; held, the pose keeps the start's x.

    Across the corridor and in heading the climb's correction stays; the log-likelihood is the held pose's.
    """
    angles = np.linspace(-2.0, 2.0, 682)
    ranges = _corridor(angles)
    start = np.array([[0.013, 0.06, 0.04], [-0.021, -0.06, -0.04], [0.032, 0.05, 0.0], [0.0, -0.05, 0.03]])
    maps, beams = _mapped(ranges, angles, start.shape[0], (-0.4, -0.2, 0.0, 0.2, 0.4))
    climbed, held, like, flat, ok = _climb_and_hold(maps, beams, start, 0.1)
    assert ok.all()
    assert np.abs(climbed[:, 0] - start[:, 0]).max() > 0.1  # GMapping's climb rides the ripple
    assert np.all(flat == 1)
    # the odometry's component along x (the flat eigenvector is x up to the cells' ripple)
    np.testing.assert_allclose(held[:, 0], start[:, 0], atol=1e-4)
    np.testing.assert_allclose(held[:, 1], climbed[:, 1], atol=1e-3)  # across and heading: the climb's
    np.testing.assert_array_equal(held[:, 2], climbed[:, 2])
    assert np.all(np.abs(held[:, 1]) < 0.01)
    assert np.all(like > -0.5 / 0.075 * beams.ex.size)  # evaluated at the held pose: the beams still match


def test_a_room_that_fixes_the_pose_is_left_alone():
    """Where the scan sees walls in two directions nothing is held: the climb's pose is returned unchanged."""
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    ranges = _room(angles)
    start = np.array([[0.08, -0.05, 0.04], [-0.06, 0.07, -0.03]])
    maps, beams = _mapped(ranges, angles, start.shape[0], (0.0, 0.0, 0.0))
    climbed, held, _, flat, ok = _climb_and_hold(maps, beams, start, 0.1)
    assert ok.all() and np.all(flat == 0)
    np.testing.assert_array_equal(held, climbed)
    assert np.all(np.hypot(held[:, 0], held[:, 1]) < 0.02)


def test_ratio_zero_changes_nothing_and_a_failed_match_is_skipped():
    angles = np.linspace(-2.0, 2.0, 682)
    ranges = _corridor(angles)
    start = np.array([[0.013, 0.06, 0.04], [3.0, 3.0, 0.0]])  # the second has no map point near any beam
    maps, beams = _mapped(ranges, angles, start.shape[0], (-0.4, 0.0, 0.4))
    climbed, held, _, flat, ok = _climb_and_hold(maps, beams, start, 0.0)
    assert ok[0] and not ok[1]
    assert np.all(flat == 0)
    np.testing.assert_array_equal(held, climbed)


def test_gmapping_flat_ratio_counts_held_matches_and_is_reproducible(tmp_path):
    """In a simulated corridor (URG-04LX) flat_ratio holds particle and tracked matches, counted; same seed, same bits."""
    assert main(["simulate", "corridor-loop", "--out", str(tmp_path), "--duration", "25", "--seed", "0"]) == 0
    frames = recording_frames(tmp_path / "recording.log.gz")
    short = {"between_updates": "guided", "odometry_prior": 1.0, "tracking_prior": 1.0}
    held = GMapping(GMappingParams(particles=8, flat_ratio=0.1, **short), seed=3).run(frames)
    again = GMapping(GMappingParams(particles=8, flat_ratio=0.1, **short), seed=3).run(frames)
    plain = GMapping(GMappingParams(particles=8, **short), seed=3).run(frames)
    c = held.diagnostics.counters
    assert c.get("degenerate_matches", 0) > 0 and c.get("degenerate_tracking", 0) > 0
    assert np.nansum(held.diagnostics.array("degenerate_matches")) == c["degenerate_matches"]
    assert np.array_equal(held.trajectory()[1], again.trajectory()[1])
    assert "degenerate_matches" not in plain.diagnostics.counters
    assert not np.array_equal(held.trajectory()[1], plain.trajectory()[1])
    # flat_sigma: the held climbs move by the wall ends' pull: a different path, the same bits with the same seed
    pulled = GMapping(GMappingParams(particles=8, flat_ratio=0.1, flat_sigma=0.03, **short), seed=3).run(frames)
    pulled2 = GMapping(GMappingParams(particles=8, flat_ratio=0.1, flat_sigma=0.03, **short), seed=3).run(frames)
    assert np.array_equal(pulled.trajectory()[1], pulled2.trajectory()[1])
    assert not np.array_equal(pulled.trajectory()[1], held.trajectory()[1])


def _corridor_with_end(angles, end=3.0, reach=4.0):
    """The endless corridor's ranges, closed by a wall across it at x = ``end`` (a surface across the direction)."""
    r = _corridor(angles, reach=np.inf)
    c = np.cos(angles)
    with np.errstate(divide="ignore"):
        to_end = np.where(c > 1e-9, end / c, np.inf)
    r = np.fmin(r, to_end)
    return np.where(r < reach, r, np.nan)


def _along(maps, beams, x, ratio_w=0.5 / 0.03**2):
    w = np.full(beams.ex.size, ratio_w)
    return along_terms(maps.pool, maps.occ, maps.table, 0, maps.origin[0], maps.origin[1], 0.05, 3, x, 0.0, 0.0,
                       1.0, 0.0, 0.05, np.zeros(3), beams.ex, beams.ey, w, np.zeros(3))


def test_along_terms_cancel_the_walls_ripple_and_keep_a_surface_across():
    """Along an endless corridor the one-cell differences of the beams' distances cancel; an end wall pulls.

    At offsets of a fraction of a cell (the ripple's phase) the endless corridor's gradient and curvature
    along it are a tiny fraction of the corridor closed by a wall 3 m ahead; there the curvature is
    about what that wall's beams give (each 1 / s^2 with s = 3 cm, times cos^2 of its incidence).
    """
    angles = np.linspace(-2.0, 2.0, 682)
    open_r, closed_r = _corridor(angles), _corridor_with_end(angles)
    maps_o, beams_o = _mapped(open_r, angles, 1, (-0.4, -0.2, 0.0, 0.2, 0.4))
    maps_c, beams_c = _mapped(closed_r, angles, 1, (0.0,))
    end_beams = np.isfinite(closed_r) & (np.abs(closed_r * np.cos(angles) - 3.0) < 1e-6)
    expected = (np.cos(angles[end_beams]) ** 2).sum() / 0.03**2
    for x in (0.0, 0.013, -0.021, 0.031):
        g_o, h_o, used_o = _along(maps_o, beams_o, x)
        g_c, h_c, _ = _along(maps_c, beams_c, x)
        assert used_o > 500
        assert abs(h_o) < 0.05 * h_c and h_c > 0.3 * expected
    # the closed corridor's gradient points back to where it was mapped
    assert _along(maps_c, beams_c, 0.03)[0] > 0 and _along(maps_c, beams_c, -0.03)[0] < 0


def test_flat_sigma_moves_a_held_pose_to_the_end_walls_position():
    """A climb held along the corridor (flat_ratio) is moved by the end wall's few beams, within the prior's pull."""
    angles = np.linspace(-2.0, 2.0, 682)
    ranges = _corridor_with_end(angles)
    start = np.array([[0.04, 0.03, 0.0], [-0.04, -0.03, 0.0], [0.02, 0.0, 0.01]])
    n = start.shape[0]
    maps, beams = _mapped(ranges, angles, n, (0.0,))
    out, score, like, ok = np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n, bool)
    common = (maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], 0.05, 1)
    match_particles(*common, start, np.zeros(3), beams.ex, beams.ey, beams.div_score,
                    beams.div_like, 0.05, 0.05, 5, 0.0, 0.0, np.zeros((n, 3)), 0.0, out, score, like, ok)
    flat = np.zeros(n, dtype=np.int64)
    w = np.full(beams.ex.size, 0.5 / 0.03**2)
    prior = np.tile([100.0, 100.0, 100.0], (n, 1))  # a 0.1 m odometry prior: far weaker than the end wall
    hold_flat_direction(*common, np.arange(n, dtype=np.int64), start, out, ok, np.zeros(3), beams.ex, beams.ey,
                        beams.div_score, beams.div_like, 0.05, 0.5, w, np.zeros((0, 5)), 0.0,
                        np.zeros((n, 3)), prior, like, flat)
    assert (flat == 1).sum() >= 2  # the end wall's ~110 beams against ~570 on the side walls: flat by the ratio
    held = flat == 1
    assert np.all(np.abs(out[held, 0]) < 0.01)  # yet the wall-end term puts it back where the map says
    assert np.all(np.abs(start[held, 0]) > 0.015)


def _corridor_with_door(angles, end=2.0):
    """The endless corridor, but its left wall (y = 1) ends at x = ``end``: beyond it the beams return nothing."""
    r = _corridor(angles, reach=np.inf)
    s, c = np.sin(angles), np.cos(angles)
    with np.errstate(divide="ignore", invalid="ignore"):
        past = (s > 0) & (c / np.where(s > 0, s, 1.0) > end)
    r = np.where(past, np.nan, r)
    return np.where(r < 4.0, r, np.nan)


def test_wall_ends_finds_the_end_and_pulls_from_both_sides():
    """A wall end seen as a depth jump: found in the scan (not the walls cut by the range limit), matched to the map's.

    From a pose 6 cm ahead or behind along the corridor the explicit wall-end step comes back to within 1.5 cm.
    """
    angles = np.linspace(-2.0, 2.0, 682)
    ranges = _corridor_with_door(angles, end=1.0)  # seen at 45 deg incidence (grazing ones are not kept)
    maps, beams = _mapped(ranges, angles, 1, (0.0,))
    ends = wall_ends(ranges, angles, np.isfinite(ranges), 4.0)
    assert ends.shape[0] == 1
    ax, ay, wx, wy, half = ends[0]
    assert abs(ay - 1.0) < 1e-6 and 0.95 < ax <= 1.0 and wx > 0.999 and 0 < half < 0.02
    w = np.full(beams.ex.size, 0.5 / 0.03**2)
    common = (maps.pool, maps.occ, maps.table, 0, maps.origin[0], maps.origin[1], 0.05, 3)
    for s0 in (-0.06, 0.06):
        off = _wall_end_step(*common, s0, 0.0, 0.0, 1.0, 0.0, 0.05, np.zeros(3), beams.ex, beams.ey, w, np.zeros(3),
                             1.0, 4, ends, 1.0 / 0.03**2)
        assert abs(s0 + off) < 0.015


def test_wall_ends_skips_walls_running_out_of_range_and_grazing_ones():
    """The range limit cutting a wall, and a wall end seen at grazing incidence, are not wall ends."""
    angles = np.linspace(-2.0, 2.0, 682)
    short = _corridor(angles, reach=1.3)  # a 1.3 m laser: the walls leave its reach at 40 deg incidence
    assert wall_ends(short, angles, np.isfinite(short), 1.3).shape[0] == 0
    assert wall_ends(short, angles, np.isfinite(short), 10.0).shape[0] >= 2  # had the laser reached on: ends
    grazing = _corridor_with_door(angles, end=2.5)  # 68 deg incidence at the end
    assert wall_ends(grazing, angles, np.isfinite(grazing), 4.0).shape[0] == 0


