"""Tracking over frames (layer 3): persons keep an id across a sequence (``tracking.tracker``)."""

from tracking.tracker import Association, Tracker

__all__ = ["Association", "Tracker"]
