"""The experiment configs run as Hydra multiruns, and benchmarks.gather_sweep tabulates them."""

import json
import subprocess
import sys
from pathlib import Path

from benchmarks.gather_sweep import main as gather_main
from benchmarks.gather_sweep import sweep_table

REPO = Path(__file__).resolve().parents[1]


def table_rows(table: str) -> list[list[str]]:
    """The cells of a markdown table, header row first, separator dropped."""
    lines = [line for line in table.splitlines() if not line.startswith("|-")]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines]


def test_matching_ablation_experiment_runs_and_gathers(tmp_path):
    sweep = tmp_path / "sweep"
    cmd = [
        sys.executable,
        "eval.py",
        "-m",
        "+experiment=matching_ablation",
        "matching=oracle,feet",
        "dataset.num_frames=1",
        "dataset.num_persons=6",
        "progress=false",
        f"hydra.sweep.dir={sweep}",
    ]
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert (sweep / "dataset.num_frames=1,dataset.num_persons=6,matching=oracle" / "metrics.json").exists()

    cmd = [sys.executable, "-m", "benchmarks.gather_sweep", str(sweep), "--out", str(tmp_path / "t.md")]
    proc = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=REPO, timeout=60)
    header, *rows = table_rows(proc.stdout)
    assert header[0] == "matching" and [r[0] for r in rows] == ["feet", "oracle"]
    assert float(rows[1][header.index("matching precision (%)")]) == 100.0
    assert (tmp_path / "t.md").read_text() == proc.stdout


def fake_run(root: Path, name: str, overrides: list[str], metrics: dict, matching_s: float, frames: int) -> None:
    """A run directory as eval.py writes it, reduced to what gather_sweep reads."""
    (root / name / ".hydra").mkdir(parents=True)
    timings = {"dataset": 1.0, "matching": matching_s}
    (root / name / "metrics.json").write_text(
        json.dumps({"metrics": metrics, "skipped": {}, "unmatched": {}, "timings_s": timings})
    )
    (root / name / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (root / name / ".hydra" / "config.yaml").write_text(f"dataset:\n  num_frames: {frames}\n")


def test_gather_sweep_rows_of_fake_runs(tmp_path, capsys):
    base = {
        "matching_precision": 0.5,
        "matching_recall": 0.25,
        "matching_recovered_share": 0.125,
        "mpjpe_mm": 40.04,
        "pcp_average": 90.0,
    }
    fake_run(tmp_path, "b", ["+experiment=x", "matching.k2=1", "progress=False"], base, 0.2, 10)
    fake_run(
        tmp_path,
        "a",
        ["+experiment=x", "matching.k2=0.5", "progress=False"],
        {**base, "matching_precision": 1.0, "mpjpe_mm": 30.0},
        0.05,
        10,
    )
    (tmp_path / "multirun.yaml").write_text("{}\n")

    headers, rows = sweep_table(tmp_path)
    assert headers == [
        "matching.k2",
        "matching precision (%)",
        "matching recall (%)",
        "persons recovered (%)",
        "MPJPE (mm)",
        "PCP (%)",
        "matching ms/frame",
    ]
    assert rows == [
        ["0.5", "100.0", "25.0", "12.5", "30.0", "90.0", "5.00"],
        ["1", "50.0", "25.0", "12.5", "40.0", "90.0", "20.00"],
    ]

    table = gather_main([str(tmp_path), "--metrics", "mpjpe_mm,missing", "--out", str(tmp_path / "t.md")])
    expected = [["matching.k2", "MPJPE (mm)", "missing"], ["0.5", "30.0", "-"], ["1", "40.0", "-"]]
    assert table_rows(table) == expected
    assert capsys.readouterr().out == table + "\n" == (tmp_path / "t.md").read_text()
