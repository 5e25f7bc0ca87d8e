"""The standard Shelf PCP protocol (VoxelPose ``Shelf.evaluate``), and 4D Association's stored output scored by it."""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import scipy.io

from data.formats.atomic_io import atomic_write_text
from data.formats.fourd_skeletons import load_4dassoc_skeletons
from data.keypoints import SHELF14_NAMES, coco23_to_shelf14, with_mid_hip
from evaluation.identity import IdentityEvaluator
from evaluation.pcp import PART_JOINTS, PART_NAMES, correct_parts, pcp_by_part

if TYPE_CHECKING:
    from data.multiview import Frame
    from reconstruction.pipeline import FrameResult

SHELF_TEST_FRAMES = range(300, 601)
AVERAGED_ACTOR_IDS = (0, 1, 2)
PROTOCOL_NOTES = {
    "strict": "an annotated actor without any prediction counts all 10 parts wrong",
    "lenient": "frames where an annotated actor has no prediction are skipped for it",
}
SELECTION_NOTE = (
    "per GT actor, the prediction with the smallest mean distance over the 14 Shelf "
    "joints (not one-to-one, as VoxelPose's Shelf evaluate)"
)

# SKEL19 of 4D Association (src/skel.h, BODY25 -> SKEL19 mapping): 0 pelvis, 1 neck, 2 R-hip,
# 3 L-hip, 4 nose, 5 R-shoulder, 6 L-shoulder, 7 R-knee, 8 L-knee, 9 R-ear, 10 L-ear, 11 R-elbow,
# 12 L-elbow, 13 R-ankle, 14 L-ankle, 15 R-wrist, 16 L-wrist, 17 L-big-toe, 18 R-big-toe.
# Shelf-14 joint j = SKEL19 joint SKEL19_TO_SHELF14[j]; joints 12 and 13 are rebuilt below.
SKEL19_TO_SHELF14 = np.array([13, 7, 2, 3, 8, 14, 15, 11, 5, 6, 12, 16, 1, 4])
SKEL19_PELVIS, SKEL19_NECK, SKEL19_SHOULDERS, SKEL19_EARS = 0, 1, (5, 6), (9, 10)
# Head rebuild of 4D Association's own Shelf evaluation (MappingToShelf in evaluate_shelf/main.cpp
# of zhangyux15/4d_association): bottom = half-way from the shoulder centre to the ear centre,
# top = bottom + 0.125 m along the facing direction + 0.145 m along world z.
FOURDA_HEAD_FORWARD_M = 0.125
FOURDA_HEAD_UP_M = 0.145


def coco23_predictions_to_shelf15(poses3d: np.ndarray) -> np.ndarray:
    """Our COCO-23 world poses to Shelf-14 + mid-hip: (P, 23, 4) -> (P, 15, 3), NaN where missing."""
    poses3d = np.asarray(poses3d, dtype=np.float64).reshape(-1, 23, 4)
    return with_mid_hip(coco23_to_shelf14(np.where(poses3d[..., 3:] > 0, poses3d[..., :3], np.nan)))


def skel19_to_shelf15(skel: np.ndarray) -> np.ndarray:
    """4D Association SKEL19 to Shelf-14 + mid-hip: (..., 19, 4) -> (..., 15, 3), NaN where invalid."""
    skel = np.asarray(skel, dtype=np.float64)
    points = np.where(skel[..., 3:] > 0, skel[..., :3], np.nan)
    out = points[..., SKEL19_TO_SHELF14, :]
    out[..., 12, :], out[..., 13, :] = _skel19_head(points)
    return with_mid_hip(out)


