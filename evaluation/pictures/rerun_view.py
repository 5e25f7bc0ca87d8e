"""A run in the rerun viewer (viewer=rerun, ``pip install rerun-sdk``): cameras, images, 2D detections, 3D skeletons
by track id and the ground on a "frame" timeline, saved as recording.rrd (and shown live where asked and possible)."""

from __future__ import annotations

import os
import sys
import uuid
from pathlib import Path
from types import ModuleType
from typing import Any, Iterable

import cv2
import numpy as np

from data.config_checks import ConfigError, fail
from data.geometry.camera import Camera
from data.keypoints import LIMBS, NUM_JOINTS
from data.multiview import Sequence, ViewDetections
from evaluation.pictures.sequence_data import id_colors, pose_roots, sequence_frames, valid_joints
from evaluation.pictures.sequence_html import _scene_points, grid_spec
from evaluation.pictures.vis_draw import DETECTION_COLOR

RRD_NAME = "recording.rrd"
TIMELINE = "frame"  # the frame numbers of the dataset
IMAGE_SIDE = 480  # px: the longest side of each camera's logged image space (images, detections, pinhole)
JPEG_QUALITY = 75
LIMB_RADIUS_M, JOINT_RADIUS_M, FRUSTUM_M = 0.015, 0.025, 0.4
_LIMB_A, _LIMB_B = np.asarray(LIMBS).T


def check_viewer(viewer: str | None, spawn: bool) -> ModuleType:
    """The rerun SDK for viewer=rerun; a ConfigError naming the key for another value or a missing package."""
    if viewer not in (None, "rerun"):
        fail("viewer", viewer, "must be null or rerun (the HTML viewer: vis_sequence=true)")
    if not isinstance(spawn, bool):
        fail("viewer_spawn", spawn, "must be true or false")
    return import_rerun()


def import_rerun() -> ModuleType:
    """The rerun SDK, imported here only; missing: ConfigError naming the pip command."""
    try:
        import rerun
    except ImportError:
        raise ConfigError(
            "viewer=rerun: the rerun SDK is not installed: pip install rerun-sdk (or viewer=null)"
        ) from None
    return rerun


def limb_segments(points: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Limbs with both ends valid: points (P, J, D), ok (P, J) -> segments (S, 2, D), person of each (S,)."""
    person, limb = np.nonzero(ok[:, _LIMB_A] & ok[:, _LIMB_B])
    return np.stack([points[person, _LIMB_A[limb]], points[person, _LIMB_B[limb]]], axis=1), person


def image_scale(camera: Camera) -> tuple[np.ndarray, tuple[int, int]]:
    """The logged image space of a camera: (sx, sy) from calibration pixels (2,), its size (w, h)."""
    w, h = camera.size
    s = min(1.0, IMAGE_SIDE / max(w, h))
    size = (max(1, round(w * s)), max(1, round(h * s)))
    return np.array([size[0] / w, size[1] / h]), size


def default_blueprint(rr: ModuleType, sequence: Sequence, grid: dict) -> Any:
    """The layout: the 3D scene (seen from behind and above the first camera) beside a grid of the camera views."""
    import rerun.blueprint as rrb

    target = np.array([*np.add(grid["min"], grid["max"]) / 2, 1.0])
    eye = target + 1.3 * (sequence.rig[0].center - target) + [0.0, 0.0, 1.5]
    scene = rrb.Spatial3DView(origin="world", eye_controls=rrb.EyeControls3D(position=eye, look_target=target))
    views = rrb.Grid(*(rrb.Spatial2DView(origin=camera_path(rr, c), name=c.name) for c in sequence.rig))
    return rrb.Blueprint(rrb.Horizontal(scene, views, column_shares=[3, 2]))


def log_static(rec: Any, rr: ModuleType, sequence: Sequence, grid: dict) -> None:
    """World z up, the ground grid at z = 0 (grid_spec) and each camera's pose and pinhole."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    (x0, y0), (x1, y1), step = grid["min"], grid["max"], grid["step"]
    lines = [[[x, y0, 0], [x, y1, 0]] for x in np.arange(x0, x1 + step / 2, step)]
    lines += [[[x0, y, 0], [x1, y, 0]] for y in np.arange(y0, y1 + step / 2, step)]
    rec.log("world/ground", rr.LineStrips3D(lines, colors=(110, 110, 110), radii=0.005), static=True)
    for camera in sequence.rig:
        scale, size = image_scale(camera)
        path = camera_path(rr, camera)
        rec.log(path, rr.Transform3D(translation=camera.center, mat3x3=camera.R.T), static=True)  # camera -> world
        K = np.diag([*scale, 1.0]) @ camera.K
        xyz = rr.ViewCoordinates.RDF  # x right, y down, z forward: OpenCV's camera frame
        rec.log(
            path,
            rr.Pinhole(image_from_camera=K, resolution=size, camera_xyz=xyz, image_plane_distance=FRUSTUM_M),
            static=True,
        )


def camera_path(rr: ModuleType, camera: Camera) -> str:
    """The entity of a camera: world/cameras/<name> (escaped)."""
    return f"world/cameras/{rr.escape_entity_path_part(camera.name)}"


def log_view(rec: Any, rr: ModuleType, camera: Camera, view: ViewDetections, image: np.ndarray | None) -> None:
    """One camera at the current frame: its image (H, W, 3) BGR as JPEG, downscaled, and its 2D detections."""
    scale, size = image_scale(camera)
    path = camera_path(rr, camera)
    if image is not None:
        small = cv2.resize(np.ascontiguousarray(image[..., :3]), size, interpolation=cv2.INTER_AREA)
        jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()
        rec.log(f"{path}/image", rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))
    xy, scores = view.keypoints[..., :2] * scale, view.keypoints[..., 2]
    ok = (scores > 0) & np.isfinite(view.keypoints).all(axis=-1)
    rec.log(f"{path}/detections", rr.LineStrips2D(limb_segments(xy, ok)[0], colors=DETECTION_COLOR))
    rec.log(f"{path}/detections/joints", rr.Points2D(xy[ok], colors=DETECTION_COLOR, radii=1.5))


