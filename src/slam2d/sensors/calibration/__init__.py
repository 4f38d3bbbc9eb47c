"""Calibration of the sensor and motion models from data.

* :mod:`~slam2d.sensors.calibration.laser` — repeated range measurements (a
  tidy CSV or a static recording) to a sigma table, fits of sigma against
  distance and a model file (``slam2d calibrate laser``), and checking a model
  on new data (``slam2d calibrate verify``);
* :mod:`~slam2d.sensors.calibration.model` — the model file and its loader;
* :mod:`~slam2d.sensors.calibration.odometry` — maximum-likelihood odometry
  noise (GMapping's srr, srt, str, stt) and scale errors against a reference
  trajectory (``slam2d calibrate odometry``);
* :mod:`~slam2d.sensors.calibration.odometry_lag` — how far the odometry leads
  (or lags) the scans in time, from the recording alone (``slam2d calibrate
  odometry-lag``; coreslam's ``odometry_delay``);
* :mod:`~slam2d.sensors.calibration.fits` — polynomial fits with the degree
  chosen by cross-validation.
"""
