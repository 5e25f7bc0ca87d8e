"""The Shelf PCP protocol (evaluation/protocols/shelf.py) on hand-built cases and the real Shelf files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from data.formats.fourd_skeletons import load_4dassoc_skeletons
from evaluation.pcp import PART_NAMES
from evaluation.protocols.shelf import (
    ShelfEvaluator,
    coco23_predictions_to_shelf15,
    format_table,
    load_actors_gt,
    main,
    score_4dassoc_output,
    skel19_to_shelf15,
)


def _person(offset_x: float) -> np.ndarray:
    """A standing Shelf-14 + mid-hip person facing +x, valid column 1: (15, 4)."""
    pts = np.array(
        [
            [0, -0.1, 0],
            [0, -0.1, 0.45],
            [0, -0.1, 0.9],
            [0, 0.1, 0.9],
            [0, 0.1, 0.45],
            [0, 0.1, 0],
            [0, -0.25, 0.9],
            [0, -0.25, 1.15],
            [0, -0.2, 1.4],
            [0, 0.2, 1.4],
            [0, 0.25, 1.15],
            [0, 0.25, 0.9],
            [0, 0, 1.5],
            [0, 0, 1.75],
            [0, 0, 0.9],
        ]
    ) + [offset_x, 0, 0]
    return np.concatenate([pts, np.ones((15, 1))], axis=1)


def _moved_head(person: np.ndarray, fraction: float) -> np.ndarray:
    """Both head ends moved sideways by fraction x head length: (15, 4) -> (15, 3)."""
    pred = person[:, :3].copy()
    length = np.linalg.norm(pred[13] - pred[12])
    pred[12:14, 0] += fraction * length
    return pred


@pytest.fixture(scope="module")
def shelf_files(shared_data: Path) -> tuple[Path, Path]:
    """(skel.txt, gt.txt) of 4D Association's Shelf folder."""
    root = shared_data / "shelf" / "4d_association"
    return root / "skel.txt", root / "gt.txt"


@pytest.fixture(scope="module")
def fourda_summary(shelf_files: tuple[Path, Path]) -> dict:
    """4D Association's stored output scored by the protocol."""
    return score_4dassoc_output(*shelf_files)


def test_ground_truth_against_itself_is_100(shelf_files: tuple[Path, Path]) -> None:
    evaluator = ShelfEvaluator()
    for i, gt in enumerate(load_4dassoc_skeletons(shelf_files[1])):
        pred = np.array([p[:, :3] for p in gt.values()]).reshape(-1, 15, 3)
        evaluator.update(300 + i, pred, gt)
    summary = evaluator.summary()
    assert summary["protocol"]["standard_frames"]
    for protocol in ("strict", "lenient"):
        assert summary[protocol]["average"]["average"] == 100.0
        assert all(actor["average"] == 100.0 for actor in summary[protocol]["actors"].values())
    assert summary["strict"]["actors"][2]["frames"] == 37
    assert summary["mpjpe_mm"]["average"] == 0.0


@pytest.mark.parametrize("fraction, expected", [(0.6, 0.0), (0.4, 100.0)])
def test_part_threshold_is_half_its_length(fraction: float, expected: float) -> None:
    person = _person(0.0)
    evaluator = ShelfEvaluator()
    evaluator.update(300, _moved_head(person, fraction)[None], {0: person})
    pcp = evaluator.summary()["strict"]["actors"][1]
    assert pcp["head"] == expected
    assert pcp["upper_legs"] == 100.0


def test_missing_prediction_strict_and_lenient() -> None:
    a, b, c = _person(0.0), _person(2.0), _person(-2.0)
    evaluator = ShelfEvaluator()
    evaluator.update(300, np.stack([a[:, :3], b[:, :3], c[:, :3]]), {0: a, 1: b, 2: c})
    # Frame 301: actor 1's head is wrong, actor 2 has no prediction near it but takes actor 1's
    # (selection is not one-to-one), actor 3 has no prediction at all.
    evaluator.update(301, _moved_head(a, 0.6)[None], {0: a, 1: b})
    evaluator.update(302, np.zeros((0, 15, 3)), {2: c})
    summary = evaluator.summary()
    strict, lenient = summary["strict"], summary["lenient"]
    assert strict["actors"][1]["average"] == pytest.approx(95.0)
    assert strict["actors"][2]["average"] == pytest.approx(50.0)
    assert strict["actors"][3]["average"] == pytest.approx(50.0)
    assert strict["average"]["average"] == pytest.approx(65.0)
    assert strict["actors"][3]["frames"] == 2 and lenient["actors"][3]["frames"] == 1
    assert lenient["actors"][2]["average"] == pytest.approx(50.0)
    assert lenient["actors"][3]["average"] == 100.0
    assert lenient["average"]["average"] == pytest.approx((95 + 50 + 100) / 3)
    assert summary["mpjpe_mm"]["actors"][3] == 0.0


