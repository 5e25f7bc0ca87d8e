"""Deterministic synthetic multi-view crowd scenes with ground truth (bodies, motion, rig, detections); layer 2."""

from data.synthetic.config import SyntheticConfig
from data.synthetic.generate import build_rig, generate_sequence

__all__ = ["SyntheticConfig", "generate_sequence", "build_rig"]
