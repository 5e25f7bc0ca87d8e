"""Run folders of eval.py: unique names, no run writing over another, a killed run leaves the earlier outputs."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from omegaconf import OmegaConf

from data.formats.atomic_io import _host

REPO = Path(__file__).resolve().parents[1]
QUICK = ["progress=false", "dataset.num_frames=1", "dataset.num_persons=3", "reconstruction=vanilla"]


def eval_cmd(*overrides: str) -> list[str]:
    """The eval.py command line with these overrides."""
    return [sys.executable, "eval.py", *QUICK, *overrides]


def run(cmd: list[str]) -> subprocess.CompletedProcess:
    """Run cmd from the repository root."""
    return subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=120)


def test_two_runs_started_together_keep_both_outputs(tmp_path):
    procs = [
        subprocess.Popen(
            eval_cmd(f"hydra.run.dir={tmp_path}/${{run_id:}}", f"dataset.seed={seed}"),
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for seed in (1, 2)
    ]
    assert all(p.wait(timeout=120) == 0 for p in procs), [p.stderr.read()[-2000:] for p in procs]
    folders = sorted(tmp_path.iterdir())
    assert len(folders) == 2
    seeds = {OmegaConf.load(f / ".hydra" / "config.yaml").dataset.seed for f in folders}
    assert seeds == {1, 2} and all((f / "metrics.json").is_file() and (f / "report.txt").is_file() for f in folders)


def test_a_reused_run_folder_is_refused_without_overwrite(tmp_path):
    folder = tmp_path / "run"
    assert run(eval_cmd(f"hydra.run.dir={folder}")).returncode == 0
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    proc = run(eval_cmd(f"hydra.run.dir={folder}", "dataset.seed=5"))
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: {folder} already holds the files of another run")
    assert "overwrite=true" in proc.stderr
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before  # untouched, .hydra/ too
    proc = run(eval_cmd(f"hydra.run.dir={folder}", "dataset.seed=5", "overwrite=true"))
    assert proc.returncode == 0, proc.stderr
    assert "seed: 5" in (folder / ".hydra" / "config.yaml").read_text() and not (folder / ".hydra.incomplete").exists()


def test_a_killed_overwriting_run_leaves_the_earlier_outputs_and_nothing_a_later_run_trips_over(tmp_path):
    folder = tmp_path / "run"
    assert run(eval_cmd(f"hydra.run.dir={folder}")).returncode == 0
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file() and p.suffix != ".log"}
    stale = folder / f".poses3d.json.{_host()}.999999999.x.tmp"
    stale.write_text("half")  # as a SIGKILLed writer leaves it
    proc = subprocess.Popen(
        eval_cmd(f"hydra.run.dir={folder}", "overwrite=true", "dataset.num_frames=400"),
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not (folder / ".hydra.incomplete" / "overrides.yaml").exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()[-2000:]
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    after = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file() and ".hydra.incomplete" not in str(p)}
    assert {p: b for p, b in after.items() if p.suffix != ".log"} == before  # .hydra/ still the earlier run's
    proc = run(eval_cmd(f"hydra.run.dir={folder}", "overwrite=true", "dataset.seed=3"))
    assert proc.returncode == 0, proc.stderr
    assert not list(folder.rglob("*.tmp")) and not (folder / ".hydra.incomplete").exists()
    assert "seed: 3" in (folder / ".hydra" / "config.yaml").read_text()
