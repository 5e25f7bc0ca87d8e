"""Issue 12: no bad input gives a silent wrong answer, and every bad input stops with one line.

One test (at least) per class of mistake in cameras.json, poses2d.json and the rig they describe.
"""

from __future__ import annotations

import copy
import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from data.datasets.files import load_files
from data.formats.poses2d_io import OUTSIDE_IMAGE_TOLERANCE, Poses2DError, read_poses2d
from data.geometry.calibration import CalibrationError, load_panoptic, load_rig
from data.geometry.camera import Camera, Rig
from data.geometry.check_rig import RigError, RigWarning, pose_findings, rig_findings
from data.geometry.check_rig import main as check_rig_main
from data.geometry.triangulation import triangulate_dlt
from reconstruction.matching.feet import feet_features
from reconstruction.matching.feet_uncertainty import image_to_plane_homography, joints_on_planes

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_rig"
CAMERAS = json.loads((EXAMPLE / "cameras.json").read_text())
ENTRIES = json.loads((EXAMPLE / "poses2d.json").read_text())


def write(tmp_path: Path, name: str, doc: object) -> Path:
    """doc as JSON in tmp_path/name."""
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def cameras(**changes: dict) -> dict:
    """A copy of the example's cameras.json with camera -> {key: value} changes."""
    doc = copy.deepcopy(CAMERAS)
    for cam, keys in changes.items():
        doc[cam].update(keys)
    return doc


def entries(i: int | None = None, **changes: object) -> list:
    """A copy of the example's poses2d.json entries with entry i's keys changed."""
    doc = copy.deepcopy(ENTRIES)
    if i is not None:
        doc[i].update(changes)
    return doc


