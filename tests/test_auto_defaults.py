"""``auto`` defaults: parameters resolved from the recording before the run (params.py, recording_profile.py)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest

from _room import frame, room_scan
from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.params import AUTO, describe, from_mapping, markdown_table, param
from slam2d.sensors.recording_profile import measure_profile


@dataclass
class _Demo:
    noise: float = param(0.2, unit="rad/m", low=0.0, help="a noise", auto="the recording")
    plain: float = param(1.0, help="not auto")


def test_an_auto_parameter_defaults_to_auto_and_takes_values():
    assert _Demo().noise == AUTO
    info = {p.name: p for p in describe(_Demo)}
    assert info["noise"].auto == "the recording" and info["noise"].fallback == 0.2
    assert info["plain"].auto is None and info["plain"].fallback == 1.0
    assert from_mapping(_Demo, {"noise": "0.05"}).noise == 0.05
    assert from_mapping(_Demo, {"noise": "auto"}).noise == AUTO
    with pytest.raises(InputError, match="below the minimum"):
        from_mapping(_Demo, {"noise": "-1"})
    with pytest.raises(InputError, match="not a valid float"):
        from_mapping(_Demo, {"plain": "auto"})  # only auto parameters take it
    table = markdown_table(_Demo, names="settings")
    assert "`auto`: from the recording; `0.2` when the recording cannot tell" in table


def _room_frames(noise_per_m=0.0, noise_per_rad=0.0, seed=0, steps=60):
    """A walk round the room with odometry whose heading drifts by the given noise (GMapping's model)."""
    rng = np.random.default_rng(seed)
    poses, frames = [], []
    true = np.array([-1.5, -0.8, 0.0])
    odom = true.copy()
    for k in range(steps):
        phase = k % 20
        step = np.array([0.3, 0.0, 0.0]) if phase < 12 else np.array([0.0, 0.0, math.radians(20.0)])
        if phase == 11:  # back to the start of the lap so the walk stays inside the room
            step = se2.relative(true, np.array([-1.5, -0.8, true[2]]))
        d = math.hypot(step[0], step[1])
        sigma = noise_per_m * d + noise_per_rad * abs(step[2])
        noisy = step + np.array([0.0, 0.0, rng.normal(0.0, sigma) if sigma > 0 else 0.0])
        true = se2.compose(true, step)
        odom = se2.compose(odom, noisy)
        poses.append(true)
        frames.append(frame(room_scan(true, t=float(k)), odom, index=k))
    return frames


def test_the_profile_measures_the_recording():
    p = measure_profile(_room_frames())
    assert p.scans == 60 and p.beams == 361 and p.has_odometry
    assert p.field_of_view == pytest.approx(math.radians(240), rel=1e-6)
    assert p.step_m is not None and p.step_m > 0.1
    assert p.pairs >= 12 and p.odometry_gaps == 0
    # exact odometry: what is measured is the registration's own error, under a hundredth
    assert p.odometry_heading_per_m < 0.02 and p.odometry_heading_per_rad < 0.02
    noisy = measure_profile(_room_frames(noise_per_m=0.0, noise_per_rad=0.15, seed=2))
    assert noisy.odometry_heading_per_rad > 0.06  # the noise is seen, in the term it is in


def test_one_scan_or_no_motion_cannot_tell():
    single = measure_profile(_room_frames()[:1])
    assert single.step_m is None and single.odometry_heading_per_m is None
    assert any("single scan" in n for n in single.notes)
    still = [frame(room_scan(np.zeros(3), t=float(k)), np.zeros(3), index=k) for k in range(30)]
    p = measure_profile(still)
    assert p.step_m == 0.0 and p.odometry_heading_per_m is None
    assert any("scan pairs" in n for n in p.notes)
    no_odometry = measure_profile([frame(room_scan(np.zeros(3), t=float(k)), None, index=k) for k in range(5)])
    assert not no_odometry.has_odometry and any("no odometry" in n for n in no_odometry.notes)
    assert measure_profile([]) is None


def test_gmapping_resolves_from_the_recording_and_an_explicit_value_wins():
    from slam2d.methods.runner import build_method, build_method_for

    frames = _room_frames(noise_per_rad=0.15, seed=2, steps=120)[::3]  # about a scan every 0.9 m or 60 deg
    slam = build_method_for("gmapping", frames)
    assert set(slam.auto) == {"srt", "stt", "between_updates"}
    assert slam.params.stt == slam.auto["stt"]["value"] and slam.params.stt != AUTO
    assert "scan pairs" in slam.auto["stt"]["from"]
    # about a scan an update (a metre or half a radian), so not guided
    assert slam.params.between_updates == "matched"
    chosen = build_method_for("gmapping", frames, settings={"stt": "0.11"})
    assert chosen.params.stt == 0.11 and "stt" not in chosen.auto
    # built with no recording (a live feed): the original's defaults, and it says why
    live = build_method("gmapping")
    assert live.params.srt == 0.2 and live.params.between_updates == "matched"
    assert "not measured" in live.auto["srt"]["from"]


def test_dense_recordings_with_a_long_range_laser_are_guided():
    from slam2d.methods.gmapping import GMapping, GMappingParams
    from slam2d.methods.runner import build_method_for
    from slam2d.sensors.recording_profile import RecordingProfile

    frames = _room_frames(steps=60)
    dense = []
    for k, f in enumerate(frames[:-1]):  # ten scans between each pair of the walk's poses
        a, b = f.odometry, frames[k + 1].odometry
        for j in range(10):
            pose = se2.compose(a, se2.relative(a, b) * (j / 10.0))
            dense.append(frame(room_scan(pose, t=k + j / 10.0), pose, index=len(dense)))
    # the room's walls are all within 7 m: a short reach, so matched however dense
    slam = build_method_for("gmapping", dense)
    assert slam.params.between_updates == "matched"
    assert "scans per filter update" in slam.auto["between_updates"]["from"]
    assert "laser reach" in slam.auto["between_updates"]["from"]

    def profile(step_m, reach):
        return RecordingProfile(scans=100, beams=360, field_of_view=math.pi, angular_resolution=math.pi / 360,
                                range_max=80.0, longest_return=reach, rate_hz=4.0, has_odometry=True,
                                step_m=step_m, step_rad=0.0, pairs=50, odometry_heading_per_m=0.1,
                                odometry_heading_per_rad=0.1)

    resolved = GMapping.auto_values(GMappingParams(), profile(0.1, 13.0))  # fr079: 0.1 m a scan, 13 m reach
    assert resolved["between_updates"][0] == "guided" and resolved["srt"][0] == 0.1
    resolved = GMapping.auto_values(GMappingParams(), profile(0.1, 5.0))  # a URG-04LX, as dense
    assert resolved["between_updates"][0] == "matched" and resolved["srt"][0] == 0.1
    resolved = GMapping.auto_values(GMappingParams(), profile(1.0, 13.0))  # a scan a metre
    assert resolved["between_updates"][0] == "matched"
    # an explicit between_updates is kept
    resolved = GMapping.auto_values(GMappingParams(between_updates="guided"), profile(1.0, 13.0))
    assert "between_updates" not in resolved and resolved["stt"][0] == 0.1


def test_a_one_scan_recording_runs_with_the_originals_defaults_and_says_so(tmp_path, capsys):
    from slam2d.cli import main
    from slam2d.io.carmen import write_carmen

    log = tmp_path / "one.log"
    write_carmen(log, _room_frames()[:1])
    assert main(["run", "gmapping", str(log), "--out", str(tmp_path / "run")]) == 0
    printed = capsys.readouterr().out
    assert "auto srt = 0.2: the original's default" in printed
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["params"]["srt"] == 0.2 and record["auto"]["srt"]["value"] == 0.2
    assert "single scan" in record["auto"]["srt"]["from"]
    # a value given on the command line is not auto
    assert main(["run", "gmapping", str(log), "--out", str(tmp_path / "run2"), "--set", "srt=0.07"]) == 0
    record = json.loads((tmp_path / "run2" / "run.json").read_text())
    assert record["params"]["srt"] == 0.07 and "srt" not in record["auto"]
