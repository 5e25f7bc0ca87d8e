"""Calibration importers: files written in each tool's own convention read back to the rig they came from."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from data.formats.calibration import main
from data.formats.poses2d_io import write_poses2d
from data.geometry.calibration import SHELF_SIZE, CalibrationError, detect_format, load_rig
from data.geometry.calibration_formats import fit_ground, load_anipose, load_easymocap, load_opencv, orient
from data.geometry.camera import Camera, Rig
from data.geometry.check_rig import RigWarning
from data.multiview import ViewDetections
from data.synthetic.body import mean_body, pose_joints
from data.synthetic.rigs import look_at_camera, ring_rig

DIST = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])


def _rig() -> Rig:
    """A ring of 4 cameras 6 m from the centre, 3 m high, world z up, with distortion and fx != fy."""
    cams = ring_rig(4, 6.0, 3.0, image_size=(1280, 720))
    K = np.array([[1010.0, 0.0, 645.5], [0.0, 1000.0, 355.25], [0.0, 0.0, 1.0]])
    return Rig(tuple(replace(c, name=f"cam{c.name}", K=K, dist=DIST * (1 + i)) for i, c in enumerate(cams)))


def _points(n: int = 200) -> np.ndarray:
    """Random world points in the scene (m): (n, 3)."""
    return np.random.default_rng(0).uniform((-2.0, -2.0, 0.0), (2.0, 2.0, 2.0), (n, 3))


def _same(rig: Rig, expected: Rig, points: np.ndarray, expected_points: np.ndarray | None = None) -> None:
    """Both rigs project the points (the second rig expected_points, when its world differs) within 0.01 px."""
    assert rig.names == expected.names and [c.size for c in rig] == [c.size for c in expected]
    other = points if expected_points is None else expected_points
    np.testing.assert_allclose(rig.project(points), expected.project(other), atol=0.01, rtol=0)


def _write_anipose(rig: Rig, path: Path, scale: float = 1.0, inverted: bool = False, pose2sim: bool = False) -> Path:
    """aniposelib's CameraGroup.dump ([cam_i], 5 distortions, [metadata]) or Pose2Sim's toml_write (tables named
    after the cameras, 4 distortions, fisheye = false); translation in units of scale; inverted: camera -> world."""
    text = []
    for i, c in enumerate(rig):
        R, t = (c.R.T, c.center) if inverted else (c.R, c.t)
        dist = c.dist[:4] if pose2sim else c.dist
        text += [f"[{c.name if pose2sim else f'cam_{i}'}]", f'name = "{c.name}"', f"size = [{c.size[0]}, {c.size[1]}]"]
        text += [f"matrix = {c.K.tolist()}", f"distortions = {dist.tolist()}"]
        text += [f"rotation = {cv2.Rodrigues(R)[0].ravel().tolist()}", f"translation = {(t * scale).tolist()}"]
        text += ["fisheye = false", ""] if pose2sim else [""]
    path.write_text("\n".join(text + ["[metadata]", "adjusted = false", "error = 0.25", ""]))
    return path


def _storage(path: Path, values: dict) -> Path:
    """An OpenCV FileStorage YAML of values (arrays, ints, or a list of names)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        if isinstance(value, list):
            fs.startWriteStruct(key, cv2.FileNode_SEQ)
            for item in value:
                fs.write("", item)
            fs.endWriteStruct()
        else:
            fs.write(key, value)
    fs.release()
    return path


def _write_easymocap(rig: Rig, folder: Path, rot: bool = True) -> Path:
    """EasyMocap's write_camera: intri.yml (names, K_, dist_ 1x5, H_, W_), extri.yml (R_ 3x1, Rot_, T_ 3x1)."""
    folder.mkdir(exist_ok=True)
    intri, extri = {"names": rig.names}, {"names": rig.names}
    for c in rig:
        intri |= {
            f"K_{c.name}": c.K,
            f"dist_{c.name}": c.dist[None],
            f"H_{c.name}": c.size[1],
            f"W_{c.name}": c.size[0],
        }
        extri |= {f"R_{c.name}": cv2.Rodrigues(c.R)[0], f"T_{c.name}": c.t[:, None]} | (
            {f"Rot_{c.name}": c.R} if rot else {}
        )
    _storage(folder / "intri.yml", intri)
    _storage(folder / "extri.yml", extri)
    return folder


