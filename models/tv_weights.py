"""Pretrained weights for the torchvision models of this repository: torchvision's weights API (a download
into torch's cache) or a local state-dict file. A failure is one ``WeightsUnavailable`` line naming the
config key, what was asked and what to do instead (e.g. on a machine that cannot download)."""

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


def cache_path(weights: WeightsEnum) -> Path:
    """Where torchvision's API looks for ``weights`` before downloading them: <torch hub dir>/checkpoints/<file>."""
    return Path(torch.hub.get_dir()) / "checkpoints" / weights.url.rsplit("/", 1)[-1]


def offline_message(weights: WeightsEnum, key: str, exc: BaseException) -> str:
    """The one line for a failed download of ``weights`` asked for by config key ``key``."""
    reason = getattr(exc, "reason", None) or exc.strerror or exc  # URLError.reason, else the OSError text
    return (
        f"{key}: cannot download {weights} from {weights.url} ({reason}); this machine cannot download: fetch "
        f"that file elsewhere and put it at {cache_path(weights)}, or give its path ({key}=/path/to/file.pth)"
    )


def with_download(load: Callable[[], T], weights: WeightsEnum, key: str) -> T:
    """load(), which may download ``weights`` through torchvision's API; a failed download -> WeightsUnavailable."""
    try:
        return load()
    except OSError as exc:  # URLError, socket errors, an unwritable cache: all OSErrors
        raise WeightsUnavailable(offline_message(weights, key, exc)) from None


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
    """ValueError naming ``source`` unless ``state`` has every key of ``own`` (except those ``may_miss``), no
    other key, and the same shapes."""
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
