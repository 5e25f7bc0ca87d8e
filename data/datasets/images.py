"""Multi-view images (dataset=images): a calibration and every camera's frames, no detections, no ground truth."""

from __future__ import annotations

import argparse
import glob
import json
import warnings
from collections.abc import Mapping
from functools import partial
from pathlib import Path
from typing import Sequence as Seq

import cv2
import numpy as np

from data.datasets.files import frame_list, frame_range
from data.formats.atomic_io import atomic_write_text
from data.formats.image_sources import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    ImageSource,
    ImageSourceError,
    VideoReader,
    open_source,
)
from data.geometry.calibration import load_rig
from data.geometry.camera import Camera, Rig
from data.image_ids import coco_image_id
from data.multiview import Frame, Sequence, ViewDetections

ALIGNS = ("index", "name")
ASPECT_TOLERANCE = 0.01  # relative difference of w / h above which the aspect ratios are said to differ
_GLOB = set("*?[")


class ImageSizeWarning(UserWarning):
    """A camera's images are not at the calibration's size (they are rescaled to it)."""


def load_images(
    cameras: str | Path,
    images: str | Path | Mapping[str, str | Path],
    pattern: str | None = None,
    frames: list[int] | int | str | None = None,
    align: str = "index",
) -> Sequence:
    """The rig of ``cameras`` and one Frame per selected frame: empty views, lazy V images (H, W, 3), image ids (V,)."""
    if align not in ALIGNS:
        raise ValueError(f"align={align!r}: must be one of {', '.join(ALIGNS)}")
    rig = load_rig(cameras)
    sources = camera_sources(rig, images, pattern)
    table = select_frames(align_frames(sources, align), frames)
    return image_sequence(
        rig, sources, table, {"dataset": "images", "cameras": str(cameras), "images": images, "align": align}
    )


def image_sequence(
    rig: Rig, sources: list[ImageSource], table: list[tuple[int, tuple[int, ...]]], meta: dict
) -> Sequence:
    """One Frame per row (frame number, positions (V,)) of ``table``: empty views, V lazy images (H, W, 3) (a video
    read forward through one open capture), image ids (V,). meta: "dataset", "cameras", the dataset's images key."""
    sizes = [checked_size(cam, source) for cam, source in zip(rig, sources)]
    readers = tuple(VideoReader(s) if s.kind == "video" else s for s in sources)
    read, sizes_wh = partial(read_frame_images, readers), tuple(cam.size for cam in rig)
    ids = lambda index: [coco_image_id(index, v, len(rig)) for v in range(len(rig))]  # noqa: E731
    empty = lambda: [ViewDetections.empty() for _ in rig]  # noqa: E731
    out = [Frame(i, empty(), images=partial(read, p, sizes_wh), image_ids=ids(i)) for i, p in table]
    images, kinds = meta[meta["dataset"]], "/".join(sorted({s.kind for s in sources}))
    shown = "a mapping of cameras" if isinstance(images, Mapping) else str(images)
    meta[meta["dataset"]] = {str(k): str(v) for k, v in images.items()} if isinstance(images, Mapping) else str(images)
    meta["image_sizes"] = {cam.name: list(size) for cam, size in zip(rig, sizes)}
    description = (
        f"{len(out)} frames of {len(rig)} cameras ({kinds}) from {shown} on {meta['cameras']}, "
        "no detections, no ground truth"
    )
    return Sequence(rig, out, meta, description=description, coco_images=coco_images(rig, sources, table, sizes))


# --- finding each camera's frames ---------------------------------------------------------------------
def camera_sources(
    rig: Rig, images: str | Path | Mapping[str, str | Path], pattern: str | None, key: str = "images"
) -> list[ImageSource]:
    """Each camera's ImageSource (rig order): from a mapping camera -> path (``key`` in messages), or under a root."""
    if isinstance(images, Mapping):
        if pattern is not None:
            raise ValueError(f"pattern={pattern!r}: applies to one root folder of images; a mapping gives each path")
        images = {str(name): path for name, path in images.items()}  # dataset.videos={1:a.mp4}: int keys
        extra = sorted(set(images) - set(rig.names))
        if extra:
            raise ValueError(f"{key}: camera {extra[0]!r} is not in the calibration (cameras {rig.names})")
        missing = [name for name in rig.names if name not in images]
        if missing:
            raise ValueError(f"{key}: camera {missing[0]!r} has no entry in the mapping (cameras {rig.names})")
        return [open_source(images[name]) for name in rig.names]
    root = Path(images)
    if not root.is_dir():
        raise ImageSourceError(f"{root}: no such folder of images")
    return [_source_under(root, name, v, pattern) for v, name in enumerate(rig.names)]