def test_unannotated_actor_is_not_scored_and_repeated_frame_rejected() -> None:
    a = _person(0.0)
    hidden = a.copy()
    hidden[:, 3] = 0
    evaluator = ShelfEvaluator()
    evaluator.update(300, a[None, :, :3], {0: a, 1: hidden})
    assert evaluator.summary()["strict"]["actors"][2]["frames"] == 0
    with pytest.raises(ValueError, match="already scored"):
        evaluator.update(300, a[None, :, :3], {0: a})


def test_fourda_stored_output_reproduces_published_average(fourda_summary: dict) -> None:
    # Published: 96.3 average PCP of Actors 1-3 for 4D Association's stored Shelf output.
    for protocol in ("strict", "lenient"):
        assert fourda_summary[protocol]["average"]["average"] == pytest.approx(96.27, abs=0.05)
    actors = fourda_summary["strict"]["actors"]
    assert [round(actors[k]["average"], 2) for k in (1, 2, 3, 4)] == [99.75, 91.35, 97.70, 91.21]
    assert fourda_summary["protocol"]["averaged_actors"] == [1, 2, 3]


def test_format_table_and_cli(
    fourda_summary: dict, shelf_files: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    table = format_table(fourda_summary, "4DA")
    assert "strict" in table and "lenient" in table and "actor 4*" in table and "96.27" in table
    assert all(name in table for name in PART_NAMES)
    main(["--skel", str(shelf_files[0]), "--gt", str(shelf_files[1])])
    assert "96.27" in capsys.readouterr().out


def test_skel19_mapping_and_head_rebuild() -> None:
    skel = np.zeros((19, 4))
    skel[:, 3] = 1
    skel[:, :3] = np.arange(19)[:, None] * [0.0, 0.0, 0.1]  # joint j sits at height 0.1 j
    skel[5, :3], skel[6, :3] = [0, -0.2, 1.4], [0, 0.2, 1.4]  # R/L shoulder, person faces +x
    skel[9, :3], skel[10, :3] = [0, -0.08, 1.6], [0, 0.08, 1.6]  # R/L ear
    skel[0, :3], skel[1, :3] = [0, 0, 0.9], [0, 0, 1.45]  # pelvis, neck
    shelf = skel19_to_shelf15(skel)
    assert np.allclose(shelf[0], skel[13, :3]) and np.allclose(shelf[11], skel[16, :3])  # R ankle, L wrist
    assert np.allclose(shelf[12], [0, 0, 1.5])
    assert np.allclose(shelf[13], [0.125, 0, 1.5 + 0.145])
    assert np.allclose(shelf[14], (skel[2, :3] + skel[3, :3]) / 2)
    skel[9, 3] = 0
    assert np.isnan(skel19_to_shelf15(skel)[12:14]).all()


def test_coco23_predictions_mark_missing_joints() -> None:
    poses = np.ones((2, 23, 4))
    poses[1, 16, 3] = 0  # right ankle missing
    shelf = coco23_predictions_to_shelf15(poses)
    assert shelf.shape == (2, 15, 3)
    assert np.isnan(shelf[1, 0]).all() and np.isfinite(shelf[0]).all() and np.isfinite(shelf[1, 1:]).all()
    assert poses[1, 16, 3] == 0  # the caller's array is untouched


def test_gt_txt_matches_actors_gt_mat(shared_data: Path, shelf_files: tuple[Path, Path]) -> None:
    from_mat = load_actors_gt(shared_data / "shelf" / "tum" / "actorsGT.mat")
    from_txt = load_4dassoc_skeletons(shelf_files[1])
    assert len(from_mat) == len(from_txt) == 301
    for mat, txt in zip(from_mat, from_txt):
        assert sorted(mat) == sorted(txt)
        for actor in mat:
            assert np.abs(mat[actor] - txt[actor]).max() < 1e-5
