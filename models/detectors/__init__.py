"""Person detectors: ``detector(images, frame) -> list[np.ndarray]``, per view (N, 5) x, y, w, h, score in pixels."""

from models.detectors.boxes import person_boxes
from models.detectors.file import FileDetector
from models.detectors.gt import GroundTruthDetector
from models.detectors.tv_detector import TorchvisionDetector

__all__ = ["FileDetector", "GroundTruthDetector", "TorchvisionDetector", "person_boxes"]
