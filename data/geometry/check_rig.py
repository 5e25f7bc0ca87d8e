"""Plausibility checks of a calibrated rig, and of 2D poses against it: ``python -m data.geometry.check_rig
cameras.json [poses2d.json]``."""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import dataclass, replace
from itertools import combinations
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from data.geometry.calibration import CalibrationError, load_rig
from data.geometry.camera import Camera, Rig, fundamental_matrix
from data.geometry.triangulation import reprojection_error, triangulate_dlt
from data.multiview import ViewDetections

_COST_CAP = 1e6  # reprojection errors (in image diagonals) are capped here, so that medians cannot overflow


class RigError(CalibrationError):
    """A calibration whose every result would be garbage (e.g. all cameras at one place)."""


class RigWarning(UserWarning):
    """A calibration or 2D input that loads but looks wrong; the message names camera and likely mistake."""


@dataclass(frozen=True)
class RigTolerances:
    """The tolerances of the rig check."""

    min_baseline_m: float = 0.05  # centres closer than this are one place
    max_centre_distance_m: float = 250.0  # centres farther from the world origin: units other than metres
    ground_clearance_m: float = 0.02  # a centre farther below z = 0 is below the ground plane
    min_camera_height_m: float = 0.3  # a centre lower than this sits on the feet's / ankles' planes
    max_image_up: float = 0.1  # sine of the angle the image's y axis may point up in the world
    scene_margin: float = 0.5  # image sizes the common scene point may lie outside the image
    # a camera is named whose epipolar residual (median distance plus shift, px) against the cameras that fit
    # each other is beyond residual_ratio times theirs: clean rigs give 1.0-1.3 (the example, Shelf), a camera
    # off by 10 px 2.8 or more; min_residual_px keeps noise-free 2D poses from naming sub-pixel differences
    residual_ratio: float = 2.0
    min_residual_px: float = 2.0
    max_residual: float = 0.04  # the best pair's epipolar residual beyond this share of the diagonal: nothing fits
    max_detections: int = 64  # the most confident detections per view and frame the 2D check pairs up
    min_joints: int = 8  # joints two detections must share to be triangulated
    max_frames: int = 20  # frames (evenly spread) the 2D check looks at
    max_axes_condition: float = 1e6  # optical axes closer to parallel have no common point


@dataclass(frozen=True)
class Finding:
    """One result of the check: level "error" or "warning", and a one-line message."""

    level: str
    message: str


def _share(fraction: float) -> str:
    """A reprojection error as a share of the image diagonal, readable for huge values too."""
    return f"{fraction:.1%} of the image diagonal" if fraction < 10 else f"{fraction:.3g} image diagonals"


def _names(cameras: Iterable[Camera]) -> str:
    """'a', 'b', 'c': the camera names quoted."""
    return ", ".join(repr(c.name) for c in cameras)


