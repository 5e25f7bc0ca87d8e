"""Run folders of the Hydra entry points (eval.py, train.py): unique names, and no run writing over another.

- ``${run_id:}`` (an OmegaConf resolver, registered by :func:`register_resolvers` before ``hydra.main``)
  names a run: the start time to the microsecond and the process id, e.g. ``2025-05-01_13-45-07.123456_4242``.
  Two runs started in the same second, on one host, get two folders. The ranks of a torchrun job share one:
  ``torchrun_<rendezvous id>``.
- :class:`RunFolderGuard` (a Hydra callback listed under ``hydra.callbacks`` in the configs) checks the run
  folder (the sweep folder of a multirun) before Hydra writes anything into it: a folder that already holds
  files of another run stops the run with one line, unless ``overwrite=true``. Stale temporaries of killed
  writers (data/formats/atomic_io.py) do not count and are removed.
- With ``overwrite=true`` over a folder that holds an earlier run's ``.hydra/``, the new run's ``.hydra/`` is
  written as ``.hydra.incomplete/`` and replaces ``.hydra/`` only when the run completes: a run killed
  part-way never leaves a ``.hydra/`` that describes it beside the earlier run's outputs.
"""

from __future__ import annotations

import os
import shutil
from datetime import datetime
from functools import lru_cache
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from data.formats.atomic_io import is_stale, is_temporary

STAGING_SUFFIX = ".incomplete"  # <output_subdir>.incomplete: the config of a run that has not completed
SHOWN_FILES = 3  # files named in the refusal message


@lru_cache(maxsize=1)
def run_id() -> str:
    """This process's run name: start time with microseconds, then the pid (fixed for the process). Under
    torchrun every rank must find the same folder: the rendezvous id (a uuid with --standalone) or the agent's pid."""
    elastic = os.environ.get("TORCHELASTIC_RUN_ID")
    if elastic is not None:
        return f"torchrun_{elastic[:8] if elastic != 'none' else f'agent{os.getppid()}'}"
    return f"{datetime.now():%Y-%m-%d_%H-%M-%S.%f}_{os.getpid()}"


def register_resolvers() -> None:
    """Register ``${run_id:}`` with OmegaConf (once per process)."""
    if not OmegaConf.has_resolver("run_id"):
        OmegaConf.register_new_resolver("run_id", run_id, use_cache=True)


def other_runs_files(folder: Path, log_name: str, limit: int = SHOWN_FILES) -> list[str]:
    """Up to limit files under folder (relative paths) that are not temporaries or the job's log (which holds no
    output, and which the other ranks of a torchrun job may have opened already); stale temporaries are deleted."""
    found: list[str] = []
    for root, _, names in os.walk(folder):
        for name in sorted(names):
            path = Path(root) / name
            if root == str(folder) and name == log_name:
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


class RunFolderGuard(Callback):
    """Hydra callback: refuse a run folder that holds another run, stage ``.hydra/`` when overwriting."""

    def __init__(self) -> None:
        self.staged: tuple[Path, Path] | None = None  # (.hydra.incomplete, .hydra) of an overwriting run

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Check hydra.run.dir before Hydra writes into it (rank 0 of a torchrun job; the others write no .hydra/)."""
        subdir = config.hydra.output_subdir
        if int(os.environ.get("RANK", "0")) > 0:
            with read_write(config.hydra), open_dict(config.hydra):
                config.hydra.output_subdir = None
            return
        folder = Path(config.hydra.run.dir)
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
