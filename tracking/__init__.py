"""Tracking over frames (layer 3): persons keep an id across a sequence (the stage after reconstruction).

``tracking.tracker`` holds the online tracker (constant-velocity Kalman filter per joint, Hungarian
association on a gated 3D distance, track birth and death, each track's bone lengths); the identity
metrics against ground-truth ids are in ``evaluation.identity``. May import ``data`` (layers 1-2) and
the other stages; never ``evaluation`` or the entry points.
"""

from tracking.tracker import Track, Tracker

__all__ = ["Track", "Tracker"]
