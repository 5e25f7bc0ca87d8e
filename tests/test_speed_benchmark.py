"""Smoke test of benchmarks/speed.py on its smallest setting: the stage table and its columns."""

from __future__ import annotations

from pathlib import Path

from benchmarks import speed


def test_speed_table_of_one_small_crowd(tmp_path: Path) -> None:
    out = tmp_path / "speed.md"
    text = speed.main(
        ["--only", "crowd 10 x 5", "--repeats", "1", "--crowd-frames", "2", "--skip-process", "--out", str(out)]
    )
    rows = [line for line in text.splitlines() if line.startswith("| crowd 10 x 5 views")]
    assert len(rows) == 1 and out.read_text().strip() == text.strip()
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    frames, grouping, *stages, total = cells[1:]
    assert frames == "2" and grouping == "-" and len(stages) == 3  # synthetic detections: no PAF grouping
    assert abs(sum(map(float, stages)) - float(total)) < 0.05 + 0.01 * float(total)  # medians: close, not equal


def test_a_filter_that_matches_no_setting_prints_empty_tables() -> None:
    text = speed.main(["--only", "no such setting", "--skip-process"])
    header = next(line for line in text.splitlines() if line.startswith("| setting"))
    following = text.splitlines()[text.splitlines().index(header) + 2 :]
    assert not following or not following[0].startswith("| ")  # the header and its rule, no rows
