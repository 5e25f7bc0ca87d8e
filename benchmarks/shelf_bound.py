"""Oracle upper bounds of per-frame multi-view reconstruction on Shelf's OpenPose detections."""

from benchmarks import common  # isort: split

import argparse
import itertools

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from tqdm import tqdm

from data.geometry.camera import Rig
from data.geometry.triangulation import triangulate_dlt
from data.keypoints import COCO23_TO_SHELF14_LIMBS, coco23_to_shelf14, with_mid_hip
from evaluation.pcp import correct_parts
from evaluation.protocols import attach_protocols
from evaluation.protocols.shelf import AVERAGED_ACTOR_IDS, coco23_predictions_to_shelf15, select_prediction
from evaluation.report import format_table
from reconstruction.pipeline import MultiViewPipeline

HEAD = (12, 13)  # Shelf-14 head bottom, head top
METHODS = ("pipeline", "view-subset oracle", "matching + view-subset oracle")


def subset_poses(keypoints: np.ndarray, rig: Rig) -> np.ndarray:
    """Shelf-15 poses of every subset of >= 2 views with a detection: (V, 23, 3) px + score -> (S, 15, 3), NaN: < 2."""
    views = [v for v in range(len(keypoints)) if keypoints[v, :, 2].any()]
    subsets = [s for k in range(2, len(views) + 1) for s in itertools.combinations(views, k)]
    if not subsets:
        return np.zeros((0, 15, 3))
    und = rig.undistort(keypoints)
    poses2d = np.zeros((len(keypoints), len(subsets), keypoints.shape[1], 3))
    for p, subset in enumerate(subsets):
        poses2d[list(subset), p] = und[list(subset)]
    points = triangulate_dlt(poses2d, rig.projection_matrices())
    return with_mid_hip(coco23_to_shelf14(np.where(points[..., 3:] > 0, points[..., :3], np.nan)))


def oracle_pose(own: np.ndarray, candidates: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per limb joint the candidate nearest gt (head: as one part), own a candidate: (15, 3), (S, 15, 3) -> (15, 3)."""
    cands = np.concatenate([own[None], candidates])
    err = np.linalg.norm(cands - gt[None], axis=-1)
    err = np.where(np.isfinite(err), err, np.inf)
    out = own.copy()
    limbs = np.arange(len(COCO23_TO_SHELF14_LIMBS))
    out[limbs] = cands[np.argmin(err[:, limbs], axis=0), limbs]
    out[list(HEAD)] = cands[np.argmin(err[:, list(HEAD)].sum(axis=1)), list(HEAD)]
    return with_mid_hip(out[:14])


def nearest_detections(views: list, rig: Rig, gt: np.ndarray, max_px: float) -> np.ndarray:
    """Per view the detection nearest the projected GT limbs (mean error < max_px px), else 0: -> (V, 23, 3)."""
    out = np.zeros((len(views), 23, 3))
    for v, (dets, cam) in enumerate(zip(views, rig)):
        if not len(dets):
            continue
        target = cam.project(gt[:12])
        kp = dets.keypoints[:, COCO23_TO_SHELF14_LIMBS]
        seen = kp[..., 2] > 0
        err = np.where(seen, np.linalg.norm(kp[..., :2] - target[None], axis=-1), 0.0).sum(1)
        mean = np.where(seen.sum(1) >= 4, err / np.maximum(seen.sum(1), 1), np.inf)
        if mean.min() < max_px:
            out[v] = dets.keypoints[int(np.argmin(mean))]
    return out


def matched_detections(views: list, row: np.ndarray) -> np.ndarray:
    """The matcher's detections of one person: V ViewDetections, (V,) index or -1 -> (V, 23, 3)."""
    out = np.zeros((len(views), 23, 3))
    for v, i in enumerate(row):
        if i >= 0:
            out[v] = views[v].keypoints[i]
    return np.where(np.isfinite(out).all(-1, keepdims=True), out, 0.0)


def run(overrides: list[str], max_px: float) -> dict[str, dict[int, list[np.ndarray]]]:
    """Rows of correct parts per method and actor: {method: {actor id: [(10,) bool per frame]}}."""
    with initialize_config_dir(str(common.CONFIG_DIR), version_base="1.3"):
        cfg = compose("eval", overrides=overrides)
    sequence = attach_protocols(instantiate(cfg.dataset, _convert_="all"))
    rig, protocol = sequence.rig, sequence.protocols[0]
    pipeline = MultiViewPipeline(rig, instantiate(cfg.matching), instantiate(cfg.reconstruction))
    pipeline.calibrate_noise(sequence.frames)  # the run's 2D noise model, as eval.py fits it
    rows: dict[str, dict[int, list[np.ndarray]]] = {m: {a: [] for a in AVERAGED_ACTOR_IDS} for m in METHODS}
    for frame in tqdm(sequence.frames, desc="Shelf frames"):
        result = pipeline(frame)
        pred = coco23_predictions_to_shelf15(result.poses3d)
        for actor, gt in protocol.gt[frame.index].items():
            if actor not in AVERAGED_ACTOR_IDS:
                continue
            gt = gt[:, :3]
            best, _ = select_prediction(pred, gt)
            own = pred[best] if best >= 0 else np.full((15, 3), np.nan)
            mine = (
                matched_detections(frame.views, result.assignment[best]) if best >= 0 else np.zeros((len(rig), 23, 3))
            )
            poses = {
                "pipeline": own,
                "view-subset oracle": oracle_pose(own, subset_poses(mine, rig), gt),
                "matching + view-subset oracle": oracle_pose(
                    own, subset_poses(nearest_detections(frame.views, rig, gt, max_px), rig), gt
                ),
            }
            for method, pose in poses.items():
                rows[method][actor].append(correct_parts(pose[None], gt[None])[0])
    return rows


def main(argv: list[str] | None = None) -> list[list]:
    """Print strict Shelf PCP (actors 1-3 and their mean) of the pipeline and of the two oracles."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--max-px", type=float, default=40.0, help="a view's nearest detection must be this close")
    parser.add_argument("overrides", nargs="*", help="eval.yaml overrides, e.g. dataset.drop_feet=true")
    args = parser.parse_args(argv)
    rows = run([*common.shelf(args.data), *args.overrides], args.max_px)
    table = []
    for method in METHODS:
        pcp = [100.0 * np.mean(rows[method][a]) for a in AVERAGED_ACTOR_IDS]
        table.append([method, *pcp, float(np.mean(pcp))])
    print(f"Strict Shelf PCP (alpha 0.5), frames 300-600, overrides: {' '.join(args.overrides) or 'none'}")
    print(format_table(["method", "actor 1", "actor 2", "actor 3", "average 1-3"], table, floatfmt=".2f"))
    return table


if __name__ == "__main__":
    main()
