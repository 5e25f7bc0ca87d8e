"""Tracking over frames (layer 3): persons keep an id across a sequence (``tracking.tracker``; the identity metrics
are in ``evaluation.identity``). May import ``data`` and the other stages; never ``evaluation`` or the entry points."""

from tracking.tracker import Association, Tracker

__all__ = ["Association", "Tracker"]
