"""Person detectors (the stage before the SPPE): ``detector(images, frame) -> list[np.ndarray]``, per view an
(N, 5) float64 array x, y, w, h, score in pixels of the image. ``needs_images`` says whether the
detector looks at the pixels (the others take the images only for their size, or not at all).

``gt`` (GroundTruthDetector): the frame's ground-truth boxes; ``file`` (FileDetector): a COCO
detection-results file; ``torchvision`` (TorchvisionDetector): a torchvision detection model.
"""

from models.detectors.boxes import person_boxes
from models.detectors.file import FileDetector
from models.detectors.gt import GroundTruthDetector
from models.detectors.tv_detector import TorchvisionDetector

__all__ = ["FileDetector", "GroundTruthDetector", "TorchvisionDetector", "person_boxes"]
