"""Train the joint-candidate SPPE with the body+feet loss: ``python train.py [key=value ...]`` (configs/train.yaml)."""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from data.config_checks import ConfigError
from data.formats.atomic_io import exit_on_sigterm
from models.load_errors import CheckpointError, WeightsUnavailable
from models.resume import resume_config
from models.train_config import check_train_config
from run_folders import one_line_errors, register_resolvers

log = logging.getLogger(__name__)


@hydra.main(config_path="configs", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """Hydra entry point -> the last validation metrics; resume=<last.ckpt> restores that run's stored config."""
    hydra_cfg = HydraConfig.get()
    choices = {k: v for k, v in hydra_cfg.runtime.choices.items() if not k.startswith("hydra")}
    with one_line_errors(FileNotFoundError, ConfigError, CheckpointError, WeightsUnavailable, config=cfg):
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


register_resolvers()  # ${run_id:} in the run folder names, before hydra.main composes the config

if __name__ == "__main__":
    exit_on_sigterm()
    main()
