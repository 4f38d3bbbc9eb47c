"""Trajectory metrics: ATE, RPE and the relations metric on cases with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.eval.trajectory_metrics import (
    Association,
    absolute_trajectory_error,
    align_se2,
    associate,
    error_stats,
    relations_error,
    relative_pose_error,
)
from slam2d.io.relations import Relations, read_relations, relations_from_trajectory, write_relations
from slam2d.io.tum import read_tum
from tests.conftest import dataset_file

KNOWN = np.array([3.0, -2.0, 0.7])


def figure_eight(n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """``n`` poses 0.1 s apart on a figure-eight, heading along the path."""
    times = 0.1 * np.arange(n)
    s = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    x, y = 10.0 * np.sin(s), 5.0 * np.sin(2.0 * s)
    heading = np.arctan2(10.0 * np.cos(2.0 * s), 10.0 * np.cos(s))
    return times, np.column_stack([x, y, heading])


def moved_by(transform: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """``transform ∘ poses`` written out with a rotation matrix, independently of se2.compose."""
    c, s = math.cos(transform[2]), math.sin(transform[2])
    rotation = np.array([[c, -s], [s, c]])
    xy = poses[:, :2] @ rotation.T + transform[:2]
    return np.column_stack([xy, poses[:, 2] + transform[2]])


# ---------------------------------------------------------------------------- error_stats


def test_error_stats_known_values():
    stats = error_stats([1.0, 2.0, 3.0, 4.0])
    assert stats["count"] == 4
    assert stats["rmse"] == pytest.approx(math.sqrt(7.5))
    assert stats["mean"] == pytest.approx(2.5)
    assert stats["median"] == pytest.approx(2.5)
    assert stats["std"] == pytest.approx(math.sqrt(5.0 / 3.0))  # sample std, ddof=1
    assert stats["max"] == 4.0


def test_error_stats_single_and_empty():
    one = error_stats([0.3])
    assert one == {"rmse": 0.3, "mean": 0.3, "median": 0.3, "std": 0.0, "max": 0.3, "count": 1}
    empty = error_stats([])
    assert empty["count"] == 0
    assert all(math.isnan(empty[k]) for k in ("rmse", "mean", "median", "std", "max"))


# ---------------------------------------------------------------------------- alignment and ATE


def test_align_se2_recovers_transform_of_points():
    rng = np.random.default_rng(1)
    source = rng.uniform(-5, 5, (30, 2))
    target = moved_by(KNOWN, np.column_stack([source, np.zeros(30)]))[:, :2]
    assert np.allclose(align_se2(source, target), KNOWN, atol=1e-12)
    # two points are enough
    assert np.allclose(align_se2(source[:2], target[:2]), KNOWN, atol=1e-12)


def test_align_se2_needs_two_points():
    with pytest.raises(ValueError, match="at least 2"):
        align_se2([[1.0, 2.0]], [[3.0, 4.0]])


def test_ate_after_alignment_is_zero_and_recovers_transform():
    times, est = figure_eight()
    ref = moved_by(KNOWN, est)
    ate = absolute_trajectory_error(associate(times, est, times, ref))
    assert ate["pairs"] == 200 and ate["unmatched"] == 0
    assert np.allclose(ate["alignment"], KNOWN, atol=1e-9)
    assert ate["translation_m"]["max"] < 1e-9
    assert ate["rotation_deg"]["max"] < 1e-9
    # before alignment: each pose is off by exactly its distance to T∘p and by 0.7 rad
    distances = np.hypot(*(ref[:, :2] - est[:, :2]).T)
    before = ate["before_alignment"]
    assert before["translation_m"]["rmse"] == pytest.approx(math.sqrt(np.mean(distances**2)), rel=1e-12)
    assert before["translation_m"]["max"] == pytest.approx(distances.max(), rel=1e-12)
    assert before["translation_m"]["rmse"] > 1.0  # the test could fail: the poses are far apart
    assert before["rotation_deg"]["mean"] == pytest.approx(math.degrees(0.7), rel=1e-12)
    assert before["rotation_deg"]["std"] == pytest.approx(0.0, abs=1e-9)


def test_ate_without_alignment_constant_offset_on_half():
    times, ref = figure_eight()
    est = ref.copy()
    est[100:, 0] += 0.1  # second half 0.1 m off in x
    ate = absolute_trajectory_error(associate(times, est, times, ref), align=False)
    assert ate["alignment"] == [0.0, 0.0, 0.0]
    t = ate["translation_m"]
    assert t["count"] == 200
    assert t["rmse"] == pytest.approx(math.sqrt(0.5 * 0.01), rel=1e-9)
    assert t["mean"] == pytest.approx(0.05, rel=1e-9)
    assert t["median"] == pytest.approx(0.05, rel=1e-9)
    assert t["std"] == pytest.approx(math.sqrt(200 * 0.05**2 / 199), rel=1e-9)
    assert t["max"] == pytest.approx(0.1, rel=1e-9)
    assert ate["rotation_deg"]["max"] == 0.0
    assert ate["before_alignment"]["translation_m"] == t
    # an alignment can only make it better
    aligned = absolute_trajectory_error(associate(times, est, times, ref))
    assert aligned["translation_m"]["rmse"] < t["rmse"]


@settings(max_examples=80, deadline=None)
@given(
    arrays(np.float64, st.tuples(st.integers(3, 40), st.just(3)), elements=st.floats(-100, 100)),
    st.floats(-1000, 1000),
    st.floats(-1000, 1000),
    st.floats(-math.pi, math.pi),
)
def test_ate_after_alignment_is_zero_property(poses, tx, ty, theta):
    spread = np.max(np.hypot(*(poses[:, :2] - poses[:, :2].mean(axis=0)).T))
    assume(spread > 0.1)  # coincident points leave the rotation undetermined
    transform = np.array([tx, ty, theta])
    times = np.arange(poses.shape[0], dtype=np.float64)
    ate = absolute_trajectory_error(associate(times, poses, times, moved_by(transform, poses)))
    assert ate["translation_m"]["max"] < 1e-8
    assert ate["rotation_deg"]["max"] < 1e-8
    alignment = np.array(ate["alignment"])
    assert np.allclose(alignment[:2], transform[:2], atol=1e-8)
    assert abs(se2.wrap_angle(alignment[2] - theta)) < 1e-9


# ---------------------------------------------------------------------------- association


def test_associate_interpolates_reference_and_counts_unmatched():
    # reference: straight line at 1 m/s sampled every 0.2 s from t=0 to t=10, gap 4..6 s
    ref_t = np.round(np.arange(0.0, 10.0001, 0.2), 9)
    ref_t = ref_t[(ref_t <= 4.0) | (ref_t >= 6.0)]
    ref = np.column_stack([ref_t, np.zeros_like(ref_t), np.full_like(ref_t, 0.3)])
    est_t = np.array([-1.0, 0.05, 1.13, 3.9, 5.0, 9.99, 12.0])
    est = np.column_stack([est_t, np.ones_like(est_t), np.zeros_like(est_t)])
    assoc = associate(est_t, est, ref_t, ref, max_gap=0.5)
    assert isinstance(assoc, Association)
    assert assoc.unmatched == 3  # before the start, inside the 2 s gap, after the end
    assert np.array_equal(assoc.times, [0.05, 1.13, 3.9, 9.99])
    assert np.allclose(assoc.reference[:, 0], assoc.times, atol=1e-12)
    assert np.allclose(assoc.reference[:, 2], 0.3)
    assert np.array_equal(assoc.estimate, est[[1, 2, 3, 5]])
    # with a wider max_gap the pose in the gap is matched too
    assert associate(est_t, est, ref_t, ref, max_gap=2.5).unmatched == 2


def test_associate_rejects_trajectories_that_do_not_overlap():
    est_t = np.linspace(0.0, 10.0, 11)
    ref_t = np.linspace(100.0, 200.0, 11)
    poses = np.zeros((11, 3))
    with pytest.raises(InputError) as err:
        associate(est_t, poses, ref_t, poses, est_name="run/est.tum", ref_name="data/reference.tum")
    text = str(err.value)
    assert "do not overlap in time" in text
    assert "run/est.tum spans 0.000-10.000 s" in text
    assert "data/reference.tum spans 100.000-200.000 s" in text
    assert err.value.field == "timestamp" and "\n" not in text


def test_associate_rejects_fewer_than_two_pairs():
    # the spans touch at one instant: one pair only
    est_t = np.array([5.0, 6.0, 7.0])
    ref_t = np.array([0.0, 2.5, 5.0])
    poses = np.zeros((3, 3))
    with pytest.raises(InputError) as err:
        associate(est_t, poses, ref_t, poses)
    text = str(err.value)
    assert "only 1 of 3" in text
    assert "estimate spans 5.000-7.000 s" in text and "reference spans 0.000-5.000 s" in text


# ---------------------------------------------------------------------------- RPE


def test_rpe_per_frame_of_exact_copy_is_zero():
    times, ref = figure_eight()
    rpe = relative_pose_error(associate(times, ref.copy(), times, ref))
    assert rpe["per"] == "frame" and rpe["delta"] == 1.0 and rpe["pairs"] == 199
    assert rpe["translation_m"]["max"] == pytest.approx(0.0, abs=1e-12)
    assert rpe["rotation_deg"]["max"] == pytest.approx(0.0, abs=1e-12)
    assert "translation_percent" not in rpe


def test_rpe_needs_no_alignment():
    times, ref = figure_eight()
    rpe = relative_pose_error(associate(times, moved_by(KNOWN, ref), times, ref), per="frame", delta=7)
    assert rpe["pairs"] == 193
    assert rpe["translation_m"]["max"] < 1e-12
    assert rpe["rotation_deg"]["max"] < 1e-10


def test_rpe_per_frame_sees_one_jump():
    times, ref = figure_eight()
    est = ref.copy()
    est[120:, 1] += 0.2  # one 0.2 m jump between poses 119 and 120
    assoc = associate(times, est, times, ref)
    rpe = relative_pose_error(assoc)
    t = rpe["translation_m"]
    assert t["count"] == 199
    assert t["max"] == pytest.approx(0.2, rel=1e-9)
    assert t["mean"] == pytest.approx(0.2 / 199, rel=1e-9)
    assert t["median"] == pytest.approx(0.0, abs=1e-12)
    assert rpe["rotation_deg"]["max"] == pytest.approx(0.0, abs=1e-12)
    # five frames apart: the jump lies inside 5 of the 195 pairs
    rpe5 = relative_pose_error(assoc, delta=5)
    assert rpe5["pairs"] == 195
    assert rpe5["translation_m"]["mean"] == pytest.approx(5 * 0.2 / 195, rel=1e-9)


def test_rpe_per_metre_on_straight_line_with_scale_error():
    # 0.125 m steps are exact in binary, so 1 m is exactly 8 steps
    n = 81
    times = np.arange(n, dtype=np.float64)
    ref = np.column_stack([0.125 * np.arange(n), np.zeros(n), np.zeros(n)])
    est = ref.copy()
    est[:, 0] *= 1.01  # odometry 1 % long
    rpe = relative_pose_error(associate(times, est, times, ref), per="metre", delta=1.0)
    assert rpe["per"] == "metre" and rpe["pairs"] == n - 8
    assert rpe["translation_percent"]["mean"] == pytest.approx(1.0, rel=1e-9)
    assert rpe["translation_percent"]["max"] == pytest.approx(1.0, rel=1e-9)
    assert rpe["translation_m"]["mean"] == pytest.approx(0.01, rel=1e-9)
    assert rpe["rotation_deg_per_m"]["max"] == 0.0
    # 3.1 m needs 25 steps (3.125 m), the percentage is unchanged
    rpe3 = relative_pose_error(associate(times, est, times, ref), per="metre", delta=3.1)
    assert rpe3["pairs"] == n - 25
    assert rpe3["translation_m"]["mean"] == pytest.approx(0.03125, rel=1e-9)
    assert rpe3["translation_percent"]["mean"] == pytest.approx(1.0, rel=1e-9)


def test_rpe_per_metre_counts_heading_drift_per_metre():
    n = 81
    times = np.arange(n, dtype=np.float64)
    ref = np.column_stack([0.125 * np.arange(n), np.zeros(n), np.zeros(n)])
    est = ref.copy()
    est[:, 2] = np.radians(0.5) * 0.125 * np.arange(n)  # heading drifts 0.5 deg per metre
    rpe = relative_pose_error(associate(times, est, times, ref), per="metre", delta=2.0)
    assert rpe["rotation_deg"]["mean"] == pytest.approx(1.0, rel=1e-9)
    assert rpe["rotation_deg_per_m"]["mean"] == pytest.approx(0.5, rel=1e-9)


def test_rpe_without_pairs_is_nan_not_an_error():
    times = np.array([0.0, 1.0, 2.0])
    ref = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    assoc = associate(times, ref, times, ref)
    rpe = relative_pose_error(assoc, per="metre", delta=5.0)
    assert rpe["pairs"] == 0
    assert math.isnan(rpe["translation_m"]["rmse"]) and math.isnan(rpe["translation_percent"]["mean"])
    assert relative_pose_error(assoc, delta=10)["pairs"] == 0


def test_rpe_rejects_bad_options():
    times, ref = figure_eight(10)
    assoc = associate(times, ref, times, ref)
    with pytest.raises(InputError, match="'mile' is not an RPE unit"):
        relative_pose_error(assoc, per="mile")
    with pytest.raises(InputError, match="delta"):
        relative_pose_error(assoc, per="metre", delta=0.0)
    with pytest.raises(InputError, match="delta"):
        relative_pose_error(assoc, per="frame", delta=0.5)


# ---------------------------------------------------------------------------- relations metric

SPANNING = [(95, 105), (50, 150), (99, 100), (0, 199)]
NOT_SPANNING = [(0, 10), (20, 30), (110, 120), (150, 199), (101, 180), (5, 99)]


def test_relations_from_truth_score_zero():
    times, truth = figure_eight()
    rng = np.random.default_rng(3)
    pairs = rng.integers(0, 200, (50, 2))
    result = relations_error(times, truth, relations_from_trajectory(times, truth, pairs))
    assert result["relations"] == 50 and result["used"] == 50 and result["skipped"] == 0
    assert result["translation_max_m"] < 1e-12
    assert result["rotation_abs_deg"]["mean"] < 1e-10


def test_relations_error_with_shift_after_time():
    times, truth = figure_eight()
    est = truth.copy()
    est[times >= 10.0, 0] += 0.1  # the estimate jumps 0.1 m at T = 10 s (pose 100)
    relations = relations_from_trajectory(times, truth, np.array(SPANNING + NOT_SPANNING))
    result = relations_error(times, est, relations)
    assert result["used"] == 10
    # 4 errors of 0.1 m and 6 of 0: worked out by hand
    assert result["translation_abs_m"]["mean"] == pytest.approx(0.04, rel=1e-9)
    assert result["translation_abs_m"]["std"] == pytest.approx(math.sqrt(0.024 / 9), rel=1e-9)
    assert result["translation_sq_m2"]["mean"] == pytest.approx(0.004, rel=1e-9)
    assert result["translation_sq_m2"]["std"] == pytest.approx(math.sqrt(2.4e-4 / 9), rel=1e-9)
    assert result["translation_max_m"] == pytest.approx(0.1, rel=1e-9)
    assert result["rotation_abs_deg"]["mean"] == pytest.approx(0.0, abs=1e-9)
    assert result["rotation_sq_deg2"]["std"] == pytest.approx(0.0, abs=1e-9)
    # the spanning ones alone
    only = relations_error(times, est, relations_from_trajectory(times, truth, np.array(SPANNING)))
    assert only["translation_abs_m"]["mean"] == pytest.approx(0.1, rel=1e-9)
    assert only["translation_abs_m"]["std"] == pytest.approx(0.0, abs=1e-9)


def test_relations_error_convention_matches_cartographer():
    # pose1 = origin, pose2 = (1, 0, 90 deg), expected motion (1, 0, 0):
    # (p1⁻¹ ⊕ p2) ⊕ expected⁻¹ = (1, 0, 90°) ⊕ (-1, 0, 0) = (1, -1, 90°)
    times = np.array([0.0, 1.0])
    est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, math.pi / 2]])
    relations = Relations(path=None, t1=np.array([0.0]), t2=np.array([1.0]), motion=np.array([[1.0, 0.0, 0.0]]))
    result = relations_error(times, est, relations)
    assert result["translation_abs_m"]["mean"] == pytest.approx(math.sqrt(2.0), rel=1e-12)
    assert result["translation_sq_m2"]["mean"] == pytest.approx(2.0, rel=1e-12)
    assert result["rotation_abs_deg"]["mean"] == pytest.approx(90.0, rel=1e-12)
    assert result["rotation_sq_deg2"]["mean"] == pytest.approx(8100.0, rel=1e-12)
    assert result["translation_abs_m"]["std"] == 0.0  # one relation


def test_relations_outside_estimate_are_skipped(tmp_path):
    times, truth = figure_eight()
    pairs = np.array([(10, 20), (30, 60), (90, 150), (150, 190), (160, 199)])
    relations = relations_from_trajectory(times, truth, pairs)
    # the estimate stops at 11.9 s: relations reaching beyond cannot be scored
    result = relations_error(times[:120], truth[:120], relations)
    assert result["relations"] == 5 and result["used"] == 2 and result["skipped"] == 3
    assert result["translation_max_m"] < 1e-12


def test_relations_not_covered_at_all_name_the_file(tmp_path):
    times, truth = figure_eight()
    path = write_relations(tmp_path / "truth.relations", times[:10] + 1000.0, times[1:11] + 1000.0, truth[:10])
    relations = read_relations(path)
    with pytest.raises(InputError) as err:
        relations_error(times, truth, relations, est_name="est.tum")
    text = str(err.value)
    assert text.startswith(str(path))
    assert "relations spans 1000.000-1001.000 s" in text
    assert "est.tum spans 0.000-19.900 s" in text
    assert err.value.field == "timestamp"


# ---------------------------------------------------------------------------- real data


@pytest.mark.datasets
def test_intel_reference_against_itself_moved_and_its_own_relations(tmp_path):
    times, ref = read_tum(dataset_file("intel/reference.tum"))
    n = times.shape[0]
    moved = moved_by(KNOWN, ref)
    ate = absolute_trajectory_error(associate(times, moved, times, ref, est_name="moved", ref_name="intel"))
    assert ate["pairs"] == n
    assert ate["translation_m"]["max"] < 1e-9
    assert np.allclose(ate["alignment"], se2.inverse(KNOWN), atol=1e-9)
    # consecutive-scan relations (as in the Freiburg files), through a file
    pairs = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    rel = relations_from_trajectory(times, ref, pairs)
    rel = read_relations(write_relations(tmp_path / "intel.relations", rel.t1, rel.t2, rel.motion))
    result = relations_error(times, moved, rel)
    assert result["used"] == n - 1
    assert result["translation_max_m"] < 1e-9
    # the metric sees a perturbation: 5 cm noise on every pose
    noisy = ref.copy()
    noisy[:, :2] += np.random.default_rng(0).normal(0.0, 0.05, (n, 2))
    scored = relations_error(times, noisy, rel)
    # difference of two N(0, 0.05^2 I) points: mean distance 0.05 * sqrt(pi) ~ 0.089
    assert scored["translation_abs_m"]["mean"] == pytest.approx(0.05 * math.sqrt(math.pi), rel=0.1)


def test_heading_agreement_ignores_a_rigid_move_and_sees_a_turned_part():
    """heading_agreement: a copy moved rigidly agrees exactly; a copy whose second half turns 20 degrees further
    (a part of the map turned against the rest) shows it in the 95th percentile."""
    from slam2d.eval.trajectory_metrics import heading_agreement

    t = np.arange(200) * 0.1
    ref = np.stack([np.cos(t / 4) * 5, np.sin(t / 4) * 3, t / 4 + 0.3], axis=-1)
    moved = se2.compose(np.array([1.0, -2.0, 0.7]), ref)
    same = heading_agreement(t, moved, t, ref)
    assert same["heading_p95_deg"] < 1e-6 and same["relative_p95_deg"] < 1e-6
    turned = ref.copy()
    turned[100:, 2] += np.radians(20)
    h = heading_agreement(t, turned, t, ref)
    assert 8 < h["heading_p95_deg"] <= 20.001 and h["relative_p95_deg"] == pytest.approx(20, abs=1e-6)
