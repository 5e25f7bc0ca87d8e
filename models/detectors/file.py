"""Person boxes from a COCO detection-results file (AlphaPose / mmpose convention), looked up by image id."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data.config_checks import ConfigError, fail, is_int, is_number
from data.formats.coco_detections import read_coco_detections
from data.multiview import Frame
from models.detectors.boxes import no_boxes, with_scores


class FileDetector:
    """The boxes of ``path`` of category_id with score >= score_threshold, per view by ``frame.image_ids[v]``."""

    needs_images = False

    def __init__(self, path: str | Path, category_id: int = 1, score_threshold: float = 0.0) -> None:
        if not is_int(category_id):
            fail("detector.category_id", category_id, "must be an integer (COCO: person = 1)")
        if not is_number(score_threshold):
            fail("detector.score_threshold", score_threshold, "must be a finite number")
        self.path = Path(path)
        dets = read_coco_detections(self.path)
        self._image_ids = dets.image_ids  # every entry's, for check_image_ids
        keep = (dets.category_ids == category_id) & (dets.scores >= score_threshold)
        boxes = with_scores(dets.boxes[keep], dets.scores[keep])
        ids = dets.image_ids[keep]
        self._boxes: dict[int, np.ndarray] = {int(i): boxes[ids == i] for i in np.unique(ids)}
        self._file_sizes: dict[int, tuple[int, int]] = {}

    def set_file_sizes(self, sizes: dict[int, tuple[int, int]]) -> None:
        """Image id -> (w, h) of the file the detections were made on; boxes are rescaled to the images seen."""
        self._file_sizes = {int(k): (int(w), int(h)) for k, (w, h) in sizes.items()}

    def check_image_ids(self, known: set[int]) -> None:
        """ConfigError (one line in eval.py) naming the first entry (file order) whose image id is not in ``known``."""
        for entry, image_id in enumerate(self._image_ids.tolist()):
            if image_id not in known:
                raise ConfigError(
                    f"{self.path}: entry {entry}: image_id {image_id} is not an image of the dataset "
                    f"({len(known)} known image ids; dataset.frames selects which)"
                )

    def boxes_of(self, image_id: int) -> np.ndarray:
        """(N, 5) x, y, w, h, score of one image (a copy; (0, 5) when the file has none)."""
        return self._boxes.get(int(image_id), no_boxes()).copy()

    def __call__(self, images: list[np.ndarray] | None, frame: Frame) -> list[np.ndarray]:
        """Per view (N, 5) x, y, w, h, score for ``frame.image_ids``; images (H, W, 3) only give sizes to rescale to."""
        if frame.image_ids is None:
            raise ValueError(
                f"{self.path}: frame {frame.index} has no image ids; detector=file needs a dataset that numbers "
                "its images (COCO image ids)"
            )
        boxes = [self.boxes_of(image_id) for image_id in frame.image_ids]
        if images is None or not self._file_sizes:
            return boxes
        for b, image, image_id in zip(boxes, images, frame.image_ids):
            w, h = self._file_sizes.get(int(image_id), (image.shape[1], image.shape[0]))
            b[:, [0, 2]] *= image.shape[1] / w
            b[:, [1, 3]] *= image.shape[0] / h
        return boxes
