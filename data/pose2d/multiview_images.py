"""Synthetic multi-view crowd images with COCO-23 labels (dataset=synthetic render=true)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Sequence

import cv2
from tqdm import tqdm

from data.pose2d.coco_keypoints import write_coco_keypoints
from data.pose2d.scene_render import render_sequence
from data.pose2d.synthetic_images import parse_size, save_preview
from data.pose2d.view_coco import ground_truth_records
from data.synthetic import SyntheticConfig, generate_sequence


def generate_multiview_dataset(
    out_dir: str | Path,
    cfg: SyntheticConfig,
    render_seed: int | None = None,
    jpeg_quality: int = 92,
    progress: bool = True,
) -> Path:
    """Write the F x V JPEGs of cfg's scene and their COCO-23 ground truth; returns the annotation path."""
    if not 1 <= jpeg_quality <= 100:
        raise ValueError(f"jpeg_quality={jpeg_quality!r} must be in 1..100")
    out_dir = Path(out_dir)
    image_dir = out_dir / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    seed = cfg.seed if render_seed is None else int(render_seed)
    sequence = render_sequence(generate_sequence(cfg), seed)
    records = [
        dataclasses.replace(r, file=image_dir / r.file) for r in ground_truth_records(sequence.frames, sequence.rig)
    ]
    views = len(sequence.rig)
    for f, frame in enumerate(tqdm(sequence.frames, desc="multi-view frames", unit="frame", disable=not progress)):
        for v, image in enumerate(frame.images()):
            path = records[f * views + v].file
            if not cv2.imwrite(str(path), image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality]):
                raise ValueError(f"{path}: cannot write the image")
    info = {"description": "synthetic multi-view crowd images (data.pose2d.multiview_images)", "scene": cfg.to_dict()}
    info |= {"render_seed": seed, "cameras": sequence.rig.to_dict()}
    ann_path = out_dir / "annotations.json"
    write_coco_keypoints(ann_path, records, image_root=image_dir, info=info)
    return ann_path


def main(argv: Sequence[str] | None = None) -> None:
    """Command line: render a multi-view training set, optionally save a preview grid."""
    parser = argparse.ArgumentParser(prog="python -m data.pose2d.multiview_images", description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--num-frames", required=True, type=int)
    parser.add_argument("--seed", type=int, default=0, help="scene seed (bodies, motion)")
    parser.add_argument("--render-seed", type=int, help="seed of the look (default: --seed)")
    parser.add_argument("--persons", type=int, default=10)
    parser.add_argument("--density", type=float, default=0.3, help="persons per m^2")
    parser.add_argument("--cameras", type=int, default=5, help="cameras of the ring")
    parser.add_argument(
        "--size", type=parse_size, default=(1280, 720), help="WIDTHxHEIGHT of the ring (default 1280x720)"
    )
    parser.add_argument("--focal", type=float, help="focal length of the ring (px; default 1000 x width / 1280)")
    parser.add_argument("--rig", default="ring", help="'ring', or a calibration file/folder (its sizes are used)")
    area = ("XMIN", "XMAX", "YMIN", "YMAX")
    parser.add_argument("--area", type=float, nargs=4, metavar=area, help="persons' area (m), for a real rig")
    parser.add_argument("--jpeg-quality", type=int, default=92)
    parser.add_argument("--preview", type=Path, help="also save a PNG grid of the first 6 images here")
    args = parser.parse_args(argv)
    try:
        focal = args.focal if args.focal is not None else 1000.0 * args.size[0] / 1280
        scene = dict(num_persons=args.persons, density=args.density, num_cameras=args.cameras, image_size=args.size)
        cfg = SyntheticConfig(
            seed=args.seed, num_frames=args.num_frames, **scene, focal_px=focal, rig=args.rig, area=args.area
        )
        ann = generate_multiview_dataset(args.out, cfg, args.render_seed, args.jpeg_quality)
    except ValueError as exc:
        parser.error(str(exc))
    print(f"wrote {ann} and its images")
    if args.preview:
        print(f"preview: {save_preview(args.preview, ann, args.out / 'images')}")


if __name__ == "__main__":
    main()
