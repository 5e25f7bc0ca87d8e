"""The tracks' ground trajectories seen from above (matplotlib); colours as in the HTML viewer."""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from data.formats.atomic_io import atomic_write_bytes
from data.geometry.camera import Rig
from evaluation.pictures.sequence_data import SequenceFrame, id_colors, pose_roots, sequence_frames

FIGSIZE_IN = (10.0, 8.0)
DPI = 100  # the PNG is FIGSIZE_IN * DPI pixels: (1000, 800)
START_MARKER, END_MARKER = "o", "s"
START_SIZE, END_SIZE = 10.0, 5.0  # points
START = dict(marker=START_MARKER, markersize=START_SIZE, markerfacecolor="none")  # a ring
ARROW_FRACTION = 0.06  # a camera's viewing-direction arrow, as a fraction of the plot's extent
LEGEND_ROWS = 30  # legend entries per column


def ground_tracks(frames: list[SequenceFrame]) -> dict[int, np.ndarray]:
    """Each id's root on the ground per frame of the sequence: {id: (F, 2) x, y, NaN where absent}."""
    tracks: dict[int, np.ndarray] = {}
    for f, frame in enumerate(frames):
        for i, root in zip(frame.ids, pose_roots(frame.poses)):
            tracks.setdefault(int(i), np.full((len(frames), 2), np.nan))[f] = root[:2]
    return tracks


def trajectories_figure(frames: Iterable[tuple], rig: Rig, title: str = "") -> Figure:
    """Top view of (frame, poses (P, 23, 4), ids (P,) or None) tuples: a path per id, its start and end, cameras."""
    seq, tracked = sequence_frames(frames)
    tracks = ground_tracks(seq)
    colors = id_colors(tracks)
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    ax = fig.add_axes((0.08, 0.08, 0.72, 0.84))
    for i, xy in tracks.items():
        seen = np.flatnonzero(np.isfinite(xy).all(axis=1))
        if not len(seen):
            continue
        if tracked:
            ax.plot(*xy.T, color=colors[i], linewidth=1.5)  # NaN rows break the line
        else:  # an id is an index in each frame: joining them would join different persons
            ax.plot(*xy.T, color=colors[i], marker=".", markersize=3, linestyle="none")
        ax.plot(*xy[seen[-1]], marker=END_MARKER, color=colors[i], markersize=END_SIZE, linestyle="none")
        ax.plot(*xy[seen[0]], color=colors[i], linestyle="none", **START)  # a ring over the end: both show
        ax.annotate(str(i), xy[seen[-1]], xytext=(4, 4), textcoords="offset points", fontsize=7, color=colors[i])
    _draw_cameras(ax, rig, tracks)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)")
    kind = "tracks" if tracked else "per-frame ids (tracking off)"
    ax.set_title(title or f"ground trajectories of the root (mid-hip), {len(tracks)} {kind}, {len(seq)} frames")
    _legend(fig, tracks, colors)
    return fig


def _draw_cameras(ax: Any, rig: Rig, tracks: dict[int, np.ndarray]) -> None:
    """Each camera as a named triangle with an arrow along its viewing direction, scaled to the plot's extent."""
    tracked = [xy[np.isfinite(xy).all(axis=1)] for xy in tracks.values()]
    points = np.concatenate([np.zeros((1, 2)), *tracked, *(c.center[None, :2] for c in rig)])
    arrow = ARROW_FRACTION * max(float(np.ptp(points, axis=0).max()), 1.0)
    for cam in rig:
        c, axis = cam.center, cam.R[2]  # the optical axis in the world
        ax.plot(*c[:2], marker="^", color="black", markersize=7, linestyle="none")
        heading = axis[:2] / max(float(np.linalg.norm(axis[:2])), 1e-9)
        ax.annotate("", c[:2] + arrow * heading, c[:2], arrowprops=dict(arrowstyle="->", color="black"))
        ax.annotate(cam.name, c[:2], xytext=(5, -10), textcoords="offset points", fontsize=8)


def _legend(fig: Figure, tracks: dict[int, np.ndarray], colors: dict) -> None:
    """The legend right of the plot: start, end, camera, then one entry per id."""
    black = dict(color="black", linestyle="none")
    handles = [
        Line2D([], [], label="start", **black, **START),
        Line2D([], [], marker=END_MARKER, markersize=END_SIZE, label="end", **black),
        Line2D([], [], marker="^", label="camera", **black),
    ]
    handles += [Line2D([], [], color=colors[i], linewidth=2, label=f"id {i}") for i in tracks]
    columns = math.ceil(len(handles) / LEGEND_ROWS)
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.82, 0.92), fontsize=7, ncol=columns, frameon=False)


def plot_trajectories(path: str | Path, frames: Iterable[tuple], rig: Rig, title: str = "") -> Path:
    """Write the top view of the tracks (see :func:`trajectories_figure`) as a PNG atomically -> path."""
    buf = io.BytesIO()
    trajectories_figure(frames, rig, title).savefig(buf, format="png", dpi=DPI)  # fixed size: no tight bbox
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)
