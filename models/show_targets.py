"""Picture the multi-modal training targets of a keypoint file: crop, own-joint targets (red), others' mu C (green)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from data.keypoints import FOOT_JOINTS, NUM_JOINTS
from data.pose2d.coco_keypoints import KINDS, load_keypoint_dataset
from data.pose2d.crop_transforms import transform_points
from data.pose2d.topdown_dataset import TopDownDataset, denormalize_image
from models.heatmap_codec import MultiModalHeatmapCodec

RED, GREEN = (255, 40, 40), (40, 255, 40)


def tint(rgb: np.ndarray, heatmap: np.ndarray, colour: tuple[int, int, int], strength: float = 0.8) -> np.ndarray:
    """A copy of rgb (H, W, 3) uint8 blended towards colour where heatmap (h, w) (values ~[0, 1]) is high."""
    size = (rgb.shape[1], rgb.shape[0])
    alpha = np.clip(cv2.resize(np.asarray(heatmap, np.float32), size, interpolation=cv2.INTER_LINEAR), 0, 1)
    alpha = (strength * alpha)[..., None]
    out = rgb.astype(np.float32) * (1 - alpha) + np.array(colour, np.float32) * alpha
    return np.ascontiguousarray(np.clip(np.round(out), 0, 255).astype(np.uint8))


def tile_grid(tiles: Sequence[np.ndarray], columns: int, gap: int = 2) -> np.ndarray:
    """Equal-sized RGB tiles (H, W, 3) -> one grid image, row-major, blank tiles to fill the last row."""
    if not tiles:
        raise ValueError("no tiles to arrange")
    h, w = tiles[0].shape[:2]
    tiles = list(tiles) + [np.zeros((h, w, 3), np.uint8)] * (-len(tiles) % columns)
    padded = [np.pad(t, ((gap, gap), (gap, gap), (0, 0))) for t in tiles]
    return np.vstack([np.hstack(padded[r : r + columns]) for r in range(0, len(padded), columns)])


def target_parts(
    dataset: TopDownDataset, index: int, affine_inv: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Own T, others' mu C (23, h, w) and crop keypoints (23, 3) of an unflipped sample (crop -> image: affine_inv)."""
    r, own = dataset.samples[index][:2]
    record, codec = dataset.records[r], dataset.codec
    affine = np.linalg.inv(np.vstack([np.asarray(affine_inv, np.float64), [0.0, 0.0, 1.0]]))[:2]
    keypoints = np.array(record.keypoints, dtype=np.float64)
    keypoints[..., :2] = transform_points(keypoints[..., :2], affine)
    others = np.delete(keypoints, own, axis=0)
    own_t, _ = codec.encode(keypoints[own], others[:0], record.labelled)
    crowd, _ = codec.encode(np.zeros((NUM_JOINTS, 3)), others, record.labelled)
    return own_t, crowd, keypoints[own]


def target_tile(dataset: TopDownDataset, index: int) -> np.ndarray:
    """The crop (H, W, 3) RGB of sample index with T in red, mu C in green and the own joints as dots."""
    sample = dataset[index]
    own_t, crowd, keypoints = target_parts(dataset, index, sample["affine_inv"].numpy())
    rgb = denormalize_image(sample["image"])
    rgb = tint(tint(rgb, own_t.max(axis=0), RED), crowd.max(axis=0), GREEN)
    for j, (x, y, v) in enumerate(keypoints):
        if v > 0 and dataset.codec.inside(np.array([x, y])):
            colour = (0, 255, 255) if j in FOOT_JOINTS else (255, 255, 255)
            cv2.circle(rgb, (int(round(x)), int(round(y))), 2, colour, -1, cv2.LINE_AA)
    return rgb


def save_target_grid(out_png: str | Path, dataset: TopDownDataset, columns: int = 6) -> Path:
    """Save a PNG grid of every sample's :func:`target_tile`; returns the path."""
    grid = tile_grid([target_tile(dataset, i) for i in range(len(dataset))], columns)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_png), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
        raise ValueError(f"{out_png}: cannot write the picture")
    return out_png


def main(argv: Sequence[str] | None = None) -> None:
    """Command line: the target grid of a keypoint annotation file."""
    parser = argparse.ArgumentParser(prog="python -m models.show_targets", description=__doc__.split("\n")[0])
    parser.add_argument("--ann", required=True, type=Path, help="COCO-format keypoint annotation file")
    parser.add_argument("--images", required=True, type=Path, help="folder of its images")
    parser.add_argument("--out", required=True, type=Path, help="PNG to write")
    parser.add_argument("--kind", choices=KINDS, default="coco_wholebody")
    parser.add_argument("--mu", type=float, default=0.5, help="attention factor of the other persons (default 0.5)")
    parser.add_argument("--sigma", type=float, default=2.0, help="Gaussian std in heatmap pixels")
    parser.add_argument("--input-size", type=int, nargs=2, default=(192, 256), metavar=("W", "H"))
    parser.add_argument("--columns", type=int, default=6)
    args = parser.parse_args(argv)
    input_size = tuple(args.input_size)
    codec = MultiModalHeatmapCodec(input_size, (input_size[0] // 4, input_size[1] // 4), args.sigma, args.mu)
    try:
        records = load_keypoint_dataset(args.kind, args.ann, args.images)
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from None
    dataset = TopDownDataset(records, codec, input_size, augment=None, train=True)
    if not len(dataset):
        raise SystemExit(f"error: {args.ann}: no person with a labelled joint")
    print(f"{len(dataset)} persons -> {save_target_grid(args.out, dataset, args.columns)}")


if __name__ == "__main__":
    main()