def no_rig_warning(fn, *args, **kwargs):
    """fn(*args, **kwargs), failing on any RigWarning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RigWarning)
        return fn(*args, **kwargs)


def centre_to_t(R: list, centre: np.ndarray) -> list:
    """t (3,) of a camera with rotation R (3, 3) and centre (3,)."""
    return (-np.asarray(R) @ centre).tolist()


# --- cameras.json ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "key,value,what",
    [
        ("K", [[1000, 0, "640"], [0, 1000, 360], [0, 0, 1]], "'640' (str)"),
        ("t", [0.0, True, 6.6], "True (bool)"),
        ("dist", [0, 0, 0, None, 0], "None (NoneType)"),
    ],
)
def test_strings_booleans_and_null_where_numbers_belong_are_named(tmp_path, key, value, what):
    path = write(tmp_path, "cameras.json", cameras(cam_b={key: value}))
    with pytest.raises(
        CalibrationError, match=re.escape(f"camera 'cam_b': key '{key}' is not an array of numbers: {what}")
    ):
        load_rig(path)


def test_a_camera_given_twice_in_the_json_is_an_error(tmp_path):
    text = json.dumps(CAMERAS)
    cam_a = json.dumps(CAMERAS["cam_a"])
    path = write(tmp_path, "cameras.json", text[:-1] + ', "cam_a": ' + cam_a + "}")
    with pytest.raises(CalibrationError, match="key 'cam_a' appears twice"):
        load_rig(path)


@pytest.mark.parametrize("size", [[10, 10], [1e308, 720], [1280, 0]])
def test_implausible_image_size_is_an_error_not_a_numpy_crash(tmp_path, size):
    path = write(tmp_path, "cameras.json", cameras(cam_c={"size": size}))
    with pytest.raises(CalibrationError, match=r"camera 'cam_c': key 'size' is not a"):
        load_rig(path)


@pytest.mark.parametrize("drop,found", [("t", "T"), ("K", None), ("R", None)])
def test_a_missing_key_in_the_first_camera_is_named_not_an_unknown_format(tmp_path, drop, found):
    doc = cameras()
    value = doc["cam_a"].pop(drop)
    if found:
        doc["cam_a"][found] = value
    path = write(tmp_path, "cameras.json", {"cam_a": doc["cam_a"]})  # one camera: nothing else to go by
    hint = f" (found '{found}': keys are case-sensitive)" if found else ""
    with pytest.raises(CalibrationError, match=re.escape(f"camera 'cam_a': key '{drop}' is missing{hint}")):
        load_rig(path)


def test_real_calibrations_load_without_a_warning(shared_data):
    for path in ("shelf/4d_association/calibration.json", "shelf/calibration_shelf.json", "wildtrack"):
        no_rig_warning(load_rig, shared_data / path)
    for path in sorted(shared_data.glob("panoptic*/*/calibration_*.json")):
        assert no_rig_warning(rig_findings, load_panoptic(path)) == []
    no_rig_warning(load_files, EXAMPLE / "cameras.json", EXAMPLE / "poses2d.json")


# --- the rig check ------------------------------------------------------------------------------------
def test_all_cameras_at_one_place_is_an_error(tmp_path):
    doc = cameras(
        cam_b={"t": CAMERAS["cam_a"]["t"], "R": CAMERAS["cam_a"]["R"]},
        cam_c={"t": CAMERAS["cam_a"]["t"], "R": CAMERAS["cam_a"]["R"]},
    )
    with pytest.raises(RigError, match="all 3 cameras have their centre at .* no baseline"):
        load_rig(write(tmp_path, "cameras.json", doc))


def test_one_camera_copied_under_two_names_is_named(tmp_path):
    doc = cameras(cam_c=CAMERAS["cam_a"])
    with pytest.warns(RigWarning, match="cameras 'cam_a' and 'cam_c' have identical calibrations"):
        load_rig(write(tmp_path, "cameras.json", doc))


def test_t_in_millimetres_is_named(tmp_path):
    doc = cameras(**{c: {"t": (np.array(CAMERAS[c]["t"]) * 1000).tolist()} for c in CAMERAS})
    with pytest.warns(
        RigWarning, match="cameras 'cam_a', 'cam_b', 'cam_c': centre .* m from the world origin .* millimetres"
    ):
        load_rig(write(tmp_path, "cameras.json", doc))


def test_camera_below_the_ground_plane_is_named(tmp_path):
    R = CAMERAS["cam_b"]["R"]
    centre = -np.asarray(R).T @ CAMERAS["cam_b"]["t"] * np.array([1, 1, -1])
    doc = cameras(cam_b={"t": centre_to_t(R, centre)})
    with pytest.warns(RigWarning, match="camera 'cam_b': centre below the ground plane"):
        load_rig(write(tmp_path, "cameras.json", doc))


def test_upside_down_camera_that_misses_the_scene_is_named(tmp_path):
    R = np.diag([-1.0, -1.0, 1.0]) @ np.asarray(CAMERAS["cam_c"]["R"])  # rolled by 180 degrees
    R = np.diag([1.0, -1.0, -1.0]) @ R  # then looking backwards
    centre = -np.asarray(CAMERAS["cam_c"]["R"]).T @ CAMERAS["cam_c"]["t"]
    doc = cameras(cam_c={"R": R.tolist(), "t": centre_to_t(R, centre)})
    with pytest.warns(RigWarning) as record:
        load_rig(write(tmp_path, "cameras.json", doc))
    text = " | ".join(str(w.message) for w in record)
    assert "camera 'cam_c': not looking at the common scene" in text


@pytest.mark.parametrize("camera", ["cam_a", "cam_c"])
def test_transposed_rotation_is_found_by_the_2d_poses(tmp_path, camera):
    doc = cameras(**{camera: {"R": np.asarray(CAMERAS[camera]["R"]).T.tolist()}})
    path = write(tmp_path, "cameras.json", doc)
    with pytest.warns(
        RigWarning, match=f"camera '{camera}': its 2D poses do not fit the other cameras' .*: likely R is transposed"
    ):
        load_files(path, EXAMPLE / "poses2d.json")


def test_one_camera_in_millimetres_is_found_by_the_2d_poses():
    rig = load_rig(EXAMPLE / "cameras.json")
    cams = list(rig)
    cams[1] = Camera(cams[1].name, cams[1].K, cams[1].dist, cams[1].R, cams[1].t * 1000, cams[1].size)
    views = read_poses2d(EXAMPLE / "poses2d.json", rig.names)
    (finding,) = pose_findings(Rig(tuple(cams)), views)
    assert "camera 'cam_b'" in finding.message and "t is in millimetres" in finding.message


def test_check_rig_command_prints_one_line_per_finding(tmp_path, capsys):
    assert check_rig_main([str(EXAMPLE / "cameras.json"), str(EXAMPLE / "poses2d.json")]) == 0
    assert capsys.readouterr().out.strip().endswith("0 errors, 0 warnings")
    doc = cameras(cam_a={"R": np.asarray(CAMERAS["cam_a"]["R"]).T.tolist()})
    path = write(tmp_path, "cameras.json", doc)
    assert check_rig_main([str(path), str(EXAMPLE / "poses2d.json")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"warning: {path}: camera 'cam_a'") and out[-1].endswith("0 errors, 1 warnings")
    same = write(tmp_path, "same.json", cameras(cam_b=CAMERAS["cam_a"], cam_c=CAMERAS["cam_a"]))
    assert check_rig_main([str(same)]) == 1
    assert capsys.readouterr().out.startswith(f"error: {same}: all 3 cameras")


# --- poses2d.json ---------------------------------------------------------------------------------------
def read(tmp_path: Path, doc: object):
    """read_poses2d of doc against the example rig, with its image sizes."""
    rig = load_rig(EXAMPLE / "cameras.json")
    return read_poses2d(write(tmp_path, "poses2d.json", doc), rig.names, [c.size for c in rig])


def test_the_same_detection_twice_is_read_not_rejected(tmp_path):
    """Repeats are data/frame_inputs.py's to drop and count (tests/test_frame_inputs.py)."""
    doc = entries()
    doc.append(copy.deepcopy(doc[3]))
    views = read(tmp_path, doc)
    assert sum(len(v) for v in views[100]) == sum(e["frame"] == 100 for e in doc)


