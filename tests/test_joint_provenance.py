"""Every output joint's provenance: joint_sources' codes, poses3d.json's joint_views / joint_source, output.fill."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from data.formats.poses_io import JOINT_SOURCES, read_joint_provenance, read_poses3d, write_poses3d
from reconstruction.results import joint_sources

ROOT = Path(__file__).resolve().parents[1]


def test_joint_sources_known_answers():
    scores = np.array([[0.9, 0.5, 0.0, 0.1], [0.9, 0.5, 0.0, 0.1]])
    views = np.array([[3, 1, 0, 0], [2, 1, 1, 0]])
    codes = joint_sources(scores, views, np.array([False, True]))
    names = [[JOINT_SOURCES[c] for c in row] for row in codes]
    assert names == [["views", "prior", "none", "prior"], ["views", "motion", "none", "motion"]]


def one_frame(tmp_path: Path, fill: bool) -> tuple[np.ndarray, dict]:
    """A person with joints seen in 3, 1 and 0 views written with fill -> (poses (1, 23, 4) read back, provenance)."""
    poses = np.ones((1, 23, 4))
    views = np.full((1, 23), 3)
    views[0, 5], views[0, 6] = 1, 0
    source = joint_sources(poses[..., 3], views, np.array([False]))
    write_poses3d(tmp_path / "p.json", [(7, poses, np.array([[0, 1]]), None, views, source)], ["a", "b"], fill=fill)
    return read_poses3d(tmp_path / "p.json")[7], read_joint_provenance(tmp_path / "p.json")[7]


def test_without_fill_joints_seen_in_fewer_than_two_views_get_score_zero(tmp_path):
    poses, (views, source) = one_frame(tmp_path, fill=False)
    assert poses[0, 5, 3] == 0 and poses[0, 6, 3] == 0 and np.all(poses[0, 5] == 0)
    assert np.all(np.delete(poses[0, :, 3], [5, 6]) == 1)
    assert views[0, 5] == 1 and views[0, 6] == 0 and views[0, 0] == 3
    assert source[0][5] == source[0][6] == "none" and source[0][0] == "views"


def test_with_fill_they_are_written_with_their_source(tmp_path):
    poses, (views, source) = one_frame(tmp_path, fill=True)
    assert np.all(poses[0, :, 3] == 1)
    assert source[0][5] == source[0][6] == "prior"


def test_a_file_without_provenance_still_reads(tmp_path):
    doc = {
        "keypoints": ["j"] * 23,
        "units": "m",
        "frames": [{"frame": 1, "poses": [{"id": 0, "keypoints": [[0] * 4] * 23}]}],
    }
    (tmp_path / "old.json").write_text(json.dumps(doc))
    views, source = read_joint_provenance(tmp_path / "old.json")[1]
    assert views.shape == (1, 23) and np.all(views == -1) and source[0] == ["unknown"] * 23
    assert read_poses3d(tmp_path / "old.json")[1].shape == (1, 23, 4)


def run_counts(tmp_path: Path, *overrides: str) -> dict[tuple[str, bool, bool], int]:
    """python eval.py on a sparse synthetic scene -> counts of (joint_source, seen in 2+ views, score > 0)."""
    settings = "dataset.num_frames=2 dataset.num_cameras=3 dataset.miss_rate=0.3 progress=false".split()
    out = tmp_path / "run"
    done = subprocess.run(
        [sys.executable, "eval.py", *settings, f"hydra.run.dir={out}", *overrides],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    counts: dict[tuple[str, bool, bool], int] = {}
    for frame in json.loads((out / "poses3d.json").read_text())["frames"]:
        for person in frame["poses"]:
            for kp, n, s in zip(person["keypoints"], person["joint_views"], person["joint_source"]):
                key = (s, n >= 2, kp[3] > 0)
                counts[key] = counts.get(key, 0) + 1
    return counts


@pytest.mark.parametrize("fill", [False, True])
def test_eval_writes_every_joints_provenance(tmp_path, fill):
    counts = run_counts(tmp_path, f"output.fill={str(fill).lower()}")
    assert counts[("views", True, True)] > 0
    fewer = {k: n for k, n in counts.items() if not k[1]}
    assert fewer, "the scene should have joints seen in fewer than 2 views"
    if fill:
        assert {s for s, _, scored in fewer} <= {"prior", "motion"} and all(scored for _, _, scored in fewer)
    else:
        assert set(fewer) == {("none", False, False)}
