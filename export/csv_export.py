"""CSV of all tracks, wide: one row per (frame, track id), columns frame, time, id, then <joint>_x/_y/_z/_score.

Our world as in poses3d.json (metres, z up); time = frame / fps. A row per frame where the track is in the file
(with --fill also per frame where a joint was filled); a missing joint has empty x, y, z and score 0, a filled one
its interpolated x, y, z and score 0.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.keypoints import COCO23_NAMES
from export.tracks import Track

COLUMNS = ("frame", "time", "id", *(f"{n}_{c}" for n in COCO23_NAMES for c in ("x", "y", "z", "score")))


def csv_text(tracks: list[Track], fps: float) -> str:
    """The CSV of tracks, rows sorted by frame then id."""
    rows = []
    for t in tracks:
        keep = t.present | np.isfinite(t.xyz).all(axis=-1).any(axis=1)
        for k in np.flatnonzero(keep):
            xyz = [[f"{v:.6f}" if np.isfinite(v) else "" for v in joint] for joint in t.xyz[k]]
            joints = (c for x, s in zip(xyz, t.score[k]) for c in (*x, f"{s:.6g}"))
            rows.append([int(t.frames[k]), f"{t.frames[k] / fps:.6f}", t.id, *joints])
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerows([COLUMNS, *sorted(rows, key=lambda r: (r[0], r[2]))])
    return buffer.getvalue()


def write_csv(tracks: list[Track], base: Path, fps: float) -> list[str]:
    """<base>.csv with every track; one line."""
    path = base.with_name(base.name + ".csv")
    text = csv_text(tracks, fps)
    atomic_write_text(path, text)
    return [f"wrote {path}: {text.count(chr(10)) - 1} rows of {len(tracks)} track(s)"]
