"""Speed of the SPPE stage's parts: FastPose crops per second, and decoding + association time per person."""

import argparse
import time

import numpy as np
import torch

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
                        setting = [f"FastPose-{depth}", name, batch, where, "on" if flip else "off"]
                        rows.append([*setting, rate, 1e3 / rate])
        del model
    torch.set_num_threads(default_threads)
    return rows


def crowd_heatmaps(persons: int, seed: int = 0) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Noisy multi-modal targets (P, 23, 64, 48) of a crowded image, crop-to-image affines (P, 2, 3), boxes (P, 4)."""
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


def decoding_ms(persons: int, repeats: int) -> float:
    """Median ms per person of candidates + association on one crowded image."""
    heatmaps, affines, boxes = crowd_heatmaps(persons)
    codec = MultiModalHeatmapCodec((192, 256), (48, 64))

    def decode() -> np.ndarray:
        candidates = joint_candidates(codec, heatmaps, affines, threshold=0.1, top_m=3)
        return associate_by_image(candidates, boxes, np.zeros(persons, dtype=int))

    decode()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        decode()
        times.append((time.perf_counter() - start) * 1e3 / persons)
    return float(np.median(times))


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
    ms = decoding_ms(args.persons, args.repeats)
    torch.set_num_threads(default_threads)
    crop = [r[6] for r in rows if r[:5] == ["FastPose-50", "256x192", 32, "CPU, 1 thread", "off"]]
    share = f"{100 * ms / crop[0]:.1f} %" if crop else "- (no CPU rows)"
    headers = ["decoding + association, 1 thread", "ms/person", "share of a FastPose-50 crop"]
    text += "\n\n" + format_table(headers, [[f"{args.persons} people in one image", ms, share]], ".3f")
    text += f"\n(torch default threads: {default_threads})"
    print(text)
    return text


if __name__ == "__main__":
    main()