# --- geometry ---------------------------------------------------------------------------------------
def axes_point(cameras: Sequence[Camera], max_condition: float) -> np.ndarray | None:
    """The point nearest (least squares) to the cameras' optical axes: (3,), None if they are parallel."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        d = cam.R[2]
        M = np.eye(3) - np.outer(d, d)
        A += M
        b += M @ cam.center
    if len(cameras) < 2 or np.linalg.cond(A) > max_condition:
        return None
    return np.linalg.solve(A, b)


def sees_point(cam: Camera, point: np.ndarray, margin: float) -> bool:
    """Whether a world point (3,) is in front of the camera and projects within `margin` image sizes of it."""
    x = cam.R @ point + cam.t
    if x[2] <= 0:
        return False
    uv = (cam.K @ (x / x[2]))[:2]
    size = np.asarray(cam.size, dtype=np.float64)
    return bool(np.all(uv >= -margin * size) and np.all(uv <= (1 + margin) * size))


def sees_ground(cam: Camera, grid: int = 9) -> bool:
    """Whether some pixel of a grid x grid lattice over the (undistorted) image sees z = 0 in front."""
    w, h = cam.size
    u, v = np.meshgrid(np.linspace(0, w, grid), np.linspace(0, h, grid))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    rays = pixels @ np.linalg.inv(cam.K).T @ cam.R  # world directions R^T K^-1 p: (grid^2, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -cam.center[2] / rays[:, 2]
    return bool(np.any(np.isfinite(s) & (s > 0)))


def _about(cams: list[Camera], text: str) -> list[Finding]:
    """One warning naming the cameras ("camera 'a': text", "cameras 'a', 'b': text"); none without cameras."""
    return [Finding("warning", f"camera{'s' if len(cams) > 1 else ''} {_names(cams)}: {text}")] if cams else []


def rig_findings(rig: Rig, tol: RigTolerances = RigTolerances()) -> list[Finding]:
    """The geometric findings of a rig, errors first: cameras at one place, far, low, upside down, looking away."""
    cams = list(rig)
    if len(cams) < 2:
        return [Finding("warning", f"only {len(cams)} camera: nothing can be triangulated")]
    C = np.array([c.center for c in cams])
    dist = np.linalg.norm(C[:, None] - C[None], axis=-1)
    if dist.max() < tol.min_baseline_m:
        where = f"({C[0, 0]:.3g}, {C[0, 1]:.3g}, {C[0, 2]:.3g}) (within {tol.min_baseline_m} m)"
        what = "no baseline, nothing can be triangulated (R and t copied from one camera?)"
        return [Finding("error", f"all {len(cams)} cameras have their centre at {where}: {what}")]
    out = []
    for a, b in zip(*np.nonzero(np.triu(dist < tol.min_baseline_m, 1))):
        same = all(np.array_equal(getattr(cams[a], k), getattr(cams[b], k)) for k in ("K", "R", "t"))
        what = "have identical calibrations" if same else "share their centre"
        why = f"({dist[a, b]:.3g} m apart): that view pair cannot triangulate (one camera copied under two names?)"
        out.append(Finding("warning", f"cameras {cams[a].name!r} and {cams[b].name!r} {what} {why}"))
    return out + _placement_findings(cams, C, tol) + _scene_findings(cams, tol)


def _placement_findings(cams: list[Camera], C: np.ndarray, tol: RigTolerances) -> list[Finding]:
    """Cameras far from the origin, below or on the ground, upside down, or not seeing the ground; C (V, 3)."""
    out = []
    far = [c for c, d in zip(cams, np.linalg.norm(C, axis=1)) if d > tol.max_centre_distance_m]
    if far:
        with np.errstate(over="ignore"):
            d = np.minimum(np.linalg.norm([c.center for c in far], axis=1), np.finfo(np.float64).max)
        span = f"{d.min():.4g}{f'-{d.max():.4g}' if d.max() > d.min() * 1.001 else ''}"
        out += _about(
            far,
            f"centre {span} m from the world origin (more than {tol.max_centre_distance_m:g} m): is t in "
            f"millimetres or centimetres? cameras.json wants metres",
        )
    below = [c for c in cams if c.center[2] < -tol.ground_clearance_m]
    out += _about(
        below,
        "centre below the ground plane z = 0 (the world must be z up with the floor at z = 0; y up or R transposed?)",
    )
    on = [c for c in cams if -tol.ground_clearance_m <= c.center[2] < tol.min_camera_height_m]
    out += _about(
        on,
        f"centre at z = {min((c.center[2] for c in on), default=0.0):.3g} m, on or just above the ground plane "
        f"(below {tol.min_camera_height_m} m): the feet matcher cannot place feet seen from the planes of the feet "
        f"and ankles and drops them",
    )
    out += _about(
        [c for c in cams if c.R[1, 2] > tol.max_image_up],
        "the image's y axis points up in the world (upside down? R transposed, or the world's z axis pointing down?)",
    )
    out += _about(
        [c for c in cams if c.center[2] >= tol.min_camera_height_m and not sees_ground(c)],
        "the ground plane z = 0 is nowhere in the image (looking up? R transposed?); the feet matcher needs the "
        "floor in front of the cameras",
    )
    return out


def _scene_findings(cams: list[Camera], tol: RigTolerances) -> list[Finding]:
    """Cameras that do not see the common scene of the others (the point nearest to their optical axes)."""
    cams = [c for c in cams if np.linalg.norm(c.center) <= tol.max_centre_distance_m]  # flagged already
    if len(cams) == 2:
        point = axes_point(cams, tol.max_axes_condition)
        if point is not None and not all(sees_point(c, point, tol.scene_margin) for c in cams):
            what = "(their optical axes meet behind or beside them): R transposed or of another camera?"
            return [Finding("warning", f"cameras {_names(cams)} do not look at a common region {what}")]
        return []
    lost = []
    for i, cam in enumerate(cams):
        point = axes_point(cams[:i] + cams[i + 1 :], tol.max_axes_condition)
        if point is not None and not sees_point(cam, point, tol.scene_margin):
            lost.append(cam)
    if lost and len(lost) == len(cams):
        what = "(every camera misses the point the others look at): R camera -> world instead of world -> camera?"
        return [Finding("warning", f"the cameras do not look at a common region {what}")]
    return _about(
        lost,
        "not looking at the common scene of the other cameras (R transposed, camera -> world, or of another camera?)",
    )


# --- 2D poses against the rig ------------------------------------------------------------------------
def _nanmedian_rows(x: np.ndarray) -> np.ndarray:
    """np.nanmedian(x, axis=1) of (P, n) -> (P,), nan for all-nan rows: 5x faster than numpy's on small rows."""
    x = np.sort(x, axis=1)  # nan last
    n = np.count_nonzero(~np.isnan(x), axis=1)
    lo = np.take_along_axis(x, np.maximum(n - 1, 0)[:, None] // 2, 1)[:, 0]
    hi = np.take_along_axis(x, n[:, None] // 2, 1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, (lo + hi) / 2, np.nan)


def _pair_costs(cam_a: Camera, cam_b: Camera, kp_a: np.ndarray, kp_b: np.ndarray, min_joints: int) -> np.ndarray:
    """Median reprojection error / image diagonal of detection pairs (Na, 23, 3), (Nb, 23, 3) -> (Na, Nb), or inf."""
    Na, Nb, J = len(kp_a), len(kp_b), kp_a.shape[1]
    ua = np.concatenate([cam_a.undistort_points(kp_a[..., :2]), kp_a[..., 2:]], -1)
    ub = np.concatenate([cam_b.undistort_points(kp_b[..., :2]), kp_b[..., 2:]], -1)
    both = (ua[:, None, :, 2] > 0) & (ub[None, :, :, 2] > 0)  # (Na, Nb, J)
    poses = np.zeros((2, Na, Nb, J, 3))
    poses[0, ..., :2], poses[1, ..., :2] = ua[:, None, :, :2], ub[None, :, :, :2]
    poses[..., 2] = both
    poses = poses.reshape(2, Na * Nb, J, 3)
    proj = np.stack([cam_a.P, cam_b.P])
    with np.errstate(all="ignore"):
        X = triangulate_dlt(poses, proj)
        err = reprojection_error(X, poses, proj)  # (2, P, J)
        front = (cam_a.depth(X[..., :3]) > 0) & (cam_b.depth(X[..., :3]) > 0)
    diag = np.array([np.hypot(*cam_a.size), np.hypot(*cam_b.size)])[:, None, None]
    err = np.where(front[None], err / diag, np.inf)
    err = np.where(both.reshape(1, Na * Nb, J), err, np.nan)
    cost = _nanmedian_rows(np.concatenate([err[0], err[1]], axis=1)).reshape(Na, Nb)
    cost = np.minimum(np.nan_to_num(cost, nan=np.inf), _COST_CAP)
    return np.where(both.sum(-1) >= min_joints, cost, np.inf)


def _mutual_best(cost: np.ndarray) -> np.ndarray:
    """Index pairs (a, b) of the mutual best, finite entries of a (Na, Nb) cost matrix: (M, 2)."""
    a_best, b_best = np.argmin(cost, axis=1), np.argmin(cost, axis=0)
    keep = [(a, b) for a, b in enumerate(a_best) if b_best[b] == a and np.isfinite(cost[a, b])]
    return np.array(keep, dtype=int).reshape(-1, 2)


def _frames(views_by_frame: Mapping[int, list[ViewDetections]], tol: RigTolerances) -> list[list[np.ndarray]]:
    """Keypoints (n, 23, 3) per view of <= max_frames frames spread evenly, n <= max_detections highest-scored."""
    keys = sorted(views_by_frame)
    pick = np.unique(np.linspace(0, len(keys) - 1, min(tol.max_frames, len(keys))).round().astype(int)) if keys else []
    cut = [views_by_frame[keys[i]] for i in pick]
    return [[d.keypoints[np.argsort(-d.scores, kind="stable")[: tol.max_detections]] for d in f] for f in cut]


def epipolar_residuals(cam_a: Camera, cam_b: Camera, kp_a: np.ndarray, kp_b: np.ndarray, min_joints: int) -> np.ndarray:
    """Signed epipolar distances (px) of the joints of mutual best pairs of (Na, 23, 3), (Nb, 23, 3) -> (n,)."""
    pairs = _mutual_best(_pair_costs(cam_a, cam_b, kp_a, kp_b, min_joints))
    ka, kb = kp_a[pairs[:, 0]], kp_b[pairs[:, 1]]
    both = (ka[..., 2] > 0) & (kb[..., 2] > 0)
    xa, xb = (
        np.hstack([c.undistort_points(k[both][:, :2]), np.ones((both.sum(), 1))]) for c, k in ((cam_a, ka), (cam_b, kb))
    )
    F = fundamental_matrix(cam_a, cam_b)
    line_b, line_a = xa @ F.T, xb @ F  # each joint's epipolar line in the other view
    with np.errstate(all="ignore"):  # a joint at an epipole has no line
        d = 0.5 * np.sum(xb * line_b, axis=1) * (1 / np.hypot(*line_b[:, :2].T) + 1 / np.hypot(*line_a[:, :2].T))
    return d[np.isfinite(d)]


def pair_fit(
    cam_a: Camera, cam_b: Camera, frames: list[list[np.ndarray]], a: int, b: int, tol: RigTolerances
) -> np.ndarray:
    """Views a, b's epipolar (median distance, |median signed distance|) px, (2,); nan: no detections, inf: none fit."""
    shared = [f for f in frames if len(f[a]) and len(f[b])]
    d = np.concatenate([epipolar_residuals(cam_a, cam_b, f[a], f[b], tol.min_joints) for f in shared] or [[]])
    if not len(d):
        return np.full(2, np.inf if shared else np.nan)
    return np.array([np.median(np.abs(d)), abs(np.median(d))])


def _median(fits: Iterable[np.ndarray]) -> np.ndarray:
    """The medians of (residual, shift) pairs, nan ones left out: (2,), nan without any."""
    fits = np.reshape(np.array(list(fits)), (-1, 2))
    fits = fits[~np.isnan(fits[:, 0])]
    return np.median(fits, axis=0) if len(fits) else np.full(2, np.nan)


def _fit_matrix(cams: list[Camera], frames: list[list[np.ndarray]], tol: RigTolerances) -> np.ndarray:
    """pair_fit of every view pair: (V, V, 2), nan on the diagonal."""
    M = np.full((len(cams), len(cams), 2), np.nan)
    for a, b in combinations(range(len(cams)), 2):
        M[a, b] = M[b, a] = pair_fit(cams[a], cams[b], frames, a, b, tol)
    return M


def _fitting_group(M: np.ndarray, tol: RigTolerances) -> tuple[list[int], float]:
    """The cameras that fit each other, grown from the best pair, and the limit (px) a camera joins within."""
    score = np.nan_to_num(M.sum(-1), nan=np.inf)
    good = [int(i) for i in np.unravel_index(np.argmin(score), score.shape)]
    while True:
        limit = max(tol.residual_ratio * _median(M[a, b] for a, b in combinations(good, 2)).sum(), tol.min_residual_px)
        fits = {v: np.nan_to_num(_median(M[v, good]).sum(), nan=np.inf) for v in range(len(M)) if v not in good}
        join = min(fits, key=fits.__getitem__, default=None)
        if join is None or fits[join] > limit:
            return good, limit
        good.append(join)


def _fixes(cams: list[Camera], frames: list[list[np.ndarray]], v: int) -> list[tuple[str, list, list]]:
    """Candidate fixes of camera v: (what was wrong, the cameras and the frames with it undone)."""
    cam, (w, h) = cams[v], cams[v].size
    R, t = cam.R, cam.t
    fixed = [
        ("R is transposed (give world -> camera)", replace(cam, R=R.T)),
        ("R, t are the camera -> world pose (invert them)", replace(cam, R=R.T, t=-R.T @ t)),
        ("t is in millimetres (metres expected)", replace(cam, t=t / 1000.0)),
        ("t is in centimetres (metres expected)", replace(cam, t=t / 100.0)),
    ]
    redone = [
        ("its 2D poses are upside down (y from the image bottom)", lambda f: f[v] * [1, -1, 1] + [0, h, 0]),
        ("its 2D poses are mirrored (x from the image right)", lambda f: f[v] * [-1, 1, 1] + [w, 0, 0]),
        ("its 2D poses have x and y swapped", lambda f: f[v][..., [1, 0, 2]]),
    ]
    redone += [
        (f"its 2D poses are {c.name!r}'s (names swapped)", lambda f, u=u: f[u]) for u, c in enumerate(cams) if u != v
    ]
    return [(what, cams[:v] + [c] + cams[v + 1 :], frames) for what, c in fixed] + [
        (what, cams, [f[:v] + [fn(f)] + f[v + 1 :] for f in frames]) for what, fn in redone
    ]


def _diagnose(
    cams: list[Camera], frames: list[list[np.ndarray]], v: int, good: list[int], limit: float, tol: RigTolerances
) -> str:
    """The fixes that make camera v's 2D poses fit the good cameras, in words; the usual causes without one."""
    fit = [
        what
        for what, c, f in _fixes(cams, frames, v)
        if _median(pair_fit(c[v], c[u], f, v, u, tol) for u in good).sum() <= limit
    ]
    if fit:
        return f"likely {' or '.join(fit)}{' (the 2D poses fit each)' if len(fit) > 1 else ''}"
    what = "K (principal point), R and t, and its 2D poses for a shift (crop, padding), a flip, or another camera's"
    return f"no single fix makes it fit: check {what}"


def _exchanged(cams: list[Camera], frames: list[list[np.ndarray]], M: np.ndarray, tol: RigTolerances) -> list[Finding]:
    """The camera pairs whose 2D poses, exchanged, cut the rig's median residual residual_ratio-fold."""
    pairs = np.triu_indices(len(cams), 1)
    before, fit = _median(M[pairs]).sum(), []
    for a, b in combinations(range(len(cams)), 2):
        order = [b if u == a else a if u == b else u for u in range(len(cams))]
        after = _median(_fit_matrix(cams, [[f[u] for u in order] for f in frames], tol)[pairs]).sum()
        fit += [f"{cams[a].name!r} and {cams[b].name!r}"] if after * tol.residual_ratio < before else []
    if not fit or before <= tol.min_residual_px:
        return []
    what = f"the 2D poses fit no camera pair well (median epipolar residual {before:.1f} px) but do with those of"
    which = " (the rig is symmetric: each fits)" if len(fit) > 1 else ""
    return [Finding("warning", f"{what} cameras {' or '.join(fit)} exchanged{which}: camera names swapped?")]


def pose_findings(
    rig: Rig,
    views_by_frame: Mapping[int, list[ViewDetections]],
    tol: RigTolerances = RigTolerances(),
    offsets: Mapping[str, int] | None = None,
) -> list[Finding]:
    """Cameras whose 2D poses {frame: V ViewDetections (N, 23, 3)} do not fit the others' (or do shifted in time,
    ``offsets`` the frame offsets already applied), with the fixes."""
    from data.geometry.sync_check import sync_findings  # it builds on this module's residuals

    cams, frames = list(rig), _frames(views_by_frame, tol)
    M = _fit_matrix(cams, frames, tol)
    if len(cams) < 2 or np.isnan(M).all():
        return []
    good, limit = _fitting_group(M, tol)
    best = M[good[0], good[1]].sum() / np.hypot(*cams[good[0]].size)
    if not best <= tol.max_residual:
        what = f"median epipolar residual {_share(best)} or more, more than {tol.max_residual:.0%}"
        why = "t in other units, R camera -> world, or the 2D poses of another rig?"
        return [Finding("warning", f"the 2D poses fit no camera pair ({what}): {why}")]
    shifted = sync_findings(cams, views_by_frame, tol, offsets)  # {view: finding}: its misfit is a time shift
    bad = [v for v in range(len(cams)) if v not in good and v not in shifted and _median(M[v, good]).sum() > limit]
    if not bad and not shifted and len(cams) == 3:  # exchanged 2D poses spoil every pair of 3 cameras
        return _exchanged(cams, frames, M, tol)
    (gr, gs), out = _median(M[a, b] for a, b in combinations(good, 2)), []
    for v in bad:
        (r, s), them = _median(M[v, good]), _names(cams[u] for u in good)
        fit = f"median epipolar residual {r:.1f} px, shifted {s:.1f} px to one side; {them}: {gr:.1f} px, {gs:.1f} px"
        what = f"its 2D poses do not fit the other cameras' ({fit}): {_diagnose(cams, frames, v, good, limit, tol)}"
        out.append(Finding("warning", f"camera {cams[v].name!r}: {what}"))
    return out + list(shifted.values())


# --- running the check --------------------------------------------------------------------------------
def check_rig(
    rig: Rig,
    path: str | Path,
    views_by_frame: Mapping[int, list[ViewDetections]] | None = None,
    tol: RigTolerances = RigTolerances(),
    warn: bool = True,
    offsets: Mapping[str, int] | None = None,
) -> list[Finding]:
    """The findings (2D ones with views_by_frame, shifted by offsets); RigError on the first error, the warnings as
    RigWarning if warn."""
    findings = rig_findings(rig, tol)
    for f in findings:
        if f.level == "error":
            raise RigError(f"{path}: {f.message}")
    if views_by_frame is not None:
        findings += pose_findings(rig, views_by_frame, tol, offsets)
    if warn:
        for f in findings:
            warnings.warn(f"{path}: {f.message}", RigWarning, stacklevel=2)
    return findings


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: print every finding in one line each; exit status 1 on an error, else 0."""
    parser = argparse.ArgumentParser(prog="python -m data.geometry.check_rig", description=__doc__.split("\n")[0])
    parser.add_argument("cameras", help="cameras.json or any calibration load_rig reads")
    parser.add_argument("poses2d", nargs="?", help="poses2d.json to check against the calibration")
    args = parser.parse_args(argv)
    from data.formats.poses2d_io import read_poses2d  # data imports reconstruction: keep the module import light

    try:
        rig = load_rig(args.cameras, check=False)
        findings = rig_findings(rig)
        errors = [f for f in findings if f.level == "error"]
        if args.poses2d and not errors:
            views = read_poses2d(args.poses2d, rig.names, [c.size for c in rig])
            findings += pose_findings(rig, views)
    except (ValueError, OSError) as err:  # CalibrationError and Poses2DError are ValueErrors
        print(f"error: {err}", file=sys.stderr)
        return 1
    for f in findings:
        print(f"{f.level}: {args.cameras}: {f.message}")
    errors = sum(f.level == "error" for f in findings)
    print(
        f"{args.cameras}: {len(rig)} cameras{f', {args.poses2d}' if args.poses2d else ''}: {errors} errors, "
        f"{len(findings) - errors} warnings"
    )
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
