"""Pictures of one reconstructed frame: reprojections over the camera images, 3D scene, top view, feet."""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure

from data.formats.atomic_io import atomic_write_bytes
from data.multiview import Frame, Sequence
from evaluation.pictures.vis_draw import draw_reprojections, image_grid, load_view_images
from evaluation.pictures.vis_plots import plot_feet_on_ground, plot_scene_3d, plot_top_view
from reconstruction.matching.feet import FeetMatcher
from reconstruction.pipeline import FrameResult


def write_png(path: str | Path, data: bytes) -> Path:
    """Write encoded PNG bytes atomically (data.formats.atomic_io)."""
    atomic_write_bytes(path, data)
    return Path(path)


def figure_png(fig: Figure) -> bytes:
    """A matplotlib figure encoded as PNG."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    return buf.getvalue()


def image_png(image: np.ndarray) -> bytes:
    """An RGB image (H, W, 3) uint8 encoded as PNG."""
    ok, data = cv2.imencode(".png", cv2.cvtColor(np.asarray(image, dtype=np.uint8), cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError("PNG encoding failed")
    return data.tobytes()


def save_frame_pictures(
    out_dir: str | Path,
    sequence: Sequence,
    result: FrameResult,
    frame: Frame,
    images: list[np.ndarray | None] | None = None,
    image_scale: list[tuple[float, float]] | None = None,
    matcher=None,
) -> list[Path]:
    """The four pictures of one frame into out_dir -> paths; poses3d (P, 23, 4), assignment (P, V)."""
    rig, out_dir, n = sequence.rig, Path(out_dir), result.frame
    if len(frame.views) != len(rig):
        raise ValueError(f"frame {frame.index} has {len(frame.views)} views, the rig {len(rig)}")
    poses, gt = np.asarray(result.poses3d, dtype=np.float64), frame.gt_poses
    images = images if images is not None else [None] * len(rig)
    drawn = draw_reprojections(images, rig, poses, image_scale, gt, [view.keypoints for view in frame.views])
    paths = [write_png(out_dir / f"frame_{n}_views.png", image_png(image_grid(drawn, rig.names)))]
    title = f"frame {n}: {len(poses)} estimated" + ("" if gt is None else f", {len(gt)} ground-truth persons")
    paths.append(write_png(out_dir / f"frame_{n}_3d.png", figure_png(plot_scene_3d(poses, gt, rig, title))))
    paths.append(write_png(out_dir / f"frame_{n}_top.png", figure_png(plot_top_view(poses, gt, rig, title))))
    features = (matcher if hasattr(matcher, "features") else FeetMatcher()).features(frame.views, rig)
    feet = plot_feet_on_ground(frame.views, rig, result.assignment, features, f"frame {n}: feet on the ground")
    paths.append(write_png(out_dir / f"frame_{n}_feet.png", figure_png(feet)))
    return paths


def save_run_pictures(
    out_dir: str | Path,
    sequence: Sequence,
    results: list[FrameResult],
    frame: int | None = None,
    images_dir: str | Path | None = None,
    pattern: str = "cam{i}.png",
    matcher=None,
) -> list[Path]:
    """Pictures of one frame of an eval.py run (``frame`` = its index, None = the first result) -> their paths."""
    if not results:
        raise ValueError("no reconstructed frame to draw")
    result = results[0] if frame is None else next((r for r in results if r.frame == frame), None)
    if result is None:
        raise ValueError(f"frame {frame} is not among the reconstructed frames {results[0].frame}..{results[-1].frame}")
    data = next(f for f in sequence.frames if f.index == result.frame)
    if images_dir is not None:
        images, scales = load_view_images(images_dir, sequence.rig, pattern)
    elif data.images is not None:  # the frame's own images (dataset=images, render=true), at the calibration size
        images, scales = [cv2.cvtColor(im, cv2.COLOR_BGR2RGB) for im in data.images()], [(1.0, 1.0)] * len(sequence.rig)
    else:
        images, scales = None, None
    return save_frame_pictures(out_dir, sequence, result, data, images, scales, matcher)
