"""Matplotlib figures (no pyplot) of one frame: the 3D scene, the top view and the feet on the ground plane."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from data.geometry.camera import Rig
from data.keypoints import LIMBS
from data.multiview import ViewDetections
from evaluation.pictures.vis_draw import UNMATCHED_COLOR, person_colors
from reconstruction.matching.feet import FeetFeatures

CAMERA_MARKERS = ("o", "s", "D", "v", "P", "<", ">", "h", "p", "d", "8", "H")  # "^" = camera centre
GT_STYLE = dict(color="black", linestyle="--", linewidth=1.0, alpha=0.8)


def _limb_segments(pose: np.ndarray) -> list[np.ndarray]:
    """Limbs of one pose whose both joints have score > 0: pose (J, 4) -> list of (2, 3)."""
    pose = np.asarray(pose, dtype=np.float64)
    ok = (pose[:, 3] > 0) & np.isfinite(pose).all(axis=1)
    return [pose[[a, b], :3] for a, b in LIMBS if ok[a] and ok[b]]


def _draw_poses(ax, poses: np.ndarray | None, dims: int, colors=None, style=None) -> None:
    """Limbs of (P, J, 4) poses on a 2D (x, y) or 3D axis: per-person colours, or one style (GT)."""
    if poses is None:
        return
    for p, pose in enumerate(np.asarray(poses, dtype=np.float64)):
        kw = dict(style) if style else dict(color=colors[p], linewidth=2.0)
        for seg in _limb_segments(pose):
            ax.plot(*seg[:, :dims].T, **kw)


def _camera_centres(ax, rig: Rig | None, dims: int) -> None:
    """Camera centres as small black triangles, named."""
    if rig is None:
        return
    for cam in rig:
        c = cam.center
        ax.plot(*c[:dims, None], marker="^", color="black", markersize=6, linestyle="none")
        ax.text(*c[:dims], f" {cam.name}", fontsize=7)


def _marker(marker: str, color, label: str, **style) -> Line2D:
    """A legend entry of a marker without a line."""
    return Line2D([], [], marker=marker, color=color, linestyle="none", label=label, **style)


def _legend_handles(num: int, gt: bool) -> list[Line2D]:
    """Legend entries: one per estimated person, one for the ground truth."""
    handles = [Line2D([], [], color=c, linewidth=2, label=f"person {p}") for p, c in enumerate(person_colors(num))]
    return handles + ([Line2D([], [], label="ground truth", **GT_STYLE)] if gt else [])


def _equal_3d(ax, points: np.ndarray) -> None:
    """One scale on the three axes around the points (N, 3), the ground z = 0 included."""
    lo, hi = np.minimum(points.min(axis=0), 0.0), points.max(axis=0)
    half = max(float((hi[:2] - lo[:2]).max()) / 2, 1.0)
    centre = (lo[:2] + hi[:2]) / 2
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(lo[2], max(hi[2], lo[2] + 0.5))
    ax.set_box_aspect((2 * half, 2 * half, max(hi[2], lo[2] + 0.5) - lo[2]))


def _scene_points(poses3d, gt_poses, rig) -> np.ndarray:
    """Every drawn point: joints with score > 0 and camera centres -> (N, 3)."""
    pts = [np.zeros((1, 3))]
    for poses in (poses3d, gt_poses):
        if poses is not None and len(poses):
            arr = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
            pts.append(arr[(arr[:, 3] > 0) & np.isfinite(arr).all(axis=1), :3])
    if rig is not None:
        pts.append(np.stack([c.center for c in rig]))
    return np.concatenate(pts)


def _poses_figure(poses3d: np.ndarray, gt_poses: np.ndarray | None, rig: Rig | None, dims: int) -> tuple[Figure, Any]:
    """A figure whose 3D (dims 3) or top-view (dims 2) axis shows estimates (P, J, 4), GT (G, J, 4) and cameras."""
    fig = Figure(figsize=(9, 8), dpi=100)
    ax = fig.add_subplot(projection="3d" if dims == 3 else None)
    _draw_poses(ax, gt_poses, dims, style=GT_STYLE)
    _draw_poses(ax, poses3d, dims, colors=person_colors(len(poses3d)))
    _camera_centres(ax, rig, dims)
    return fig, ax


def _ground_axes(ax: Any) -> None:
    """Equal x-y scale, a light grid and the metre labels of a top view."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)")


