"""Top-down training: the crop dataset on real images, overfitting, exact resume, the Hydra sweep, the
validation geometry and the target picture."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from torch.utils.data import DataLoader

from data.keypoints import FOOT_JOINTS, LEFT_FOOT, RIGHT_FOOT
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.coco_keypoints import load_coco23, load_coco_wholebody, load_keypoint_dataset
from data.pose2d.crop_transforms import CropAugmentation, transform_points
from data.pose2d.synthetic_images import ImageOptions, generate_dataset
from data.pose2d.topdown_dataset import EpochSampler, TopDownDataset
from models.checkpoint_io import read_checkpoint
from models.fastpose import FastPose
from models.heatmap_codec import MultiModalHeatmapCodec
from models.loss import WeightedHeatmapLoss
from models.show_targets import main as show_targets_main
from models.show_targets import target_parts
from models.train_loop import run as train_run
from models.training import TrainState, decode_predictions, save_checkpoint, save_weights, train_one_epoch

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "model=fastpose_r18",
    "data.input_size=[64,64]",
    "data.sigma=1.0",
    "trainer.batch_size=4",
    "trainer.val_batch_size=16",
    "trainer.num_workers=0",
    "trainer.progress=false",
    "trainer.grid_images=2",
    "trainer.threads=1",
]


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """One torch thread: on 2 shared cores two threads of each of several processes thrash."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    """A tiny synthetic dataset: train (3 images) and held-out val (2 images), 320 x 240."""
    root = tmp_path_factory.mktemp("synthetic")
    options = ImageOptions(size=(320, 240), persons=(3, 4))
    generate_dataset(root / "train", 3, seed=0, options=options, progress=False)
    generate_dataset(root / "val", 2, seed=1, options=options, progress=False)
    return root


@pytest.fixture(scope="module")
def wholebody(shared_data):
    """The 4 real COCO-WholeBody sample images' records."""
    folder = shared_data / "coco_wholebody_sample"
    return load_coco_wholebody(folder / "test_coco_wholebody.json", folder)


def present_joints(codec: MultiModalHeatmapCodec, keypoints: np.ndarray, affine_inv: np.ndarray) -> np.ndarray:
    """Labelled joints (23,) of keypoints (23, 3) in image pixels that fall on the crop."""
    affine = np.linalg.inv(np.vstack([affine_inv, [0, 0, 1]]))[:2]
    return (keypoints[:, 2] > 0) & codec.inside(transform_points(keypoints[:, :2], affine))


# --- (d) the dataset on real images -----------------------------------------------------------------


def test_decoded_targets_land_on_the_annotated_keypoints(wholebody):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=0.5)
    dataset = TopDownDataset(wholebody, codec, (192, 256), augment=None, train=True)
    assert len(dataset) == 12  # persons with >= 1 labelled joint (2 have none)
    checked = 0
    for i in range(len(dataset)):
        sample = dataset[i]
        record, own = dataset.records[dataset.samples[i][0]], dataset.samples[i][1]
        assert sample["image"].shape == (3, 256, 192) and sample["image"].dtype == torch.float32
        assert sample["target"].shape == (23, 64, 48) and sample["weight"].shape == (23,)
        affine_inv = sample["affine_inv"].numpy()
        present = present_joints(codec, record.keypoints[own], affine_inv)
        points, _ = codec.decode(sample["target"])
        error = np.linalg.norm(transform_points(points, affine_inv) - record.keypoints[own, :, :2], axis=1)
        heatmap_px = 4 * np.linalg.norm(affine_inv[:, 0])  # one heatmap pixel in image pixels
        assert np.all(error[present] <= heatmap_px), (i, error[present] / heatmap_px)
        assert np.all(sample["weight"].numpy()[present] == 1)
        checked += present.sum()
    assert checked > 150


