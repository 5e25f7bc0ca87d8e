"""Shared by eval.py and train.py: unique run folders (``${run_id:}``, RunFolderGuard) and one-line errors."""

from __future__ import annotations

import fcntl
import os
import re
import shutil
from contextlib import contextmanager
from datetime import datetime
from functools import lru_cache
from pathlib import Path
from typing import IO, Any, Iterator

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, JobStatus
from hydra.errors import InstantiationException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from data.formats.atomic_io import is_stale, is_temporary

STAGING_SUFFIX = ".incomplete"  # <output_subdir>.incomplete: the config of a run that has not completed
SHOWN_FILES = 3  # files named in the refusal message
LOCK_NAME = ".run.lock"  # flock()ed by the run writing into the folder: a second run at once stops


@lru_cache(maxsize=1)
def run_id() -> str:
    """This process's run name, e.g. ``2025-05-01_13-45-07.123456_4242``; torchrun's ranks share ``torchrun_<id>``."""
    elastic = os.environ.get("TORCHELASTIC_RUN_ID")
    if elastic is not None:
        return f"torchrun_{elastic[:8] if elastic != 'none' else f'agent{os.getppid()}'}"
    return f"{datetime.now():%Y-%m-%d_%H-%M-%S.%f}_{os.getpid()}"


def register_resolvers() -> None:
    """Register ``${run_id:}`` with OmegaConf (once per process)."""
    if not OmegaConf.has_resolver("run_id"):
        OmegaConf.register_new_resolver("run_id", run_id, use_cache=True)


@contextmanager
def one_line_errors(*errors: type[Exception], config: DictConfig | None = None) -> Iterator[None]:
    """Stop with ``error: <message>`` on errors, and on a ``_target_``'s FileNotFoundError, TypeError, ValueError."""
    try:
        yield
    except errors as err:
        raise SystemExit(f"error: {err}") from None
    except InstantiationException as err:
        cause, full_key = err.__cause__, re.search(r"full_key: (\S+)$", str(err))
        if isinstance(cause, (*errors, FileNotFoundError)):
            raise SystemExit(f"error: {cause}") from None
        if isinstance(cause, (TypeError, ValueError)) and full_key:
            raise SystemExit(f"error: {keyed(full_key[1], str(cause), config)}") from None
        raise


def keyed(full_key: str, message: str, config: DictConfig | None) -> str:
    """A constructor's message naming its key with the group ('frames=5' -> 'dataset.frames=5'; 'group: ...')."""
    node = OmegaConf.select(config, full_key) if config is not None else None
    names = [str(k) for k in node] if isinstance(node, DictConfig) else []
    unknown = re.search(r"unexpected keyword argument '(\w+)'", message)
    if unknown and unknown[1] in names:  # a key its config file does not have, e.g. +dataset.camera=x
        group = full_key.split(".")[0]
        choice = HydraConfig.get().runtime.choices.get(group) if HydraConfig.initialized() else None
        return f"{full_key}.{unknown[1]}: not a key of {group}" + (
            f" (see configs/{group}/{choice}.yaml)" if choice else ""
        )
    if message.startswith(full_key.rsplit(".")[-1]):  # e.g. 'tracking: need ...'
        return message
    pattern = rf"(?<![\w.])({'|'.join(map(re.escape, names))})=" if names else "(?!)"
    message, named = re.subn(pattern, rf"{full_key}.\1=", message, count=1)
    return message if named else f"{full_key}: {message}"


def other_runs_files(folder: Path, log_name: str, limit: int = SHOWN_FILES) -> list[str]:
    """Up to limit files under folder (relative) other than temporaries and the job's log; deletes stale temporaries."""
    found: list[str] = []
    for root, _, names in os.walk(folder):
        for name in sorted(names):
            path = Path(root) / name
            if root == str(folder) and name in (log_name, LOCK_NAME):
                continue
            if is_temporary(path):
                if is_stale(path):
                    path.unlink(missing_ok=True)
                continue
            found.append(str(path.relative_to(folder)))
            if len(found) >= limit:
                return found
    return found


def check_folder(folder: Path, config: DictConfig, key: str) -> bool:
    """Stop with one line when folder holds another run's files and config.overwrite is off -> whether it does."""
    overwrite = bool(config.get("overwrite", False))
    files = other_runs_files(folder, f"{config.hydra.job.name}.log") if folder.is_dir() else []
    if files and not overwrite:
        shown = ", ".join(files) + (", ..." if len(files) >= SHOWN_FILES else "")
        raise SystemExit(
            f"error: {folder} already holds the files of another run ({shown}); "
            f"choose a new folder ({key}=...) or pass overwrite=true to write into it"
        )
    return bool(files)


def lock_folder(folder: Path, key: str) -> IO:
    """Create folder and hold its lock file (until closed or exit); one line when it cannot or another run holds it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = open(folder / LOCK_NAME, "a")
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return lock
    except BlockingIOError:  # flock: another process holds it
        raise SystemExit(f"error: {key}={folder} is in use by another run; choose another folder") from None
    except OSError as err:
        raise SystemExit(f"error: {key}={folder}: cannot write the run folder ({err.strerror or err})") from None


class RunFolderGuard(Callback):
    """Hydra callback: refuses a folder holding another run; overwrite=true stages .hydra/ until the run completes."""

    def __init__(self) -> None:
        self.staged: tuple[Path, Path] | None = None  # (.hydra.incomplete, .hydra) of an overwriting run
        self.lock: IO | None = None  # the run folder's lock file, held until the process exits

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Check hydra.run.dir before Hydra writes into it (rank 0 of a torchrun job; the others write no .hydra/)."""
        subdir = config.hydra.output_subdir
        if int(os.environ.get("RANK", "0")) > 0:
            with read_write(config.hydra), open_dict(config.hydra):
                config.hydra.output_subdir = None
            return
        folder = Path(config.hydra.run.dir)
        self.lock = lock_folder(folder, "hydra.run.dir")  # before the check: a run starting beside it waits for none
        occupied = check_folder(folder, config, "hydra.run.dir")
        if occupied and subdir is not None and (folder / subdir).exists():
            staging = f"{subdir}{STAGING_SUFFIX}"
            shutil.rmtree(folder / staging, ignore_errors=True)  # left by an earlier killed run
            with read_write(config.hydra), open_dict(config.hydra):
                config.hydra.output_subdir = staging
            self.staged = (folder / staging, folder / subdir)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Check hydra.sweep.dir before the launcher writes into it (its jobs' folders lie inside)."""
        check_folder(Path(config.hydra.sweep.dir), config, "hydra.sweep.dir")

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        """A completed overwriting run: its staged config replaces the earlier run's."""
        if self.staged is None or job_return.status != JobStatus.COMPLETED:
            return
        staging, final = self.staged
        old = final.with_name(final.name + ".replaced")
        shutil.rmtree(old, ignore_errors=True)
        final.rename(old)
        staging.rename(final)
        shutil.rmtree(old, ignore_errors=True)
        self.staged = None
