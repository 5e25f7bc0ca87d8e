"""The Shelf loader (data/datasets/shelf.py), its ShelfProtocol and eval.py on Shelf frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.datasets.shelf import load_shelf as load_shelf_sequence
from data.formats.poses2d_io import write_poses2d
from data.keypoints import COCO23_TO_SHELF14_LIMBS, SHELF_HEAD_BLEND, SHELF_HEAD_TOP_NOSE_SCALE
from data.multiview import Frame
from evaluation.protocols import attach_protocols
from evaluation.protocols.shelf import AVERAGED_ACTOR_IDS, ShelfProtocol
from models.paf_grouping import group_view
from reconstruction.pipeline import FrameResult


def load_shelf(*args, **kwargs):
    """The Shelf loader as configs/dataset/shelf.yaml builds it (PAF grouper given), protocols attached as eval.py does."""
    return attach_protocols(load_shelf_sequence(*args, grouper=group_view, **kwargs))


CONFIGS = str(Path(__file__).resolve().parents[1] / "configs")


@pytest.fixture(scope="module")
def shelf_root(shared_data: Path) -> Path:
    """The Shelf folder holding 4d_association/."""
    return shared_data / "shelf"


@pytest.fixture(scope="module")
def five_frames(shelf_root: Path):
    """Shelf frames 300..304, grouped from the detection files."""
    return load_shelf(shelf_root, frames="0:5")


def _coco23_from_shelf15(pose: np.ndarray) -> np.ndarray:
    """A COCO-23 pose (23, 4) whose Shelf-14 (coco23_to_shelf14) is the given one up to ~2 cm at the head.

    Limb joints are copied; nose and ears solve the head construction in the least-squares sense
    (its z rows are singular, so the head cannot be exact). Face-less joints (eyes, feet) stay invalid.
    """
    out = np.zeros((23, 4))
    out[COCO23_TO_SHELF14_LIMBS, :3] = pose[:12, :3]
    out[COCO23_TO_SHELF14_LIMBS, 3] = 1.0
    mid_shoulder = (out[5, :3] + out[6, :3]) / 2
    a, scale = SHELF_HEAD_BLEND, SHELF_HEAD_TOP_NOSE_SCALE
    for k in range(3):
        system = np.array([[0.5 * a, 0.5 * (1 - a)], [a * scale[k], 1.5 * (1 - a)]])
        rhs = np.array([pose[12, k], pose[13, k]]) - mid_shoulder[k]
        nose, ear = np.linalg.lstsq(system, rhs, rcond=None)[0]
        out[0, k], out[3, k], out[4, k] = mid_shoulder[k] + nose, mid_shoulder[k] + ear, mid_shoulder[k] + ear
    out[[0, 3, 4], 3] = 1.0
    return out


def test_load_shelf_gives_five_views_of_grouped_detections(five_frames) -> None:
    seq = five_frames
    assert [f.index for f in seq.frames] == [300, 301, 302, 303, 304]
    assert list(seq.rig.names) == ["0", "1", "2", "3", "4"]
    for frame in seq.frames:
        assert len(frame.views) == 5 and frame.gt_poses is None
        for view in frame.views:
            assert 2 <= len(view) <= 6
            assert view.keypoints.shape[1:] == (23, 3) and np.all(view.person_ids == -1)
            visible = view.keypoints[..., 2] > 0
            assert np.all(view.keypoints[..., 0][visible] <= 1031) and np.all(view.keypoints[..., 1][visible] <= 775)
    assert seq.stage_seconds["grouping"] > 0
    assert "Shelf frames 300-304" in seq.description
    assert [type(p) for p in seq.protocols] == [ShelfProtocol]


def test_ground_truth_through_the_protocol_scores_100_and_the_baseline_uses_the_same_frames(five_frames) -> None:
    protocol = load_shelf(five_frames.meta["root"], frames="0:40").protocols[0]
    for frame, gt in protocol.gt.items():
        poses = np.array([_coco23_from_shelf15(p) for p in gt.values()]).reshape(-1, 23, 4)
        protocol.update(Frame(frame, []), FrameResult(frame, poses, np.zeros((len(poses), 5), int)))
    summary = protocol.summary()
    for name in ("strict", "lenient"):
        assert summary["ours"][name]["average"]["average"] == 100.0
        scored = [actor for actor in summary["ours"][name]["actors"].values() if actor["frames"]]
        assert len(scored) == 2 and all(actor["average"] == 100.0 for actor in scored)
    baseline = summary["4d_association"]
    assert baseline["protocol"]["frames"] == 40 and baseline["protocol"]["last_frame"] == 339
    assert 80.0 < baseline["strict"]["average"]["average"] < 100.0
    text = protocol.report()
    assert "frames 300-339 (40)" in text and "4D Association stored output, same code" in text
    assert "Shelf average PCP, actors 1-3: strict 100.00" in text


def test_track_ids_of_the_predictions_actors_take_give_the_identity_summary(five_frames) -> None:
    protocol = load_shelf(five_frames.meta["root"], frames="0:10", baseline=None).protocols[0]
    for k, (frame, gt) in enumerate(sorted(protocol.gt.items())):
        poses = np.array([_coco23_from_shelf15(p) for p in gt.values()]).reshape(-1, 23, 4)
        ids = np.arange(len(poses)) + (100 if k >= 6 else 0)  # every actor switches id once, at frame 6
        protocol.update(Frame(frame, []), FrameResult(frame, poses, np.zeros((len(poses), 5), int), ids))
    tracking = protocol.summary()["tracking"]
    actors = sum(a in AVERAGED_ACTOR_IDS for a in protocol.gt[300])
    assert tracking["id_switches"] == actors and tracking["idf1_like"] == pytest.approx(60.0)
    assert "identity switches" in protocol.report()


def test_a_frame_without_predictions_is_wrong_when_strict_and_skipped_when_lenient(shelf_root: Path) -> None:
    protocol = load_shelf(shelf_root, frames=[300, 301], baseline=None).protocols[0]
    protocol.update_shelf15(300, np.zeros((0, 15, 3)))
    protocol.update_shelf15(301, np.array([p[:, :3] for p in protocol.gt[301].values()]))
    summary = protocol.summary()
    assert "4d_association" not in summary
    strict, lenient = summary["ours"]["strict"], summary["ours"]["lenient"]
    assert strict["actors"][1]["frames"] == 2 and strict["actors"][1]["average"] == 50.0
    assert lenient["actors"][1]["frames"] == 1 and lenient["actors"][1]["average"] == 100.0
    assert summary["ours"]["protocol"]["averaged_actors"] == [1, 3]  # actor 2 is not in frames 300-301


def test_write_saves_the_scored_shelf_predictions(shelf_root: Path, tmp_path: Path) -> None:
    protocol = load_shelf(shelf_root, frames=[300, 301], baseline=None).protocols[0]
    pred = np.array([p[:, :3] for p in protocol.gt[300].values()])
    pred[0, 13] = np.nan
    protocol.update_shelf15(300, pred)
    protocol.update_shelf15(301, np.zeros((0, 15, 3)))
    doc = json.loads(protocol.write(tmp_path).read_text())
    assert len(doc["joints"]) == 15 and doc["joints"][-1] == "mid_hip"
    first, second = doc["frames"]
    assert first["frame"] == 300 and len(first["poses"]) == len(pred) and first["poses"][0][13] is None
    assert np.allclose(first["poses"][1][0], pred[1, 0], atol=1e-4)
    assert first["chosen_for_actor"]["1"] == list(protocol.gt[300]).index(0)
    assert second["poses"] == [] and set(second["chosen_for_actor"].values()) == {-1}


def test_poses2d_input_replaces_grouping(five_frames, tmp_path: Path) -> None:
    path = tmp_path / "poses2d.json"
    write_poses2d(path, {f.index: f.views for f in five_frames.frames[:3]}, list(five_frames.rig.names))
    seq = load_shelf(five_frames.meta["root"], frames="0:3", poses2d=str(path))
    assert not seq.stage_seconds and seq.meta["poses2d_frames_not_selected"] == 0
    for mine, grouped in zip(seq.frames, five_frames.frames):
        assert [len(v) for v in mine.views] == [len(v) for v in grouped.views]
        assert np.allclose(mine.views[2].keypoints, grouped.views[2].keypoints, atol=1e-4)


def test_bad_input_names_the_file(shelf_root: Path, tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=str(tmp_path / "0.txt")):
        load_shelf(shelf_root, detections=str(tmp_path), frames="0:2")
    with pytest.raises(ValueError, match="gt.txt: frame 700 requested"):
        load_shelf(shelf_root, frames=[300, 700])
    with pytest.raises(FileNotFoundError, match="nowhere.json"):
        load_shelf(shelf_root, calibration="nowhere.json")


def test_eval_on_ten_frames_with_feet_matching_prints_the_shelf_table(shelf_root: Path, tmp_path: Path, capsys) -> None:
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            config_name="eval",
            overrides=[
                "progress=false",
                "dataset=shelf",
                f"dataset.root={shelf_root}",
                "dataset.frames=0:10",
                "matching=feet",
            ],
        )
    report = eval_script.run(cfg, tmp_path)
    ours = report.protocols["shelf"]["ours"]
    assert ours["protocol"]["frames"] == 10 and ours["strict"]["average"]["average"] > 80.0
    assert report.protocols["shelf"]["4d_association"]["protocol"]["frames"] == 10
    assert "mpjpe_mm" not in report.metrics and set(report.timings) >= {"grouping", "matching", "reconstruction"}
    out = capsys.readouterr().out
    assert "Shelf protocol: frames 300-309 (10)" in out and "4D Association stored output, same code" in out
    assert "| grouping" in out and "ms / frame" in out
    scored = json.loads((tmp_path / "shelf_predictions.json").read_text())  # eval.py calls protocol.write
    assert [f["frame"] for f in scored["frames"]] == list(range(300, 310))
