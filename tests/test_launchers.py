"""Sweeps on existing engines: a two-job eval.py sweep through Hydra's joblib launcher (two processes), and the
SLURM launcher's config composing (no cluster here)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir

REPO = Path(__file__).resolve().parents[1]


def test_a_two_job_sweep_runs_in_parallel_with_the_joblib_launcher(tmp_path):
    sweep = tmp_path / "sweep"
    command = [sys.executable, "eval.py", "-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]
    command += ["dataset.num_frames=2", "dataset.num_persons=3", "dataset.seed=0,1", "progress=false"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    # the timeout: a parent that left without shutting its joblib workers down held the pipes for their 300 s idle time
    done = subprocess.run(
        [*command, f"hydra.sweep.dir={sweep}"], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = [json.loads((sweep / str(job) / "metrics.json").read_text())["metrics"] for job in (0, 1)]
    assert metrics[0]["num_gt"] == metrics[1]["num_gt"] == 6
    assert metrics[0]["mpjpe_mm"] != metrics[1]["mpjpe_mm"]  # two scenes (seeds), not one job twice
    assert "JoblibLauncher" in (sweep / "multirun.yaml").read_text()


def test_the_slurm_launcher_composes_with_its_documented_keys():
    with initialize_config_dir(str(REPO / "configs"), version_base="1.3"):
        overrides = ["hydra/launcher=submitit_slurm", "hydra.launcher.partition=gpu", "hydra.launcher.timeout_min=30"]
        cfg = compose("eval", overrides=overrides, return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")
    assert cfg.hydra.launcher.partition == "gpu" and cfg.hydra.launcher.timeout_min == 30
