"""Smoke test of benchmarks/speed.py on its smallest setting: the stage table and its columns."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks import speed


def test_speed_table_of_one_small_crowd(tmp_path: Path) -> None:
    out = tmp_path / "speed.md"
    text = speed.main(
        ["--only", "crowd 10 x 5", "--repeats", "1", "--crowd-frames", "2", "--skip-process", "--out", str(out)]
    )
    rows = [line for line in text.splitlines() if line.startswith("| crowd 10 x 5 views")]
    assert len(rows) == 1 and out.read_text().strip() == text.strip()
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    frames, grouping, *stages, total = cells[1:7]
    assert frames == "2" and grouping == "-"  # synthetic detections: no PAF grouping
    assert abs(sum(map(float, stages)) - float(total)) < 0.05 + 0.01 * float(total)  # medians: close, not equal
    assert cells[7:] == ["-", "-", "-", "-"]  # no target, no figure of the issue for this setting


def test_the_counted_time_sums_the_stages_of_each_target() -> None:
    """Shelf's target counts every stage; the crowds' (issue 16's "default matching + MAP") matching + MAP only; a
    setting without a target counts nothing."""
    per_frame = np.array([[1.0, 2.0, 4.0], [8.0, 16.0, 32.0]])  # matching, reconstruction, tracking
    grouping = np.array([0.5, 0.25])
    np.testing.assert_array_equal(speed.counted_times("Shelf 300-600", grouping, per_frame), [7.5, 56.25])
    crowd = speed.counted_times("100 people x 7 ring views", np.full(2, np.nan), per_frame)
    np.testing.assert_array_equal(crowd, [3.0, 24.0])
    assert np.isnan(speed.counted_times("crowd 10 x 5 views", np.full(2, np.nan), per_frame)).all()
    assert set(speed.TARGET_STAGES) == set(speed.TARGETS)  # every target says what it counts


def test_a_filter_that_matches_no_setting_prints_empty_tables() -> None:
    text = speed.main(["--only", "no such setting", "--skip-process"])
    header = next(line for line in text.splitlines() if line.startswith("| setting"))
    following = text.splitlines()[text.splitlines().index(header) + 2 :]
    assert not following or not following[0].startswith("| ")  # the header and its rule, no rows
