"""One camera's frames (a folder, a video or one image) read lazily as (H, W, 3) uint8 BGR; ImageSourceError."""

from __future__ import annotations

import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".jp2")
VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".m4v", ".mpg", ".mpeg", ".webm", ".wmv", ".mts", ".ts")


class ImageSourceError(ValueError):
    """A folder, video or image that is missing or cannot be read; the message names the path."""


@dataclass(frozen=True)
class ImageSource:
    """One camera's frames: kind "folder" (files, natural order), "video" or "image" (files = (path,))."""

    path: Path
    kind: str
    files: tuple[Path, ...]
    num_frames: int

    @property
    def names(self) -> list[str]:
        """The name of every frame: a folder's file stems; a video's or an image's frame positions."""
        if self.kind == "folder":
            return [f.stem for f in self.files]
        return [str(i) for i in range(self.num_frames)]

    def file_name(self, position: int) -> str:
        """The file that holds frame ``position``: its image file, or the video."""
        return str(self.files[position] if self.kind == "folder" else self.path)

    def read(self, position: int) -> np.ndarray:
        """Frame ``position`` (0-based) as (H, W, 3) uint8 BGR."""
        if not 0 <= position < self.num_frames:
            raise ImageSourceError(f"{self.path}: no frame {position} (it has {self.num_frames})")
        if self.kind == "video":
            return VideoReader(self).read(position)  # one frame; a stream keeps its own VideoReader
        return read_image(self.files[0] if self.kind == "image" else self.files[position])

    def frame_size(self) -> tuple[int, int]:
        """The (w, h) of the first frame (a video's from its header)."""
        if self.kind == "video":
            capture = _open_video(self.path)
            try:
                return int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
            finally:
                capture.release()
        h, w = self.read(0).shape[:2]
        return w, h


def open_source(path: str | Path, pattern: str | None = None) -> ImageSource:
    """The frames at ``path``: a folder's images (those matching a glob ``pattern``), a video or an image file."""
    path = Path(path)
    if path.is_dir():
        candidates = [Path(p) for p in glob.glob(str(path / pattern))] if pattern else list(path.iterdir())
        files = sorted((f for f in candidates if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)
        if not files:
            what = f"matching {pattern!r}" if pattern else f"({', '.join(IMAGE_SUFFIXES)})"
            raise ImageSourceError(f"{path}: no image files {what} in this folder")
        return ImageSource(path, "folder", tuple(files), len(files))
    if not path.is_file():
        raise ImageSourceError(f"{path}: no such folder, video or image")
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return ImageSource(path, "video", (path,), video_frame_count(path))
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return ImageSource(path, "image", (path,), 1)
    raise ImageSourceError(f"{path}: not a folder, a video ({', '.join(VIDEO_SUFFIXES)}) or an image file")


def natural_key(path: Path) -> list:
    """Sort key of a file name with its digit runs compared as numbers ('img2' < 'img10')."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", path.name)]


def read_image(path: Path) -> np.ndarray:
    """One image file as (H, W, 3) uint8 BGR (grey and 16-bit images converted)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ImageSourceError(f"{path}: cannot read this image (missing, unreadable or not an image)")
    return image


def _open_video(path: Path) -> cv2.VideoCapture:
    """An opened capture of the video, or ImageSourceError naming it."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # FFmpeg quiet (read at the first open): our line says it
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        capture.release()
        raise ImageSourceError(f"{path}: OpenCV cannot open this video (codec or file broken?)")
    return capture


def video_frame_count(path: Path) -> int:
    """The number of frames of a video: its header's count, else counted by reading through it."""
    capture = _open_video(path)
    try:
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        if count <= 0:  # containers without a frame count in the header
            count = 0
            while capture.grab():
                count += 1
    finally:
        capture.release()
    if count == 0:
        raise ImageSourceError(f"{path}: this video holds no frame OpenCV can read")
    return count


class VideoReader:
    """A video read forward through one open capture: grab() over gaps of up to ``max_skip`` frames, else a seek."""

    def __init__(self, source: ImageSource, max_skip: int = 30) -> None:
        self.source, self.max_skip = source, max_skip
        self.capture: cv2.VideoCapture | None = None
        self.next = 0  # the position the capture's next read() returns

    def read(self, position: int) -> np.ndarray:
        """Frame ``position`` (0-based) as (H, W, 3) uint8 BGR; opens the video on the first call."""
        if not 0 <= position < self.source.num_frames:
            raise ImageSourceError(f"{self.source.path}: no frame {position} (it has {self.source.num_frames})")
        if self.capture is None:
            self.capture, self.next = _open_video(self.source.path), 0
        if not 0 <= position - self.next <= self.max_skip:  # backwards or far ahead
            self.capture.set(cv2.CAP_PROP_POS_FRAMES, position)
            self.next = position
        ok = all(self.capture.grab() for _ in range(position - self.next))
        ok, image = self.capture.read() if ok else (False, None)
        if not ok or image is None:
            self.capture = None  # reopened by the next call
            raise ImageSourceError(f"{self.source.path}: cannot read frame {position} of this video")
        self.next = position + 1
        return image
