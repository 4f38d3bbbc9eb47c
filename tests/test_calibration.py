"""Laser calibration: fits and their degree, the model file, verification, the CLI and bad inputs."""

from __future__ import annotations

import json
import re
import math

import numpy as np
import pytest
import yaml

from slam2d.cli import main
from slam2d.errors import InputError
from slam2d.sensors import load_sensor_model
from slam2d.sensors.calibration.fits import choose_degree, cv_scores, fit_polynomial
from slam2d.sensors.calibration.laser import calibrate_laser, load_laser_data, verify_model
from slam2d.sensors.calibration.model import (
    CalibratedModel, dump_model_yaml, model_from_document, sensor_model_from_spec,
)
from slam2d.sensors.range_noise import MATERIALS, ConstantSigma, StudyModel
from slam2d.sim.repeatability import Setup, repeated_measurements, write_repeatability_csv, write_setup_log


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *needles):
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("slam2d: error: "), err
    for n in needles:
        assert n in lines[0], lines[0]


# --------------------------------------------------------------------------- fits


def test_weighted_fit_recovers_a_polynomial_and_its_band_covers_it():
    rng = np.random.default_rng(0)
    d = np.repeat(np.linspace(0.5, 4, 8), 3)
    truth = np.array([0.004, -0.001, 0.0003, 0.00004])  # c0..c3
    y0 = np.polynomial.polynomial.polyval(d, truth)
    se = 0.03 * y0
    covered = 0
    for _ in range(200):
        fit = fit_polynomial(d, y0 + se * rng.standard_normal(d.size), se, 3)
        x = np.array([2.5])
        covered += abs(fit(x)[0] - np.polynomial.polynomial.polyval(2.5, truth)) <= 1.96 * fit.standard_error(x)[0]
    assert 0.88 <= covered / 200 <= 0.99  # a 95 % band covers the truth about 95 % of the time
    exact = fit_polynomial(d, y0, se, 3)
    assert np.allclose(exact.coefficients, truth, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("true_degree", [1, 2, 3])
def test_cross_validation_never_misses_the_shape(true_degree):
    rng = np.random.default_rng(true_degree)
    d = np.repeat(np.linspace(0.5, 4.0, 9), 4)
    coef = [0.005, 0.002, -0.0012, 0.0003][: true_degree + 1]
    y = np.polynomial.polynomial.polyval(d, coef)
    se = np.full(d.size, 2e-5)
    degree, scores = choose_degree(d, y + se * rng.standard_normal(d.size), se, max_degree=4)
    assert true_degree <= degree <= true_degree + 2, scores
    assert set(scores) == {0, 1, 2, 3, 4}
    assert min(scores[k] for k in range(true_degree)) > 10 * scores[degree]  # too low a degree is plainly worse
    fit = fit_polynomial(d, y, se, degree)
    assert np.allclose(fit(d), y, atol=1e-9)


def test_cross_validation_picks_the_lower_of_equal_degrees():
    d = np.linspace(1.0, 4.0, 7)
    y = 0.004 + 0.001 * d  # exactly a line: degrees 1..3 predict it perfectly
    degree, scores = choose_degree(d, y, np.full(7, 1e-4), max_degree=3)
    assert degree == 1 and scores[0] > 1


def test_cross_validation_needs_distances_to_leave_out():
    d = np.array([1.0, 1.0, 2.0, 2.0])
    assert set(cv_scores(d, np.array([1.0, 1.1, 2.0, 2.1]), np.ones(4), 3)) == {0}  # a line cannot be held out
    degree, scores = choose_degree(d, np.array([1.0, 1.1, 2.0, 2.1]), np.ones(4), 3)
    assert (degree, scores) == (1, {})


# --------------------------------------------------------------------------- the model file


def _doc(**overrides):
    doc = {
        "format": "slam2d-sensor-model", "version": 1, "kind": "range-incidence", "distance_range_m": [1.0, 4.0],
        "fits": [
            {"incidence_deg": 0.0, "coefficients": [0.003, 0.0005]},
            {"incidence_deg": 45.0, "coefficients": [0.004, 0.001], "scatter": 0.1,
             "covariance": [[1e-8, 0.0], [0.0, 1e-9]]},
        ],
        "materials": {"cardboard": {"fits": [{"incidence_deg": 0.0, "coefficients": [0.01, 0.0]}]},
                      "my-wall": {"fits": [{"incidence_deg": 0.0, "coefficients": [0.02]}]}},
    }
    doc.update(overrides)
    return doc


def test_model_interpolates_in_incidence_and_continues_beyond_the_distances():
    m = model_from_document(_doc())
    wood = MATERIALS.index("varnished-wood")
    assert m.sigma(2.0, 0.0, wood) == pytest.approx(0.004)
    assert m.sigma(2.0, math.radians(45), wood) == pytest.approx(0.006)
    assert m.sigma(2.0, math.radians(22.5), wood) == pytest.approx(0.005)
    assert m.sigma(2.0, math.radians(70), wood) == pytest.approx(0.006)  # held beyond 45 deg
    assert m.sigma(6.0, 0.0, wood) == pytest.approx(0.003 + 0.0005 * 6)  # tangent (a line: itself)
    assert m.sigma(0.0, 0.0, wood) == pytest.approx(0.0035)  # never below the fit's minimum over 1-4 m
    card = MATERIALS.index("cardboard")
    assert m.sigma(2.0, 0.3, card) == pytest.approx(0.01)  # the surface's own fit
    out = m.sigma(np.array([2.0, 2.0]), np.array([0.0, 0.0]), np.array([wood, card]))
    assert out == pytest.approx([0.004, 0.01])
    assert m.band(2.0, 0.0, wood) == pytest.approx(0.0)
    assert m.band(2.0, math.radians(45), wood) > 0.1 * 0.006
    extend = model_from_document(_doc(beyond_measured_incidence="extend", max_incidence_deg=80))
    assert extend.sigma(2.0, math.radians(90), wood) == pytest.approx(0.004 + 0.002 * 80 / 45)


def test_model_file_round_trip(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text(dump_model_yaml(_doc(), "a test model"))
    m = load_sensor_model(path)
    assert isinstance(m, CalibratedModel)
    again = model_from_document(yaml.safe_load(path.read_text()))
    d = np.linspace(0.2, 6, 30)
    for mat in range(len(MATERIALS)):
        for a in (0.0, 0.4, 1.2):
            assert np.array_equal(m.sigma(d, a, mat), again.sigma(d, a, mat))
    assert path.read_text().startswith("# a test model\n")
    c = load_sensor_model_text(tmp_path, "format: slam2d-sensor-model\nversion: 1\nkind: constant\nsigma: 0.0041\n")
    assert c.sigma(np.ones(3), np.zeros(3), np.zeros(3, int)) == pytest.approx([0.0041] * 3)


def load_sensor_model_text(tmp_path, text, name="m.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return load_sensor_model(p)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"format": "other"}, "format"),
        ({"version": 9}, "version"),
        ({"kind": "cubic"}, "kind"),
        ({"distance_range_m": [4, 1]}, "distance_range_m"),
        ({"distance_range_m": [1]}, "distance_range_m"),
        ({"fits": []}, "fits"),
        ({"fits": [{"incidence_deg": 0, "coefficients": [0.001, "x"]}]}, "fits[0].coefficients[1]"),
        ({"fits": [{"coefficients": [0.001]}]}, "fits[0].incidence_deg"),
        ({"fits": [{"incidence_deg": 0, "coefficients": [0.004, -0.002]}]}, "fits[0].coefficients"),
        ({"fits": [{"incidence_deg": 95, "coefficients": [0.004]}]}, "fits[0].incidence_deg"),
        ({"fits": [{"incidence_deg": 0, "coefficients": [0.004]}, {"incidence_deg": 0, "coefficients": [0.005]}]},
         "fits"),
        ({"fits": [{"incidence_deg": 0, "coefficients": [0.004], "covariance": [[1, 2]]}]}, "fits[0].covariance[0]"),
        ({"beyond_measured_incidence": "wrap"}, "beyond_measured_incidence"),
        ({"fits": [{"incidence_deg": 0, "coefficients": [0.004], "distance_range_m": [3, 1]}]},
         "fits[0].distance_range_m"),
        ({"materials": {"cardboard": {"fits": "no"}}}, "materials.cardboard.fits"),
        ({"kind": "range"}, "fits"),
    ],
)
def test_bad_model_files_name_the_file_and_field(tmp_path, change, field):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_doc(**change)))
    with pytest.raises(InputError) as exc:
        load_sensor_model(path)
    assert exc.value.field == field
    assert str(path) in str(exc.value)


