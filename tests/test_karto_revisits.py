"""Driving an area again and again: the graph grows with the area, not with the scans (revisit_without_nodes).

The first half of the intel log is driven forwards, backwards, forwards (as ``benchmarks/memory.py`` repeats a log). Once two
older passes are connected at a place, a kept scan within the travel gate of one of their nodes adds no node
(a revisit frame): the third pass adds almost none, and every pass's frames stay on the reference.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from slam2d.core.frames import Frame
from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
from slam2d.methods import get_method
from slam2d.params import from_mapping

from tests.conftest import dataset_file


def _repeated(frames, times):
    """``frames`` played forwards, backwards, forwards... ``times`` passes (as memory.py), and each frame's source index."""
    t = [f.timestamp for f in frames]
    step = (t[-1] - t[0]) / max(1, len(t) - 1)
    out, source, clock = [], [], t[0]
    for k in range(times):
        order = range(len(frames)) if k % 2 == 0 else range(len(frames) - 1, -1, -1)
        first = frames[order[0]].timestamp
        for i in order:
            f = frames[i]
            out.append(Frame(len(out), replace(f.scan, timestamp=clock + abs(f.timestamp - first)), f.odometry))
            source.append(i)
        clock = out[-1].timestamp + step
    return out, np.asarray(source)


def _run(frames, **settings):
    # The odometry gap guard is off: with a forward-looking laser a scan taken a metre behind the last one
    # (the backward passes) fits it poorly, and the guard then takes correct odometry for a missed shift
    # (60 "recoveries" per backward pass on intel), which tears the passes apart.
    settings.setdefault("odometry_gap_check", False)
    cls = get_method("karto")
    return cls(from_mapping(cls.Params, settings), seed=0).run(frames)


@pytest.fixture(scope="module")
def intel():
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    frames = list(open_recording(dataset_file("intel/intel.clf.gz")).frames())[:450]  # the first half: 20 minutes
    return frames, read_tum(dataset_file("intel/reference.tum"))


@pytest.fixture(scope="module")
def once(intel):
    return _run(intel[0])


@pytest.fixture(scope="module")
def thrice(intel):
    three, source = _repeated(intel[0], 3)
    return _run(three), source


def test_a_repeated_drive_adds_nodes_for_the_area_not_the_scans(intel, once, thrice):
    frames, (rt, rp) = intel
    slam, source = thrice
    assert slam.params.revisit_without_nodes
    n1, n3 = once.frontend.num_nodes, slam.frontend.num_nodes
    # Karto adds a node per kept scan (nearly every scan); the repeated passes add a fraction of that
    assert n3 < 1.5 * n1, (n1, n3)
    assert slam.diagnostics.counters["revisit_frames"] > 0.7 * len(frames)
    # every pass's frames, revisit frames included, stay on the reference (the frame's source scan's time)
    t, p = slam.trajectory()
    q = len(frames)
    src_t = np.array([frames[i].timestamp for i in source])
    ate = []
    for k in range(3):
        part = slice(k * q, (k + 1) * q)
        ate.append(absolute_trajectory_error(associate(src_t[part], p[part], rt, rp))["translation_m"]["rmse"])
    assert max(ate) < 0.10, ate
    # the map holds the whole area
    assert slam.map().occupied().sum() >= 0.95 * once.map().occupied().sum()


def test_revisit_frames_hang_from_old_nodes(thrice):
    slam, _ = thrice
    fe = slam.frontend
    revisit = np.asarray(slam._revisit)
    anchors = np.asarray(slam._anchor)
    assert revisit.sum() > 100
    # a revisit frame hangs from an old node; the node after a revisit stretch has its sequential edge from
    # the old node the robot hung from
    assert np.all(anchors[revisit] < fe.num_nodes)
    jumps = [node for node in range(1, fe.num_nodes) if fe._pred[node] != node - 1]
    assert jumps
    for node in range(1, fe.num_nodes):
        assert fe._has_edge(fe._pred[node], node)
    t, p = slam.trajectory()
    assert len(t) == len(slam._anchor) and np.all(np.isfinite(p))


@pytest.mark.slow
def test_without_it_every_pass_adds_its_nodes(intel, once):
    frames, _ = intel
    two, _ = _repeated(frames, 2)
    every = _run(two, revisit_without_nodes=False)
    assert every.frontend.num_nodes > 1.9 * once.frontend.num_nodes
    assert "revisit_frames" not in every.diagnostics.counters
