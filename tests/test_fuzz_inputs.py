"""Seeded fuzzer of dataset=files inputs (issue 12): mutated cameras.json + poses2d.json pairs.

Every case starts from examples/own_rig/, applies one mutation class and goes through what eval.py
does with dataset=files: load_files (calibration, 2D poses, rig check), clean_frames, the default matcher and
reconstruction on the first frame with detections, and write_poses3d. A case fails on any exception
other than the one-line input errors, on an input error of more than one line, and on silent
acceptance of a class that is invalid. Expectations per class:

- "error": must stop with CalibrationError / Poses2DError;
- "flag": must stop or warn (RigWarning): the input loads but its result would be wrong;
- "ok": valid but odd input, must run (warnings allowed) and give finite 3D poses.

Add a class to CLASSES (name, expectation, mutation) when a format grows; SEEDS_PER_CLASS seeds each.
"""

from __future__ import annotations

import copy
import json
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from data.datasets.files import load_files
from data.formats.poses2d_io import Poses2DError
from data.formats.poses_io import write_poses3d
from data.frame_inputs import clean_frames
from data.geometry.calibration import CalibrationError
from data.geometry.check_rig import RigWarning
from reconstruction.pipeline import MultiViewPipeline

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_rig"
BASE_CAMERAS: dict = json.loads((EXAMPLE / "cameras.json").read_text())
BASE_ENTRIES: list = json.loads((EXAMPLE / "poses2d.json").read_text())
INPUT_ERRORS = (CalibrationError, Poses2DError)
SEEDS_PER_CLASS = 8
BAD_VALUES = ("12", "", True, False, None, {"x": 1}, [])

Case = tuple[Any, Any]  # (cameras document or raw text, poses2d document or raw text)
Mutation = Callable[[np.random.Generator, dict, list], Case]


def pick(rng: np.random.Generator, items: list) -> Any:
    """One item of a list."""
    return items[int(rng.integers(len(items)))]


def leaf_paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Index paths of the number leaves of nested lists."""
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in leaf_paths(v, prefix + (i,))]
    return [prefix]


def set_leaf(value: list, path: tuple, new: Any) -> None:
    """value[path[0]][path[1]]... = new."""
    for i in path[:-1]:
        value = value[i]
    value[path[-1]] = new


def camera_leaf(rng: np.random.Generator, cams: dict, keys: tuple = ("K", "dist", "R", "t", "size")) -> tuple:
    """(camera name, key, leaf path) of a random number in cameras.json."""
    name, key = pick(rng, list(cams)), pick(rng, list(keys))
    return name, key, pick(rng, leaf_paths(cams[name][key]))


def kp(entry: dict) -> np.ndarray:
    """An entry's keypoints as (23, 3)."""
    return np.array(entry["keypoints"], dtype=np.float64).reshape(23, 3)


def scored_joint(rng: np.random.Generator, entry: dict) -> int:
    """A keypoint index with score > 0."""
    return int(pick(rng, list(np.flatnonzero(kp(entry)[:, 2] > 0))))


