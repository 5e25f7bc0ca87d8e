"""Train the joint-candidate SPPE with the multi-modal body+feet loss: ``python train.py [key=value ...]``.

See configs/train.yaml for the commands (experiments, sweeps, resume, torchrun). This file is the command:
it checks the config and the resume checkpoint, then runs the loop of models/train_loop.py, whose pieces live
in models/training.py. Torch is imported only to read a resume checkpoint or once the config has passed its
checks, so that a typo stops in about a second.
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from omegaconf import DictConfig

from data.config_checks import ConfigError
from data.formats.atomic_io import exit_on_sigterm
from models.load_errors import CheckpointError, WeightsUnavailable
from models.resume import resume_config
from models.train_config import check_train_config
from run_folders import register_resolvers

log = logging.getLogger(__name__)


@hydra.main(config_path="configs", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """Hydra entry point; returns the last validation metrics (for sweeps). With resume=<last.ckpt> the stored
    config of that run is restored (models/resume.py). A missing or damaged file, a bad config value or an
    unsafe override of a resumed run stops with one line."""
    hydra_cfg = HydraConfig.get()
    choices = {k: v for k, v in hydra_cfg.runtime.choices.items() if not k.startswith("hydra")}
    try:
        checkpoint = None
        if cfg.resume:
            from models.checkpoint_io import read_checkpoint  # torch

            checkpoint = read_checkpoint(cfg.resume, "resume")
            cfg = resume_config(cfg, checkpoint, list(hydra_cfg.overrides.task), choices, cfg.resume)
            choices = checkpoint.get("choices")
            log.info("resuming %s with its stored config", cfg.resume)
        check_train_config(cfg)
        from models.train_loop import run  # torch, the data pipeline and the model

        return run(cfg, Path(hydra_cfg.runtime.output_dir), checkpoint, choices)["metrics"]
    except (FileNotFoundError, ConfigError, CheckpointError, WeightsUnavailable) as err:
        raise SystemExit(f"error: {err}") from None
    except InstantiationException as err:  # e.g. model.pretrained=imagenet on a machine that cannot download
        if isinstance(err.__cause__, (FileNotFoundError, ValueError)):
            raise SystemExit(f"error: {err.__cause__}") from None
        raise


register_resolvers()  # ${run_id:} in the run folder names, before hydra.main composes the config

if __name__ == "__main__":
    exit_on_sigterm()
    main()
