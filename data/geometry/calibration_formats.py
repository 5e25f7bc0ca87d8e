"""Other tools' calibration files to a `Rig` (anipose TOML, EasyMocap and OpenCV YAML), the unit and rotation
rules of files that do not state them, and the ground plane z = 0 fitted to triangulated feet."""

from __future__ import annotations

import re
import tomllib
import warnings
from dataclasses import dataclass, replace
from itertools import combinations
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np

from data.geometry.calibration import CalibrationError, _array, _camera, _error
from data.geometry.camera import Camera, Rig
from data.geometry.check_rig import RigTolerances, RigWarning, _mutual_best, _pair_costs, axes_point, sees_point
from data.geometry.triangulation import triangulate_dlt
from data.keypoints import joint_indices
from data.multiview import ViewDetections

# anipose (aniposelib CameraGroup.dump; Pose2Sim and freemocap write the same): a table per camera ([cam_0] ...;
# Pose2Sim names them after the cameras) with name, size [w, h], matrix (3x3), distortions (OpenCV k1 k2 p1 p2
# [k3]; Pose2Sim writes 4), rotation (Rodrigues, world -> camera), translation (x_cam = R x + t, in the unit of the
# board's square length: usually mm for aniposelib / freemocap, m for Pose2Sim), fisheye (refused when true); a
# [metadata] table is skipped. Cameras in file order (aniposelib itself sorts the table names as strings).
# EasyMocap (easymocap/mytools/camera_utils.py write_camera): intri.yml names [list], K_<name> (3x3), dist_<name>
# (1x5 or 1x4; D_<name> in old files), optional H_<name> W_<name> (px); extri.yml R_<name> (Rodrigues 3x1) and
# Rot_<name> (3x3, preferred), T_<name> (3x1, m), world -> camera.
# OpenCV samples: calibration.cpp camera_matrix, distortion_coefficients, image_width, image_height (one camera at
# the origin); stereo_calib.cpp intrinsics.yml M1 D1 M2 D2 and extrinsics.yml R T (x_2 = R x_1 + T, T in the
# board's unit): camera "1" at the origin, its frame the world (y down). No image size: twice the principal point.
FREE_FORMATS = ("anipose", "easymocap", "opencv")  # formats whose files do not fix units, direction or ground
UNITS_M, ROTATIONS = {"m": 1.0, "cm": 0.01, "mm": 0.001}, ("world_to_camera", "camera_to_world")
# Rotation rule: R, t are camera -> world when at most a third of the cameras see the centroid of the camera
# centres (in front, within half an image of it) as given and all of them do inverted; the file must state
# --rotation. Units rule: a camera centre farther than these from the world origin, or from another camera, in the
# file's unit is not a room rig in metres (but mm or cm); the file must state --units.
MAX_ORIGIN_DISTANCE = 100.0
MAX_BASELINE = 40.0
# Units plausibility (a RigWarning, the rule above passes small rigs in cm: a 12 cm stereo bar reads as 12 m):
# cameras set more than PLAUSIBLE_SPREAD apart in metres surround a scene they turn to and share within
# PLAUSIBLE_VIEW_DISTANCE (the point nearest their optical axes, mean distance: Panoptic 2.8, Shelf 3.5, Wildtrack
# 13 m), while a stereo bar or a close-up rig in cm looks parallel (no such point in front) or converges far away.
PLAUSIBLE_SPREAD = 2.0
PLAUSIBLE_VIEW_DISTANCE = 30.0
GROUND_FRAMES = 100  # the first frames of poses2d.json whose feet fit the ground
GROUND_INLIER_M = 0.03  # a foot point this close to the plane supports it (RANSAC)
MIN_GROUND_POINTS = 30
MAX_PAIR_COST = 0.01  # two views' detections are one person below this median reprojection error / diagonal
ANKLE_HEIGHT_M = 0.066  # ankle above the sole: 0.039 x 1.70 m stature (Drillis & Contini, data/synthetic/body.py)
HEELS, ANKLES = joint_indices(("left_heel", "right_heel")), joint_indices(("left_ankle", "right_ankle"))


def _dist(entry: Mapping, key: str, path: str | Path, name: str) -> np.ndarray:
    """OpenCV k1 k2 p1 p2 [k3 ...] of any length >= 4 (further terms must be 0), zeros without the key: (5,)."""
    if key not in entry:
        return np.zeros(5)
    count = np.asarray(entry[key], dtype=object).size
    d = _array(entry, key, (count,), path, name)
    if count < 4 or np.any(d[5:] != 0):
        raise _error(path, name, key, f"has {count} coefficients: OpenCV k1 k2 p1 p2 [k3] expected (no other model)")
    return np.pad(d[:5], (0, 5 - min(count, 5)))


