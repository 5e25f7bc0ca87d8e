"""Fit the 2D noise model (``noise_model`` config group) to the real errors of Shelf's OpenPose detections."""

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from data.datasets.shelf import load_shelf
from data.formats.atomic_io import atomic_write_text
from data.keypoints import COCO23_TO_SHELF14_LIMBS
from evaluation.protocols.shelf import load_actors_gt
from evaluation.report import format_table
from models.paf_grouping import group_view
from reconstruction.noise_model import NoiseModel

RAYLEIGH_MEDIAN = float(np.sqrt(2 * np.log(2)))
SCORE_BINS = (0.2, 0.4, 0.55, 0.7, 0.8, 0.9, 1.01)
SIZE_BINS = (0.0, 150.0, 250.0, 350.0, 1e9)
MIN_BIN = 30


def joint_errors(root: Path, frames: str | None, max_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel errors, scores and box sizes of every matched detection's scored limb joints: 3 x (K,)."""
    seq = load_shelf(root, frames=frames, baseline=None, grouper=group_view)
    first = seq.meta["first_frame"]
    gt = load_actors_gt(root / "tum" / "actorsGT.mat", range(first, first + 301))
    errors, scores, sizes = [], [], []
    for frame in seq.frames:
        actors = gt[frame.index - first]
        for camera, view in zip(seq.rig, frame.views):
            if not len(view) or not actors:
                continue
            truth = np.stack([camera.project(pose[:12, :3]) for pose in actors.values()])  # (A, 12, 2)
            kp = view.keypoints[:, COCO23_TO_SHELF14_LIMBS]  # (N, 12, 3)
            seen = kp[..., 2] > 0
            dist = np.linalg.norm(kp[:, None, :, :2] - truth[None], axis=-1)  # (N, A, 12)
            median = np.array([[np.median(d[s]) if s.any() else np.inf for d in row] for row, s in zip(dist, seen)])
            for n in range(len(view)):
                a = int(np.argmin(median[n]))
                if median[n, a] > max_px:
                    continue
                ok = seen[n]
                errors.append(dist[n, a, ok])
                scores.append(kp[n, ok, 2])
                sizes.append(np.full(int(ok.sum()), np.sqrt(view.bboxes[n, 2] * view.bboxes[n, 3])))
    return np.concatenate(errors), np.concatenate(scores), np.concatenate(sizes)


def binned_sigmas(errors: np.ndarray, scores: np.ndarray, sizes: np.ndarray) -> list[tuple[float, float, float, int]]:
    """(mean score, mean size, sigma = median error / Rayleigh median, count) of every bin with enough joints."""
    out = []
    for s0, s1 in zip(SCORE_BINS[:-1], SCORE_BINS[1:]):
        for b0, b1 in zip(SIZE_BINS[:-1], SIZE_BINS[1:]):
            hit = (scores >= s0) & (scores < s1) & (sizes >= b0) & (sizes < b1)
            if hit.sum() >= MIN_BIN:
                sigma = float(np.median(errors[hit])) / RAYLEIGH_MEDIAN
                out.append((float(scores[hit].mean()), float(sizes[hit].mean()), sigma, int(hit.sum())))
    return out


def model_sigma(
    score: np.ndarray, size: np.ndarray, sigma_px: float, c: float, k: float, sigma_min: float
) -> np.ndarray:
    """The sigma model at scores and box sizes: (K,), (K,) -> (K,) px."""
    return np.maximum(sigma_min, np.hypot(sigma_px, c * size) / score**k)


def fit(bins: list[tuple[float, float, float, int]], sigma_min: float) -> tuple[float, float, float]:
    """sigma_px, c and k of the model, least squares of log sigma weighted by sqrt(count)."""
    score, size, sigma, count = (np.array(v) for v in zip(*bins))

    def residual(theta: np.ndarray) -> np.ndarray:
        model = model_sigma(score, size, np.exp(theta[0]), np.exp(theta[1]), theta[2], sigma_min)
        return np.sqrt(count) * (np.log(model) - np.log(sigma))

    result = least_squares(residual, x0=np.array([np.log(5.0), np.log(0.01), 1.0]))
    return float(np.exp(result.x[0])), float(np.exp(result.x[1])), float(result.x[2])


def main(argv: list[str] | None = None) -> tuple[float, float, float]:
    """Print the binned errors and the fit (noise_model keys); -> (sigma_px, c, score_power)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", default="../shared/data/shelf", type=Path)
    parser.add_argument("--frames", default=None, help='"start:stop[:step]" positions (default: all 301)')
    parser.add_argument("--max-px", type=float, default=40.0, help="largest median joint distance of a match")
    parser.add_argument("--sigma-min", type=float, default=1.0)
    parser.add_argument("--out", type=Path, default=None, help="write the fit as a configs/noise_model/*.yaml")
    args = parser.parse_args(argv)
    errors, scores, sizes = joint_errors(args.root, args.frames, args.max_px)
    bins = binned_sigmas(errors, scores, sizes)
    sigma_px, c, k = fit(bins, args.sigma_min)
    models = (NoiseModel(c=c, sigma_px=sigma_px, score_power=k, sigma_min=args.sigma_min), NoiseModel())
    at = lambda m, s, b: float(model_sigma(s, b, m.sigma_px, m.c, m.score_power, m.sigma_min))
    rows = [[f"{s:.2f}", f"{b:.0f}", n, sig, *(at(m, s, b) for m in models)] for s, b, sig, n in bins]
    print(
        f"Shelf OpenPose limb joints matched to the projected actorsGT.mat: {len(errors)} joints; "
        f"median error {np.median(errors):.2f} px, {100 * np.mean(errors > 30):.1f} % beyond 30 px"
    )
    headers = ["score", "box size (px)", "joints", "sigma measured (px)", "fit", "configured"]
    print(format_table(headers, rows, floatfmt=".2f"))
    keys = f"c: {c:.4f}\nsigma_px: {sigma_px:.2f}\nscore_power: {k:.2f}\nsigma_min: {args.sigma_min:g}\n"
    print(
        f"\nfit: sigma = max({args.sigma_min:g}, sqrt({sigma_px:.2f}^2 + ({c:.4f} sqrt(w h))^2) / score ** {k:.2f}) px"
    )
    print(f"noise_model keys (configs/noise_model/*.yaml):\n{keys}")
    if args.out:
        atomic_write_text(args.out, f"_target_: reconstruction.noise_model.NoiseModel\n{keys}")
    return sigma_px, c, k


if __name__ == "__main__":
    main()