def test_a_flipped_sample_mirrors_the_image_and_swaps_the_feet(wholebody):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=0.5)
    plain = TopDownDataset(wholebody, codec, (192, 256), augment=None)
    flip_only = CropAugmentation(scale_factor=0, rotation_factor=0, rotation_prob=0, flip_prob=1)
    flipped = TopDownDataset(wholebody, codec, (192, 256), augment=flip_only)
    a, b = plain[0], flipped[0]  # the person with all 6 foot joints
    assert not a["flipped"] and b["flipped"]
    assert a["weight"][list(FOOT_JOINTS)].min() == 1
    mirrored = a["target"].numpy()[..., ::-1]
    np.testing.assert_allclose(b["target"].numpy()[list(LEFT_FOOT)], mirrored[list(RIGHT_FOOT)], atol=1e-6)
    np.testing.assert_allclose(b["target"].numpy()[list(RIGHT_FOOT)], mirrored[list(LEFT_FOOT)], atol=1e-6)
    assert not np.allclose(b["target"].numpy()[list(LEFT_FOOT)], mirrored[list(LEFT_FOOT)], atol=1e-3)
    # the whole image is flipped: the crop is the mirror image, up to warpAffine's fixed-point rounding
    assert np.abs(b["image"].numpy() - a["image"].numpy()[..., ::-1]).max() < 0.05


def test_evaluation_on_detector_boxes(shared_data):
    folder = shared_data / "crowdpose_sample"
    records = load_keypoint_dataset(
        "crowdpose", folder / "test_crowdpose.json", folder, det_file=folder / "test_crowdpose_det_AP_40.json"
    )
    codec = MultiModalHeatmapCodec((64, 64), (16, 16))
    dets = TopDownDataset(records, codec, (64, 64), train=False, use_det_boxes=True)
    assert len(dets) == sum(len(r.det_boxes) for r in records) == 6
    sample = dets[4]
    record = records[dets.samples[4][0]]
    assert sample["score"] == pytest.approx(record.det_scores[1]) and sample["image_id"] == record.image_id
    np.testing.assert_allclose(sample["box"].numpy(), record.det_boxes[1])
    assert sample["weight"].sum() == 0 and sample["target"].abs().sum() == 0  # no own person is known
    gt_boxes = TopDownDataset(records, codec, (64, 64), train=False)
    assert len(gt_boxes) == 4 < sum(len(r) for r in records)  # not the person without joints
    assert gt_boxes[0]["score"] == 1.0
    assert gt_boxes[0]["weight"][:5].sum() == 0  # CrowdPose has no eyes, ears


def test_augmentation_is_seeded_per_epoch_and_sample(wholebody):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64))
    dataset = TopDownDataset(wholebody, codec, (192, 256), augment=CropAugmentation(), seed=3)
    first = [dataset.augmentation(i) for i in range(len(dataset))]
    assert [dataset.augmentation(i) for i in range(len(dataset))] == first
    dataset.set_epoch(1)
    assert [dataset.augmentation(i) for i in range(len(dataset))] != first
    eval_set = TopDownDataset(wholebody, codec, (192, 256), augment=CropAugmentation(), train=False)
    assert eval_set.augmentation(0) == (1.0, 0.0, False)


def test_epoch_sampler_resumes_and_shards():
    full = EpochSampler(10, seed=5)
    full.set_epoch(2)
    order = list(full)
    assert sorted(order) == list(range(10))
    full.set_epoch(2, start=6)
    assert list(full) == order[6:] and len(full) == 4
    full.set_epoch(3)
    assert list(full) != order
    shards = [EpochSampler(10, seed=5, rank=r, world_size=3) for r in range(3)]
    for s in shards:
        s.set_epoch(2)
    assert {len(s) for s in shards} == {4} and set(sum((list(s) for s in shards), [])) == set(range(10))