def test_anipose_round_trip(tmp_path: Path) -> None:
    rig, points = _rig(), _points()
    for pose2sim in (False, True):
        flat = Rig(tuple(replace(c, dist=c.dist * [1, 1, 1, 1, 0]) for c in rig)) if pose2sim else rig
        path = _write_anipose(flat, tmp_path / f"calib_{pose2sim}.toml", pose2sim=pose2sim)
        assert detect_format(path) == "anipose"
        _same(load_rig(path), flat, points)


def test_easymocap_round_trip(tmp_path: Path) -> None:
    rig, points = _rig(), _points()
    folder = _write_easymocap(rig, tmp_path / "calib")
    for path in (folder, folder / "intri.yml", folder / "extri.yml"):  # the folder, or either file and its sibling
        assert detect_format(path) == "easymocap"
        _same(load_rig(path), rig, points)
    rodrigues = _write_easymocap(rig, tmp_path / "rvec", rot=False)  # R_ (Rodrigues) alone
    _same(load_easymocap(rodrigues / "intri.yml", rodrigues / "extri.yml"), rig, points)


def test_opencv_stereo_and_calibrate_round_trip(tmp_path: Path) -> None:
    rig, points = _rig(), _points()
    a, b = rig[0], rig[1]
    R, T = b.R @ a.R.T, b.t - b.R @ a.R.T @ a.t  # stereoCalibrate: x_b = R x_a + T
    _storage(tmp_path / "intrinsics.yml", {"M1": a.K, "D1": a.dist[None], "M2": b.K, "D2": b.dist[None]})
    _storage(tmp_path / "extrinsics.yml", {"R": R, "T": T[:, None], "R1": np.eye(3), "Q": np.eye(4)})
    with pytest.warns(RigWarning, match=r"camera '\d': no image size in the file: twice the principal point"):
        stereo = load_opencv(tmp_path / "intrinsics.yml", units="m")  # the sibling extrinsics.yml is found
    assert stereo.names == ["1", "2"] and stereo[1].size == (1291, 710)
    np.testing.assert_allclose(stereo[1].project(a.world_to_camera(points)), b.project(points), atol=0.01, rtol=0)
    calibrate = {
        "image_width": 1280,
        "image_height": 720,
        "camera_matrix": a.K,
        "distortion_coefficients": a.dist[None],
    }
    single = _storage(tmp_path / "cam_left.yml", calibrate)  # OpenCV's calibration.cpp sample
    one = load_rig(single, check=False)
    assert detect_format(single) == "opencv" and one.names == ["cam_left"] and one[0].size == (1280, 720)
    np.testing.assert_allclose(one[0].project(a.world_to_camera(points)), a.project(points), atol=0.01, rtol=0)


def _shelf_rig(distortion: bool) -> Rig:
    """_rig() at Shelf's image size (the VoxelPose and P-matrix files state none), cameras "0".."3"."""
    return Rig(tuple(replace(c, name=str(i), size=SHELF_SIZE, dist=c.dist * distortion) for i, c in enumerate(_rig())))


def _read_back(path: Path, fmt: str, rig: Rig, tmp_path: Path) -> None:
    """path is detected as fmt and reads back to rig within 0.01 px, through load_rig and through the command line."""
    points, out = _points(), tmp_path / f"{fmt}_cameras.json"
    assert detect_format(path) == fmt
    _same(load_rig(path), rig, points)
    assert main([str(path), "-o", str(out)]) == 0
    _same(load_rig(out), rig, points)


def test_voxelpose_round_trip(tmp_path: Path) -> None:
    # VoxelPose (lib/utils/cameras.py project_point_radial): x_cam = R (X - T), T (3x1) the centre in mm; fx fy cx
    # cy scalars; k (3x1) k1 k2 k3, p (2x1) p1 p2 as OpenCV's; keys "0".. in any order; no image size.
    rig, points = _shelf_rig(distortion=True), _points()
    cams = {}
    for c in reversed(list(rig)):  # numeric order, not file order
        k, p = c.dist[[0, 1, 4]], c.dist[[2, 3]]
        cams[c.name] = {"R": c.R.tolist(), "T": (1000 * c.center)[:, None].tolist(), "k": k[:, None].tolist()}
        cams[c.name] |= {"p": p[:, None].tolist(), "fx": c.K[0, 0], "fy": c.K[1, 1], "cx": c.K[0, 2], "cy": c.K[1, 2]}
    for c in rig:  # the file as VoxelPose projects it (points in mm), independent of the loader
        e = {key: np.array(v, dtype=float) for key, v in cams[c.name].items()}
        y = e["R"] @ (1000 * points.T - e["T"])
        y = y[:2] / y[2]
        r2 = np.sum(y**2, axis=0)
        radial = 1 + e["k"][:, 0] @ np.stack([r2, r2**2, r2**3])
        y = y * (radial + 2 * (e["p"][0] * y[1] + e["p"][1] * y[0])) + np.outer(e["p"][::-1, 0], r2)
        uv = y * [[e["fx"]], [e["fy"]]] + [[e["cx"]], [e["cy"]]]
        np.testing.assert_allclose(uv.T, c.project(points), atol=0.01, rtol=0)
    path = tmp_path / "calibration_shelf.json"
    path.write_text(json.dumps(cams))
    _read_back(path, "voxelpose", rig, tmp_path)


