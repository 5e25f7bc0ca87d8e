"""Pretrained TFLite models that ship inside a pip wheel (MediaPipe 0.10's BlazePose), found and run offline."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from data.config_checks import ConfigError

INSTALL = "pip install --no-deps -r requirements-models.txt"
MEDIAPIPE_FILES = {
    "pose_detection": "modules/pose_detection/pose_detection.tflite",
    "pose_landmark_full": "modules/pose_landmark/pose_landmark_full.tflite",
}


def mediapipe_model(name: str, key: str) -> Path:
    """The path of MediaPipe's ``name`` model inside the installed wheel (nothing imported); a ConfigError if absent."""
    spec = importlib.util.find_spec("mediapipe")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(f"{key}: BlazePose's weights come with the mediapipe 0.10 wheel, not installed: {INSTALL}")
    path = Path(next(iter(spec.submodule_search_locations))) / MEDIAPIPE_FILES[name]
    if not path.is_file():
        raise ConfigError(
            f"{key}: the installed mediapipe has no {MEDIAPIPE_FILES[name]} (1.x wheels ship no models): {INSTALL}"
        )
    return path


def interpreter_class(key: str) -> type:
    """The TFLite Interpreter class of ai-edge-litert (or TensorFlow's); a ConfigError naming the pip command if absent."""
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        try:
            from tensorflow.lite import Interpreter  # type: ignore[no-redef]
        except ImportError:
            raise ConfigError(f"{key}: running BlazePose needs a TFLite runtime (ai-edge-litert): {INSTALL}") from None
    return Interpreter


class TFLiteModel:
    """One .tflite network: ``model(batch (B, H, W, C) float32) -> its outputs (B, ...)``; B > 1 only where the graph allows."""

    def __init__(self, path: Path, key: str, threads: int = 1) -> None:
        self.interpreter = interpreter_class(key)(model_path=str(path), num_threads=threads)
        self.input = self.interpreter.get_input_details()[0]
        self.outputs = [d["index"] for d in self.interpreter.get_output_details()]
        self.input_size = tuple(int(s) for s in self.input["shape"][1:3])  # (H, W)
        self.batch = 0

    def __call__(self, batch: np.ndarray) -> list[np.ndarray]:
        """(B, H, W, C) float32 -> the outputs with a leading batch axis B."""
        batch = np.ascontiguousarray(batch, np.float32)
        if len(batch) != self.batch:
            self.interpreter.resize_tensor_input(self.input["index"], list(batch.shape))
            self.interpreter.allocate_tensors()
            self.batch = len(batch)
        self.interpreter.set_tensor(self.input["index"], batch)
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(i).copy() for i in self.outputs]
