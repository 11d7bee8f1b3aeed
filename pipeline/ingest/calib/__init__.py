"""Calibration of a recording: camera models and the rectifier, calibration over time,
the static TF tree."""