def log_skeletons(rec: Any, rr: ModuleType, poses: np.ndarray, ids: np.ndarray, colors: dict) -> None:
    """The 3D skeletons of the current frame, poses (P, 23, 4) and ids (P,), each in its id's colour."""
    rgb = np.array([colors[int(i)] for i in ids], dtype=np.float64).reshape(-1, 3)
    rgb = np.round(255 * rgb).astype(np.uint8)
    ok = valid_joints(poses)
    segments, person = limb_segments(poses[..., :3], ok)
    rec.log("world/skeletons", rr.LineStrips3D(segments, colors=rgb[person], radii=LIMB_RADIUS_M))
    p, j = np.nonzero(ok)
    rec.log("world/skeletons/joints", rr.Points3D(poses[p, j, :3], colors=rgb[p], radii=JOINT_RADIUS_M))
    roots = pose_roots(poses)
    has = np.isfinite(roots).all(axis=1)
    labels = [f"id {i}" for i in ids[has]]
    rec.log("world/skeletons/ids", rr.Points3D(roots[has], colors=rgb[has], labels=labels, radii=JOINT_RADIUS_M))


def has_display() -> bool:
    """Whether a viewer window can open here (macOS and Windows: always; else $DISPLAY or $WAYLAND_DISPLAY)."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def open_recording(rr: ModuleType, path: Path, spawn: bool, blueprint: Any) -> Any:
    """A recording stream into path, and into a spawned viewer when spawn and a display exist."""
    rec = rr.RecordingStream("crowd3d", recording_id=uuid.uuid4())
    if spawn and has_display():
        rec.spawn(connect=False)
        rec.set_sinks(rr.FileSink(str(path)), rr.GrpcSink(), default_blueprint=blueprint)
    else:
        if spawn:
            print(f"viewer_spawn=true: no display ($DISPLAY, $WAYLAND_DISPLAY unset), not spawned; open: rerun {path}")
        rec.save(path, default_blueprint=blueprint)
    return rec


def save_rerun_recording(
    out_dir: str | Path, sequence: Sequence, results: Iterable[Any], viewer: str | None, spawn: bool
) -> Path:
    """recording.rrd of a run's sequence and results (FrameResult: frame, poses3d (P, 23, 4), ids) -> its path."""
    rr = check_viewer(viewer, spawn)
    frames, _ = sequence_frames((r.frame, r.poses3d, r.ids) for r in results)
    by_number = {f.frame: f for f in frames}
    colors = id_colors(i for f in frames for i in f.ids)
    path = Path(out_dir) / RRD_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    grid = grid_spec(_scene_points(frames, sequence.rig))
    rec = open_recording(rr, path, spawn, default_blueprint(rr, sequence, grid))
    log_static(rec, rr, sequence, grid)
    empty = (np.zeros((0, NUM_JOINTS, 4)), np.zeros(0, np.int64))
    for frame in sequence.frames:
        rec.set_time(TIMELINE, sequence=frame.index)
        images = frame.images() if frame.images is not None else [None] * len(sequence.rig)
        for camera, view, image in zip(sequence.rig, frame.views, images):
            log_view(rec, rr, camera, view, image)
        result = by_number.get(frame.index)
        log_skeletons(rec, rr, *((result.poses, result.ids) if result else empty), colors)
    rec.flush()
    rec.disconnect()
    return path