def test_target_picture_parts_add_up_to_the_target(wholebody, tmp_path):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), mu=0.5)
    dataset = TopDownDataset(wholebody, codec, (192, 256))
    sample = dataset[8]  # a skier among others: the crowd term is non-zero
    own_t, crowd, _ = target_parts(dataset, 8, sample["affine_inv"].numpy())
    assert crowd.max() > 0.3
    np.testing.assert_allclose(own_t + crowd, sample["target"].numpy(), atol=1e-6)
    folder = Path(wholebody[0].file).parent
    out = tmp_path / "targets.png"
    show_targets_main(["--ann", str(folder / "test_coco_wholebody.json"), "--images", str(folder), "--out", str(out)])
    assert out.stat().st_size > 10_000


# --- validation geometry ----------------------------------------------------------------------------


def test_decoding_the_targets_as_predictions_scores_near_perfect_ap(wholebody):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=0.0)
    dataset = TopDownDataset(wholebody, codec, (192, 256), train=False)
    batch = next(iter(DataLoader(dataset, batch_size=len(dataset))))
    predictions = decode_predictions(codec, batch["target"], batch)
    assert len(predictions) == 12 and predictions[0]["keypoints"].shape == (23, 3)
    assert evaluate_keypoints(wholebody, predictions, "body")["AP"] > 0.9
    assert evaluate_keypoints(wholebody, predictions, "foot")["AP"] > 0.9


# --- (a) overfitting --------------------------------------------------------------------------------


def test_fastpose18_overfits_four_synthetic_crops(synthetic_root):
    torch.manual_seed(0)
    records = load_coco23(synthetic_root / "train" / "annotations.json", synthetic_root / "train" / "images")
    codec = MultiModalHeatmapCodec((64, 64), (16, 16), sigma=1.0, mu=0.5)
    dataset = TopDownDataset(records, codec, (64, 64), augment=None)
    dataset.samples = dataset.samples[:4]
    loader = DataLoader(dataset, batch_size=4, sampler=EpochSampler(4, shuffle=False))
    model = FastPose(18)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    loss_fn, state, losses = WeightedHeatmapLoss(1.5), TrainState(), []
    for _ in range(40):  # the loss falls about 15x by step 30, 28x by step 40, 220x by step 100
        losses += train_one_epoch(model, loader, loss_fn, optimizer, torch.device("cpu"), state)
    assert state.global_step == 40 and len(losses) == 40
    assert losses[-1] <= losses[0] / 10, (losses[0], losses[-1])


# --- (b) exact resume -------------------------------------------------------------------------------


def run_training(root: Path, run_dir: Path, *overrides: str) -> dict:
    """models.train_loop.run with the tiny config and these overrides, into run_dir."""
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        cfg = compose("train", overrides=[*TINY, f"data.root={root}", *overrides])
    return train_run(cfg, run_dir)


def test_resume_reproduces_the_uninterrupted_losses(synthetic_root, tmp_path):
    straight = run_training(synthetic_root, tmp_path / "straight", "trainer.epochs=2")
    steps_per_epoch = straight["state"].global_step // 2
    assert steps_per_epoch >= 2 and len(straight["losses"]) == 2 * steps_per_epoch
    assert set(straight["metrics"]) >= {"AP_all", "AP_body", "AP_foot", "loss"}

    run_training(synthetic_root, tmp_path / "first", "trainer.epochs=1")  # stops after epoch 0
    resumed = run_training(
        synthetic_root,
        tmp_path / "second",
        "trainer.epochs=2",
        f"resume={tmp_path / 'first' / 'checkpoints' / 'last.ckpt'}",
    )
    assert sorted(resumed["losses"]) == list(range(steps_per_epoch + 1, 2 * steps_per_epoch + 1))
    for step, loss in resumed["losses"].items():
        assert loss == pytest.approx(straight["losses"][step], rel=1e-6), step

    run_training(synthetic_root, tmp_path / "cut", "trainer.epochs=2", "trainer.max_steps=1")  # mid-epoch
    rest = run_training(
        synthetic_root,
        tmp_path / "rest",
        "trainer.epochs=2",
        f"resume={tmp_path / 'cut' / 'checkpoints' / 'last.ckpt'}",
    )
    assert sorted(rest["losses"]) == list(range(2, 2 * steps_per_epoch + 1))
    for step, loss in rest["losses"].items():
        assert loss == pytest.approx(straight["losses"][step], rel=1e-6), step


