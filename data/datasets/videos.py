"""Synchronised videos (dataset=videos): one video per camera, per-camera frame offsets, frames read as a stream."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np

from data.datasets.files import camera_shifts, frame_list, frame_range
from data.datasets.images import camera_sources, image_sequence
from data.formats.image_sources import ImageSource, ImageSourceError
from data.frame_inputs import InputWarning
from data.geometry.calibration import load_rig
from data.geometry.camera import Rig
from data.multiview import Sequence


class VideoLengthWarning(InputWarning):
    """The cameras' videos differ in length after their offsets: only the frames every camera has are used."""


class VideoRateWarning(InputWarning):
    """The cameras' videos declare frame rates more than 1 % apart: the first camera's is recorded."""


def load_videos(
    cameras: str | Path,
    videos: str | Path | Mapping[str, str | Path],
    offsets: Mapping[str, int] | None = None,
    frames: list[int] | int | str | None = None,
) -> Sequence:
    """The rig of ``cameras`` and one Frame per selected frame f: empty views, V images (H, W, 3) read forward from
    every camera's video at position f + offsets[camera], image ids (V,); meta["fps"]: video_rate's, where known."""
    rig = load_rig(cameras)
    sources = camera_sources(rig, videos, None, key="videos")
    for source in sources:
        if source.kind != "video":
            raise ImageSourceError(f"{source.path}: dataset=videos reads one video per camera, this is a {source.kind}")
    shifts = camera_offsets(rig, sources, offsets)
    table = [(f, tuple(f + s for s in shifts)) for f in frame_numbers(rig, sources, shifts, frames)]
    meta = {"dataset": "videos", "cameras": str(cameras), "videos": videos, "offsets": dict(zip(rig.names, shifts))}
    if fps := video_rate(rig, sources):
        meta["fps"] = fps
    return image_sequence(rig, sources, table, meta)


def video_rate(rig: Rig, sources: list[ImageSource]) -> float | None:
    """The first camera's frame rate (its header's CAP_PROP_FPS; None where not a positive number), a warning when
    the cameras' rates differ by more than 1 %."""
    rates = []
    for source in sources:
        capture = cv2.VideoCapture(str(source.path))
        rate = float(capture.get(cv2.CAP_PROP_FPS)) if capture.isOpened() else 0.0
        capture.release()
        rates.append(rate if np.isfinite(rate) and rate > 0 else None)
    known = [r for r in rates if r]
    if known and max(known) > 1.01 * min(known):
        listed = ", ".join(f"{name!r}: {r:g}" if r else f"{name!r}: unknown" for name, r in zip(rig.names, rates))
        warnings.warn(
            VideoRateWarning(
                f"dataset.videos: the cameras' videos declare different frame rates ({listed} frames per second):"
                + (f" the first camera's, {rates[0]:g}, is recorded" if rates[0] else " none is recorded (the first's)")
            ),
            stacklevel=3,
        )
    return rates[0]


def camera_offsets(rig: Rig, sources: list[ImageSource], offsets: Mapping[str, int] | None) -> list[int]:
    """Each camera's offset (V,), 0 where not given: its frame f is its video's frame f + offset."""
    out = camera_shifts(rig.names, offsets)
    for name, source, shift in zip(rig.names, sources, out):
        if not 0 <= shift < source.num_frames:
            where = "before the start" if shift < 0 else "past the end"
            raise ValueError(
                f"offsets: camera {name!r}: {shift} puts frame 0 {where} of {source.path} ({source.num_frames} frames;"
                " offsets count from each video's first frame, >= 0: give the other cameras positive ones)"
            )
    return out


def frame_numbers(
    rig: Rig, sources: list[ImageSource], shifts: list[int], frames: list[int] | int | str | None
) -> list[int]:
    """The selected frame numbers (null: all that every camera has, a warning when the lengths differ)."""
    ends = [source.num_frames - shift for source, shift in zip(sources, shifts)]  # each camera's frames 0..end-1
    lengths = ", ".join(f"{name!r}: {end}" for name, end in zip(rig.names, ends))
    if frames is None:
        if len(set(ends)) > 1:
            warnings.warn(
                VideoLengthWarning(
                    f"dataset.videos: the cameras have different numbers of frames after their offsets ({lengths}):"
                    f" frames 0..{min(ends) - 1} used, those every camera has"
                ),
                stacklevel=2,
            )
        return list(range(min(ends)))
    if isinstance(frames, str):
        wanted = list(frame_range(frames, min(ends)))
    else:
        wanted = sorted(set([int(frames)] if isinstance(frames, (int, np.integer)) else frame_list(frames)))
    if not wanted:
        raise ValueError(f"frames={frames!r}: selects no frame (every camera has frames 0..{min(ends) - 1})")
    for v, end in enumerate(ends):
        bad = next((f for f in wanted if not 0 <= f < end), None)
        if bad is not None:
            raise ValueError(
                f"frames={frames!r}: camera {rig.names[v]!r} has no frame {bad} ({sources[v].path}, offset "
                f"{shifts[v]}: frames 0..{end - 1}; frames per camera after the offsets: {lengths})"
            )
    return wanted
