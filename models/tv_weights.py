"""Pretrained weights of torchvision models: a weights API download or a state-dict file; WeightsUnavailable."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import TYPE_CHECKING, Callable, TypeVar

import torch
from torch import Tensor

from models.load_errors import WeightsUnavailable

if TYPE_CHECKING:
    from torchvision.models import WeightsEnum

T = TypeVar("T")


def with_download(load: Callable[[], T], weights: WeightsEnum, key: str) -> T:
    """load(), which may download ``weights`` through torchvision's API; a failed download -> WeightsUnavailable."""
    try:
        return load()
    except OSError as exc:  # URLError, socket errors, an unwritable cache: all OSErrors
        reason = getattr(exc, "reason", None) or exc.strerror or exc  # URLError.reason, else the OSError text
        cache = Path(torch.hub.get_dir()) / "checkpoints" / weights.url.rsplit("/", 1)[-1]  # where the API looks
        raise WeightsUnavailable(
            f"{key}: cannot download {weights} from {weights.url} ({reason}); this machine cannot download: fetch "
            f"that file elsewhere and put it at {cache}, or give its path ({key}=/path/to/file.pth)"
        ) from None


def download_state_dict(weights: WeightsEnum, key: str) -> dict[str, Tensor]:
    """The state dict of torchvision ``weights`` (from torch's cache, else downloaded and hash-checked)."""
    return with_download(lambda: weights.get_state_dict(progress=False, check_hash=True), weights, key)


def read_state_dict(path: str | Path) -> dict[str, Tensor]:
    """A state dict (name -> tensor) from a local file written by torch.save; ValueError naming the file."""
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        raise WeightsUnavailable(f"cannot read pretrained weights from {path}: {exc}") from None
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise WeightsUnavailable(f"{path}: expected a state dict (name -> tensor), got {type(state).__name__}")
    return state


def _listed(names: list[str], shown: int = 8) -> str:
    """At most ``shown`` names, then how many there are in all."""
    return str(names[:shown]) + (f" ... ({len(names)} in all)" if len(names) > shown else "")


def check_state_fits(
    own: dict[str, Tensor], state: dict[str, Tensor], source: str, what: str, may_miss: Callable[[str], bool]
) -> None:
    """ValueError naming source unless state has own's keys (but may_miss ones), no other, and the same shapes."""
    missing = sorted(k for k in own if k not in state and not may_miss(k))
    unexpected = sorted(k for k in state if k not in own)
    wrong_shape = sorted(
        f"{k}: file {tuple(v.shape)} vs model {tuple(own[k].shape)}"
        for k, v in state.items()
        if k in own and tuple(v.shape) != tuple(own[k].shape)
    )
    if missing or unexpected or wrong_shape:
        raise ValueError(
            f"{source} does not fit {what}: missing keys {_listed(missing)}, unexpected keys {_listed(unexpected)}, "
            f"wrong shapes {_listed(wrong_shape)}"
        )