def plot_scene_3d(
    poses3d: np.ndarray, gt_poses: np.ndarray | None = None, rig: Rig | None = None, title: str = ""
) -> Figure:
    """Estimates (P, J, 4) solid per person beside ground truth (G, J, 4) dashed, cameras as markers."""
    fig, ax = _poses_figure(poses3d, gt_poses, rig, 3)
    _equal_3d(ax, _scene_points(poses3d, gt_poses, rig))
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.set_zlabel("z (m)")
    ax.view_init(elev=25, azim=-60)
    ax.set_title(title or f"{len(poses3d)} estimated persons")
    ax.legend(handles=_legend_handles(len(poses3d), gt_poses is not None), fontsize=7, loc="upper left")
    return fig


def plot_top_view(
    poses3d: np.ndarray, gt_poses: np.ndarray | None = None, rig: Rig | None = None, title: str = ""
) -> Figure:
    """The x-y ground plane seen from above: estimates (P, J, 4), ground truth (G, J, 4), cameras."""
    fig, ax = _poses_figure(poses3d, gt_poses, rig, 2)
    _ground_axes(ax)
    ax.set_title(title or f"top view: {len(poses3d)} estimated persons")
    ax.legend(handles=_legend_handles(len(poses3d), gt_poses is not None), fontsize=7, loc="best")
    return fig


def feet_owner(assignment: np.ndarray, view: int, num_detections: int) -> np.ndarray:
    """Person of each detection of one view from the (P, V) assignment: -> (N,) person index or -1."""
    owner = np.full(num_detections, -1, dtype=np.int64)
    for p, det in enumerate(np.asarray(assignment, dtype=np.int64)[:, view]):
        if det >= 0:
            owner[det] = p
    return owner


def plot_feet_on_ground(
    views: list[ViewDetections], rig: Rig, assignment: np.ndarray, features: list[FeetFeatures], title: str = ""
) -> Figure:
    """Each detection's feet location on z = 0, coloured by its person in the (P, V) assignment (unmatched: grey)."""
    if not len(views) == len(features) == len(rig) or any(len(d) != len(f) for d, f in zip(views, features)):
        raise ValueError("views, features and rig must agree: one FeetFeatures per view, one row per detection")
    assignment = np.asarray(assignment, dtype=np.int64).reshape(-1, len(rig))
    colors = person_colors(len(assignment))
    fig = Figure(figsize=(9, 8), dpi=100)
    ax = fig.add_subplot()
    missing = 0
    for v, feats in enumerate(features):
        owner = feet_owner(assignment, v, len(feats))
        marker = CAMERA_MARKERS[v % len(CAMERA_MARKERS)]
        missing += int((~feats.has_p).sum())
        for n in np.flatnonzero(feats.has_p):
            color = colors[owner[n]] if owner[n] >= 0 else UNMATCHED_COLOR
            if feats.has_stride[n]:
                ax.plot(*np.stack([feats.left[n], feats.right[n]]).T, color=color, linewidth=0.6, alpha=0.6)
            matched = owner[n] >= 0
            style = dict(marker=marker, markerfacecolor="none") if matched else dict(marker="x", markerfacecolor=color)
            ax.plot(*feats.p[n], color=color, markersize=7, linestyle="none", **style)
    _camera_centres(ax, rig, 2)
    markers = [CAMERA_MARKERS[v % len(CAMERA_MARKERS)] for v in range(len(rig))]
    handles = [_marker(m, "black", f"camera {name}", markerfacecolor="none") for m, name in zip(markers, rig.names)]
    handles += [_marker("s", c, f"person {p}") for p, c in enumerate(colors)]
    handles.append(_marker("x", UNMATCHED_COLOR, "unmatched"))
    ax.legend(handles=handles, fontsize=7, loc="best", ncol=2)
    _ground_axes(ax)
    ax.set_title((title or "feet on the ground plane") + (f" ({missing} detections without feet)" if missing else ""))
    return fig