def test_unreadable_model_files(tmp_path):
    with pytest.raises(InputError, match="no such sensor model file"):
        load_sensor_model(tmp_path / "missing.yaml")
    with pytest.raises(InputError, match="not valid YAML") as exc:
        load_sensor_model_text(tmp_path, "format: [\n")
    assert exc.value.where is not None
    with pytest.raises(InputError, match="expected a mapping"):
        load_sensor_model_text(tmp_path, "- 1\n")
    with pytest.raises(InputError, match="sigma"):
        load_sensor_model_text(tmp_path, "format: slam2d-sensor-model\nversion: 1\nkind: constant\nsigma: -1\n")


def test_sensor_model_specs(tmp_path):
    assert isinstance(sensor_model_from_spec("study"), StudyModel)
    assert sensor_model_from_spec("constant:0.0041") == ConstantSigma(0.0041)
    assert sensor_model_from_spec("constant:0.005m") == ConstantSigma(0.005)
    for bad in ("constant:x", "constant:-1", "nothing-here.yaml"):
        with pytest.raises(InputError) as exc:
            sensor_model_from_spec(bad)
        assert exc.value.field == "--sensor-model"


def test_beam_sigmas_use_a_calibrated_model():
    from slam2d.core.scan import make_scan
    from slam2d.sensors.beam_model import beam_sigmas

    m = model_from_document(_doc(materials={}))
    angles = np.radians(np.linspace(-30, 30, 61))
    ranges = 2.0 / np.cos(angles)  # a wall square to the central beam, 2 m ahead
    scan = make_scan(0.0, ranges, angles[0], angles[1] - angles[0], 0.0, 10.0)
    s = beam_sigmas(scan, m, 0.05)
    inc = np.abs(angles)
    expected = m.sigma(ranges, inc, np.zeros(61, int))
    assert np.allclose(s, expected, rtol=1e-6, atol=1e-9)
    assert s[30] < s[0]  # square to the wall is the quietest beam