def _skel19_head(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bottom and top of the head from SKEL19 points: (..., 19, 3) -> (..., 3), (..., 3)."""
    right, left = (points[..., j, :] for j in SKEL19_SHOULDERS)
    up = points[..., SKEL19_NECK, :] - points[..., SKEL19_PELVIS, :]
    forward = np.cross(up, right - left)
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    forward = forward / np.where(norm > 0, norm, np.nan)
    shoulder_centre = (right + left) / 2
    ear_centre = (points[..., SKEL19_EARS[0], :] + points[..., SKEL19_EARS[1], :]) / 2
    bottom = (shoulder_centre + ear_centre) / 2
    top = bottom + FOURDA_HEAD_FORWARD_M * forward + np.array([0.0, 0.0, FOURDA_HEAD_UP_M])
    return bottom, top


def select_prediction(pred: np.ndarray, gt: np.ndarray) -> tuple[int, float]:
    """Index and mean 14-joint distance (m) of the closest prediction: (P, 15, 3), (15, 3) -> (i, d) or (-1, nan)."""
    dist = np.linalg.norm(pred[:, :14, :3] - gt[None, :14, :3], axis=-1)
    present = np.isfinite(dist)
    count = present.sum(-1)
    mean = np.where(count > 0, np.where(present, dist, 0.0).sum(-1) / np.maximum(count, 1), np.inf)
    if mean.size == 0 or not np.isfinite(mean.min()):
        return -1, float("nan")
    best = int(np.argmin(mean))
    return best, float(mean[best])


def _annotated(actor: int, pose: np.ndarray) -> bool:
    """Whether a GT actor is annotated in its frame: (15, 3 or 4); partial annotation is an error."""
    if pose.shape[-1] < 4:
        return True
    valid = pose[:, 3] > 0
    if valid.any() and not valid.all():
        raise ValueError(f"ground-truth actor {actor} is only partly annotated ({int(valid.sum())}/15)")
    return bool(valid.all())


class ShelfEvaluator:
    """Accumulates the Shelf PCP protocol (strict and lenient) and the MPJPE of the chosen predictions."""

    def __init__(self, alpha: float = 0.5, averaged_ids: tuple[int, ...] = AVERAGED_ACTOR_IDS) -> None:
        """alpha: PCP threshold fraction of the part length; averaged_ids: GT ids in the headline mean."""
        self.alpha = alpha
        self.averaged_ids = tuple(averaged_ids)
        self._frames: set[int] = set()
        self._rows: dict[str, dict[int, list[np.ndarray]]] = {p: defaultdict(list) for p in PROTOCOL_NOTES}
        self._errors: dict[int, list[float]] = defaultdict(list)

    def update(self, frame: int, pred_shelf15: np.ndarray, gt: dict[int, np.ndarray]) -> None:
        """Score one frame: predictions (P, 15, 3) world metres; gt {actor id: (15, 4) x, y, z, valid}."""
        if frame in self._frames:
            raise ValueError(f"frame {frame} was already scored")
        self._frames.add(frame)
        pred = np.asarray(pred_shelf15, dtype=np.float64)
        if pred.size == 0:
            pred = pred.reshape(0, 15, 3)
        if pred.ndim != 3 or pred.shape[1:] != (15, 3):
            raise ValueError(f"frame {frame}: predictions must be (P, 15, 3), got {pred.shape}")
        for actor, pose in gt.items():
            pose = np.asarray(pose, dtype=np.float64)
            if pose.shape[0] != 15 or pose.shape[-1] not in (3, 4):
                raise ValueError(f"frame {frame}: GT actor {actor} must be (15, 4), got {pose.shape}")
            if _annotated(actor, pose):
                self._score_actor(actor, pred, pose[:, :3])

    def _score_actor(self, actor: int, pred: np.ndarray, gt: np.ndarray) -> None:
        """Append one annotated actor's parts to both protocols: (P, 15, 3), (15, 3)."""
        best, error = select_prediction(pred, gt)
        if best < 0:
            self._rows["strict"][actor].append(np.zeros(len(PART_JOINTS), dtype=bool))
            return
        row = correct_parts(pred[best][None], gt[None], self.alpha)[0]
        self._rows["strict"][actor].append(row)
        self._rows["lenient"][actor].append(row)
        self._errors[actor].append(error)

    def summary(self) -> dict:
        """Per-actor per-part PCP (%) for both protocols, the mean over Actors 1-3 and MPJPE (mm)."""
        actors = sorted(set(self._rows["strict"]) | set(self.averaged_ids))
        ids = self._averaged_present()
        out: dict = {"protocol": self._protocol()}
        for name, rows in self._rows.items():
            per_actor = {a + 1: _actor_pcp(rows.get(a, [])) for a in actors}
            out[name] = {"actors": per_actor, "average": _mean_over(per_actor, ids)}
        errors = {
            a + 1: 1000.0 * float(np.mean(self._errors[a])) if a in self._errors else float("nan") for a in actors
        }
        averaged = [errors[a + 1] for a in ids]
        out["mpjpe_mm"] = {"actors": errors, "average": float(np.mean(averaged)) if averaged else float("nan")}
        return out

    def _averaged_present(self) -> tuple[int, ...]:
        """The averaged GT ids annotated in a scored frame; all of them when none is (a NaN mean, not one over nobody)."""
        return tuple(a for a in self.averaged_ids if self._rows["strict"].get(a)) or self.averaged_ids

    def _protocol(self) -> dict:
        """The settings and frame range behind a summary."""
        frames = sorted(self._frames)
        return {
            "alpha": self.alpha,
            "frames": len(frames),
            "first_frame": frames[0] if frames else None,
            "last_frame": frames[-1] if frames else None,
            "standard_frames": frames == list(SHELF_TEST_FRAMES),
            "averaged_actors": [a + 1 for a in self._averaged_present()],
            "selection": SELECTION_NOTE,
            **PROTOCOL_NOTES,
        }


def _actor_pcp(rows: list[np.ndarray]) -> dict[str, float]:
    """Per-part and average PCP (%) of one actor plus its frame count: K rows of (10,) bool."""
    return {**pcp_by_part(np.array(rows, dtype=bool).reshape(-1, len(PART_JOINTS))), "frames": len(rows)}


def _mean_over(per_actor: dict[int, dict[str, float]], ids: tuple[int, ...]) -> dict[str, float]:
    """Mean over the given actors (GT ids) of each part's PCP and of the average."""
    keys = (*PART_NAMES, "average")
    return {k: float(np.mean([per_actor[a + 1][k] for a in ids])) if ids else float("nan") for k in keys}


def format_table(summary: dict, name: str) -> str:
    """Rows per protocol x actor, columns the 6 part groups, the average and MPJPE: a text table."""
    proto = summary["protocol"]
    lines = [
        f"{name}: Shelf PCP, alpha {proto['alpha']}, frames {proto['first_frame']}-"
        f"{proto['last_frame']} ({proto['frames']} frames"
        f"{'' if proto['standard_frames'] else ', NOT the standard 300-600'}); {proto['selection']}"
    ]
    header = f"{'protocol':9}{'actor':10}{'frames':>7}" + "".join(f"{p:>12}" for p in PART_NAMES)
    lines.append(header + f"{'average':>10}{'MPJPE mm':>10}")
    averaged = proto["averaged_actors"]
    for protocol in PROTOCOL_NOTES:
        block = summary[protocol]
        for actor, pcp in block["actors"].items():
            label = f"actor {actor}" + ("" if actor in averaged else "*")
            lines.append(_row(protocol, label, pcp["frames"], pcp, summary["mpjpe_mm"]["actors"][actor]))
        label = "avg " + ",".join(str(a) for a in averaged)
        lines.append(_row(protocol, label, None, block["average"], summary["mpjpe_mm"]["average"]))
    lines.append("* not in the average.  " + "  ".join(f"{k}: {v}." for k, v in PROTOCOL_NOTES.items()))
    return "\n".join(lines)


def _row(protocol: str, label: str, frames: int | None, pcp: dict[str, float], mpjpe: float) -> str:
    """One table row."""
    cells = "".join(f"{pcp[p]:12.1f}" for p in PART_NAMES)
    count = "" if frames is None else str(frames)
    return f"{protocol:9}{label:10}{count:>7}{cells}{pcp['average']:10.2f}{mpjpe:10.1f}"


def score_4dassoc_output(
    skel_path: str | Path,
    gt_path: str | Path,
    first_frame: int = 300,
    frames: list[int] | None = None,
    alpha: float = 0.5,
) -> dict:
    """Score 4D Association's stored skel.txt (SKEL19) against gt.txt -> ShelfEvaluator.summary()."""
    skels = load_4dassoc_skeletons(skel_path)
    gts = load_4dassoc_skeletons(gt_path)
    if len(skels) != len(gts):
        raise ValueError(f"{skel_path}: {len(skels)} frames but {gt_path} has {len(gts)}")
    positions = range(len(gts)) if frames is None else [f - first_frame for f in frames]
    evaluator = ShelfEvaluator(alpha)
    for i in positions:
        if not 0 <= i < len(gts):
            raise ValueError(
                f"{skel_path}: frame {first_frame + i} is outside the file's {first_frame}.."
                f"{first_frame + len(gts) - 1}"
            )
        poses = [p for p in skels[i].values() if (p[:, 3] > 0).any()]
        if any(p.shape[0] != 19 for p in poses):
            raise ValueError(f"{skel_path}: frame {i} is not a 19-joint SKEL19 skeleton")
        evaluator.update(first_frame + i, skel19_to_shelf15(np.array(poses).reshape(-1, 19, 4)), gts[i])
    return evaluator.summary()


class ShelfProtocol:
    """The Shelf protocol as a dataset protocol: ours beside 4D Association's stored output, scored by the same code."""

    name = "shelf"
    predictions_file = "shelf_predictions.json"

    def __init__(
        self,
        gt: dict[int, dict[int, np.ndarray]],
        gt_path: str | Path | None = None,
        baseline_path: str | Path | None = None,
        first_frame: int = 300,
        alpha: float = 0.5,
    ) -> None:
        """gt: per Shelf frame {actor id: (15, 4)}; baseline_path: skel.txt (None = no baseline)."""
        self.gt = gt
        self.gt_path, self.baseline_path = gt_path, baseline_path
        self.first_frame, self.alpha = first_frame, alpha
        self.evaluator = ShelfEvaluator(alpha)
        self.identities = IdentityEvaluator()
        self.predictions: dict[int, np.ndarray] = {}
        self._baseline: tuple[tuple[int, ...], dict] | None = None  # (frames, summary) of the last scoring

    def update(self, frame: Frame, result: FrameResult) -> None:
        """Score one frame's poses3d (P, 23, 4); with track ids, record the id of the pose each annotated actor takes."""
        pred = coco23_predictions_to_shelf15(result.poses3d)
        self.update_shelf15(frame.index, pred)
        if result.ids is not None:
            for actor, gt in self.gt[frame.index].items():
                if _annotated(actor, np.asarray(gt)):
                    best = select_prediction(pred, np.asarray(gt)[:, :3])[0]
                    self.identities.record(actor, int(result.ids[best]) if best >= 0 else -1)

    def update_shelf15(self, frame: int, pred: np.ndarray) -> None:
        """Score Shelf-14 + mid-hip predictions (P, 15, 3), NaN = missing, of one Shelf frame."""
        if frame not in self.gt:
            raise ValueError(f"frame {frame} has no Shelf ground truth ({self.gt_path})")
        self.evaluator.update(frame, pred, self.gt[frame])
        self.predictions[frame] = np.array(pred, dtype=np.float64).reshape(-1, 15, 3)

    def summary(self) -> dict:
        """{"ours": ShelfEvaluator summary, "4d_association": the same for skel.txt (when given)}."""
        out = {"ours": self.evaluator.summary()}
        if self.identities.history:
            actors = [a + 1 for a in AVERAGED_ACTOR_IDS]
            out["tracking"] = {**self.identities.summary(AVERAGED_ACTOR_IDS), "actors": actors}
        if self.baseline_path is not None and self.gt_path is not None and self.predictions:
            frames = tuple(sorted(self.predictions))
            if self._baseline is None or self._baseline[0] != frames:
                baseline = score_4dassoc_output(
                    self.baseline_path, self.gt_path, self.first_frame, list(frames), self.alpha
                )
                self._baseline = (frames, baseline)
            out["4d_association"] = self._baseline[1]
        return out

    def report(self) -> str:
        """A protocol header line, our table and 4D Association's, and the headline comparison."""
        summary = self.summary()
        proto = summary["ours"]["protocol"]
        lines = [
            f"Shelf protocol: frames {proto['first_frame']}-{proto['last_frame']} ({proto['frames']}), "
            f"PCP alpha {self.alpha} over 10 parts, headline = mean of actors "
            f"{', '.join(map(str, proto['averaged_actors']))}; {SELECTION_NOTE}",
            "",
            format_table(summary["ours"], "ours"),
        ]
        if "4d_association" in summary:
            lines += ["", format_table(summary["4d_association"], "4D Association stored output, same code")]
        lines += ["", _headline(summary)]
        if "tracking" in summary:
            t = summary["tracking"]
            lines.append(
                f"Tracking, actors 1-3 (the track id of the prediction each actor takes): {t['id_switches']} "
                f"identity switches, {t['idf1_like']:.1f} % of actor-frames with their most frequent id, "
                f"{t['fragmentations']} fragmentations"
            )
        return "\n".join(lines)

    def write(self, out_dir: str | Path) -> Path:
        """Write the scored Shelf-15 predictions and each actor's chosen one to out_dir/shelf_predictions.json."""
        frames = []
        for frame, pred in sorted(self.predictions.items()):
            chosen = {str(a + 1): select_prediction(pred, np.asarray(g)[:, :3])[0] for a, g in self.gt[frame].items()}
            frames.append({"frame": frame, "chosen_for_actor": chosen, "poses": [_points(pose) for pose in pred]})
        doc = {
            "joints": [*SHELF14_NAMES, "mid_hip"],
            "units": "m",
            "note": "our COCO-23 poses as scored by the Shelf protocol; null = missing joint; "
            "chosen_for_actor: the pose each GT actor (1-4) took, -1 none",
            "frames": frames,
        }
        path = Path(out_dir) / self.predictions_file
        atomic_write_text(path, json.dumps(doc))
        return path


def _points(pose: np.ndarray) -> list[list[float] | None]:
    """A pose's joints for JSON: (K, 3) -> K [x, y, z] rounded to 0.1 mm, or None where missing."""
    pose = np.asarray(pose, dtype=np.float64)[:, :3]
    finite = np.isfinite(pose).all(axis=1).tolist()
    return [xyz if ok else None for xyz, ok in zip(np.round(pose, 4).tolist(), finite)]


def _headline(summary: dict) -> str:
    """One line: strict and lenient average PCP of ours vs 4D Association."""
    parts = []
    for protocol in PROTOCOL_NOTES:
        ours = summary["ours"][protocol]["average"]["average"]
        base = summary.get("4d_association", {}).get(protocol, {}).get("average", {}).get("average")
        parts.append(f"{protocol} {ours:.2f}" + ("" if base is None else f" (4D Association {base:.2f})"))
    return "Shelf average PCP, actors 1-3: " + "; ".join(parts)


def load_actors_gt(mat_path: str | Path, frames: range = SHELF_TEST_FRAMES) -> list[dict[int, np.ndarray]]:
    """TUM actorsGT.mat -> per frame {actor id 0..3: (15, 4)}, mid-hip appended; row f = Shelf frame f."""
    actors = scipy.io.loadmat(str(mat_path))["actor3D"].ravel()
    out = []
    for f in frames:
        persons = {}
        for actor, track in enumerate(actors):
            pose = np.asarray(track.ravel()[f], dtype=np.float64)
            if pose.size:
                persons[actor] = np.concatenate([with_mid_hip(pose.reshape(14, 3)), np.ones((15, 1))], axis=1)
        out.append(persons)
    return out


def main(argv: list[str] | None = None) -> None:
    """CLI: ``python -m evaluation.protocols.shelf --skel skel.txt --gt gt.txt`` prints the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skel", required=True, help="4D Association SKEL19 output (skel.txt layout)")
    parser.add_argument("--gt", required=True, help="ground truth in the gt.txt layout (Shelf-14 + mid-hip)")
    parser.add_argument("--first-frame", type=int, default=300, help="Shelf frame of the files' frame 0")
    parser.add_argument("--name", default="4D Association (stored skel.txt)")
    args = parser.parse_args(argv)
    try:
        summary = score_4dassoc_output(args.skel, args.gt, args.first_frame)
    except ValueError as err:
        parser.exit(2, f"error: {err}\n")
    print(format_table(summary, args.name))


if __name__ == "__main__":
    main()