def test_shelf_projection_matrices_round_trip(tmp_path: Path) -> None:
    # Shelf / Campus Calibration/P{i}.txt: 3 lines of 4 comma-separated numbers, P = K [R | t], metres, no
    # distortion; a projection matrix is defined up to scale (P2 written times -0.5 projects alike).
    rig, points = _shelf_rig(distortion=False), _points()
    folder = tmp_path / "Calibration"
    folder.mkdir()
    for i, c in enumerate(rig):
        P = c.K @ np.column_stack([c.R, c.t]) * (-0.5 if i == 2 else 1.0)
        uv = np.column_stack([points, np.ones(len(points))]) @ P.T
        np.testing.assert_allclose(uv[:, :2] / uv[:, 2:], c.project(points), atol=0.01, rtol=0)
        (folder / f"P{c.name}.txt").write_text("".join(",".join(map(repr, row)) + "\n" for row in P.tolist()))
    (folder / "Camera0.cal").write_text("not read\n")
    _read_back(folder, "shelf_p", rig, tmp_path)


def test_panoptic_round_trip(tmp_path: Path) -> None:
    # CMU Panoptic calibration_<seq>.json: cameras [{name, type, resolution, K, distCoef (OpenCV 5), R, t (3x1)}],
    # x_cam = R x + t with x in cm, y down: x_pan = 100 M^T x_ours (M = _PANOPTIC_M) so R = R_ours M, t = 100 t_ours.
    rig, points = Rig(tuple(replace(c, name=f"00_{i:02d}") for i, c in enumerate(_rig()))), _points()
    M = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    cams = [{"name": "01_01", "type": "vga", "resolution": [640, 480], **_panoptic_entry(rig[0], M)}]
    cams += [{"name": c.name, "type": "hd", "resolution": list(c.size), **_panoptic_entry(c, M)} for c in rig]
    for c, e in zip(rig, cams[1:]):  # the file as the Panoptic toolbox projects it (cv2.projectPoints on cm points)
        R, t, K, dist = (np.array(e[key], dtype=float) for key in ("R", "t", "K", "distCoef"))
        uv = cv2.projectPoints(100 * points @ M, cv2.Rodrigues(R)[0], t, K, dist)[0][:, 0]
        np.testing.assert_allclose(uv, c.project(points), atol=0.01, rtol=0)
    path = tmp_path / "calibration_seq.json"
    path.write_text(json.dumps({"calibDataSource": "synthetic", "cameras": cams}))
    _read_back(path, "panoptic", rig, tmp_path)


def _panoptic_entry(c: Camera, M: np.ndarray) -> dict:
    """One camera's K, distCoef, R, t in Panoptic's convention (test_panoptic_round_trip)."""
    return {"K": c.K.tolist(), "distCoef": c.dist.tolist(), "R": (c.R @ M).tolist(), "t": (100 * c.t)[:, None].tolist()}


def _units_warnings(caught: list) -> list[str]:
    """The messages of the units plausibility warnings among caught warnings."""
    return [str(w.message) for w in caught if "--units" in str(w.message)]


def _stereo_bar(toe_in: bool) -> Rig:
    """Two cameras 12 cm apart about the origin (as stereoCalibrate's) looking along +y: parallel, or converging
    1.5 m ahead (toe_in)."""
    ahead = lambda x: (0.0, 1.5, 0.0) if toe_in else (x, 10.0, 0.0)
    return Rig(
        tuple(look_at_camera(n, (x, 0.0, 0.0), ahead(x), (1280, 720), 1000.0) for n, x in (("L", -0.06), ("R", 0.06)))
    )


