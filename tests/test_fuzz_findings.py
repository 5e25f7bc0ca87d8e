"""Fuzz findings of the command lines: bad stage keys, frame ranges, run folders, metrics.json, checkpoints' temporaries
and `python -m` outside the repository each end as one `error:` line (or run correctly)."""

from __future__ import annotations

import fcntl
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from data.config_checks import KINDS, ConfigError, check_target, target_hints
from data.datasets.files import load_files
from data.formats.atomic_io import _host
from models.checkpoint_io import KEYS, read_checkpoint, write_checkpoint
from run_folders import LOCK_NAME, keyed

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
OWN_RIG = REPO / "examples" / "own_rig"
FILES = ["dataset=files", f"dataset.cameras={OWN_RIG / 'cameras.json'}", f"dataset.poses2d={OWN_RIG / 'poses2d.json'}"]
STAGES = ("noise_model", "matching", "reconstruction", "tracking")


def eval_run(tmp_path: Path, *overrides: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    """eval.py with these overrides, quick settings, into tmp_path/run."""
    run_dir = [] if any(o.startswith("hydra.run.dir=") for o in overrides) else [f"hydra.run.dir={tmp_path / 'run'}"]
    cmd = [sys.executable, str(REPO / "eval.py"), "progress=false", *run_dir, *overrides]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, timeout=120)


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    """The single stderr line of a run that failed (asserted)."""
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1, proc.stderr[-2000:]
    return proc.stderr.strip()


def choices(group: str) -> list[str]:
    """The config files of a group."""
    return sorted(p.stem for p in (CONFIGS / group).glob("*.yaml"))


@pytest.mark.parametrize(
    "override, message",
    [
        ("matching.reject_rate=abc", "error: matching.reject_rate='abc': must be a finite number"),
        ("+dataset.camera=x", "error: dataset.camera: not a key of dataset (see configs/dataset/synthetic.yaml)"),
        ("matching.min_score=2", "error: matching.min_score=2: must be a score in [0, 1]"),
        (  # a constructor's own range check: the group named before its message
            "matching.reject_rate=2",
            "error: matching: need 0 < reject_rate < 1, min_dof >= 1, min_views >= 1, evidence_per_dof >= 0; "
            "got 2, 2, 2, 2.0",
        ),
        ("dataset.seed=abc", "error: synthetic dataset option dataset.seed='abc' must be int"),
    ],
)
def test_a_bad_stage_key_stops_with_one_line_naming_it_with_its_group(tmp_path, override, message):
    proc = eval_run(tmp_path, override, "dataset.num_frames=1")
    assert one_line_error(proc) == message and not (tmp_path / "run" / "poses3d.json").exists()


def test_every_number_of_the_stages_refuses_nan_and_inf_and_every_shipped_config_passes():
    checked = 0
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        for group in ("dataset", *STAGES):
            for choice in choices(group):
                cfg = compose(config_name="eval", overrides=[f"{group}={choice}"])
                check_target(cfg, group)  # the shipped values pass
                target = cfg[group].get("_target_")
                hints = target_hints(target) if target else {}
                floats = [k for k, h in hints.items() if h.startswith("float")]
                for name in (k for k in floats if k in cfg[group] and group in STAGES):
                    for bad in (math.nan, math.inf, -math.inf):
                        bad_cfg = cfg.copy()
                        OmegaConf.update(bad_cfg, f"{group}.{name}", bad)
                        with pytest.raises(ConfigError) as err:
                            check_target(bad_cfg, group)
                        null = " or null" if hints[name].endswith(" | None") else ""
                        assert str(err.value) == f"{group}.{name}={bad!r}: must be {KINDS['float'][1]}{null}"
                        checked += 1
    assert checked >= 3 * 100  # every float key of every matcher, noise model, reconstruction and tracker


def test_a_constructor_message_gets_the_group_of_its_key():
    config = OmegaConf.create({"dataset": {"frames": "5:1", "seed": 0}})
    assert keyed("dataset", "frames='5:1': selects no frame", config) == "dataset.frames='5:1': selects no frame"
    assert keyed("dataset", "bad seed", config) == "dataset: bad seed"
    assert keyed("tracking", "tracking: need seed=1", config) == "tracking: need seed=1"  # already named