def _source_under(root: Path, name: str, view: int, pattern: str | None) -> ImageSource:
    """Camera ``name``'s source under a root folder: by pattern, else a sub-folder or file named like it."""
    if pattern is not None:
        try:
            relative = Path(pattern.format(name=name, i=view))
        except (KeyError, IndexError, ValueError) as exc:
            raise ValueError(f"pattern={pattern!r}: only {{name}} and {{i}} may be used ({exc!r})") from None
        if _GLOB & set(str(relative.parent)):
            raise ValueError(f"pattern={pattern!r}: a wildcard may only be in the last part of the path")
        if _GLOB & set(relative.name):
            return open_source(root / relative.parent, relative.name)
        path = root / relative
        if not path.exists():
            raise ImageSourceError(f"{path}: camera {name!r} has no images here (pattern={pattern!r})")
        return open_source(path)
    if (root / name).is_dir():
        return open_source(root / name)
    files = [f for f in root.glob(f"{glob.escape(name)}.*") if f.suffix.lower() in VIDEO_SUFFIXES + IMAGE_SUFFIXES]
    if len(files) != 1:
        found = "none" if not files else ", ".join(sorted(f.name for f in files))
        raise ImageSourceError(
            f"{root}: camera {name!r} needs one sub-folder {name!r} or one video or image named {name}.* (found {found})"
        )
    return open_source(files[0])


# --- matching frames across cameras -------------------------------------------------------------------
def align_frames(sources: list[ImageSource], align: str) -> list[tuple[int, tuple[int, ...]]]:
    """(frame number, position in every source (V,)) of every frame, in frame order."""
    if align == "index":
        counts = [s.num_frames for s in sources]
        if len(set(counts)) > 1:
            listed = ", ".join(f"{s.path} {s.num_frames}" for s in sources)
            raise ValueError(f"images: unequal frame counts under align=index ({listed}); use align=name or trim them")
        return [(i, (i,) * len(sources)) for i in range(counts[0])]
    for source in sources:
        if source.kind != "folder":
            raise ImageSourceError(f"{source.path}: align=name needs folders of image files, this is a {source.kind}")
    positions = [_name_positions(s) for s in sources]
    common = [n for n in sources[0].names if all(n in p for p in positions)]
    if not common:
        raise ValueError(f"images: no file stem is found in every camera's folder ({sources[0].path}, ...), align=name")
    _warn_left_out(sources, positions, len(common))
    numbered = all(n.isdigit() for n in common)
    return [(int(n) if numbered else i, tuple(p[n] for p in positions)) for i, n in enumerate(common)]


def _name_positions(source: ImageSource) -> dict[str, int]:
    """Position of every file stem of a folder source; a stem twice (a.png, a.jpg) is an error."""
    out: dict[str, int] = {}
    for i, name in enumerate(source.names):
        if name in out:
            raise ImageSourceError(f"{source.path}: two image files are named {name!r} (align=name needs unique stems)")
        out[name] = i
    return out


def _warn_left_out(sources: list[ImageSource], positions: list[dict[str, int]], common: int) -> None:
    """One warning listing the files of each camera that no other camera matches."""
    extra = [(s.path, len(p) - common) for s, p in zip(sources, positions) if len(p) > common]
    if extra:
        listed = ", ".join(f"{path} {n}" for path, n in extra)
        warnings.warn(f"images: align=name keeps the {common} stems found in every camera; left out: {listed}")


def select_frames(
    table: list[tuple[int, tuple[int, ...]]], frames: list[int] | int | str | None
) -> list[tuple[int, tuple[int, ...]]]:
    """The rows of (frame number, positions) selected by ``frames`` (see :func:`load_images`)."""
    if frames is None:
        return table
    numbers = [n for n, _ in table]
    if isinstance(frames, str):
        wanted = frame_range(frames, max(numbers) + 1)
        kept = [row for row in table if row[0] in wanted]
        if not kept:
            raise ValueError(
                f"frames={frames!r}: none of the {len(table)} frames ({numbers[0]}..{numbers[-1]}) is in it"
            )
        return kept
    wanted_list = [int(frames)] if isinstance(frames, (int, np.integer)) else frame_list(frames)
    rows = dict(table)
    absent = [f for f in wanted_list if f not in rows]
    if absent:
        raise ValueError(
            f"frames: frame {absent[0]} is not among the {len(table)} frames found ({numbers[0]}..{numbers[-1]})"
        )
    return [(f, rows[f]) for f in sorted(set(wanted_list))]


