"""A run that reconstructs nobody says which stage lost the people and the likeliest cause, in one line."""

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from evaluation.sequence_eval import SequenceReport, nobody_diagnosis
from reconstruction.pipeline import FrameResult

ROOT = Path(__file__).resolve().parents[1]
NOBODY = FrameResult(0, np.zeros((0, 23, 4)), np.zeros((0, 3), dtype=np.int64))


def report(unmatched: Counter, detections: int, results: list | None = None) -> SequenceReport:
    return SequenceReport(results or [NOBODY], {}, Counter(), unmatched=unmatched, detections=detections)


def test_the_commonest_reason_names_the_cause():
    line = nobody_diagnosis(report(Counter(no_counterpart=9, too_little_evidence=2), 11))
    assert line.startswith("Nobody reconstructed from 11 detections: the matcher left them out (9 no_counterpart)")
    assert "check_rig" in line
    assert "min_score" in nobody_diagnosis(report(Counter(too_little_evidence=5), 5))
    assert "no 2D detection" in nobody_diagnosis(report(Counter(), 0))


def test_a_run_with_people_has_no_diagnosis():
    someone = FrameResult(0, np.ones((1, 23, 4)), np.zeros((1, 3), dtype=np.int64))
    assert nobody_diagnosis(report(Counter(no_counterpart=3), 5, [NOBODY, someone])) is None


def test_images_flipped_upside_down_are_diagnosed_in_the_report(tmp_path):
    entries = json.loads((ROOT / "examples/own_rig/poses2d.json").read_text())
    for entry in entries:  # every view's y measured from the bottom of its 720 px image
        points = np.asarray(entry["keypoints"]).reshape(-1, 3)
        points[:, 1] = 719.0 - points[:, 1]
        entry["keypoints"] = points.ravel().tolist()
        x, y, w, h = entry["bbox"]
        entry["bbox"] = [x, 719.0 - y - h, w, h]
    (tmp_path / "poses2d.json").write_text(json.dumps(entries))
    command = [
        sys.executable,
        "eval.py",
        "dataset=files",
        f"dataset.cameras={ROOT / 'examples/own_rig/cameras.json'}",
        f"dataset.poses2d={tmp_path / 'poses2d.json'}",
        f"hydra.run.dir={tmp_path / 'run'}",
        "progress=false",
    ]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [line for line in done.stdout.splitlines() if line.startswith("Nobody reconstructed")]
    assert len(lines) == 1 and "no_counterpart" in lines[0] and "check_rig" in lines[0], done.stdout[-3000:]
