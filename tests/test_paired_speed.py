"""benchmarks/paired_speed.py: reading benchmarks.speed's table, and the paired differences; the frames driver
(benchmarks/frame_times.py) and the process driver."""

import argparse
from pathlib import Path

import numpy as np
import pytest
from hydra.utils import instantiate

from benchmarks import frame_times
from benchmarks.paired_speed import PROCESS_SETTING, paired_difference, report, run_process, stage_medians

ROOT = Path(__file__).resolve().parents[1]

OUTPUT = """Per frame by stage, ms (median over frames x repeats, one core; ...)

| setting                   | frames | grouping | matching | reconstruction | tracking | total | target | issue's figure | figure / total |
|---------------------------|--------|----------|----------|----------------|----------|-------|--------|----------------|----------------|
| Shelf 300-600             | 301    | 0.29     | 0.35     | 0.57           | 0.06     | 1.31  | 2.40   | 4.86           | 3.70           |
| 100 people x 7 ring views | 4      | -        | 6.99     | 8.99           | 0.63     | 16.61 | 15.00  | 37.00          | 2.23           |

References in the same run, same inputs (ms per frame, median)

| what                         | setting                   | ours | reference | reference / ours |
|------------------------------|---------------------------|------|-----------|------------------|
| MAP compiled vs solver=numpy | 100 people x 7 ring views | 8.01 | 149.28    | 18.63            |
"""


def test_the_stage_medians_are_read_from_the_first_table_only():
    rows = stage_medians(OUTPUT)
    assert list(rows) == ["Shelf 300-600", "100 people x 7 ring views"]
    assert rows["100 people x 7 ring views"] == {
        "matching": 6.99,
        "reconstruction": 8.99,
        "tracking": 0.63,
        "total": 16.61,
    }
    with pytest.raises(ValueError, match="no table"):
        stage_medians("the benchmark printed nothing")


def test_the_paired_difference_is_the_mean_and_standard_error_of_the_differences():
    base, ours = [16.1, 14.9, 17.4, 18.8], [14.0, 14.0, 17.0, 17.0]
    mean, se = paired_difference(base, ours)
    diff = np.subtract(ours, base)
    assert mean == pytest.approx(diff.mean()) and se == pytest.approx(diff.std(ddof=1) / 2)
    assert np.isnan(paired_difference([1.0], [2.0])[1])
    with pytest.raises(ValueError):
        paired_difference([1.0, 2.0], [1.0])


def test_the_report_lists_every_pair_and_each_stage_difference():
    one = stage_medians(OUTPUT)
    faster = {s: {c: v - 1.0 for c, v in stages.items()} for s, stages in one.items()}
    text = report({"baseline": [one, one], "this tree": [faster, faster]}, "abc123")
    assert text.count("| 100 people x 7 ring views |") == 2 + 4  # two pairs, four stages
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if "| total " in line]
    assert ["100 people x 7 ring views", "total", "16.61", "15.61", "1.06", "-1.00", "0.00"] in rows
    untracked = {s: {**stages, "tracking": 0.0} for s, stages in one.items()}  # a baseline without a tracker
    text = report({"baseline": [untracked], "this tree": [one]}, "abc123")
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if "| tracking " in line]
    assert rows[-1][:5] == ["100 people x 7 ring views", "tracking", "0.00", "0.63", "nan"]


def test_the_frames_driver_prints_a_table_the_pairs_read(capsys):
    text = frame_times.main(["--only", "crowd 10 x 5", "--repeats", "1"])
    assert text in capsys.readouterr().out
    rows = stage_medians(text)
    assert list(rows) == ["crowd 10 x 5 views"]
    stages = rows["crowd 10 x 5 views"]
    assert all(stages[s] > 0 for s in ("matching", "reconstruction", "tracking"))
    # each frame's total is the sum of its stages, so its median is at least each stage's median (medians of 3
    # frames under a loaded machine are too noisy to compare with the sum of the stage medians)
    assert stages["total"] >= max(stages["matching"], stages["reconstruction"], stages["tracking"])
    with pytest.raises(SystemExit):  # no setting of that name
        frame_times.main(["--only", "no such setting"])


def test_the_frames_driver_builds_the_pipeline_with_and_without_a_tracker():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(str(ROOT / "configs"), version_base="1.3"):
        cfg, off = compose("eval"), compose("eval", overrides=["tracking=off"])
    sequence = instantiate(cfg.dataset, _convert_="all")
    assert frame_times.build_pipeline(cfg, sequence.rig).tracker is not None
    assert frame_times.build_pipeline(off, sequence.rig).tracker is None


def test_the_process_driver_times_the_shelf_command_of_a_tree(tmp_path):
    tree, cache = tmp_path / "tree", tmp_path / "cache"
    tree.mkdir()
    cache.mkdir()
    (tree / "eval.py").write_text(  # a stand-in that records its arguments where the driver put numba's cache
        "import os, sys\nassert os.environ['OMP_NUM_THREADS'] == os.environ['NUMBA_NUM_THREADS'] == '1'\n"
        "open(os.path.join(os.environ['NUMBA_CACHE_DIR'], 'argv'), 'a').write(' '.join(sys.argv[1:]) + '\\n')\n"
    )
    args = argparse.Namespace(repeats=3, cpu=None, data=str(tmp_path / "data"))
    got = run_process(tree, cache, args)
    assert list(got) == [PROCESS_SETTING] and got[PROCESS_SETTING]["total"] > 0
    calls = (cache / "argv").read_text().splitlines()
    assert len(calls) == 3 and all(
        c.startswith(f"dataset=shelf dataset.root={tmp_path}/data/shelf progress=false") for c in calls
    )
    assert len({c.split("hydra.run.dir=")[1] for c in calls}) == 3  # a run folder each
    (tree / "eval.py").write_text("raise SystemExit('no such dataset')\n")
    with pytest.raises(RuntimeError, match="no such dataset"):
        run_process(tree, cache, args)
    text = report({"baseline": [got], "this tree": [got]}, "abc123", "process")
    assert "seconds per run" in text and "| total " in text and "| matching " not in text