def test_a_frame_range_is_clamped_to_the_files_frames_in_its_order(capsys):
    sequence = load_files(OWN_RIG / "cameras.json", OWN_RIG / "poses2d.json", "0:100000")
    assert [f.index for f in sequence.frames] == list(range(100, 140))  # the example's frames 100..139
    assert capsys.readouterr().err == "warning: dataset.frames: 100000 frames clamped to the file's 100..139\n"
    sequence = load_files(OWN_RIG / "cameras.json", OWN_RIG / "poses2d.json", "102:0:-1")
    assert [f.index for f in sequence.frames] == [102, 101, 100]
    assert capsys.readouterr().err == "warning: dataset.frames: 102 frames clamped to the file's 100..139\n"
    sequence = load_files(OWN_RIG / "cameras.json", OWN_RIG / "poses2d.json", "101:102")
    assert [f.index for f in sequence.frames] == [101] and capsys.readouterr().err == ""  # within: no line


@pytest.mark.parametrize("frames", ["5:1", "[]"])
def test_frames_that_select_nothing_stop_with_one_line(tmp_path, frames):
    proc = eval_run(tmp_path, *FILES, f"dataset.frames={frames}")
    shown = "'5:1'" if frames == "5:1" else "[]"
    assert one_line_error(proc) == (
        f"error: dataset.frames={shown}: selects no frame ({OWN_RIG / 'poses2d.json'} holds frames 100..139)"
    )


def test_a_run_folder_that_cannot_be_created_stops_with_one_line(tmp_path):
    proc = eval_run(tmp_path, "hydra.run.dir=/proc/nope/run")
    assert (
        one_line_error(proc)
        == "error: hydra.run.dir=/proc/nope/run: cannot write the run folder (No such file or directory)"
    )


def test_a_run_folder_in_use_by_another_run_stops_the_second_with_one_line(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    with open(folder / LOCK_NAME, "a") as held:  # as the first run holds it
        fcntl.flock(held, fcntl.LOCK_EX)
        proc = eval_run(tmp_path, "dataset.num_frames=1")
    assert one_line_error(proc) == f"error: hydra.run.dir={folder} is in use by another run; choose another folder"
    assert [p.name for p in folder.iterdir()] == [LOCK_NAME]  # nothing written beside the first run's files


def test_metrics_json_holds_null_where_a_metric_is_undefined(tmp_path):
    proc = eval_run(tmp_path, "dataset.miss_rate=1.0", "dataset.num_frames=1", "dataset.num_persons=2")
    assert proc.returncode == 0, proc.stderr[-2000:]

    def refuse(constant: str) -> None:
        raise ValueError(f"metrics.json holds {constant}")

    doc = json.loads((tmp_path / "run" / "metrics.json").read_text(), parse_constant=refuse)
    assert doc["metrics"]["mpjpe_mm"] is None  # nothing reconstructed: undefined, not NaN


def test_resuming_removes_the_partial_checkpoints_of_a_sigkilled_run(tmp_path):
    last = tmp_path / "checkpoints" / "last.ckpt"
    write_checkpoint({k: 0 for k in KEYS["resume"]}, last, "resume")
    writer = (
        "import sys, time\nfrom data.formats.atomic_io import atomic_open\n"
        f"with atomic_open({str(last)!r}, binary=True) as f:\n"
        "    f.write(b'half a checkpoint'); f.flush(); print('writing', flush=True); time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", writer], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.kill()  # SIGKILL: no handler removes the temporary
    proc.wait()
    live = last.parent / f".best.pth.{_host()}.{os.getpid()}.x.tmp"  # a writer still running keeps its temporary
    live.write_bytes(b"")
    (partial,) = [p for p in last.parent.iterdir() if p.name.startswith(".last.ckpt.")]
    assert read_checkpoint(last, "resume")["epoch"] == 0
    assert sorted(p.name for p in last.parent.iterdir()) == sorted(["last.ckpt", live.name]) and not partial.exists()
    assert torch.load(last, weights_only=False)["kind"] == "resume"  # the checkpoint itself untouched


def test_python_m_outside_the_repository_fails_in_one_line_and_runs_with_the_documented_pythonpath(tmp_path):
    cmd = [sys.executable, "-m", "data.geometry.check_rig", "--help"]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    outside = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)
    assert outside.returncode != 0 and outside.stderr.count("\n") == 1 and "No module named 'data'" in outside.stderr
    inside = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env={**env, "PYTHONPATH": str(REPO)})
    assert inside.returncode == 0 and "usage:" in inside.stdout
    usage = " ".join((REPO / "docs" / "usage.md").read_text().split())
    assert "The tools run as python -m are modules of this repository, not an installed package" in usage
    assert "`PYTHONPATH`" in usage


def test_finite_writes_numpy_nan_and_inf_as_null():
    import json

    import numpy as np

    from data.formats.strict_json import finite

    doc = {"ap": np.float64("nan"), "loss": [1.0, float("inf")], "n": 3}
    assert json.loads(json.dumps(finite(doc))) == {"ap": None, "loss": [1.0, None], "n": 3}