# --------------------------------------------------------------------------- calibration from data


@pytest.fixture(scope="module")
def study_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("rep")
    rows = repeated_measurements(["white-paper", "cardboard"], [1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0], [90, 45], 1000)
    return write_repeatability_csv(d / "repeatability.csv", rows)


def test_calibration_recovers_the_injected_model(study_csv):
    data = load_laser_data([study_csv])
    assert len(data.setups) == 28 and data.materials == ["white-paper", "cardboard"] and data.angles == [90.0, 45.0]
    cal = calibrate_laser(data)
    truth = StudyModel()
    doc = cal.model_document()
    model = model_from_document(doc)
    assert doc["kind"] == "range-incidence" and set(doc["materials"]) == {"white-paper", "cardboard"}
    d = np.linspace(1.0, 4.0, 31)
    for name in ("white-paper", "cardboard"):
        i = MATERIALS.index(name)
        for inc in (0.0, math.pi / 4):
            err = model.sigma(d, inc, i) / truth.sigma(d, np.full(31, inc), np.full(31, i)) - 1
            assert np.abs(err).max() < 0.08, (name, inc, err)  # 1000 readings: 2.2 % per set-up
    # Table I form: each surface's mean over the distances, against the truth's
    table = {r["material"]: r for r in cal.table()}
    grid = np.array([1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0])
    for name in ("white-paper", "cardboard"):
        i = MATERIALS.index(name)
        for angle, inc in ((90.0, 0.0), (45.0, math.pi / 4)):
            t = truth.sigma(grid, np.full(7, inc), np.full(7, i)).mean()
            assert table[name][angle] == pytest.approx(t, rel=0.03)
    ref = cal.sigma_at_reference()
    t = np.mean([truth.sigma(2.5, inc, MATERIALS.index(n)) for n in ("white-paper", "cardboard") for inc in (0, math.pi / 4)])
    assert ref["all"] == pytest.approx(t, rel=0.04)
    # the readings are Gaussian: every probability plot is straight
    assert min(s.normality() for s in data.setups) > 0.99
    for s in data.setups:
        lo, hi = s.interval()
        assert lo < s.sigma < hi


def test_one_angle_gives_a_range_model_and_a_fixed_degree(tmp_path):
    rows = repeated_measurements(["white-paper"], [1.0, 2.0, 3.0, 4.0], [90], 200)
    data = load_laser_data([write_repeatability_csv(tmp_path / "r.csv", rows)])
    cal = calibrate_laser(data, degree=5)
    doc = cal.model_document()
    assert doc["kind"] == "range" and len(doc["fits"]) == 1 and "incidence_deg" not in doc["fits"][0]
    assert cal.per_angle[90.0].fit.degree == 3 and "only 4 distances" in cal.per_angle[90.0].note
    assert "materials" not in doc
    m = model_from_document(doc)
    assert m.sigma(2.0, 0.0, 0) == m.sigma(2.0, 1.0, 0)  # no incidence dependence in a range model


