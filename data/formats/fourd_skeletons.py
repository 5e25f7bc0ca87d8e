"""Shelf benchmark files of the 4D Association repository (see ../shared/data/PROVENANCE.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def load_4dassoc_skeletons(path: str | Path) -> list[dict[int, np.ndarray]]:
    """gt.txt / skel.txt -> per frame of the file {actor id: (J, 4) x, y, z (m), valid}."""
    path = Path(path)
    try:
        tokens = path.read_text().split()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read skeleton file ({exc})") from None
    pos = 0

    def take(n: int, what: str) -> np.ndarray:
        """The next n numbers of the file: (n,)."""
        nonlocal pos
        if pos + n > len(tokens):
            raise ValueError(f"{path}: file ends while reading {what}")
        try:
            values = np.array(tokens[pos : pos + n], dtype=np.float64)
        except ValueError:
            raise ValueError(f"{path}: non-numeric value while reading {what}") from None
        pos += n
        return values

    num_joints, num_frames = (int(v) for v in take(2, "the header 'joints frames'"))
    frames: list[dict[int, np.ndarray]] = []
    for f in range(num_frames):
        persons: dict[int, np.ndarray] = {}
        for _ in range(int(take(1, f"the person count of frame {f}")[0])):
            actor = int(take(1, f"an actor id of frame {f}")[0])
            persons[actor] = take(4 * num_joints, f"actor {actor} of frame {f}").reshape(4, num_joints).T.copy()
        frames.append(persons)
    if pos != len(tokens):
        raise ValueError(f"{path}: {len(tokens) - pos} numbers left after {num_frames} frames")
    return frames