def kill_after_first_checkpoint(
    cmd: list[str], checkpoint: Path, timeout_s: float = 120.0, run_on_s: float = 1.0
) -> None:
    """Start cmd, wait until checkpoint exists, let it run on run_on_s seconds, then SIGKILL it."""
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    try:
        while not checkpoint.exists():
            assert proc.poll() is None, proc.stderr.read()[-3000:]
            assert time.monotonic() < deadline, "no checkpoint in time"
            time.sleep(0.05)
        time.sleep(run_on_s)  # killed somewhere in a later epoch
        assert proc.poll() is None, "the run ended before it was killed"
    finally:
        proc.kill()
        proc.wait()


SMALL = [
    "+experiment=train_small",
    "trainer.epochs=10000",
    "trainer.log_every=1",
    "trainer.val_every=1000",
]  # max_steps
#                                                                             bounds the run, only its end is validated


@pytest.fixture(scope="module")
def killed_run(synthetic_root, tmp_path_factory) -> tuple[Path, int]:
    """A train_small run (tiny overrides, max_steps = 3 epochs) SIGKILLed after its first checkpoint ->
    (its last.ckpt, its max_steps)."""
    run_dir = tmp_path_factory.mktemp("killed") / "run"
    checkpoint = run_dir / "checkpoints" / "last.ckpt"
    steps_per_epoch = -(
        -len(
            TopDownDataset(
                load_coco23(synthetic_root / "train" / "annotations.json", synthetic_root / "train" / "images"),
                MultiModalHeatmapCodec((64, 64), (16, 16)),
                (64, 64),
            )
        )
        // 4
    )
    max_steps = 3 * steps_per_epoch
    cmd = [
        sys.executable,
        "train.py",
        *TINY,
        *SMALL,
        f"data.root={synthetic_root}",
        f"trainer.max_steps={max_steps}",
        f"hydra.run.dir={run_dir}",
    ]
    kill_after_first_checkpoint(cmd, checkpoint, run_on_s=0.0)
    return checkpoint, max_steps


def tensorboard_losses(run_dir: Path) -> dict[int, float]:
    """The train/loss scalars of a run's TensorBoard events: {step: loss}."""
    accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    events = accumulator.EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    events.Reload()
    return {e.step: e.value for e in events.Scalars("train/loss")}