def test_verify_band_share_tells_a_good_model_from_a_wrong_one(study_csv, tmp_path):
    cal = calibrate_laser(load_laser_data([study_csv]))
    model = model_from_document(cal.model_document())
    new = repeated_measurements(["white-paper", "cardboard"], [1.25, 2.25, 3.25], [90, 67.5, 45], 400, seed=7)
    data = load_laser_data([write_repeatability_csv(tmp_path / "new.csv", new)])
    good = verify_model(model, data)
    assert good.share_inside >= 0.8
    assert verify_model(StudyModel(), data).share_inside >= 0.8
    assert verify_model(ConstantSigma(0.0041), data).share_inside <= 0.4
    doubled = ConstantSigma(1.0)
    assert verify_model(doubled, data).share_inside == 0.0


def test_static_recording_gives_the_same_sigma_as_the_readings(tmp_path):
    setup = Setup("cardboard", 90.0, 2.0)
    log = write_setup_log(tmp_path / "plate.log.gz", setup, 300)
    data = load_laser_data([log])
    assert data.kind == "recording" and data.materials == ["scene"]
    near = [s for s in data.setups if abs(s.distance - 2.0) < 0.13 and s.angle_deg == 90.0]
    assert near, [(s.distance, s.angle_deg) for s in data.setups]
    truth = StudyModel().sigma(2.0, 0.0, MATERIALS.index("cardboard"))
    assert near[0].sigma == pytest.approx(truth, rel=0.1)
    assert near[0].beams > 5  # many beams pooled
    assert any("depth jump" in s for s in data.skipped)  # the plate's edges are left out


def test_cli_calibrates_from_static_recordings_and_refuses_a_moving_one(capsys, tmp_path):
    logs = [write_setup_log(tmp_path / f"plate-{d:g}m.log.gz", Setup("white-paper", 90.0, d), 200) for d in (1.0, 2.0, 3.0)]
    code, text, err = run(capsys, "calibrate", "laser", *logs, "--out", tmp_path / "cal")
    assert code == 0, err
    model = load_sensor_model(tmp_path / "cal" / "model.yaml")
    truth = StudyModel().sigma(2.0, 0.0, MATERIALS.index("white-paper"))
    assert model.sigma(2.0, 0.0, MATERIALS.index("white-paper")) == pytest.approx(truth, rel=0.15)
    assert "plate-2m" in (tmp_path / "cal" / "report.md").read_text()  # each recording is its own surface
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    write_outputs(simulate("paper-arena", SimulationParams(seed=2, duration=4.0)), tmp_path / "sim")
    code, _, err = run(capsys, "calibrate", "laser", tmp_path / "sim" / "recording.log.gz", "--out", tmp_path / "x")
    one_line_error(code, err, "the robot moved", "standing still")


# --------------------------------------------------------------------------- CLI


def test_cli_calibrate_laser_and_verify_end_to_end(capsys, study_csv, tmp_path):
    out = tmp_path / "cal"
    code, text, err = run(capsys, "calibrate", "laser", study_csv, "--out", out, "--reference-distance", "2")
    assert code == 0, err
    assert "sigma at 2 m" in text
    for name in ("model.yaml", "report.md", "report.html", "figures/fits.png", "figures/probability-cardboard.png"):
        assert (out / name).is_file(), name
    md = (out / "report.md").read_text()
    assert "Table I form" in md and "![" in md and "figures/fits.png" in md
    assert "data:image/png;base64," in (out / "report.html").read_text()
    # in a 1280 px browser: every picture loads, the page does not scroll sideways, no figure shrunk below half
    from tests import browser

    dom = browser.dump_dom(out / "report.html")
    loaded = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom)
    assert loaded and loaded.group(1) == loaded.group(2) and int(loaded.group(2)) >= 2
    assert int(re.search(r'data-page-overflow="(-?\d+)"', dom).group(1)) <= 0
    assert int(re.search(r'data-smallest-figure-scale="(\d+)"', dom).group(1)) >= 50
    model = load_sensor_model(out / "model.yaml")
    assert model.kind == "range-incidence"
    code, text, err = run(capsys, "calibrate", "verify", out / "model.yaml", study_csv, "--out", tmp_path / "ver")
    assert code == 0, err
    summary = json.loads((tmp_path / "ver" / "verification.json").read_text())
    assert summary["share_inside"] >= 0.9 and len(summary["setups"]) == 28
    assert (tmp_path / "ver" / "figures" / "verify.png").is_file()
    code, text, err = run(capsys, "calibrate", "verify", "constant:0.0041", study_csv, "--out", tmp_path / "v2")
    assert code == 0 and json.loads((tmp_path / "v2" / "verification.json").read_text())["share_inside"] < 0.5


