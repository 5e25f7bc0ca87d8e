"""TRC per track (OpenSim's marker file, laid out as Pose2Sim writes it): tab-separated, metres, Y up.

Five header lines (PathFileType 4 (X/Y/Z) <file name>; the DataRate ... OrigNumFrames keys; their values, Units
m, OrigDataStartFrame the first frame number; Frame#, Time and the 23 COCO-23 marker names, each over its three
columns; X1 Y1 Z1 ... Z23), a blank line, then one row per frame of the file's grid (export/tracks.py): the frame
number, time = frame / fps, and (X, Y, Z) = (y, z, x) of our z-up world per marker. Every value ends with a tab
(OpenSim's own layout), so a missing marker is three empty fields, which OpenSim reads as NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.keypoints import COCO23_NAMES
from export.tracks import Track, to_y_up, track_path

HEADER_KEYS = "DataRate CameraRate NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames"


def trc_text(track: Track, name: str, fps: float) -> str:
    """The TRC file of one track (T frames x 23 markers) named name."""
    rate, count = f"{fps / track.step:g}", len(track.frames)
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{name}", HEADER_KEYS.replace(" ", "\t")]
    lines.append("\t".join(map(str, [rate, rate, count, len(COCO23_NAMES), "m", rate, track.frames[0], count])))
    lines.append("Frame#\tTime\t" + "".join(f"{n}\t\t\t" for n in COCO23_NAMES))
    lines += ["\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, len(COCO23_NAMES) + 1)), ""]
    values = to_y_up(track.xyz).reshape(count, -1)
    for frame, row in zip(track.frames, values):
        cells = "".join(f"{v:.6f}\t" if np.isfinite(v) else "\t" for v in row)
        lines.append(f"{frame}\t{frame / fps:.6f}\t{cells}")
    return "\n".join(lines) + "\n"


def write_trc(tracks: list[Track], base: Path, fps: float) -> list[str]:
    """<base>_id<k>.trc per track; one line per file."""
    out = []
    for track in tracks:
        path = track_path(base, track, "trc")
        atomic_write_text(path, trc_text(track, path.name, fps))
        out.append(f"wrote {path}: {len(track.frames)} frames of 23 markers")
    return out
