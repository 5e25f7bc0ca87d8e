"""Top-down person crops with multi-modal heatmap targets (Sec. 3.1), and a resumable epoch sampler (design.md)."""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING, Iterator

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from data.keypoints import NUM_JOINTS
from data.pose2d.coco_keypoints import training_persons
from data.pose2d.crop_transforms import (
    CropAugmentation,
    box_to_center_scale,
    crop_affine,
    flip_keypoints,
    flip_points,
    sample_augmentation,
)
from data.pose2d.photometric import JitterDraw, jitter_colour, sample_jitter, shift_box
from data.pose2d.records import ImageRecord

if TYPE_CHECKING:  # annotation only: the codec (a stage, layer 3) is given by the caller
    from models.heatmap_codec import MultiModalHeatmapCodec

IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)


def normalize_image(rgb: np.ndarray) -> torch.Tensor:
    """RGB uint8 (H, W, 3) -> ImageNet-normalised float32 tensor (3, H, W)."""
    image = (rgb.astype(np.float32) / 255.0 - IMAGENET_MEAN) / IMAGENET_STD
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)))


def denormalize_image(image: torch.Tensor | np.ndarray) -> np.ndarray:
    """Normalised (3, H, W) -> RGB uint8 (H, W, 3), the inverse of :func:`normalize_image`."""
    array = image.detach().cpu().numpy() if isinstance(image, torch.Tensor) else np.asarray(image)
    rgb = array.transpose(1, 2, 0) * IMAGENET_STD + IMAGENET_MEAN
    return np.ascontiguousarray(np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8))


class TopDownDataset(Dataset):
    """Person crops -> dict(image (3, H, W), target (23, h, w), weight (23,), affine_inv (2, 3), box, ...)."""

    def __init__(
        self,
        records: list[ImageRecord],
        codec: MultiModalHeatmapCodec,
        input_size: tuple[int, int] = (192, 256),
        augment: CropAugmentation | None = None,
        train: bool = True,
        min_keypoints: int = 1,
        use_det_boxes: bool = False,
        padding: float = 1.25,
        seed: int = 0,
        cache_size: int = 32,
    ) -> None:
        self.input_size = (int(input_size[0]), int(input_size[1]))
        if self.input_size != codec.input_size:
            raise ValueError(f"dataset input_size {self.input_size} differs from the codec's {codec.input_size}")
        self.records, self.codec, self.train = list(records), codec, bool(train)
        self.augment = augment if train else None
        self.padding, self.seed, self.epoch = float(padding), int(seed), 0
        self.samples = self._index(min_keypoints, use_det_boxes and not train)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_size = int(cache_size)

    def _index(self, min_keypoints: int, det_boxes: bool) -> list[tuple[int, int, np.ndarray, float, float]]:
        """(record index, own person index or -1, box (4,), score, area) of every sample."""
        samples = []
        for r, record in enumerate(self.records):
            if det_boxes:
                detections = zip(record.det_boxes, record.det_scores)
                samples += [(r, -1, box, float(score), float(box[2] * box[3])) for box, score in detections]
            else:
                persons = training_persons(record, min_keypoints)
                samples += [(r, int(p), record.boxes[p], 1.0, float(record.areas[p])) for p in persons]
        return samples

    def set_epoch(self, epoch: int) -> None:
        """Use epoch ``epoch``'s augmentation draws from now on."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.samples)

    def read_image(self, record_index: int) -> np.ndarray:
        """The RGB image (H, W, 3) uint8 of a record, from the cache when there; do not modify it."""
        if record_index in self._cache:
            self._cache.move_to_end(record_index)
            return self._cache[record_index]
        record = self.records[record_index]
        bgr = cv2.imread(str(record.file), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(f"{record.file}: cannot read the image of image id {record.image_id}")
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        if self._cache_size > 0:
            self._cache[record_index] = rgb
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return rgb

    def augmentation(self, index: int) -> tuple[float, float, bool]:
        """(scale multiplier, rotation degrees, flip) of sample ``index`` in the current epoch."""
        if self.augment is None:
            return 1.0, 0.0, False
        rng = np.random.default_rng([self.seed, self.epoch, int(index)])
        return sample_augmentation(rng, self.augment)

    def jitter(self, index: int) -> JitterDraw | None:
        """Box shift and colour draw of sample ``index`` in the current epoch; None when both are off."""
        a = self.augment
        if a is None or not (a.shift_factor or a.colour_factor or a.hue_deg):
            return None
        rng = np.random.default_rng([self.seed, self.epoch, int(index), 1])  # own stream: geometry unchanged
        return sample_jitter(rng, a.shift_factor, a.colour_factor, a.hue_deg)

    def __getitem__(self, index: int) -> dict:
        r, own, box, score, area = self.samples[index]
        record = self.records[r]
        image = self.read_image(r)
        keypoints = record.keypoints
        aspect = self.input_size[0] / self.input_size[1]
        jitter = self.jitter(index)
        center, scale = box_to_center_scale(box if jitter is None else shift_box(box, jitter), aspect, self.padding)
        scale_mult, rotation, flip = self.augmentation(index)
        if flip:
            image = cv2.flip(image, 1)
            keypoints = flip_keypoints(keypoints, image.shape[1])
            center = flip_points(center, image.shape[1])
        scale = scale * scale_mult
        affine = crop_affine(center, scale, rotation, self.input_size)
        crop = cv2.warpAffine(image, affine, self.input_size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        if jitter is not None:
            crop = jitter_colour(crop, jitter)
        if own >= 0:
            target, weight = self.codec.encode_crop(keypoints, own, affine, record.labelled)
        else:
            w, h = self.codec.heatmap_size
            target, weight = np.zeros((NUM_JOINTS, h, w), np.float32), np.zeros(NUM_JOINTS, np.float32)
        affine_inv = torch.from_numpy(crop_affine(center, scale, rotation, self.input_size, inverse=True))
        sample = {"image": normalize_image(crop), "target": torch.from_numpy(target)}
        sample |= {"weight": torch.from_numpy(weight), "affine_inv": affine_inv, "image_id": record.image_id}
        box = torch.from_numpy(np.asarray(box, dtype=np.float64))
        return sample | {"box": box, "area": area, "score": score, "flipped": flip}


class EpochSampler(Sampler[int]):
    """A seeded per-epoch permutation (identity without shuffle), sharded like DistributedSampler, resumable."""

    def __init__(self, size: int, seed: int = 0, shuffle: bool = True, rank: int = 0, world_size: int = 1) -> None:
        self.size, self.seed, self.shuffle = int(size), int(seed), bool(shuffle)
        self.rank, self.world_size = int(rank), int(world_size)
        self.epoch, self.start = 0, 0

    def set_epoch(self, epoch: int, start: int = 0) -> None:
        """Iterate epoch ``epoch``'s order from its ``start``-th index (of this rank) on."""
        self.epoch, self.start = int(epoch), int(start)

    def indices(self) -> np.ndarray:
        """This rank's indices (K,) of the current epoch, from the start position."""
        order = np.arange(self.size)
        if self.shuffle:
            order = np.random.default_rng([self.seed, self.epoch]).permutation(self.size)
        total = -(-self.size // self.world_size) * self.world_size
        order = np.resize(order, total) if self.size else order
        return order[self.rank :: self.world_size][self.start :]

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices().tolist())

    def __len__(self) -> int:
        return len(self.indices())
