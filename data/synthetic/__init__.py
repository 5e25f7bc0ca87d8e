"""Deterministic synthetic multi-view crowd scenes with ground truth (bodies, motion, rig, detections).

Layer 2: may import layers 1 and 2 (``data.*``); never the stages, ``evaluation`` or the entry points.
"""

from data.synthetic.config import SyntheticConfig
from data.synthetic.generate import build_rig, generate_sequence

__all__ = ["SyntheticConfig", "generate_sequence", "build_rig"]