def test_small_rig_in_centimetres_warns(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    points = _points() * 0.2 + [0.0, 2.5, -0.2]  # in front of the bar
    for toe_in in (False, True):
        bar = _stereo_bar(toe_in)
        cm = _write_anipose(bar, tmp_path / f"stereo_{toe_in}.toml", scale=100.0)  # 12 cm written in cm: "12 m"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            load_rig(cm, check=False)
        (message,) = _units_warnings(caught)
        assert message.startswith(f"{cm}: cameras 12 apart and ") and "centimetres" in message and "\n" not in message
        with warnings.catch_warnings():
            warnings.simplefilter("error", RigWarning)
            _same(load_rig(cm, check=False, units="cm"), bar, points)  # stated: read in cm, no warning
        assert main([str(cm), "-o", str(tmp_path / "cameras.json")]) == 0  # a warning, not an error
        assert f"warning: {message}" in capsys.readouterr().out.splitlines()
    metres = [_stereo_bar(False), _stereo_bar(True), _rig(), ring_rig(6, 3.0, 2.5)]  # the bars, 6 m and 3 m rings
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for i, rig in enumerate(metres):
            orient(rig, f"rig{i}.toml")
    assert not _units_warnings(caught)


def test_camera_to_world_and_millimetres_are_named(tmp_path: Path) -> None:
    rig, points = _rig(), _points()
    inverted = _write_anipose(rig, tmp_path / "c2w.toml", inverted=True)
    with pytest.raises(CalibrationError, match=r"c2w.toml: camera 'cam0': R, t look like camera -> world .*--rotation"):
        load_rig(inverted)
    _same(load_anipose(inverted, rotation="camera_to_world"), rig, points)
    mm = _write_anipose(rig, tmp_path / "mm.toml", scale=1000.0)
    with pytest.raises(CalibrationError, match=r"mm.toml: camera 'cam\d': centre .* millimetres .*--units mm") as err:
        load_rig(mm)
    assert "\n" not in str(err.value)
    _same(load_anipose(mm, units="mm"), rig, points)
    both = _write_anipose(rig, tmp_path / "both.toml", scale=100.0, inverted=True)
    _same(load_anipose(both, units="cm", rotation="camera_to_world"), rig, points)


def test_bad_files_stop_with_one_line(tmp_path: Path) -> None:
    text = _write_anipose(_rig(), tmp_path / "good.toml").read_text()
    bad = {
        "[cam_0\nname = 1": r"bad.toml: cannot read calibration TOML",
        text.replace("translation", "T"): r"bad.toml: camera 'cam0': key 'translation' is missing",
        text.replace("[metadata]", "[cam_9]\nname = 'cam0'\n[metadata]"): r"bad.toml: camera 'cam0'",
        text.replace("-0.12, ", "-0.12, 0.1, 0.1, 0.1, ", 1): r"camera 'cam0': key 'distortions' has 8 coefficients",
        text.replace('name = "cam1"', 'name = "cam1"\nfisheye = true'): r"camera 'cam1': key 'fisheye' is true",
    }
    for content, message in bad.items():
        (tmp_path / "bad.toml").write_text(content)
        with pytest.raises(CalibrationError, match=message) as err:
            load_rig(tmp_path / "bad.toml")
        assert "\n" not in str(err.value)
    folder = _write_easymocap(_rig(), tmp_path / "em")
    (folder / "extri.yml").unlink()
    with pytest.raises(CalibrationError, match=r"intri.yml: camera 'cam0': key 'R_cam0' is missing"):
        load_rig(folder / "intri.yml")
    (folder / "intri.yml").write_text("%YAML:1.0\nfoo: [1, 2\n")
    with pytest.raises(CalibrationError, match=r"intri.yml: cannot read OpenCV YAML / XML \(.*\)$"):
        load_rig(folder / "intri.yml")


def _standing_people(rig: Rig, frames: int = 3, people: int = 6) -> dict[int, list[ViewDetections]]:
    """Noise-free 2D poses of people standing on z = 0 in the true world, seen by rig: {frame: V ViewDetections}."""
    rng, out = np.random.default_rng(1), {}
    for f in range(frames):
        joints = np.stack(
            [pose_joints(mean_body(), *rng.uniform(-2, 2, 2), rng.uniform(0, 6.3)) for _ in range(people)]
        )
        views = []
        for cam in rig:
            kp = np.concatenate([cam.project(joints), cam.in_view(joints)[..., None].astype(float)], axis=-1)
            views.append(
                ViewDetections(kp, np.tile([0.0, 0.0, 10.0, 10.0], (people, 1)), np.ones(people), np.arange(people))
            )
        out[f] = views
    return out


def _tilted(rig: Rig, angle_deg: float, shift: np.ndarray) -> Rig:
    """The same cameras in a world rotated by angle_deg about (1, 0.5, 0) and shifted: x_file = Q x + shift."""
    axis = np.array([1.0, 0.5, 0.0]) / np.linalg.norm([1.0, 0.5, 0.0])
    Q = cv2.Rodrigues(axis * np.radians(angle_deg))[0]
    return Rig(tuple(replace(c, R=c.R @ Q.T, t=c.t - c.R @ Q.T @ shift) for c in rig))


def test_ground_fit_recovers_the_plane(tmp_path: Path) -> None:
    rig = _rig()
    views = _standing_people(rig)
    tilted = _tilted(rig, 8.0, np.array([0.4, -0.3, 1.2]))
    for heels, tol in ((True, 1e-4), (False, 0.005)):  # without heels: ankles ANKLE_HEIGHT_M above the ground
        seen = (
            views
            if heels
            else {f: [replace(v, keypoints=v.keypoints * _no_heels()) for v in vs] for f, vs in views.items()}
        )
        fitted, fit = fit_ground(tilted, seen, "poses2d.json")
        np.testing.assert_allclose([c.center[2] for c in fitted], [c.center[2] for c in rig], atol=tol)
        np.testing.assert_allclose([c.R[2, 2] for c in fitted], [c.R[2, 2] for c in rig], atol=1e-4)
        assert fit.angle_deg == pytest.approx(8.0, abs=0.01) and fit.residual_mm < (0.1 if heels else 5.0)
        assert fit.joints == ("heel" if heels else "ankle") and fit.inliers == fit.points
        what = "heel points" if heels else "ankle points (ankles 0.066 m above it)"
        assert f"ground: plane z = 0 fitted to {fit.points} of {fit.points} {what} in 3 frames" in str(fit)
        assert "world rotated by 8.00 deg" in str(fit)
    with pytest.raises(CalibrationError, match=r"poses2d.json: 0 ankle points .* at least 30 are needed"):
        fit_ground(tilted, {0: [ViewDetections.empty() for _ in rig]}, "poses2d.json")


def _no_heels() -> np.ndarray:
    """A (23, 3) factor that zeroes the heels' scores."""
    factor = np.ones((23, 3))
    factor[[19, 22], 2] = 0.0
    return factor


def test_cli_writes_cameras_json(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rig, points = _rig(), _points()
    tilted = _tilted(rig, 5.0, np.array([0.0, 0.0, 0.8]))
    toml = _write_anipose(tilted, tmp_path / "calibration.toml", scale=1000.0)
    write_poses2d(tmp_path / "poses2d.json", _standing_people(rig), rig.names)
    out = tmp_path / "cameras.json"
    assert main([str(toml), "-o", str(out)]) == 1
    assert "--units mm" in capsys.readouterr().err
    assert main([str(toml), "-o", str(out), "--units", "mm", "--ground", str(tmp_path / "poses2d.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].startswith("ground: plane z = 0 fitted to") and "rotated by 5.00 deg" in lines[-1]
    back = load_rig(out)
    np.testing.assert_allclose([c.center[2] for c in back], [3.0] * 4, atol=1e-3)
    folder = _write_easymocap(rig, tmp_path / "em")
    assert main([str(folder / "intri.yml"), str(folder / "extri.yml"), "-o", str(out)]) == 0
    assert "ground: not in" in capsys.readouterr().out
    _same(load_rig(out), rig, points)


DATASET_CALIBRATIONS = [
    "shelf/4d_association/calibration.json",
    "shelf/calibration_shelf.json",
    "shelf/tum/Calibration",
    "panoptic/160906_band1/calibration_160906_band1.json",
    "wildtrack",
]


@pytest.mark.parametrize("name", DATASET_CALIBRATIONS)
def test_cli_reaches_the_dataset_formats(shared_data: Path, tmp_path: Path, name: str) -> None:
    out, rig = tmp_path / "cameras.json", load_rig(shared_data / name)
    assert main([str(shared_data / name), "-o", str(out)]) == 0
    _same(load_rig(out), rig, _points())
    assert list(json.loads(out.read_text())) == rig.names
    # the real rig as anipose TOML: no rule fires (the units warning neither) as it is; written camera -> world,
    # the rotation rule names it
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _same(load_rig(_write_anipose(rig, tmp_path / "w2c.toml")), rig, _points())
    assert not _units_warnings(caught)
    with pytest.raises(CalibrationError, match=r"w.toml: camera '.+': R, t look like camera -> world"):
        load_rig(_write_anipose(rig, tmp_path / "c2w.toml", inverted=True))
