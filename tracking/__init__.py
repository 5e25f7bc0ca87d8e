"""Tracking over frames: persons keep an id across a sequence (the stage after reconstruction).

``tracking.tracker`` holds the online tracker (constant-velocity Kalman filter per joint, Hungarian
association on a gated 3D distance, track birth and death, each track's bone lengths);
``evaluation.identity`` the identity metrics against ground-truth ids. May import ``data`` (keypoint and
bone metadata) and numpy / scipy; nothing imports upwards from here but the pipeline and evaluation.
"""
from tracking.tracker import Track, Tracker

__all__ = ["Track", "Tracker"]
