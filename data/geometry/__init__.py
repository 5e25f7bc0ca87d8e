"""Geometry (layer 1): cameras and rigs, calibration formats, the rig check, DLT triangulation, 3x3 inverses."""
