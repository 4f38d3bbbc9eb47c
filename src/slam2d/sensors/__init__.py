"""Sensor and motion models shared by the simulator and by calibration.

* :mod:`slam2d.sensors.range_noise` — how noisy a laser range is, as a function
  of distance, incidence angle and surface material (the source study's
  Hokuyo URG-04LX model), and how likely a beam is to return nothing.
* :mod:`slam2d.sensors.motion_noise` — odometry noise (GMapping's srr/srt/str/stt).
"""
