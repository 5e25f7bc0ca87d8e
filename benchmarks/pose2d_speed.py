"""Speed of the SPPE stage's parts: FastPose crops per second, and decoding + association time per person.

    python -m benchmarks.pose2d_speed [--min-time 0.3] [--persons 10] [--repeats 10] [--devices cpu,cuda]

Network: FastPose-18 and FastPose-50 with random weights (speed does not depend on them), inputs 256x192
and 128x96 (h x w), batches of 1 and 32 crops, flip test off and on (twice the images), on this CPU with 1
thread and with torch's default thread count, and on CUDA with float16 autocast when there is a GPU
(models/heatmap_inference.predict_heatmaps, exactly what the stage runs; ``--devices`` picks among them). Each
model, input and device gets one warm-up crop (with and without flip), and each setting one untimed pass of its
own (a batch of 32 is a new shape: CUDA's first pass of it loads kernels); each setting then runs passes until
``--min-time`` seconds have gone (at least one); crops/s = crops / mean pass time. The CPU rows are only as
steady as the machine is idle: other processes on its cores show up most in the multi-thread rows.

Decoding: real-ish heatmaps of one crowded image: ``--persons`` people 12 px apart with COCO-23 joints,
each crop's multi-modal target (mu 0.5: the own joints plus the neighbours' in the crop) with uniform noise,
48x64 heatmaps. The torch path (models/pose_decoding: candidates for all crops at once, vectorised
association) and the numpy reference it replaced (benchmarks/reference_decoding.py) decode the same heatmaps
(3 candidates per joint, threshold 0.1) ``--repeats`` times, interleaved, 1 thread; medians per person and
their ratio, and the torch path's share of the FastPose-50 256x192 batch-32 crop time (1 thread, no flip).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from benchmarks import reference_decoding as reference
from data.keypoints import NUM_JOINTS
from data.pose2d.crop_transforms import box_to_center_scale, crop_affine
from evaluation.report import format_table
from models.fastpose import FastPose
from models.heatmap_codec import MultiModalHeatmapCodec
from models.heatmap_inference import predict_heatmaps
from models.pose_decoding import associate_by_image, joint_candidates

SIZES = {"256x192": (256, 192), "128x96": (128, 96)}  # h x w


def crops_per_second(
    model: FastPose, device: torch.device, size: tuple[int, int], batch: int, flip: bool, min_time: float
) -> float:
    """Crops per second of predict_heatmaps on a batch of random crops (h, w) = size."""
    crops = torch.randn(batch, 3, *size, device=device)
    amp = device.type == "cuda"

    def one_pass() -> None:
        predict_heatmaps(model, crops, batch_size=batch, flip_test=flip, amp=amp)
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    one_pass()  # untimed: this shape's first pass
    passes, start = 0, time.perf_counter()
    while passes == 0 or time.perf_counter() - start < min_time:
        one_pass()
        passes += 1
    return batch * passes / (time.perf_counter() - start)


def network_rows(
    min_time: float, default_threads: int, devices: tuple[str, ...] = ("cpu", "cuda")
) -> list[list[object]]:
    """Table rows: model, input, batch, device / threads, flip test, crops/s, ms per crop (CUDA where available)."""
    targets = ([("cpu", 1)] + [("cpu", default_threads)] * (default_threads > 1)) * ("cpu" in devices)
    targets += [("cuda", 0)] * (torch.cuda.is_available() and "cuda" in devices)
    rows = []
    for depth in (18, 50):
        torch.manual_seed(0)
        model = FastPose(depth).eval()
        for name, size in SIZES.items():
            for device_name, threads in targets:
                device = torch.device(device_name)
                model.to(device)
                if threads:
                    torch.set_num_threads(threads)
                for flip in (False, True):  # warm-up: kernels chosen and loaded, memory allocated
                    predict_heatmaps(model, torch.randn(1, 3, *size, device=device), 1, flip, device.type == "cuda")
                where = f"CPU, {threads} thread{'s' * (threads > 1)}" if threads else "CUDA, fp16 autocast"
                for batch in (1, 32):
                    for flip in (False, True):
                        rate = crops_per_second(model, device, size, batch, flip, min_time)
                        rows.append(
                            [f"FastPose-{depth}", name, batch, where, "on" if flip else "off", rate, 1e3 / rate]
                        )
        del model
    torch.set_num_threads(default_threads)
    return rows


def crowd_heatmaps(persons: int, seed: int = 0) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Noisy multi-modal targets (P, 23, 64, 48) float32 of one crowded image, crop-to-image affines (P, 2, 3) and
    boxes (P, 4)."""
    rng = np.random.default_rng(seed)
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=0.5)
    corner = np.column_stack([np.arange(persons) * 12.0 + 100, rng.uniform(100, 120, persons)])
    joints = corner[:, None] + rng.uniform((0, 0), (60, 170), (persons, NUM_JOINTS, 2))
    keypoints = np.concatenate([joints, np.full((persons, NUM_JOINTS, 1), 2.0)], axis=-1)
    boxes = np.column_stack([joints.min(1), joints.max(1) - joints.min(1)])
    heatmaps, affines = [], []
    for p, box in enumerate(boxes):
        center, scale = box_to_center_scale(box, 192 / 256)
        target, _ = codec.encode_crop(keypoints, p, crop_affine(center, scale, 0.0, (192, 256)), np.ones(23, bool))
        heatmaps.append(target + rng.uniform(0, 0.05, target.shape).astype(np.float32))
        affines.append(crop_affine(center, scale, 0.0, (192, 256), inverse=True))
    return torch.from_numpy(np.stack(heatmaps)), np.stack(affines), boxes


