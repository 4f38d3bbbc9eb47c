"""Sensor and motion models shared by the simulator and by calibration.

* :mod:`slam2d.sensors.range_noise` — how noisy a laser range is, as a function
  of distance, incidence angle and surface material (the source study's
  Hokuyo URG-04LX model), and how likely a beam is to return nothing.
* :mod:`slam2d.sensors.motion_noise` — odometry noise (GMapping's srr/srt/str/stt).
* :mod:`slam2d.sensors.beam_model` — the per-beam sigma every method takes from a model.
* :mod:`slam2d.sensors.calibration` — both models estimated from data, and the
  sensor model file: :func:`load_sensor_model` reads one.
"""

from __future__ import annotations

from typing import Any

__all__ = ["load_sensor_model"]


def load_sensor_model(path: Any) -> Any:
    """The range noise model in a sensor model file (YAML): an object with ``sigma(distance, incidence, material)``.

    A wrong file raises :class:`~slam2d.errors.InputError` naming the file and the field.
    See :mod:`slam2d.sensors.calibration.model` for the format.
    """
    from slam2d.sensors.calibration.model import load_sensor_model as load

    return load(path)