HEADER = "material,angle_deg,distance_m,repetition,range_m\n"


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("", ["file is empty"]),
        (HEADER, ["no readings"]),
        ("material,angle_deg,distance_m,range_m\nwood,90,1,1.0\n", ["missing column(s) repetition", ":1"]),
        (HEADER + "wood,90,1,0,1.001\nwood,90,1,1,abc\n", [":3", "range_m", "'abc' is not a float"]),
        (HEADER + "wood,ninety,1,0,1.001\n", [":2", "angle_deg"]),
        (HEADER + "wood,90,1,0,1.0\n" * 3, ["no set-up has enough readings"]),
        (HEADER + "wood,120,1,0,1.0\n", ["angle_deg", "(0, 90]"]),
        (HEADER + "wood,90,-1,0,1.0\n", ["distance_m"]),
    ],
)
def test_cli_bad_csv(capsys, tmp_path, text, needles):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    code, _, err = run(capsys, "calibrate", "laser", path, "--out", tmp_path / "o")
    one_line_error(code, err, *needles)


def test_cli_bad_options(capsys, study_csv, tmp_path):
    o = tmp_path / "o"
    one_line_error(*run(capsys, "calibrate", "laser", study_csv, "--out", o, "--degree", "three")[::2], "--degree")
    one_line_error(*run(capsys, "calibrate", "laser", study_csv, "--out", o, "--reference-distance", "-1")[::2],
                   "--reference-distance")
    one_line_error(*run(capsys, "calibrate", "laser", tmp_path / "none.csv", "--out", o)[::2], "no such file")
    one_line_error(*run(capsys, "calibrate", "verify", "bogus", study_csv, "--out", o)[::2], "--sensor-model")
    one_line_error(*run(capsys, "calibrate", "verify", "study", study_csv, "--out", o, "--z", "0")[::2], "--z")


def test_run_records_the_sensor_model_and_repeats_it(capsys, tmp_path):
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    sim = simulate("paper-arena", SimulationParams(seed=1, duration=5.0))
    write_outputs(sim, tmp_path / "sim")
    log = tmp_path / "sim" / "recording.log.gz"
    model = tmp_path / "m.yaml"
    model.write_text(dump_model_yaml(_doc()))
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r1", "--sensor-model", model)
    assert code == 0, err
    rec = json.loads((tmp_path / "r1" / "run.json").read_text())["sensor_model"]
    assert rec["type"] == "file" and rec["kind"] == "range-incidence" and len(rec["sha256"]) == 64
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r2", "--params", tmp_path / "r1" / "run.json")
    assert code == 0, err
    assert json.loads((tmp_path / "r2" / "run.json").read_text())["sensor_model"] == rec
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r3", "--sensor-model", "constant:0.0041")
    assert json.loads((tmp_path / "r3" / "run.json").read_text())["sensor_model"]["sigma_m"] == 0.0041
    code, _, err = run(capsys, "run", "odometry", log, "--out", tmp_path / "r4")
    assert json.loads((tmp_path / "r4" / "run.json").read_text())["sensor_model"] is None
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(_doc(kind="polynomial")))
    one_line_error(*run(capsys, "run", "odometry", log, "--out", tmp_path / "r5", "--sensor-model", bad)[::2],
                   str(bad), "kind")


