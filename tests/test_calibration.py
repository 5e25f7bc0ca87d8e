"""Calibration loaders: the real files of every dataset agree with each other and with raw OpenCV."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from data.formats.fourd_skeletons import load_4dassoc_skeletons
from data.geometry.calibration import (
    CalibrationError,
    decompose_projection,
    detect_format,
    load_4dassoc,
    load_cameras_json,
    load_panoptic,
    load_rig,
    load_shelf_projections,
    load_voxelpose,
    load_wildtrack,
    load_wildtrack_positions,
    panoptic_world_to_ours,
    save_cameras_json,
)
from data.geometry.camera import Camera, Rig

PANOPTIC_SEQ = "panoptic/160906_band1"
PANOPTIC_CAMERAS = ["00_00", "00_03", "00_12", "00_16", "00_30"]


def _shelf_rigs(root: Path) -> tuple[Rig, Rig, Rig]:
    """The Shelf rig from the 4D Association, VoxelPose and original P-matrix files."""
    return (
        load_4dassoc(root / "shelf/4d_association/calibration.json"),
        load_voxelpose(root / "shelf/calibration_shelf.json", image_size=(1032, 776)),
        load_shelf_projections(root / "shelf/tum/Calibration"),
    )


def _shelf_gt_joints(root: Path) -> np.ndarray:
    """Every valid ground-truth joint of the 301 Shelf frames: (N, 3) metres."""
    frames = load_4dassoc_skeletons(root / "shelf/4d_association/gt.txt")
    assert len(frames) == 301 and all(p.shape == (15, 4) for f in frames for p in f.values())
    return np.concatenate([p[p[:, 3] > 0, :3] for f in frames for p in f.values()])


def _panoptic_bodies(root: Path) -> np.ndarray:
    """All Panoptic ground-truth joints of both sample sequences, raw: (N, 19, 4) cm, y down."""
    files = sorted(root.glob("panoptic/*/hdPose3d_stage1_coco19/body3DScene_*.json"))
    assert files
    return np.array([np.reshape(b["joints19"], (19, 4)) for f in files for b in json.loads(f.read_text())["bodies"]])


def _wildtrack_ground(root: Path) -> np.ndarray:
    """Every Wildtrack ground-truth position of all 400 frames: (N, 2) metres."""
    positions = load_wildtrack_positions(root / "wildtrack/gt_positions_mvdet.txt")
    assert len(positions) == 400 and list(positions)[:2] == [0, 5]
    return np.concatenate(list(positions.values()))


# --- Shelf ----------------------------------------------------------------------------------------
def test_shelf_three_calibrations_project_alike(shared_data: Path) -> None:
    assoc, voxel, proj = _shelf_rigs(shared_data)
    assert assoc.names == voxel.names == proj.names == ["0", "1", "2", "3", "4"]
    joints = _shelf_gt_joints(shared_data)
    assert len(joints) > 300
    for a, v, p in zip(assoc, voxel, proj):
        assert a.size == v.size == p.size == (1032, 776)
        np.testing.assert_allclose(v.center, a.center, atol=1e-3)  # same world axes, mm -> m right
        np.testing.assert_allclose(p.center, a.center, atol=1e-3)
        assert np.all(a.depth(joints) > 0)
        uv = a.project(joints)
        assert np.max(np.linalg.norm(v.project(joints) - uv, axis=-1)) < 0.5
        assert np.max(np.linalg.norm(p.project(joints) - uv, axis=-1)) < 0.5


def test_shelf_world_is_z_up_with_floor_at_zero(shared_data: Path) -> None:
    frames = load_4dassoc_skeletons(shared_data / "shelf/4d_association/gt.txt")
    poses = np.stack([p for f in frames for p in f.values() if np.all(p[:, 3] > 0)])
    ankles, head_top = poses[:, [0, 5], 2], poses[:, 13, 2]
    assert np.all(np.abs(ankles) < 0.2) and np.all(head_top > 1.3)


def test_decompose_projection_recovers_negative_scaled_matrix() -> None:
    K = np.array([[900.0, 0.5, 400.0], [0.0, 950.0, 300.0], [0.0, 0.0, 1.0]])
    R = cv2.Rodrigues(np.array([0.3, -1.2, 0.7]))[0]
    t = np.array([0.2, -0.4, 3.0])
    K2, R2, t2 = decompose_projection(-2.5 * K @ np.column_stack([R, t]))
    np.testing.assert_allclose(K2, K, atol=1e-8)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-10)


# --- Panoptic -------------------------------------------------------------------------------------
def test_panoptic_projects_like_raw_opencv(shared_data: Path) -> None:
    path = shared_data / PANOPTIC_SEQ / "calibration_160906_band1.json"
    raw = {c["name"]: c for c in json.loads(path.read_text())["cameras"]}
    rig = load_panoptic(path, cameras=PANOPTIC_CAMERAS)
    assert rig.names == PANOPTIC_CAMERAS
    joints_cm = _panoptic_bodies(shared_data).reshape(-1, 4)
    joints_cm = joints_cm[joints_cm[:, 3] > 0, :3]
    ours = panoptic_world_to_ours(joints_cm)
    for cam in rig:
        c = raw[cam.name]
        assert np.linalg.det(cam.R) == pytest.approx(1.0)
        R, t, K, dist = (np.array(c[key], dtype=np.float64) for key in ("R", "t", "K", "distCoef"))
        expected, _ = cv2.projectPoints(joints_cm, R, t, K, dist)  # raw cm points and raw parameters
        np.testing.assert_allclose(cam.project(ours), expected[:, 0], atol=1e-6, rtol=0)
        assert cam.size == tuple(c["resolution"])


def test_panoptic_default_is_hd_and_world_is_z_up(shared_data: Path) -> None:
    rig = load_panoptic(shared_data / PANOPTIC_SEQ / "calibration_160906_band1.json")
    assert len(rig) == 31 and rig.names[0] == "00_00" and all(c.size == (1920, 1080) for c in rig)
    assert all(c.center[2] > 0.5 for c in rig)  # the dome's cameras look down from above the floor
    bodies = _panoptic_bodies(shared_data)
    z = panoptic_world_to_ours(bodies[..., :3])[..., 2]
    valid = bodies[..., 3] > 0
    ankles = z[:, [8, 14]][valid[:, [8, 14]]]
    assert np.all((ankles > 0.0) & (ankles < 0.25))  # ankle joints a few cm above the floor z = 0
    assert np.all(z[valid] > -0.05)
    assert np.all(z[:, 0][valid[:, 0]] > 0.8)  # necks of the (seated) band players


# --- Wildtrack ------------------------------------------------------------------------------------
def test_wildtrack_every_position_seen_by_a_camera(shared_data: Path) -> None:
    rig = load_wildtrack(shared_data / "wildtrack")
    assert rig.names == ["CVLab1", "CVLab2", "CVLab3", "CVLab4", "IDIAP1", "IDIAP2", "IDIAP3"]
    assert all(c.has_distortion and c.size == (1920, 1080) for c in rig)
    ground = _wildtrack_ground(shared_data)
    feet = np.column_stack([ground, np.zeros(len(ground))])
    seen = np.stack([c.in_view(feet) for c in rig])
    assert np.all(seen.any(axis=0)), f"{np.sum(~seen.any(axis=0))} positions seen by no camera"


def test_wildtrack_world_is_z_up(shared_data: Path) -> None:
    rig = load_wildtrack(shared_data / "wildtrack")
    ground = _wildtrack_ground(shared_data)
    feet = np.column_stack([ground, np.zeros(len(ground))])
    heads = np.column_stack([ground, np.full(len(ground), 1.7)])
    for cam in rig:
        assert 1.0 < cam.center[2] < 5.0
        both = cam.in_view(feet) & cam.in_view(heads)
        assert both.sum() > 100
        assert np.all(cam.project(heads[both])[:, 1] < cam.project(feet[both])[:, 1])


# --- cameras.json and ground-plane homographies ---------------------------------------------------
def test_cameras_json_round_trip_is_exact(shared_data: Path, tmp_path: Path) -> None:
    rig = Rig(
        load_wildtrack(shared_data / "wildtrack").cameras[:3]
        + load_panoptic(shared_data / PANOPTIC_SEQ / "calibration_160906_band1.json", ["00_07"]).cameras
    )
    path = tmp_path / "cameras.json"
    save_cameras_json(rig, path)
    save_cameras_json(rig, path)  # overwriting works too
    assert [p.name for p in tmp_path.iterdir()] == ["cameras.json"]  # no temporary file left behind
    loaded = load_rig(path)
    assert detect_format(path) == "cameras_json" and loaded.names == rig.names
    for a, b in zip(rig, loaded):
        for key in ("K", "dist", "R", "t"):
            assert np.array_equal(getattr(a, key), getattr(b, key)), key
        assert a.size == b.size
    numeric = Rig(tuple(Camera(n, c.K, c.dist, c.R, c.t, c.size) for n, c in zip(["10", "2"], rig)))
    save_cameras_json(numeric, path)
    assert load_cameras_json(path).names == ["10", "2"]  # cameras.json keeps the file's order


def _ray_ground(cam: Camera, uv: np.ndarray) -> np.ndarray:
    """Intersect the back-projected rays of distorted pixels (N, 2) with z = 0: (N, 2)."""
    norm = cv2.undistortPoints(
        uv.reshape(-1, 1, 2), cam.K, cam.dist, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    )[:, 0]
    rays = np.column_stack([norm, np.ones(len(norm))]) @ cam.R  # R^T d, as rows
    lam = -cam.center[2] / rays[:, 2]
    return (cam.center + lam[:, None] * rays)[:, :2]


def _check_ground_round_trip(cam: Camera, ground: np.ndarray) -> None:
    """Ground (N, 2) -> image -> ground within 1e-6 m, and image -> ground equals the ray/z=0 intersection."""
    feet = np.column_stack([ground, np.zeros(len(ground))])
    uv = cam.ground_to_image(ground)
    np.testing.assert_allclose(uv, cam.project(feet), atol=1e-6, rtol=0)
    np.testing.assert_allclose(cam.image_to_ground(uv), ground, atol=1e-6, rtol=0)
    np.testing.assert_allclose(cam.image_to_ground(uv), _ray_ground(cam, uv), atol=1e-6, rtol=0)


def test_ground_homography_round_trip_wildtrack(shared_data: Path) -> None:
    # 50 px inside the border: at the very corners Wildtrack's radial polynomial (k1 -0.43, k3 -0.69) is
    # near its turning point and iterative undistortion does not invert it (CVLab1: 0.6 m off at 1 point).
    ground = _wildtrack_ground(shared_data)[::5]
    for cam in load_wildtrack(shared_data / "wildtrack"):
        inner = ground[cam.in_view(np.column_stack([ground, np.zeros(len(ground))]), margin=-50)]
        assert len(inner) > 300 and cam.has_distortion
        _check_ground_round_trip(cam, inner)


def test_ground_homography_round_trip_shelf(shared_data: Path) -> None:
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, 21), np.linspace(-2, 2, 21)), -1).reshape(-1, 2)
    for cam in load_4dassoc(shared_data / "shelf/4d_association/calibration.json"):
        inner = grid[cam.in_view(np.column_stack([grid, np.zeros(len(grid))]))]
        assert len(inner) > 50
        _check_ground_round_trip(cam, inner)


# --- dispatch and bad input -----------------------------------------------------------------------
def test_load_rig_detects_every_format(shared_data: Path) -> None:
    cases = {
        "shelf/4d_association/calibration.json": ("4dassoc", 5),
        "shelf/calibration_shelf.json": ("voxelpose", 5),
        "shelf/tum/Calibration": ("shelf_p", 5),
        "wildtrack": ("wildtrack", 7),
        f"{PANOPTIC_SEQ}/calibration_160906_band1.json": ("panoptic", 31),
    }
    for rel, (fmt, count) in cases.items():
        assert detect_format(shared_data / rel) == fmt
        assert len(load_rig(shared_data / rel)) == count
        assert len(load_rig(shared_data / rel, fmt=fmt)) == count


def _good_entry(fmt: str) -> dict:
    """One valid camera entry of the cameras.json or the 4D Association format."""
    K, R, t = [[1000.0, 0, 500], [0, 1000.0, 400], [0, 0, 1]], np.eye(3).tolist(), [0.0, 0.0, 3.0]
    if fmt == "cameras_json":
        return {"K": K, "dist": [0.0] * 5, "R": R, "t": t, "size": [1000, 800]}
    return {"K": sum(K, []), "RT": [v for row, ti in zip(R, t) for v in row + [ti]], "imgSize": [1000, 800]}


@pytest.mark.parametrize(
    "fmt,loader,key",
    [
        ("cameras_json", load_cameras_json, "K"),
        ("cameras_json", load_cameras_json, "t"),
        ("4dassoc", load_4dassoc, "RT"),
        ("4dassoc", load_4dassoc, "K"),
    ],
)
@pytest.mark.parametrize(
    "fault,message",
    [
        ("missing", "is missing"),
        ("nan", "has a non-finite value"),
        ("shape", "has shape"),
        ("text", "is not an array of numbers"),
    ],
)
def test_bad_calibration_names_file_camera_key(
    tmp_path: Path, fmt: str, loader, key: str, fault: str, message: str
) -> None:
    entry = _good_entry(fmt)
    if fault == "missing":
        del entry[key]
    elif fault == "nan":
        entry[key] = (np.array(entry[key], dtype=float) * np.nan).tolist()
    elif fault == "shape":
        entry[key] = np.ravel(entry[key])[:-1].tolist()
    else:
        entry[key] = "oops"
    path = tmp_path / f"bad_{fmt}.json"
    path.write_text(json.dumps({"0": _good_entry(fmt), "2": entry}))
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"0": _good_entry(fmt), "2": _good_entry(fmt)}))
    assert loader(good).names == ["0", "2"]
    with pytest.raises(CalibrationError, match=re.escape(f"bad_{fmt}.json: camera '2': key '{key}' {message}")):
        loader(path)


@pytest.mark.parametrize("loader", [load_cameras_json, load_4dassoc, load_voxelpose, load_panoptic])
def test_unreadable_or_missing_json(tmp_path: Path, loader) -> None:
    path = tmp_path / "broken_calib.json"
    path.write_text('{"0": {"K": [1, 2,')
    with pytest.raises(CalibrationError, match=r"broken_calib\.json: cannot read calibration JSON"):
        loader(path)
    with pytest.raises(CalibrationError, match=r"absent\.json: calibration file not found"):
        loader(tmp_path / "absent.json")


def test_inconsistent_values_and_other_formats(shared_data: Path, tmp_path: Path) -> None:
    entry = _good_entry("cameras_json")
    entry["R"] = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]]  # a reflection, not a rotation
    path = tmp_path / "reflect.json"
    path.write_text(json.dumps({"cam": entry}))
    with pytest.raises(CalibrationError, match=r"reflect\.json: camera 'cam': key 'R' is not a rotation"):
        load_cameras_json(path)
    with pytest.raises(CalibrationError, match=r"calibration_160906_band1\.json: camera '99_99'"):
        load_panoptic(shared_data / PANOPTIC_SEQ / "calibration_160906_band1.json", cameras=["00_00", "99_99"])
    (tmp_path / "P0.txt").write_text("1,2,3,4\n5,6,7,8\n")
    with pytest.raises(CalibrationError, match=r"P0\.txt: camera '0': key 'P' has shape"):
        load_shelf_projections(tmp_path)
    extr = tmp_path / "calibrations/extrinsic"
    extr.mkdir(parents=True)
    (tmp_path / "calibrations/intrinsic").mkdir()
    with pytest.raises(CalibrationError, match=r"intr_CVLab1\.xml: calibration file not found"):
        load_wildtrack(tmp_path)