def test_killed_run_resumes_with_its_stored_config_from_the_command_line(killed_run, synthetic_root, tmp_path):
    checkpoint, max_steps = killed_run
    saved = read_checkpoint(checkpoint)  # whole, whenever the kill came
    step = saved["global_step"]
    assert saved["epoch"] >= 1 and saved["step_in_epoch"] == 0 and 0 < step < max_steps
    assert saved["choices"]["experiment"] == "train_small"
    resumed_dir = tmp_path / "resumed"
    proc = subprocess.run(
        [sys.executable, "train.py", f"resume={checkpoint}", f"hydra.run.dir={resumed_dir}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )  # no other override
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert read_checkpoint(resumed_dir / "checkpoints" / "last.ckpt")["global_step"] == max_steps
    straight = run_training(synthetic_root, tmp_path / "straight", *SMALL, f"trainer.max_steps={max_steps}")
    resumed = tensorboard_losses(resumed_dir)
    assert sorted(resumed) == list(range(step + 1, max_steps + 1))
    for s, loss in resumed.items():
        assert loss == pytest.approx(straight["losses"][s], rel=1e-5), s


STOPS = """
import json, runpy, sys
stops = []
for argv in json.loads(sys.argv[1]):
    sys.argv = ["train.py", *argv]
    try:
        runpy.run_path("train.py", run_name="__main__")
        stops.append(None)
    except SystemExit as stop:
        stops.append(stop.code)
print(json.dumps(stops))
"""


def train_stops(*argvs: list[str]) -> list[str | None]:
    """What ``python train.py <argv>`` exits with for each argv (SystemExit's message, None when it ran through),
    all run in one process: torch is imported once, not once per command."""
    proc = subprocess.run(
        [sys.executable, "-c", STOPS, json.dumps(argvs)], capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.splitlines()[-1])


UNSAFE = [
    ("trainer.batch_size=8", "trainer.batch_size"),
    ("model=fastpose_r50", "model"),
    ("optimizer.lr=0.1", "optimizer.lr"),
]


def test_an_unsafe_override_of_a_resumed_run_stops_with_one_line(killed_run, tmp_path):
    checkpoint, _ = killed_run
    stops = train_stops(
        *(
            [f"resume={checkpoint}", override, f"hydra.run.dir={tmp_path / str(k)}"]
            for k, (override, _) in enumerate(UNSAFE)
        )
    )
    for (override, key), stop in zip(UNSAFE, stops):
        assert isinstance(stop, str) and "\n" not in stop, stop  # python prints the message as one line
        assert stop.startswith(f"error: resume: {override} would change {key} ") and str(checkpoint) in stop


def corrupt(kind: str, good: bytes, weights: Path) -> bytes:
    """A damaged version of the checkpoint bytes good (or the weights file's bytes)."""
    if kind == "truncated":
        return good[: len(good) // 2]
    if kind == "empty":
        return b""
    if kind == "random":
        return np.random.default_rng(0).bytes(len(good))
    if kind == "flipped":
        middle = len(good) // 2
        return good[:middle] + bytes(b ^ 0xFF for b in good[middle : middle + 8]) + good[middle + 8 :]
    return weights.read_bytes()


DAMAGE = [
    ("truncated", "cannot be read"),
    ("empty", "empty file"),
    ("random", "cannot be read"),
    ("flipped", "checksum mismatch"),
    ("best.pth", "model weights only"),
]


def test_a_damaged_checkpoint_stops_resume_with_one_line_naming_the_file(tmp_path):
    model = FastPose(18)
    optimizer = torch.optim.Adam(model.parameters())
    scheduler = torch.optim.lr_scheduler.MultiStepLR(optimizer, [1])
    good, weights = tmp_path / "last.ckpt", tmp_path / "best.pth"
    save_checkpoint(good, model, optimizer, scheduler, TrainState(epoch=1), {"ok": 1})
    save_weights(weights, model, TrainState(epoch=1), {}, {"ok": 1})
    damaged = []
    for kind, _ in DAMAGE:
        damaged.append(tmp_path / f"{kind}.ckpt")
        damaged[-1].write_bytes(corrupt(kind, good.read_bytes(), weights))
    stops = train_stops(*([f"resume={bad}", f"hydra.run.dir={bad.with_suffix('.run')}"] for bad in damaged))
    for (kind, says), bad, stop in zip(DAMAGE, damaged, stops):
        assert isinstance(stop, str) and "\n" not in stop, (kind, stop)
        assert stop.startswith(f"error: {bad}: ") and says in stop, (kind, stop)
    # and as a command: the one line on stderr, no traceback
    proc = subprocess.run(
        [sys.executable, "train.py", f"resume={damaged[0]}", f"hydra.run.dir={tmp_path / 'command'}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert proc.returncode == 1 and proc.stderr == stops[0] + "\n", proc.stderr


def test_a_checkpoint_written_before_the_envelope_loads_with_a_warning(tmp_path, caplog):
    model = torch.nn.Linear(2, 2)
    legacy = {"model": model.state_dict(), "epoch": 1, "global_step": 3, "config": {"ok": 1}}
    torch.save(legacy, tmp_path / "old.pth")
    with caplog.at_level("WARNING"):
        assert read_checkpoint(tmp_path / "old.pth")["global_step"] == 3
    assert "no checksum" in caplog.text


@pytest.mark.parametrize(
    "override, key",
    [
        ("trainer.max_steps=abc", "trainer.max_steps"),
        ("trainer.batch_size=0", "trainer.batch_size"),
        ("data.input_size=[100,100]", "data.input_size"),
        ("optimizer.lr=-1", "optimizer.lr"),
        ("trainer.epochs=0", "trainer.epochs"),
        pytest.param(
            "trainer.device=cuda",
            "trainer.device",
            marks=pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA"),
        ),
    ],
)
def test_a_bad_config_value_stops_training_with_one_line_naming_the_key(tmp_path, override, key):
    proc = subprocess.run(
        [sys.executable, "train.py", override, f"hydra.run.dir={tmp_path}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith(f"error: {key}=")


def test_a_bad_config_value_stops_before_torch_is_imported(tmp_path):
    # the check comes first, so that a typo costs a second, not torch's import (several on a slow machine)
    code = (
        "import runpy, sys\n"
        f"sys.argv = ['train.py', 'trainer.epochs=0', 'hydra.run.dir={tmp_path}']\n"
        "try:\n"
        "    runpy.run_path('train.py', run_name='__main__')\n"
        "except SystemExit as stop:\n"
        "    print(stop.code)\n"
        "    print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'torchvision', 'cv2')))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    message, modules = proc.stdout.splitlines()
    assert message.startswith("error: trainer.epochs=0") and modules == "[]", proc.stdout


def test_tensorboard_logs_losses_lr_ap_and_heatmap_grid(synthetic_root, tmp_path):
    accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    out = run_training(synthetic_root, tmp_path / "tb", "trainer.epochs=1", "trainer.log_every=1")
    events = accumulator.EventAccumulator(str(tmp_path / "tb"), size_guidance={"images": 0, "scalars": 0})
    events.Reload()
    scalars = set(events.Tags()["scalars"])
    expected = {"train/loss", "train/body", "train/foot", "train/lr", "val/loss"} | {
        f"val/{m}_{s}" for m in ("AP", "AR") for s in ("all", "body", "foot")
    }
    assert expected <= scalars, expected - scalars
    assert [e.value for e in events.Scalars("train/loss")] == pytest.approx(list(out["losses"].values()), rel=1e-5)
    assert events.Scalars("train/lr")[0].value == pytest.approx(1e-3)
    assert events.Scalars("val/AP_foot")[-1].value == pytest.approx(out["metrics"]["AP_foot"])
    (grid,) = events.Images("val/heatmaps")
    assert grid.width == 2 * (192 + 4) and grid.height == 2 * (192 + 4)  # 2 crops x [target | prediction]


def test_a_failed_checkpoint_write_keeps_the_previous_file(tmp_path):
    model = torch.nn.Linear(2, 2)
    optimizer = torch.optim.Adam(model.parameters())
    scheduler = torch.optim.lr_scheduler.MultiStepLR(optimizer, [1])
    path = tmp_path / "last.ckpt"
    save_checkpoint(path, model, optimizer, scheduler, TrainState(epoch=1), {"ok": 1})
    before = path.read_bytes()
    with pytest.raises(Exception):
        save_checkpoint(path, model, optimizer, scheduler, TrainState(epoch=2), {"bad": lambda: 0})
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["last.ckpt"]


# --- DistributedDataParallel ----------------------------------------------------------------------


def test_torchrun_two_processes_shard_the_epoch(synthetic_root, tmp_path):
    run_dir = tmp_path / "ddp"
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node=2",
        "train.py",
        *TINY,
        f"data.root={synthetic_root}",
        "trainer.epochs=2",
        "trainer.device=cpu",
        f"hydra.run.dir={run_dir}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    single = TopDownDataset(
        load_coco23(synthetic_root / "train" / "annotations.json", synthetic_root / "train" / "images"),
        MultiModalHeatmapCodec((64, 64), (16, 16)),
        (64, 64),
    )
    per_rank = -(-len(single) // 2)  # DistributedSampler-style shards
    checkpoint = read_checkpoint(run_dir / "checkpoints" / "last.ckpt")
    assert checkpoint["epoch"] == 2 and checkpoint["global_step"] == 2 * -(-per_rank // 4)
    assert checkpoint["global_step"] < 2 * -(-len(single) // 4)  # fewer steps than one process takes
    assert list(run_dir.glob("events.out.tfevents.*")) and (run_dir / "metrics.json").is_file()


# --- (c) the Hydra sweep ----------------------------------------------------------------------------


def test_mu_lambda_multirun_writes_checkpoints_and_tensorboard(synthetic_root, tmp_path):
    sweep = tmp_path / "sweep"
    cmd = [
        sys.executable,
        "train.py",
        "-m",
        "+experiment=mu_lambda_ablation",
        "loss.mu=0,0.5",
        "loss.foot_weight=1.5",
        "trainer.max_steps=2",
        f"data.root={synthetic_root}",
        "data.input_size=[64,64]",
        "trainer.batch_size=4",
        "trainer.val_batch_size=16",
        "trainer.progress=false",
        "trainer.threads=1",
        f"hydra.sweep.dir={sweep}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    for mu in ("0", "0.5"):
        run_dir = sweep / f"loss.foot_weight=1.5,loss.mu={mu}"  # named by the swept settings only
        assert list(run_dir.glob("events.out.tfevents.*")), sorted(p.name for p in sweep.iterdir())
        checkpoint = read_checkpoint(run_dir / "checkpoints" / "last.ckpt")
        assert checkpoint["global_step"] == 2 and checkpoint["config"]["loss"]["mu"] == float(mu)
        assert checkpoint["config"]["model"]["depth"] == 18 and (run_dir / "val_predictions.json").is_file()


def test_box_and_colour_jitter_leave_the_geometric_draws_unchanged(wholebody):
    codec = MultiModalHeatmapCodec((192, 256), (48, 64))
    plain = TopDownDataset(wholebody, codec, (192, 256), augment=CropAugmentation(), seed=3)
    jittered = TopDownDataset(
        wholebody, codec, (192, 256), augment=CropAugmentation(shift_factor=0.1, colour_factor=0.3), seed=3
    )
    assert [plain.augmentation(i) for i in range(len(plain))] == [jittered.augmentation(i) for i in range(len(plain))]
    assert plain.jitter(0) is None and jittered.jitter(0) is not None
    a, b = plain[0], jittered[0]
    assert a["image"].shape == b["image"].shape and not torch.equal(a["image"], b["image"])


def test_validation_flip_test_scores_flip_tested_heatmaps(wholebody):
    """A mirror-equivariant network scores the same with and without the flip test; a network that looks at
    one side of the crop does not, and its loss (from the plain heatmaps) is the same both ways."""
    from models.training import validate
    from tests.test_heatmap_inference import BlobFinder

    codec = MultiModalHeatmapCodec((64, 64), (16, 16), sigma=1.0)
    dataset = TopDownDataset(wholebody, codec, (64, 64), augment=None, train=False)
    loader = DataLoader(dataset, batch_size=4, sampler=EpochSampler(len(dataset), shuffle=False))
    run = lambda model, flip: validate(
        model, loader, codec, wholebody, WeightedHeatmapLoss(1.5), torch.device("cpu"), 0, False, flip
    )  # noqa: E501
    equivariant = BlobFinder()
    assert run(equivariant, True).metrics == run(equivariant, False).metrics

    class LeftHalf(torch.nn.Module):
        def forward(self, x):
            out = BlobFinder()(x).clone()
            out[..., out.shape[-1] // 2 :] = 0
            return out

    plain, flipped = run(LeftHalf(), False), run(LeftHalf(), True)
    assert plain.metrics["loss"] == flipped.metrics["loss"]
    a, b = (np.array([p["keypoints"] for p in v.predictions], float) for v in (plain, flipped))
    assert a.shape == b.shape and not np.allclose(a, b)