def test_methods_receive_the_model(tmp_path):
    from slam2d.methods.runner import build_method, run_method
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    slam = build_method("odometry", sensor_model="study")
    assert isinstance(slam.sensor_model, StudyModel)
    sim = simulate("paper-arena", SimulationParams(seed=1, duration=3.0))
    write_outputs(sim, tmp_path / "sim")
    from slam2d.eval.compare import compare

    cmp = compare(tmp_path / "sim" / "recording.log.gz", ["odometry"], tmp_path / "cmp", sensor_model="constant:0.007",
                  jobs=1)
    assert cmp.outcomes[0].ok
    rec = json.loads((tmp_path / "cmp" / "runs" / "odometry" / "run.json").read_text())
    assert rec["sensor_model"] == {"type": "constant", "spec": "constant:0.007", "sigma_m": 0.007}
    with pytest.raises(InputError, match="--sensor-model"):
        compare(tmp_path / "sim" / "recording.log.gz", ["odometry"], tmp_path / "c2", sensor_model="nope", jobs=1)
    summary = run_method("odometry", tmp_path / "sim" / "recording.log.gz", tmp_path / "r", sensor_model="study")
    assert summary.record["sensor_model"]["spec"] == "study"


# --------------------------------------------------------------------------- the target


@pytest.mark.slow
def test_target_sigma_within_5_percent_from_half_a_metre_to_four_for_every_surface(tmp_path, capsys):
    """The issue's target, through the commands: `slam2d repeatability` (the study model injected) at
    0.5-4 m every 0.25 m, 2000 readings per set-up, then `slam2d calibrate laser`; the model file's
    sigma(distance) for every surface at both angles is within 5 % of the truth over 0.5-4 m.

    Default settings: the degree is chosen by cross-validation. The study model below 1 m is its
    cubic's tangent, so over 0.5-4 m it is not a cubic (at 45 deg the best cubic is off by 4.3 % at
    the ends before any noise); with 15 distances cross-validation can and does choose a higher degree.
    """
    distances = ",".join(f"{d:g}" for d in np.arange(0.5, 4.01, 0.25))
    code, _, err = run(capsys, "repeatability", "--out", tmp_path / "rep", "--distances", distances,
                       "--repetitions", "2000", "--seed", "11")
    assert code == 0, err
    code, _, err = run(capsys, "calibrate", "laser", tmp_path / "rep" / "repeatability.csv", "--out", tmp_path / "cal")
    assert code == 0, err
    chosen = yaml.safe_load((tmp_path / "cal" / "model.yaml").read_text())["fits"]
    assert all(f["degree"] > 3 for f in chosen), [f["degree"] for f in chosen]  # cross-validation asked for more
    model = load_sensor_model(tmp_path / "cal" / "model.yaml")
    truth = StudyModel()
    d = np.linspace(0.5, 4.0, 71)
    worst = 0.0
    for i in range(len(MATERIALS)):
        for inc in (0.0, math.pi / 4):
            err = np.abs(model.sigma(d, inc, i) / truth.sigma(d, np.full(d.size, inc), np.full(d.size, i)) - 1)
            worst = max(worst, float(err.max()))
    assert worst < 0.05, worst


def test_one_distance_is_refused_naming_the_csv_not_the_model(tmp_path):
    rows = repeated_measurements(["white-paper", "cardboard"], [2.0], [90, 45], 50)
    csv = write_repeatability_csv(tmp_path / "one-distance.csv", rows)
    with pytest.raises(InputError, match="every set-up is at 2 m") as info:
        calibrate_laser(load_laser_data([csv]))
    assert info.value.path == str(csv) and info.value.field == "distance_m"


def test_bad_csv_values_are_shown_as_plain_numbers(tmp_path):
    rows = repeated_measurements(["white-paper"], [1.0, 2.0], [90], 5)
    csv = write_repeatability_csv(tmp_path / "r.csv", rows)
    lines = csv.read_text().splitlines()
    lines[3] = lines[3].replace(",90.0,", ",200.0,")
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        load_laser_data([csv])
    assert "200.0 is not an angle" in str(info.value) and "np.float64" not in str(info.value)


def test_repetitions_beyond_memory_are_refused_before_allocating():
    with pytest.raises(InputError, match="more than") as info:
        repeated_measurements(["white-paper"], [1.0, 2.0], [90], 100_000_000_000)
    assert info.value.field == "repetitions"


def test_a_csv_saved_with_a_byte_order_mark_reads_like_one_without(tmp_path):
    rows = repeated_measurements(["white-paper"], [1.0, 2.0], [90], 20)
    plain = write_repeatability_csv(tmp_path / "plain.csv", rows)
    bom = tmp_path / "bom.csv"  # as a spreadsheet saves "CSV UTF-8"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = load_laser_data([plain]), load_laser_data([bom])
    assert [(s.material, s.distance, s.sigma) for s in a.setups] == [(s.material, s.distance, s.sigma) for s in b.setups]