def _keyed(data: Mapping, path: str | Path, name: str, keys: Mapping[str, Any]) -> Camera:
    """The camera under these keys of data: K, dist, R (3x3) or rvec (Rodrigues), t (none: the origin), size (the
    keys of (w, h) or of [w, h]; none: twice the principal point, with a RigWarning)."""
    K, dist = _array(data, keys["K"], (3, 3), path, name), _dist(data, keys["dist"], path, name)
    R = _array(data, keys["R"], (3, 3), path, name) if "R" in keys else np.eye(3)
    R = cv2.Rodrigues(_array(data, keys["rvec"], (3,), path, name))[0] if "rvec" in keys else R
    t = _array(data, keys["t"], (3,), path, name) if "t" in keys else np.zeros(3)
    wh = keys["size"]
    if all(k in data for k in wh):
        size = np.concatenate([_array(data, k, (2 // len(wh),), path, name) for k in wh])
    else:
        size = tuple(int(round(2 * c)) for c in K[:2, 2])
        what = f"no image size in the file: twice the principal point, {size}; check it"
        warnings.warn(f"{path}: camera {name!r}: {what}", RigWarning, stacklevel=3)
    return _camera(name, K, dist, R, t, size, path, (keys["K"], keys.get("R", keys.get("rvec", "R")), wh[0]))


def _rig(cameras: list[Camera], path: str | Path, units: str | None, rotation: str | None) -> Rig:
    """The rig of these cameras, its direction and units stated or checked (orient)."""
    names = [c.name for c in cameras]
    twice = [n for n in names if names.count(n) > 1]
    if twice:
        raise _error(path, twice[0], None, "is named twice")
    return orient(Rig(tuple(cameras)), path, units, rotation)


# --- anipose / Pose2Sim / freemocap TOML ----------------------------------------------------------
def load_anipose(path: str | Path, units: str | None = None, rotation: str | None = None) -> Rig:
    """An anipose calibration.toml (conventions above) in file order."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise _error(path, None, None, "calibration file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise _error(path, None, None, f"cannot read calibration TOML ({exc})") from None
    tables = [(str(v.get("name", k)), v) for k, v in data.items() if k != "metadata" and isinstance(v, dict)]
    if not tables:
        raise _error(path, None, None, "no camera tables ([cam_0] with matrix, rotation, translation ...)")
    keys = {"K": "matrix", "dist": "distortions", "rvec": "rotation", "t": "translation", "size": ("size",)}
    for name, entry in tables:
        if entry.get("fisheye"):
            raise _error(path, name, "fisheye", "is true: the OpenCV fisheye model is not supported")
    return _rig([_keyed(entry, path, name, keys) for name, entry in tables], path, units, rotation)


# --- OpenCV FileStorage: EasyMocap, calibrateCamera and stereoCalibrate samples ---------------------
def _node(node: cv2.FileNode) -> Any:
    """A FileStorage node as Python: matrices as nested lists, sequences as lists, other maps as None."""
    if node.isSeq():
        return [_node(node.at(i)) for i in range(node.size())]
    if node.isMap():
        try:
            return node.mat().tolist()
        except (cv2.error, AttributeError):  # a map that is no matrix
            return None
    return node.string() if node.isString() else node.real()


def read_filestorage(paths: Sequence[Path]) -> dict[str, Any]:
    """The top-level keys of OpenCV FileStorage YAML / XML files, merged in order: {key: value}."""
    out: dict[str, Any] = {}
    for path in paths:
        if not path.is_file():
            raise _error(path, None, None, "calibration file not found")
        try:
            storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # kept alive while its nodes are read
            out |= {key: _node(storage.getNode(key)) for key in storage.root().keys()}
        except (cv2.error, SystemError) as exc:  # a parse error arrives as a SystemError from its cv2.error
            cause = " ".join(str(exc.__cause__ or exc).split())
            raise _error(path, None, None, f"cannot read OpenCV YAML / XML ({cause})") from None
    return out


def _pair(path: str | Path, second: str | Path | None, words: tuple[str, str]) -> list[Path]:
    """The files of a two-file calibration: a folder's, both given, or the file and its sibling if there."""
    path = Path(path)
    if path.is_dir():
        return [path / f"{word}.yml" for word in words]
    if second is not None:
        return [path, Path(second)]
    for a, b in (words, words[::-1]):
        other = re.sub(a, lambda m: b.capitalize() if m.group()[0].isupper() else b, path.name, flags=re.I)
        if other != path.name and (path.parent / other).is_file():
            return [path, path.parent / other]
    return [path]


def load_easymocap(
    path: str | Path, second: str | Path | None = None, units: str | None = None, rotation: str | None = None
) -> Rig:
    """EasyMocap intri.yml + extri.yml (a folder, either file with its sibling, or both), in the order of names."""
    paths = _pair(path, second, ("intri", "extri"))
    data, where = read_filestorage(paths), " + ".join(map(str, paths))
    if not isinstance(data.get("names"), list) or not data["names"]:
        raise _error(where, None, "names", "is missing or empty (the list of camera names)")
    cameras = []
    for name in (str(int(n)) if isinstance(n, float) else str(n) for n in data["names"]):
        keys = {"K": f"K_{name}", "dist": f"dist_{name}" if f"dist_{name}" in data else f"D_{name}", "t": f"T_{name}"}
        keys |= {"R": f"Rot_{name}"} if f"Rot_{name}" in data else {"rvec": f"R_{name}"}
        cameras.append(_keyed(data, where, name, keys | {"size": (f"W_{name}", f"H_{name}")}))
    return _rig(cameras, where, units, rotation)


def load_opencv(
    path: str | Path, second: str | Path | None = None, units: str | None = None, rotation: str | None = None
) -> Rig:
    """OpenCV's calibrateCamera (one camera "<file stem>") or stereoCalibrate YAML (cameras "1", "2"), see above."""
    paths = _pair(path, second, ("intrinsics", "extrinsics"))
    data, where = read_filestorage(paths), " + ".join(map(str, paths))
    size = {"size": ("image_width", "image_height")}
    if "M1" not in data:
        keys = {"K": "camera_matrix", "dist": "distortion_coefficients"} | size
        return _rig([_keyed(data, where, paths[0].stem, keys)], where, units, rotation)
    stereo = [{"K": f"M{i}", "dist": f"D{i}"} | size for i in (1, 2)]
    stereo[1] |= {"R": "R", "t": "T"}
    return _rig([_keyed(data, where, str(i + 1), keys) for i, keys in enumerate(stereo)], where, units, rotation)


LOADERS = {"anipose": load_anipose, "easymocap": load_easymocap, "opencv": load_opencv}


def detect_file_format(path: Path) -> str | None:
    """'anipose', 'easymocap' or 'opencv' for such a file or folder, None for any other (calibration.detect_format)."""
    if path.is_dir():
        names = {"easymocap": "intri.yml", "opencv": "intrinsics.yml"}
        return next((fmt for fmt, name in names.items() if (path / name).is_file()), None)
    if path.suffix.lower() == ".toml":
        return "anipose"
    if path.suffix.lower() not in (".yml", ".yaml", ".xml"):
        return None
    keys = set(read_filestorage([path]))
    if "names" in keys:
        return "easymocap"
    if keys & {"camera_matrix", "M1", "R", "T"}:
        return "opencv"
    expected = "names + K_<name> (EasyMocap), camera_matrix (calibrateCamera) or M1 D1 M2 D2 / R T (stereoCalibrate)"
    raise _error(path, None, None, f"cannot detect the calibration format of this YAML (expected {expected})")


# --- the rules: direction and units -------------------------------------------------------------------
def _inverted(rig: Rig) -> Rig:
    """Every camera's (R, t) read as camera -> world and inverted."""
    return Rig(tuple(replace(c, R=c.R.T, t=-c.R.T @ c.t) for c in rig))


def _looking(rig: Rig) -> np.ndarray:
    """Which cameras see the centroid of the camera centres (in front, within half an image of it): (V,) bool."""
    centre = np.mean([c.center for c in rig], axis=0)
    return np.array([sees_point(c, centre, RigTolerances().scene_margin) for c in rig])


def viewed_point(rig: Rig) -> np.ndarray | None:
    """The point nearest the cameras' optical axes (check_rig.axes_point), None when they are near parallel or it
    lies behind a camera: (3,)."""
    X = axes_point(list(rig), RigTolerances().max_axes_condition)
    C, D = np.array([c.center for c in rig]), np.array([c.R[2] for c in rig])
    return X if X is not None and np.all(np.einsum("vi,vi->v", D, X - C) > 0) else None


def _implausible_units(rig: Rig, path: str | Path) -> None:
    """A RigWarning when the rig's size disagrees with its own view (PLAUSIBLE_SPREAD, PLAUSIBLE_VIEW_DISTANCE)."""
    C = np.array([c.center for c in rig])
    spread = float(np.linalg.norm(C[:, None] - C[None], axis=-1).max())
    X = viewed_point(rig)
    view = np.inf if X is None else float(np.linalg.norm(C - X, axis=1).mean())
    if len(rig) > 1 and spread > PLAUSIBLE_SPREAD and view > PLAUSIBLE_VIEW_DISTANCE:
        seen = "their optical axes meet no point in front" if X is None else f"they view a point {view:.3g} away"
        what = f"cameras {spread:.3g} apart and {seen}: t may be in centimetres or millimetres, not metres"
        fix = "state --units cm|mm (or --units m) to python -m data.formats.calibration"
        warnings.warn(f"{path}: {what}: {fix}", RigWarning, stacklevel=3)


def orient(rig: Rig, path: str | Path, units: str | None = None, rotation: str | None = None) -> Rig:
    """The rig in metres, world -> camera, as stated (units m|cm|mm, rotation world_to_camera|camera_to_world) or,
    unstated, checked: CalibrationError when at most a third of the cameras see the centroid of the camera centres
    and all do inverted (camera -> world), or a centre lies MAX_ORIGIN_DISTANCE from the origin or MAX_BASELINE
    from another camera (not metres); a RigWarning when its size disagrees with its view (_implausible_units)."""
    if units not in (None, *UNITS_M) or rotation not in (None, *ROTATIONS):
        raise CalibrationError(f"{path}: units {units!r}, rotation {rotation!r}: expected {list(UNITS_M)}, {ROTATIONS}")
    if rotation == "camera_to_world":
        rig = _inverted(rig)
    elif rotation is None and len(rig) > 1:
        given = _looking(rig)
        if 3 * given.sum() <= len(rig) and _looking(_inverted(rig)).all():
            what = f"{given.sum()} of {len(rig)} cameras see the centroid of the cameras as given, all inverted"
            fix = "state --rotation camera_to_world (world_to_camera keeps them) to python -m data.formats.calibration"
            raise _error(
                path, rig.names[int(np.argmin(given))], None, f"R, t look like camera -> world ({what}): {fix}"
            )
    if units is None:
        C = np.array([c.center for c in rig])
        gap = np.linalg.norm(C[:, None] - C[None], axis=-1).max(axis=1)
        far = np.maximum(np.linalg.norm(C, axis=1) / MAX_ORIGIN_DISTANCE, gap / MAX_BASELINE)
        if far.max() > 1:
            v = int(np.argmax(far))
            what = f"centre {np.linalg.norm(C[v]):.4g} from the world origin, up to {gap[v]:.4g} from another camera"
            fix = "state --units mm|cm|m to python -m data.formats.calibration"
            raise _error(
                path, rig.names[v], None, f"{what}: t looks like millimetres or centimetres, not metres: {fix}"
            )
        _implausible_units(rig, path)
    scale = UNITS_M[units or "m"]
    return rig if scale == 1 else Rig(tuple(replace(c, t=c.t * scale) for c in rig))


# --- the ground plane from the feet ----------------------------------------------------------------
@dataclass(frozen=True)
class GroundFit:
    """The ground plane fitted to triangulated feet, and the rigid motion of the world that made it z = 0."""

    joints: str  # "heel" or "ankle"
    points: int
    inliers: int
    frames: int
    residual_mm: float  # RMS distance of the inliers to the plane
    angle_deg: float  # rotation applied to the world
    shift_m: float  # translation along the new z axis

    def __str__(self) -> str:
        what = "heel points" if self.joints == "heel" else f"ankle points (ankles {ANKLE_HEIGHT_M} m above it)"
        fit = f"{self.inliers} of {self.points} {what} in {self.frames} frames"
        moved = f"world rotated by {self.angle_deg:.2f} deg and shifted {self.shift_m:+.3f} m along z"
        return f"ground: plane z = 0 fitted to {fit}, residual {self.residual_mm:.1f} mm RMS; {moved}"


def foot_points(rig: Rig, views_by_frame: Mapping[int, list[ViewDetections]], joints: Sequence[int]) -> np.ndarray:
    """The joints triangulated from every view pair's detections of one person (mutual best, reprojection
    below MAX_PAIR_COST image diagonals) over the frames {frame: V ViewDetections}: (N, 3)."""
    out = [np.zeros((0, 3))]
    for views in views_by_frame.values():
        for a, b in combinations(range(len(rig)), 2):
            ka, kb = views[a].keypoints, views[b].keypoints
            if not (len(ka) and len(kb)):
                continue
            cost = _pair_costs(rig[a], rig[b], ka, kb, RigTolerances().min_joints)
            pairs = _mutual_best(cost)
            pairs = pairs[cost[pairs[:, 0], pairs[:, 1]] < MAX_PAIR_COST]
            feet = [(rig[v], k[p][:, joints]) for v, k, p in ((a, ka, pairs[:, 0]), (b, kb, pairs[:, 1]))]
            uv = [np.concatenate([cam.undistort_points(f[..., :2]), f[..., 2:]], axis=-1) for cam, f in feet]
            X = triangulate_dlt(np.stack(uv), np.stack([rig[a].P, rig[b].P])).reshape(-1, 4)
            out.append(X[X[:, 3] > 0, :3])
    return np.concatenate(out)


def fit_plane(points: np.ndarray, iterations: int = 300, seed: int = 0) -> tuple[np.ndarray, float, np.ndarray]:
    """RANSAC (GROUND_INLIER_M) then least squares on the inliers of points (N, 3): normal (3,), d, inliers (N,)."""
    rng = np.random.default_rng(seed)
    sample = points[np.array([rng.choice(len(points), 3, replace=False) for _ in range(iterations)])]
    normals = np.cross(sample[:, 1] - sample[:, 0], sample[:, 2] - sample[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals /= np.maximum(length, 1e-12)
    probe = points[rng.choice(len(points), min(len(points), 2000), replace=False)]  # bounds the memory
    support = (np.abs(np.einsum("ikj,ij->ik", probe[None] - sample[:, :1], normals)) < GROUND_INLIER_M).sum(axis=1)
    best = np.argmax(np.where(length[:, 0] > 1e-9, support, -1))  # not a degenerate (collinear) sample
    n, inliers = normals[best], np.abs((points - sample[best, 0]) @ normals[best]) < GROUND_INLIER_M
    for _ in range(3):
        centre = points[inliers].mean(axis=0)
        n = np.linalg.svd(points[inliers] - centre)[2][2]
        inliers = np.abs((points - centre) @ n) < GROUND_INLIER_M
    return n, float(n @ centre), inliers


def fit_ground(
    rig: Rig, views_by_frame: Mapping[int, list[ViewDetections]], path: str | Path, frames: int = GROUND_FRAMES
) -> tuple[Rig, GroundFit]:
    """The rig with its world moved so that the feet of the first frames {frame: V ViewDetections} stand on z = 0,
    z up toward the cameras (heels on it, or ankles ANKLE_HEIGHT_M above it without heels); the fit."""
    first = {f: views_by_frame[f] for f in sorted(views_by_frame)[:frames]}
    points, joints, height = foot_points(rig, first, HEELS), "heel", 0.0
    if len(points) < MIN_GROUND_POINTS:
        points, joints, height = foot_points(rig, first, ANKLES), "ankle", ANKLE_HEIGHT_M
    if len(points) < MIN_GROUND_POINTS:
        what = f"{len(points)} ankle points seen in two views in the first {len(first)} frames"
        raise CalibrationError(f"{path}: {what}: at least {MIN_GROUND_POINTS} are needed to fit the ground")
    n, d, inliers = fit_plane(points)
    if inliers.sum() < MIN_GROUND_POINTS:
        what = f"{inliers.sum()} of {len(points)} {joints} points lie within {GROUND_INLIER_M} m of one plane"
        raise CalibrationError(f"{path}: {what}: at least {MIN_GROUND_POINTS} are needed to fit the ground")
    if n @ np.mean([c.center for c in rig], axis=0) < d:  # z up toward the cameras
        n, d = -n, -d
    axis = np.cross(n, (0.0, 0.0, 1.0))
    angle = np.arctan2(np.linalg.norm(axis), n[2])
    Q = cv2.Rodrigues(axis / max(np.linalg.norm(axis), 1e-300) * angle)[0]  # n -> z; x_new = Q x + s
    Q = Q if np.linalg.norm(axis) > 1e-12 or n[2] > 0 else np.diag([1.0, -1.0, -1.0])  # n = -z: half a turn
    s = np.array([0.0, 0.0, height - d])
    moved = Rig(tuple(replace(c, R=c.R @ Q.T, t=c.t - c.R @ Q.T @ s) for c in rig))
    residual = 1000 * float(np.sqrt(np.mean((points[inliers] @ n - d) ** 2)))
    fit = GroundFit(joints, len(points), int(inliers.sum()), len(first), residual, float(np.degrees(angle)), s[2])
    return moved, fit