def decoding_times(persons: int, repeats: int) -> tuple[float, float, int]:
    """Median ms per person of the numpy reference and the torch path on one crowded image, and the number of
    joint types whose association had a shared node (work for the Hungarian step) in the reference output."""
    heatmaps, affines, boxes = crowd_heatmaps(persons)
    codec = MultiModalHeatmapCodec((192, 256), (48, 64))

    def numpy_path() -> np.ndarray:
        xy, scores = reference.find_candidates(heatmaps, threshold=0.1, top_m=3)
        return reference.associate_joints(reference.candidates_to_image(xy, affines, 4.0), scores, boxes)

    def torch_path() -> np.ndarray:
        candidates = joint_candidates(codec, heatmaps, affines, threshold=0.1, top_m=3)
        return associate_by_image(candidates, boxes, np.zeros(persons, dtype=int))

    if not np.allclose(numpy_path(), torch_path(), rtol=0, atol=1e-9):
        raise AssertionError("the torch decoding differs from the numpy reference")
    times: dict[str, list[float]] = {"numpy": [], "torch": []}
    for _ in range(repeats):
        for name, fn in (("numpy", numpy_path), ("torch", torch_path)):
            start = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - start) * 1e3 / persons)
    xy, scores = reference.find_candidates(heatmaps, threshold=0.1, top_m=3)
    lost = reference.associate_joints(reference.candidates_to_image(xy, affines, 4.0), scores, boxes)[..., 2] == 0
    return float(np.median(times["numpy"])), float(np.median(times["torch"])), int(lost.any(0).sum())


def main(argv: list[str] | None = None) -> str:
    """Print both tables."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--min-time", type=float, default=0.3, help="seconds of timed passes per network setting")
    parser.add_argument("--persons", type=int, default=10, help="people in the decoding benchmark's image")
    parser.add_argument("--repeats", type=int, default=10, help="interleaved decoding runs (median)")
    parser.add_argument("--devices", default="cpu,cuda", help="devices of the network table (cuda where available)")
    args = parser.parse_args(argv)
    default_threads = torch.get_num_threads()
    rows = network_rows(args.min_time, default_threads, tuple(args.devices.split(",")))
    text = format_table(["network", "input h x w", "batch", "device", "flip test", "crops/s", "ms/crop"], rows, ".2f")
    torch.set_num_threads(1)
    ref_ms, torch_ms, contested = decoding_times(args.persons, args.repeats)
    torch.set_num_threads(default_threads)
    crop = [r[6] for r in rows if r[:5] == ["FastPose-50", "256x192", 32, "CPU, 1 thread", "off"]]
    text += "\n\n" + format_table(
        [
            "decoding + association, 1 thread",
            "numpy reference ms/person",
            "torch ms/person",
            "numpy / torch",
            "torch / FastPose-50 crop",
        ],
        [
            [
                f"{args.persons} people in one image, 3 candidates per joint",
                ref_ms,
                torch_ms,
                ref_ms / torch_ms,
                f"{100 * torch_ms / crop[0]:.1f} %" if crop else "- (no CPU rows)",
            ]
        ],
        ".3f",
    )
    text += f"\n({contested} of 23 joint types had a person lose a joint to a neighbour; torch default threads: {default_threads})"
    print(text)
    return text


if __name__ == "__main__":
    main()