# --- reading ----------------------------------------------------------------------------------------
def checked_size(camera: Camera, source: ImageSource) -> tuple[int, int]:
    """The (w, h) of a camera's images; an ImageSizeWarning when it is not the calibration's size."""
    size = source.frame_size()
    if size != camera.size:
        (w, h), (cw, ch) = size, camera.size
        message = (
            f"{source.path}: images are {w}x{h}, the calibration of camera {camera.name!r} says {cw}x{ch}: "
            f"rescaled to {cw}x{ch}"
        )
        if abs((w / h) / (cw / ch) - 1.0) > ASPECT_TOLERANCE:
            message += f"; the aspect ratios differ ({w / h:.3f} vs {cw / ch:.3f}): are these the calibrated images?"
        warnings.warn(ImageSizeWarning(message), stacklevel=3)
    return size


def read_frame_images(
    sources: Seq[ImageSource | VideoReader], positions: Seq[int], sizes: Seq[tuple[int, int]]
) -> list[np.ndarray]:
    """Frame ``positions[v]`` of every source, as (H, W, 3) uint8 BGR rescaled to sizes[v] = (w, h)."""
    out = []
    for source, position, (w, h) in zip(sources, positions, sizes):
        image = source.read(position)
        if image.shape[:2] != (h, w):
            shrink = image.shape[1] > w or image.shape[0] > h
            image = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        out.append(image)
    return out


def coco_images(
    rig: Rig, sources: list[ImageSource], table: list[tuple[int, tuple[int, ...]]], sizes: list[tuple[int, int]]
) -> list[dict]:
    """The COCO "images" entries of the selected frames, frame-major, with the file's size (and a video's frame)."""
    out = []
    for index, positions in table:
        for v, (cam, source, position) in enumerate(zip(rig, sources, positions)):
            entry = {"id": coco_image_id(index, v, len(rig)), "frame": int(index), "camera": cam.name}
            entry |= {"file_name": source.file_name(position), "width": sizes[v][0], "height": sizes[v][1]}
            if source.kind == "video":
                entry["video_frame"] = int(position)
            out.append(entry)
    return out


# --- CLI --------------------------------------------------------------------------------------------
def main(argv: Seq[str] | None = None) -> None:
    """Command line: write the COCO images list of a multi-view image set."""
    parser = argparse.ArgumentParser(prog="python -m data.datasets.images", description=__doc__.split("\n")[0])
    parser.add_argument("--cameras", required=True, help="cameras.json or any calibration load_rig reads")
    parser.add_argument(
        "--images", required=True, nargs="+", help="a root folder, or CAMERA=PATH for every camera (folder/video)"
    )
    parser.add_argument("--pattern", help="path of a camera's frames under the root: {name}, {i}, a glob at the end")
    parser.add_argument("--frames", help="'start:stop[:step]' frame numbers (default: all)")
    parser.add_argument("--align", choices=ALIGNS, default="index")
    parser.add_argument("-o", "--out", required=True, type=Path, help="output JSON: {images, categories}")
    args = parser.parse_args(argv)
    images = args.images[0] if len(args.images) == 1 and "=" not in args.images[0] else _mapping(parser, args.images)
    try:
        sequence = load_images(args.cameras, images, args.pattern, args.frames, args.align)
    except (ValueError, OSError) as exc:
        parser.exit(1, f"error: {exc}\n")
    doc = {"images": sequence.coco_images, "categories": [{"id": 1, "name": "person"}]}
    atomic_write_text(args.out, json.dumps(doc, indent=1))
    print(
        f"wrote {len(doc['images'])} images ({len(sequence.frames)} frames x {len(sequence.rig)} cameras) to {args.out}"
    )


def _mapping(parser: argparse.ArgumentParser, items: list[str]) -> dict[str, str]:
    """CAMERA=PATH items as a mapping."""
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            parser.error(f"--images {item!r}: give one root folder, or CAMERA=PATH for every camera")
        out[name] = path
    return out


if __name__ == "__main__":
    main()
