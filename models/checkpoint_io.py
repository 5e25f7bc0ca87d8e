"""train.py's checkpoints: a versioned envelope (format, version, kind, sha256, payload); unpickled: trusted only."""

from __future__ import annotations

import hashlib
import io
import logging
from contextlib import suppress
from pathlib import Path
from typing import Any

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn

from data.formats.atomic_io import atomic_open, remove_stale_temporaries
from models.load_errors import CheckpointError

log = logging.getLogger(__name__)

FORMAT = "multiview-crowd-pose/train-checkpoint"
VERSION = 2  # 1: the plain state dict written before the envelope
KEYS = {
    "resume": ("model", "optimizer", "scheduler", "epoch", "step_in_epoch", "global_step", "best_ap", "rng", "config"),
    "weights": ("model", "epoch", "global_step", "config"),
}
ENVELOPE_KEYS = ("format", "version", "kind", "sha256", "payload")


def write_checkpoint(state: dict, path: str | Path, kind: str) -> None:
    """Write state (a dict holding KEYS[kind]) to path atomically, in the envelope with its sha256."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    payload = buffer.getvalue()
    envelope = {"format": FORMAT, "version": VERSION, "kind": kind, "sha256": hashlib.sha256(payload).hexdigest()}
    with atomic_open(path, binary=True, fsync=True) as f:  # a temporary file beside path, renamed over it
        torch.save({**envelope, "payload": torch.frombuffer(bytearray(payload), dtype=torch.uint8)}, f)


def _load(source: str | Path | io.BytesIO, path: Path, what: str) -> Any:
    """torch.load onto the CPU; any failure -> CheckpointError naming path."""
    try:
        return torch.load(source, map_location="cpu", weights_only=False)
    except Exception as err:  # truncated zip, random bytes, bad pickle: torch raises many kinds
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(
            f"{path}: {what} cannot be read ({reason[:120]}); the file is truncated, corrupted "
            "or not a train.py checkpoint"
        ) from None


def _unwrap(outer: Any, path: Path) -> tuple[dict, str]:
    """The state dict and kind of a loaded file (the envelope checked, or a pre-envelope state dict)."""
    if isinstance(outer, dict) and outer.get("format") == FORMAT:
        missing = [k for k in ENVELOPE_KEYS if k not in outer]
        if missing:
            raise CheckpointError(f"{path}: checkpoint envelope lacks {', '.join(missing)}")
        if not isinstance(outer["version"], int) or outer["version"] > VERSION:
            raise CheckpointError(
                f"{path}: checkpoint format version {outer['version']!r}; this code reads up to {VERSION}"
            )
        payload = outer["payload"].numpy().tobytes() if isinstance(outer["payload"], torch.Tensor) else None
        if payload is None or hashlib.sha256(payload).hexdigest() != outer["sha256"]:
            raise CheckpointError(f"{path}: checksum mismatch, the file is corrupted")
        return _load(io.BytesIO(payload), path, "the checked payload"), outer["kind"]
    if isinstance(outer, dict) and "model" in outer and "config" in outer:
        log.warning(
            "%s: checkpoint written before format version %d: no checksum to verify, loaded unchecked", path, VERSION
        )
        return outer, "resume" if "optimizer" in outer else "weights"
    raise CheckpointError(f"{path}: not a train.py checkpoint")


def read_checkpoint(path: str | Path, kind: str | None = None) -> dict:
    """The checked state dict of a train.py file; kind 'resume' also refuses a weights-only file (best.pth)."""
    path = Path(path)
    if kind == "resume":  # a killed run's partial checkpoints: its resumed run saves into another folder
        with suppress(OSError):  # a read-only folder keeps them
            remove_stale_temporaries(path.parent)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    if path.stat().st_size == 0:
        raise CheckpointError(f"{path}: empty file, not a checkpoint")
    state, found = _unwrap(_load(path, path, "the file"), path)
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: the checked payload is not a state dict")
    if kind == "resume" and found != "resume":
        raise CheckpointError(
            f"{path}: holds model weights only (like best.pth); resume needs the run's checkpoints/last.ckpt"
        )
    missing = [k for k in KEYS.get(found, ()) if k not in state]
    if found not in KEYS or missing:
        raise CheckpointError(f"{path}: {found!r} checkpoint lacks {', '.join(missing) or 'a known kind'}")
    return state


def load_trained_model(path: str | Path, device: torch.device) -> tuple[nn.Module, DictConfig]:
    """The network of a train.py checkpoint or weights file, in eval mode on device, and its training config."""
    checkpoint = read_checkpoint(path)  # a missing or damaged file -> FileNotFoundError / CheckpointError
    train_cfg = OmegaConf.create(checkpoint["config"])
    model = instantiate(train_cfg.model, pretrained=None)  # the weights come from the checkpoint
    model.load_state_dict(checkpoint["model"])
    return model.to(device).eval(), train_cfg