@pytest.mark.parametrize("factor,offset", [(100.0, 0.0), (1e200, 0.0), (1.0, -1.0)])
def test_keypoint_scores_outside_0_1_are_rejected_naming_entry_and_joint(tmp_path, factor, offset):
    kps = np.array(ENTRIES[2]["keypoints"]).reshape(23, 3)
    kps[:, 2] = kps[:, 2] * factor + offset
    with pytest.raises(
        Poses2DError,
        match=r"entry 2: frame 100, camera '\w+': keypoint 0 \(nose\) has score "
        r".*outside \[0, 1\]",
    ):
        read(tmp_path, entries(2, keypoints=kps.ravel().tolist()))


def test_detection_score_outside_0_1_is_rejected_and_slightly_above_1_is_clipped(tmp_path):
    with pytest.raises(Poses2DError, match=r"entry 1: .*: score 91.85 is outside \[0, 1\]"):
        read(tmp_path, entries(1, score=91.85))
    kps = np.array(ENTRIES[1]["keypoints"]).reshape(23, 3)
    kps[0, 2] = 1.02  # OpenPose's confidences exceed 1 a little
    views = read(tmp_path, entries(1, keypoints=kps.ravel().tolist(), score=1.01))
    assert max(v.keypoints[..., 2].max() for f in views.values() for v in f) == 1.0


@pytest.mark.parametrize("xy", [(1e15, 300.0), (500.0, -1e6)])
def test_keypoints_far_outside_the_image_are_rejected(tmp_path, xy):
    kps = np.array(ENTRIES[0]["keypoints"]).reshape(23, 3)
    kps[5, :2] = xy
    with pytest.raises(
        Poses2DError,
        match=r"entry 0: .* keypoint 5 \(left_shoulder\) at .* far outside the "
        r"1280x720 image",
    ):
        read(tmp_path, entries(0, keypoints=kps.ravel().tolist()))
    kps[5, :2] = (-0.9 * OUTSIDE_IMAGE_TOLERANCE * 1280, 300.0)  # within the tolerance: a guessed joint
    read(tmp_path, entries(0, keypoints=kps.ravel().tolist()))


def test_an_empty_list_is_an_error(tmp_path):
    with pytest.raises(Poses2DError, match="the list of detections is empty"):
        read(tmp_path, [])


@pytest.mark.parametrize("key", ["frame", "id"])
def test_integers_beyond_64_bits_are_one_line_errors(tmp_path, key):
    with pytest.raises(Poses2DError, match=f"entry 4: {key} 1180591620717411303424 does not fit a 64-bit integer"):
        read(tmp_path, entries(4, **{key: 2**70}))


