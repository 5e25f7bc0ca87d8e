"""eval.py checkpoint=...: 2D evaluation of a train.py checkpoint, multi-peak decoding with the global joint
association, COCO AP/AR and poses2d.json for the multi-view pipeline."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from torch.utils.data import DataLoader

import eval as eval_script
from data.formats.poses2d_io import read_poses2d
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.coco_keypoints import load_coco_wholebody
from data.pose2d.synthetic_images import ImageOptions, generate_dataset
from data.pose2d.topdown_dataset import TopDownDataset
from evaluation.pose2d_eval import associate_crops, decode_candidates
from models.heatmap_codec import MultiModalHeatmapCodec
from models.train_loop import run as train_run

REPO = Path(__file__).resolve().parents[1]
CONFIGS = str(REPO / "configs")


@pytest.fixture(scope="module")
def wholebody(shared_data):
    """The 4 real COCO-WholeBody sample images' records."""
    folder = shared_data / "coco_wholebody_sample"
    return load_coco_wholebody(folder / "test_coco_wholebody.json", folder)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> tuple[Path, Path]:
    """(last.ckpt of a 2-step FastPose-18 run on tiny synthetic data, the synthetic root)."""
    root = tmp_path_factory.mktemp("synthetic")
    options = ImageOptions(size=(320, 240), persons=(3, 4))
    generate_dataset(root / "train", 2, seed=0, options=options, progress=False)
    generate_dataset(root / "val", 2, seed=1, options=options, progress=False)
    run_dir = tmp_path_factory.mktemp("run")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            "train",
            overrides=[
                "model=fastpose_r18",
                "data.input_size=[64,64]",
                "data.sigma=1.0",
                "trainer.batch_size=4",
                "trainer.num_workers=0",
                "trainer.progress=false",
                "trainer.max_steps=2",
                "trainer.threads=1",
                f"data.root={root}",
            ],
        )
    train_run(cfg, run_dir)
    torch.set_num_threads(threads)
    return run_dir / "checkpoints" / "last.ckpt", root


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_association_decoding_of_multimodal_targets_finds_every_own_joint(wholebody, mu):
    # with mu = 0.5 a crop's heatmaps also peak at the neighbours' joints: the association must give each
    # box its own joint, not a neighbour's, so the targets decoded as predictions score near-perfect AP
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=mu)
    dataset = TopDownDataset(wholebody, codec, (192, 256), train=False)
    batch = next(iter(DataLoader(dataset, batch_size=len(dataset))))
    crops = decode_candidates(codec, batch["target"], batch, threshold=0.1, top_m=3)
    assert crops[0]["candidates"].shape == (23, 3, 3)
    if mu:
        assert max(int(np.sum(c["candidates"][..., 2] > 0.1, axis=1).max()) for c in crops) >= 2  # several peaks
    predictions = associate_crops(crops)
    assert [p["image_id"] for p in predictions] == [int(i) for i in batch["image_id"]]
    for subset in ("body", "foot"):
        assert evaluate_keypoints(wholebody, predictions, subset)["AP"] > 0.9, subset


def eval_config(overrides: list[str]):
    """The eval.py config with these overrides."""
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="eval", overrides=overrides)


def test_eval_py_evaluates_a_checkpoint_and_writes_poses2d(checkpoint, tmp_path):
    ckpt, root = checkpoint
    doc = json.loads((root / "val" / "annotations.json").read_text())
    for n, image in enumerate(doc["images"]):  # two cameras of one frame
        image.update(frame=300, camera=f"cam{n}")
    ann = tmp_path / "val_views.json"
    ann.write_text(json.dumps(doc))
    cfg = eval_config([f"checkpoint={ckpt}", f"coco2d.ann_file={ann}", f"coco2d.image_dir={root / 'val' / 'images'}"])
    metrics = eval_script.run_pose2d(cfg, tmp_path)
    assert set(metrics) == {f"{m}_{s}" for m in ("AP", "AR") for s in ("all", "body", "foot")}
    results = json.loads((tmp_path / "keypoints_results.json").read_text())
    assert len(results) == len(doc["annotations"])  # one per ground-truth box
    poses = read_poses2d(tmp_path / "poses2d.json", ["cam0", "cam1"])  # what dataset=files reads
    assert list(poses) == [300]
    per_camera = [sum(a["image_id"] == img["id"] for a in doc["annotations"]) for img in doc["images"]]
    assert [len(v) for v in poses[300]] == per_camera
    got = np.concatenate([v.keypoints for v in poses[300]]).reshape(len(results), -1)
    expected = np.array(sorted((r["keypoints"] for r in results), key=lambda k: k[:3]))
    np.testing.assert_allclose(got[np.lexsort(got[:, :3].T[::-1])], expected, atol=2e-4)
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["metrics"] == metrics and saved["decode"] == "association" and saved["cameras"] == ["cam0", "cam1"]


def test_eval_py_single_decoding_matches_train_validation(checkpoint, tmp_path):
    ckpt, root = checkpoint
    overrides = [f"checkpoint={ckpt}", "coco2d.decode=single", "coco2d.flip_test=false"]
    metrics = eval_script.run_pose2d(eval_config(overrides), tmp_path)
    # the checkpoint's own validation set by default, decoded as train.py's validation decodes it (no flip test)
    stored = json.loads((ckpt.parent.parent / "metrics.json").read_text())["metrics"]
    for key, value in metrics.items():
        assert value == pytest.approx(stored[key]), key


def test_eval_py_command_line_and_a_missing_checkpoint(checkpoint, tmp_path):
    ckpt, _ = checkpoint
    ok = subprocess.run(
        [sys.executable, "eval.py", f"checkpoint={ckpt}", f"hydra.run.dir={tmp_path / 'ok'}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stderr[-3000:]
    assert "AP_foot" in ok.stdout and (tmp_path / "ok" / "poses2d.json").is_file()
    bad = subprocess.run(
        [sys.executable, "eval.py", f"checkpoint={tmp_path / 'absent.ckpt'}", f"hydra.run.dir={tmp_path / 'bad'}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert bad.returncode == 1 and bad.stderr.strip() == f"error: {tmp_path / 'absent.ckpt'}: no such checkpoint"
