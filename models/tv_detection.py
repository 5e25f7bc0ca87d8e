"""torchvision detection models built by name, weights coco | <state-dict file> | null, run on BGR uint8 images."""

from __future__ import annotations

import numpy as np
import torch
import torchvision
from torch import Tensor, nn

from data.config_checks import fail
from models.tv_weights import check_state_fits, read_state_dict, with_download

COCO = "coco"  # weights value: the model's DEFAULT weights through torchvision's weights API


def build_detection_model(
    name: str, weights: str | None, group: str, **kwargs: object
) -> tuple[nn.Module, list[str] | None]:
    """(model in eval mode, its category names) for weights ``coco`` | a state-dict file | None."""
    known = torchvision.models.list_models(module=torchvision.models.detection)
    if name not in known:
        fail(f"{group}.model", name, f"not a torchvision detection model (known: {', '.join(sorted(known))})")
    builder = torchvision.models.get_model_builder(name)
    if weights == COCO:
        default = torchvision.models.get_model_weights(name).DEFAULT
        model = with_download(lambda: builder(weights=default, **kwargs), default, f"{group}.weights")
        return model.eval(), list(default.meta["categories"])
    model = builder(weights=None, weights_backbone=None, **kwargs)
    if weights is not None:
        state, what = read_state_dict(weights), f"torchvision's {type(model).__name__}"
        check_state_fits(model.state_dict(), state, str(weights), what, lambda k: k.endswith("num_batches_tracked"))
        model.load_state_dict(state, strict=False)
    return model.eval(), None


def image_tensor(image: np.ndarray, index: int) -> Tensor:
    """(H, W, 3) uint8 BGR -> (3, H, W) float32 RGB in [0, 1], torchvision's detection input."""
    if not (isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8):
        got = f"{image.shape} {image.dtype}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ValueError(f"image of view {index}: expected an (H, W, 3) uint8 BGR array, got {got}")
    return torch.from_numpy(np.ascontiguousarray(image[:, :, ::-1])).permute(2, 0, 1).float().div_(255.0)


def detect(model: nn.Module, images: list[np.ndarray], batch_size: int, device: torch.device) -> list[dict]:
    """torchvision's per-image output dicts (tensors moved to the cpu) for (H, W, 3) uint8 BGR ``images``."""
    outputs: list[dict] = []
    with torch.inference_mode():
        for start in range(0, len(images), batch_size):
            chunk = images[start : start + batch_size]
            batch = [image_tensor(img, start + i).to(device) for i, img in enumerate(chunk)]
            outputs += [{k: v.cpu() for k, v in out.items()} for out in model(batch)]
    return outputs