@pytest.mark.parametrize(
    "key,value,what",
    [
        ("frame", "100", "frame must be an integer, got '100' (str)"),
        ("score", True, "score must be a number, got True (bool)"),
        ("camera", 1.5, "camera must be a camera name"),
        ("bbox", [1, 2, "3", 4], "bbox must be x, y, w, h, got '3' (str)"),
    ],
)
def test_strings_and_booleans_where_numbers_belong_are_named(tmp_path, key, value, what):
    with pytest.raises(Poses2DError, match=re.escape(f"entry 6: {what}")):
        read(tmp_path, entries(6, **{key: value}))


def test_a_key_twice_in_an_entry_is_an_error(tmp_path):
    text = json.dumps(ENTRIES).replace('"score": ', '"score": 0.5, "score": ', 1)
    with pytest.raises(Poses2DError, match="key 'score' appears twice"):
        read(tmp_path, text)


# --- the pipeline on degenerate geometry ---------------------------------------------------------------
def horizontal_camera(height: float) -> Camera:
    """A camera 5 m from the origin looking along +y, its centre at `height` m: an exactly singular plane."""
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    K = np.array([[1000.0, 0, 640], [0, 1000, 360], [0, 0, 1]])
    return Camera("low", K, np.zeros(5), R, -R @ np.array([0.0, -5.0, height]), (1280, 720))


@pytest.mark.parametrize("height", [0.0, 0.07])
def test_camera_centre_on_the_feet_plane_drops_those_joints_instead_of_crashing(height):
    cam = horizontal_camera(height)
    assert image_to_plane_homography(cam, height) is None
    uv = np.array([[[640.0, 500.0], [600.0, 500.0]]])
    xy, depth, cov = joints_on_planes(cam, uv, np.array([height, height + 1.0]), sigma_px=2.0)
    assert np.isnan(xy[0, 0]).all() and np.isfinite(xy[0, 1]).all()
    kps = np.zeros((1, 23, 3))
    kps[0, 15:, :] = (640.0, 500.0, 0.9)  # ankles and feet
    feet = feet_features(kps, cam, pixel_sigma=2.0, ankle_height_m=height, foot_joint_height_m=height)
    assert np.isfinite(feet.p).all()


def test_triangulation_ignores_non_finite_and_survives_huge_scores():
    rig = load_rig(EXAMPLE / "cameras.json")
    views = read_poses2d(EXAMPLE / "poses2d.json", rig.names)
    poses = np.stack([views[100][v].keypoints[:1] for v in range(3)])  # (3, 1, 23, 3), the same person? any
    proj = rig.projection_matrices()
    huge = poses.copy()
    huge[..., 2] *= 1e200
    assert np.allclose(triangulate_dlt(huge, proj)[..., :3], triangulate_dlt(poses, proj)[..., :3])
    bad = poses.copy()
    bad[0, 0, :5, 2] = np.inf
    bad[1, 0, 5:8, 0] = np.nan
    bad[2, 0, 8, :2] = 1e300
    out = triangulate_dlt(bad, proj)
    assert np.isfinite(out).all()


# --- eval.py -------------------------------------------------------------------------------------------
def test_eval_files_without_paths_stops_with_one_line(tmp_path):
    cmd = [sys.executable, "eval.py", "dataset=files", "progress=false", f"hydra.run.dir={tmp_path}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.strip() == (
        "error: dataset.cameras is not set: give it on the command line (dataset.cameras=...; see configs/dataset/)"
    )


def test_eval_prints_rig_warnings_in_one_line_each(tmp_path):
    doc = cameras(cam_c={"R": np.asarray(CAMERAS["cam_c"]["R"]).T.tolist()})
    path = write(tmp_path, "cameras.json", doc)
    cmd = [
        sys.executable,
        "eval.py",
        "dataset=files",
        f"dataset.cameras={path}",
        f"dataset.poses2d={EXAMPLE / 'poses2d.json'}",
        "progress=false",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and all(ln.startswith(f"warning: {path}: camera 'cam_c'") for ln in lines)