# --- calibration mutations ---------------------------------------------------------------------------
def cam_missing_key(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    del cams[name][pick(rng, ["K", "dist", "R", "t", "size"])]
    return cams, poses


def cam_wrong_type(rng, cams, poses) -> Case:
    name, key, path = camera_leaf(rng, cams)
    set_leaf(cams[name][key], path, pick(rng, list(BAD_VALUES)))
    if rng.random() < 0.25:
        cams[name][key] = pick(rng, ["matrix", 3, None, True])
    return cams, poses


def cam_non_finite(rng, cams, poses) -> Case:
    name, key, path = camera_leaf(rng, cams)
    set_leaf(cams[name][key], path, pick(rng, [float("nan"), float("inf"), -float("inf")]))
    return cams, poses


def cam_wrong_shape(rng, cams, poses) -> Case:
    name, key = pick(rng, list(cams)), pick(rng, ["K", "dist", "R", "t", "size"])
    flat = np.ravel(cams[name][key]).tolist()
    cams[name][key] = flat[:-1] if rng.random() < 0.5 else flat + [0.0]
    return cams, poses


def cam_not_rotation(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    R = np.array(cams[name]["R"])
    cams[name]["R"] = pick(
        rng,
        [
            (R * 1.5).tolist(),
            (-R).tolist(),
            (R @ np.diag([1, 1, -1])).tolist(),
            (R + 0.2 * rng.standard_normal((3, 3))).tolist(),
        ],
    )
    return cams, poses


def cam_bad_intrinsics(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    K = np.array(cams[name]["K"])
    choice = int(rng.integers(3))
    if choice == 0:
        K[0, 0] = -K[0, 0]
    elif choice == 1:
        K = K.T
    else:
        K[1, 1] = 0.0
    cams[name]["K"] = K.tolist()
    return cams, poses


def cam_bad_size(rng, cams, poses) -> Case:
    cams[pick(rng, list(cams))]["size"] = pick(
        rng, [[10, 10], [1e308, 720], [0, 720], [-1280, 720], [1280.5, 720], [1e6, 1e6]]
    )
    return cams, poses


def cam_huge_t(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    cams[name]["t"][int(rng.integers(3))] = float(pick(rng, [1e300, -1e300, 1e15]))
    return cams, poses


def cam_transposed_r(rng, cams, poses) -> Case:
    name = pick(rng, ["cam_a", "cam_c"])  # cam_b's R is symmetric: transposing it changes nothing
    cams[name]["R"] = np.array(cams[name]["R"]).T.tolist()
    return cams, poses


def cam_millimetres(rng, cams, poses) -> Case:
    names = list(cams) if rng.random() < 0.5 else [pick(rng, list(cams))]
    for name in names:
        cams[name]["t"] = (np.array(cams[name]["t"]) * 1000.0).tolist()
    return cams, poses


def cam_key_twice(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    text = json.dumps(cams)
    if rng.random() < 0.5:
        return text[:-1] + f', "{name}": ' + json.dumps(cams[name]) + "}", poses
    return text.replace('"t": ', '"t": [0, 0, 1], "t": ', 1), poses


def cam_all_identical(rng, cams, poses) -> Case:
    first = pick(rng, list(cams))
    return {name: copy.deepcopy(cams[first]) for name in cams}, poses


def cam_one_copied(rng, cams, poses) -> Case:
    a, b = rng.choice(list(cams), 2, replace=False)
    cams[str(b)] = copy.deepcopy(cams[str(a)])
    return cams, poses


def cam_empty_or_not_object(rng, cams, poses) -> Case:
    return pick(rng, [{}, [], list(cams.values()), "cameras", {"cam_a": [1, 2, 3]}, 3]), poses


def cam_renamed(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    cams[name + "_renamed"] = cams.pop(name)
    return cams, poses


def cam_below_ground(rng, cams, poses) -> Case:
    name = pick(rng, list(cams))
    R = np.array(cams[name]["R"])
    centre = -R.T @ np.array(cams[name]["t"])
    centre[2] = -centre[2] * rng.uniform(0.5, 2.0)
    cams[name]["t"] = (-R @ centre).tolist()
    return cams, poses


def cam_small_distortion(rng, cams, poses) -> Case:  # valid: a little distortion, poses still fit
    cams[pick(rng, list(cams))]["dist"] = (rng.uniform(-1e-3, 1e-3, 5) * np.array([1, 1, 0.1, 0.1, 0.1])).tolist()
    return cams, poses


def cam_extra_camera(rng, cams, poses) -> Case:  # valid: a camera without any detection
    src = cams[pick(rng, list(cams))]
    extra = copy.deepcopy(src)
    R = np.array(src["R"])
    centre = -R.T @ np.array(src["t"]) + np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 0.0])
    extra["t"] = (-R @ centre).tolist()
    cams["cam_extra"] = extra
    return cams, poses


def cam_integer_values(rng, cams, poses) -> Case:  # valid: integers where floats are usual
    name = pick(rng, list(cams))
    cams[name]["K"] = np.round(cams[name]["K"]).astype(int).tolist()
    cams[name]["dist"] = [0, 0, 0, 0, 0]
    return cams, poses


# --- poses2d mutations ----------------------------------------------------------------------------------
def p_missing_key(rng, cams, poses) -> Case:
    del pick(rng, poses)[pick(rng, ["frame", "camera", "bbox", "score", "keypoints"])]
    return cams, poses


def p_wrong_type(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    key = pick(rng, ["frame", "camera", "score", "bbox", "keypoints", "id"])
    bad = pick(rng, [v for v in BAD_VALUES if key != "camera" or not isinstance(v, str)] + [1.5])
    if key in ("bbox", "keypoints") and rng.random() < 0.7:
        entry[key][int(rng.integers(len(entry[key])))] = pick(rng, list(BAD_VALUES))
    elif key == "frame" and isinstance(bad, float):
        entry[key] = 100.0
    else:
        entry[key] = bad if not (key == "id" and bad is None) else "7"
    return cams, poses


def p_non_finite(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    value = pick(rng, [float("nan"), float("inf"), -float("inf")])
    key = pick(rng, ["score", "bbox", "keypoints"])
    if key == "score":
        entry[key] = value
    else:
        entry[key][int(rng.integers(len(entry[key])))] = value
    return cams, poses


def p_huge_numbers(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    choice = int(rng.integers(5))
    if choice == 0:
        entry["frame"] = 2**70
    elif choice == 1:
        entry["id"] = -(2**70)
    elif choice == 2:
        entry["score"] = 1e200
    elif choice == 3:
        entry["keypoints"][3 * scored_joint(rng, entry) + int(rng.integers(2))] = pick(rng, [1e15, -1e15, 1e300])
    else:
        entry["keypoints"][3 * scored_joint(rng, entry) + 2] = 10**400
    return cams, poses


def p_negative_numbers(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    choice = int(rng.integers(3))
    if choice == 0:
        entry["score"] = -0.5
    elif choice == 1:
        entry["keypoints"][3 * scored_joint(rng, entry) + 2] = -1.0
    else:
        entry["bbox"][2] = -abs(entry["bbox"][2]) - 1
    return cams, poses


def p_duplicate_entry(rng, cams, poses) -> Case:
    poses.insert(int(rng.integers(len(poses) + 1)), copy.deepcopy(pick(rng, poses)))
    return cams, poses


def p_scores_times_100(rng, cams, poses) -> Case:
    for entry in poses if rng.random() < 0.5 else [pick(rng, poses)]:
        k = kp(entry)
        k[:, 2] *= 100.0
        entry["keypoints"] = k.ravel().tolist()
    return cams, poses


def p_far_outside_image(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    w, h = BASE_CAMERAS[entry["camera"]]["size"]
    j = scored_joint(rng, entry)
    entry["keypoints"][3 * j] = pick(rng, [-2.5 * w, 3.5 * w, 1e9])
    return cams, poses


def p_empty_or_not_list(rng, cams, poses) -> Case:
    return cams, pick(rng, [[], {}, {"frames": poses}, "poses", 7, [[]], [None]])


def p_unknown_camera(rng, cams, poses) -> Case:
    pick(rng, poses)["camera"] = pick(rng, ["cam_z", "CAM_A", "0", 0, ""])
    return cams, poses


def p_wrong_keypoint_count(rng, cams, poses) -> Case:
    entry = pick(rng, poses)
    n = pick(rng, [0, 51, 66, 68, 70, 72, 75])
    entry["keypoints"] = (entry["keypoints"] * 2)[:n]
    return cams, poses


def p_key_twice(rng, cams, poses) -> Case:
    return cams, json.dumps(poses).replace('"score": ', '"score": 0.5, "score": ', int(rng.integers(1, 4)))


def p_cameras_swapped(rng, cams, poses) -> Case:
    a, b = (str(c) for c in rng.choice(list(cams), 2, replace=False))
    for entry in poses:
        entry["camera"] = {a: b, b: a}.get(entry["camera"], entry["camera"])
    return cams, poses


def p_missing_joints(rng, cams, poses) -> Case:  # valid: joints missing (score 0), some at odd coordinates
    for entry in poses:
        k = kp(entry)
        drop = rng.random(23) < 0.3
        k[drop, 2] = 0.0
        k[drop & (rng.random(23) < 0.5), :2] = rng.choice([0.0, -1e6, 1e12])
        entry["keypoints"] = k.ravel().tolist()
    return cams, poses


def p_no_feet(rng, cams, poses) -> Case:  # valid: COCO-17 detections (feet score 0), maybe no ankles either
    last = 17 if rng.random() < 0.5 else 15
    for entry in poses:
        k = kp(entry)
        k[last:, :] = 0.0
        entry["keypoints"] = k.ravel().tolist()
    return cams, poses


def p_drop_view(rng, cams, poses) -> Case:  # valid: a camera without detections
    camera = pick(rng, list(cams))
    return cams, [e for e in poses if e["camera"] != camera]


def p_few_entries(rng, cams, poses) -> Case:  # valid: one or two detections only (frame skipped)
    return cams, [copy.deepcopy(e) for e in rng.choice(poses, int(rng.integers(1, 3)), replace=False)]


def p_shuffled_extra_keys(rng, cams, poses) -> Case:  # valid: any order, unknown keys ignored, int ids
    order = rng.permutation(len(poses))
    out = [copy.deepcopy(poses[i]) for i in order]
    for i, entry in enumerate(out):
        entry["comment"] = "from detector X"
        entry["id"] = i
    return cams, out


def p_noise_and_integers(rng, cams, poses) -> Case:  # valid: 2 px noise, integer pixels, scores up to 1.04
    for entry in poses:
        k = kp(entry)
        k[:, :2] = np.round(k[:, :2] + rng.normal(0, 2.0, (23, 2)))
        k[:, 2] = np.where(k[:, 2] > 0, np.minimum(k[:, 2] + 0.1, 1.04), 0.0)
        entry["keypoints"] = [int(v) if i % 3 != 2 else float(v) for i, v in enumerate(k.ravel())]
    return cams, poses


def p_slightly_outside_image(rng, cams, poses) -> Case:  # valid: joints guessed just outside the image
    entry = pick(rng, poses)
    w, _ = BASE_CAMERAS[entry["camera"]]["size"]
    entry["keypoints"][3 * scored_joint(rng, entry)] = pick(rng, [-0.5 * w, 1.6 * w])
    return cams, poses


def p_big_frame_numbers(rng, cams, poses) -> Case:  # valid: frame numbers near the int64 limit
    offset = 2**62
    for entry in poses:
        entry["frame"] += offset
    return cams, poses


def p_all_zero_detection(rng, cams, poses) -> Case:  # valid: a detection without any joint
    entry = copy.deepcopy(pick(rng, poses))
    entry["keypoints"] = [0.0] * 69
    entry["bbox"], entry["score"] = [0.0, 0.0, 0.0, 0.0], 0.0
    poses.append(entry)
    return cams, poses


CLASSES: list[tuple[str, str, Mutation]] = [
    ("cam_missing_key", "error", cam_missing_key),
    ("cam_wrong_type", "error", cam_wrong_type),
    ("cam_non_finite", "error", cam_non_finite),
    ("cam_wrong_shape", "error", cam_wrong_shape),
    ("cam_not_rotation", "error", cam_not_rotation),
    ("cam_bad_intrinsics", "error", cam_bad_intrinsics),
    ("cam_bad_size", "error", cam_bad_size),
    ("cam_huge_t", "flag", cam_huge_t),
    ("cam_transposed_r", "flag", cam_transposed_r),
    ("cam_millimetres", "flag", cam_millimetres),
    ("cam_key_twice", "error", cam_key_twice),
    ("cam_all_identical", "error", cam_all_identical),
    ("cam_one_copied", "flag", cam_one_copied),
    ("cam_empty_or_not_object", "error", cam_empty_or_not_object),
    ("cam_renamed", "error", cam_renamed),
    ("cam_below_ground", "flag", cam_below_ground),
    ("cam_small_distortion", "ok", cam_small_distortion),
    ("cam_extra_camera", "ok", cam_extra_camera),
    ("cam_integer_values", "ok", cam_integer_values),
    ("p_missing_key", "error", p_missing_key),
    ("p_wrong_type", "error", p_wrong_type),
    ("p_non_finite", "error", p_non_finite),
    ("p_huge_numbers", "error", p_huge_numbers),
    ("p_negative_numbers", "error", p_negative_numbers),
    ("p_duplicate_entry", "ok", p_duplicate_entry),  # dropped before matching (data/frame_inputs.py), counted
    ("p_scores_times_100", "error", p_scores_times_100),
    ("p_far_outside_image", "error", p_far_outside_image),
    ("p_empty_or_not_list", "error", p_empty_or_not_list),
    ("p_unknown_camera", "error", p_unknown_camera),
    ("p_wrong_keypoint_count", "error", p_wrong_keypoint_count),
    ("p_key_twice", "error", p_key_twice),
    # Two cameras' labels swapped: on this symmetric ring the rig check warns that exchanging some two cameras'
    # poses fits, but cannot tell which two (a rotated labelling fits as well). Must run, not crash.
    ("p_cameras_swapped", "ok", p_cameras_swapped),
    ("p_missing_joints", "ok", p_missing_joints),
    ("p_no_feet", "ok", p_no_feet),
    ("p_drop_view", "ok", p_drop_view),
    ("p_few_entries", "ok", p_few_entries),
    ("p_shuffled_extra_keys", "ok", p_shuffled_extra_keys),
    ("p_noise_and_integers", "ok", p_noise_and_integers),
    ("p_slightly_outside_image", "ok", p_slightly_outside_image),
    ("p_big_frame_numbers", "ok", p_big_frame_numbers),
    ("p_all_zero_detection", "ok", p_all_zero_detection),
]
CASES = [(name, seed) for name, _, _ in CLASSES for seed in range(SEEDS_PER_CLASS)]


@pytest.fixture(scope="module")
def eval_cfg():
    """eval.py's default configuration (the matcher and reconstruction every dataset gets)."""
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        return compose(config_name="eval", overrides=["dataset=files", "dataset.cameras=x", "dataset.poses2d=y"])


def dump(doc: Any) -> str:
    """A document as JSON text (NaN / Infinity literals allowed, as Python writes them); text as is."""
    return doc if isinstance(doc, str) else json.dumps(doc)


def run_like_eval(cfg, cameras: Path, poses2d: Path, out: Path) -> np.ndarray:
    """load_files + clean_frames + the default pipeline on the first frame with detections + write_poses3d -> (P, 23, 4)."""
    seq, _ = clean_frames(load_files(cameras, poses2d), 2000, 0.01)
    pipeline = MultiViewPipeline(seq.rig, instantiate(cfg.matching), instantiate(cfg.reconstruction))
    frame = next((f for f in seq.frames if any(len(v) for v in f.views)), seq.frames[0])
    result = pipeline(frame)
    write_poses3d(out, [(result.frame, result.poses3d, result.assignment)], seq.rig.names)
    return result.poses3d


def test_class_list_covers_every_expectation_and_at_least_300_cases():
    assert {e for _, e, _ in CLASSES} == {"error", "flag", "ok"} and len(CASES) >= 300


@pytest.mark.parametrize("name,seed", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_fuzzed_input_stops_with_one_line_or_runs(name, seed, tmp_path, eval_cfg):
    expected, mutate = next((e, m) for n, e, m in CLASSES if n == name)
    rng = np.random.default_rng([seed, CASES.index((name, seed))])
    cams, poses = mutate(rng, copy.deepcopy(BASE_CAMERAS), copy.deepcopy(BASE_ENTRIES))
    cameras, poses2d = tmp_path / "cameras.json", tmp_path / "poses2d.json"
    cameras.write_text(dump(cams))
    poses2d.write_text(dump(poses))
    error = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            poses3d = run_like_eval(eval_cfg, cameras, poses2d, tmp_path / "poses3d.json")
        except INPUT_ERRORS as err:
            error = str(err)
    flagged = [str(w.message) for w in caught if issubclass(w.category, RigWarning)]
    if error is not None:
        assert "\n" not in error and (str(cameras) in error or str(poses2d) in error), error
        assert expected != "ok", f"{name}/{seed}: valid input rejected: {error}"
        return
    assert all("\n" not in w for w in flagged)
    assert expected != "error", f"{name}/{seed}: invalid input accepted silently (warnings: {flagged})"
    if expected == "flag":
        assert flagged, f"{name}/{seed}: wrong calibration accepted without a warning"
    else:
        assert np.isfinite(poses3d).all()
