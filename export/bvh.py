"""BVH per track: a skeleton of the track's own bone lengths rooted at the hip centre, rotations from the 3D joints.

Axes and units: Y up, (X, Y, Z) = (y, z, x) of our z-up world (export/tracks.py), centimetres. The rest pose
(all rotations 0) is a T-pose facing +Z, the person's left on +X, soles flat; each OFFSET is the median, over the
frames where both ends are known, of that bone's length (never known: the synthetic mean body's, data/synthetic).
Hierarchy: the 23 COCO-23 joints and four virtual ones: ``hip_centre`` (root, mid-hip) -> hips -> knees -> ankles
-> big toe -> small toe, and heel; ``spine`` (at the hip centre) -> ``neck`` (mid-shoulder) -> shoulders ->
elbows -> wrists, and ``head`` (at the neck) -> nose -> eyes -> ears. Leaves end in an End Site 0.3 of their bone
beyond. Channels: root Xposition Yposition Zposition, every joint Zrotation Xrotation Yrotation (degrees; intrinsic,
R = Rz Rx Ry maps the joint's frame into its parent's). A joint's world rotation turns its rest bones towards the
observed targets, aimed from where the skeleton puts the joint (so errors do not add up along a chain): a full
frame where it has two (the primary exact, the secondary fixing the roll: hip centre: left hip + neck; neck: left
shoulder + hip centre; ankle: big toe + heel; nose: left eye + right eye), else the smallest rotation (swing, no
twist relative to the parent) onto its one target. On rigid bones the joints come back exactly (the walking test:
< 1 cm); on real ones off by their bone's length change (and the right eye and heel by their triangle's change);
the CLI prints the mean and max distance per file. Gaps are not filled unless --fill: a joint without an observed
target in a frame keeps its rest pose relative to its parent (rotation 0). The root follows the person where the
hip centre is missing (either hip unseen) but other joints are seen: each seen joint j votes for joint - d_j, d_j
its offset from the hip centre linearly interpolated in time between the track's frames where both are known (held
beyond the first and last; never known: the mean body's standing offset), the votes weighted by 1 / (variance of
d_j over those frames + (2 cm)^2) so that the joints that keep their place about the hips (torso, head) lead; the
pelvis then turns with the shoulder line in place of the hips. A frame without any joint of the track holds the
last root (before the first: the first; none ever: the origin), so an absent track stands in a T-pose where it was
last seen.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from data.formats.atomic_io import atomic_write_text
from data.keypoints import JOINT_INDEX
from data.synthetic.body import local_pose, mean_body
from export.tracks import Track, to_y_up, track_path

# "joint parent [primary target [secondary target]]" rows; {s}: the left side, then the right one
_LEG = "{s}_hip hip_centre {s}_knee,{s}_knee {s}_hip {s}_ankle,{s}_ankle {s}_knee {s}_big_toe {s}_heel"
_LEG += ",{s}_big_toe {s}_ankle {s}_small_toe,{s}_small_toe {s}_big_toe,{s}_heel {s}_ankle"
_ARM = "{s}_shoulder neck {s}_elbow,{s}_elbow {s}_shoulder {s}_wrist,{s}_wrist {s}_elbow"
_TRUNK = ("hip_centre - left_hip neck", _LEG, "spine hip_centre neck", "neck spine left_shoulder hip_centre", _ARM)
_HEAD = ("head neck nose", "nose head left_eye right_eye", "{s}_eye nose {s}_ear,{s}_ear {s}_eye")
SKELETON = tuple(  # (joint, parent, primary, secondary), depth-first: the order of the hierarchy and MOTION columns
    (*(None if word == "-" else word for word in row.split()), None, None)[:4]
    for part in _TRUNK + _HEAD
    for side in (("left", "right") if "{s}" in part else ("",))
    for row in part.format(s=side).split(",")
)
NAMES = tuple(j[0] for j in SKELETON)
INDEX = {name: i for i, name in enumerate(NAMES)}
CHILDREN = {name: [j[0] for j in SKELETON if j[1] == name] for name in NAMES}
_X, _Y = np.eye(3)[:2]
_LATERAL, _DOWN = ("hip", "shoulder", "elbow", "wrist", "small_toe", "ear"), ("knee", "ankle", "heel")


def bvh_positions(coco: np.ndarray) -> np.ndarray:
    """The BVH joints' positions from COCO-23 ones in BVH axes: (T, 23, 3) -> (T, J, 3), NaN where unknown."""
    hips = coco[:, [JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]]].mean(axis=1)
    neck = coco[:, [JOINT_INDEX["left_shoulder"], JOINT_INDEX["right_shoulder"]]].mean(axis=1)
    virtual = {"hip_centre": hips, "spine": hips, "neck": neck, "head": neck}
    return np.stack([virtual[n] if n in virtual else coco[:, JOINT_INDEX[n]] for n in NAMES], axis=1)


_TEMPLATE = bvh_positions(to_y_up(local_pose(mean_body(), 0.0, walking=False))[None])[0]  # (J, 3) m, standing


def _length(pos: np.ndarray, a: str, b: str) -> float:
    """Median distance (m) of joints a and b over the frames where both are known; the template's if never."""
    d = np.linalg.norm(pos[:, INDEX[a]] - pos[:, INDEX[b]], axis=-1)
    d = d[np.isfinite(d)]
    return float(np.median(d)) if len(d) else float(np.linalg.norm(_TEMPLATE[INDEX[a]] - _TEMPLATE[INDEX[b]]))


def _angle(a: float, b: float, c: float) -> float:
    """The angle (rad) between sides a and b of a triangle with third side c."""
    return float(np.arccos(np.clip((a * a + b * b - c * c) / max(2 * a * b, 1e-12), -1.0, 1.0)))


def rest_offsets(pos: np.ndarray) -> np.ndarray:
    """Each joint's OFFSET from its parent in the T-pose (m, BVH axes): (T, J, 3) positions -> (J, 3)."""
    direction = {}
    for name in NAMES:  # T-pose; big toe and eyes from their triangles below; spine, neck, head, nose: up
        part, sign = name.removeprefix("left_").removeprefix("right_"), -1.0 if name.startswith("right") else 1.0
        direction[name] = sign * _X if part in _LATERAL else -_Y if part in _DOWN else _Y
    for s in ("left", "right"):
        ankle, toe, heel = f"{s}_ankle", f"{s}_big_toe", f"{s}_heel"
        l_toe, l_heel = _length(pos, ankle, toe), _length(pos, ankle, heel)
        theta = _angle(l_toe, l_heel, _length(pos, toe, heel))  # toe and heel level: a flat sole
        beta = np.arctan2(l_toe - l_heel * np.cos(theta), l_heel * np.sin(theta))
        direction[toe] = np.array([0.0, -np.cos(beta), np.sin(beta)])
        direction[heel] = np.array([0.0, -np.cos(theta - beta), -np.sin(theta - beta)])
    eyes = (_length(pos, "nose", "left_eye"), _length(pos, "nose", "right_eye"), _length(pos, "left_eye", "right_eye"))
    for name, sign in (("left_eye", 1.0), ("right_eye", -1.0)):
        direction[name] = np.array([sign * np.sin(_angle(*eyes) / 2), np.cos(_angle(*eyes) / 2), 0.0])
    return np.array([np.zeros(3) if p is None else _length(pos, n, p) * direction[n] for n, p, *_ in SKELETON])


def _unit(v: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3); zero-length ones become NaN."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotations taking directions u to v: (T, 3), (T, 3) -> (T, 3, 3) (NaN where v is unknown)."""
    u, v = _unit(u), _unit(v)
    axis, cos = np.cross(u, v), (u * v).sum(-1)
    other = np.where(np.abs(u[:, :1]) < 0.9, _X, _Y)  # antiparallel: turn about any axis normal to u
    axis = np.where(np.linalg.norm(axis, axis=-1, keepdims=True) < 1e-9, np.cross(u, other), axis)
    k = np.nan_to_num(_unit(axis))
    skew = np.swapaxes(np.cross(k[:, None, :], np.eye(3)), -1, -2)
    angle = np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), cos)[:, None, None]
    return np.eye(3) + np.sin(angle) * skew + (1 - np.cos(angle)) * skew @ skew


def _basis(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Right-handed frames, columns first, second made normal to it, their cross: (..., 3) x 2 -> (..., 3, 3)."""
    e1 = _unit(first)
    e2 = _unit(second - (second * e1).sum(-1, keepdims=True) * e1)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def solve(pos: np.ndarray, offsets: np.ndarray, root: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (T, J, 3, 3) and FK positions (T, J, 3) of positions (T, J, 3), offsets (J, 3), root (T, 3)."""
    rest = np.zeros_like(offsets)
    for j, (_, parent, *_) in enumerate(SKELETON[1:], 1):
        rest[j] = rest[INDEX[parent]] + offsets[j]
    rot, fk = np.zeros(pos.shape + (3,)), np.zeros_like(pos)
    fk[:, 0] = root
    for j, (_, parent, first, second) in enumerate(SKELETON):
        up = np.broadcast_to(np.eye(3), rot[:, 0].shape) if parent is None else rot[:, INDEX[parent]]
        if parent is not None:
            fk[:, j] = fk[:, INDEX[parent]] + up @ offsets[j]
        rot[:, j] = up  # bones aim from the FK joint at the observed targets: the secondary, then the primary
        bones = [(pos[:, INDEX[t]] - fk[:, j], rest[INDEX[t]] - rest[j]) for t in (second, first) if t]
        if parent is None:  # no hips: the shoulder line (also +X at rest) turns the pelvis
            line = pos[:, INDEX["left_shoulder"]] - pos[:, INDEX["right_shoulder"]]
            bones[1] = (np.where(np.isfinite(bones[1][0]), bones[1][0], line), bones[1][1])
        for seen, bone in bones:
            swing = _swing(up @ bone, seen) @ up
            rot[:, j] = np.where(np.isfinite(swing).all(axis=(1, 2))[:, None, None], swing, rot[:, j])
        if len(bones) == 2:
            frame = _basis(bones[1][0], bones[0][0]) @ _basis(bones[1][1], bones[0][1]).T
            rot[:, j] = np.where(np.isfinite(frame).all(axis=(1, 2))[:, None, None], frame, rot[:, j])
    return rot, fk


def root_positions(pos: np.ndarray) -> np.ndarray:
    """The root (T, 3) of BVH positions (T, J, 3): the hip centre where known; else where the seen joints put it
    (the module docstring); a frame without any seen joint holds the last root (before the first: the first)."""
    coco = [INDEX[n] for n in NAMES if n in JOINT_INDEX]
    root, hip, t = pos[:, 0].copy(), np.isfinite(pos[:, 0]).all(axis=1), np.arange(len(pos))
    votes = np.full((2, len(pos), len(coco), 3), np.nan)  # from the track's own frames, from the mean body
    weight = np.ones((2, len(coco)))
    for i, j in enumerate(coco):
        ref = np.flatnonzero(np.isfinite(pos[:, j]).all(axis=1) & hip)
        votes[1, :, i] = pos[:, j] - (_TEMPLATE[j] - _TEMPLATE[0])
        if len(ref):
            offset = pos[ref, j] - pos[ref, 0]
            votes[0, :, i] = pos[:, j] - np.stack([np.interp(t, ref, offset[:, c]) for c in range(3)], axis=1)
            weight[0, i] = 1 / (offset.var(axis=0).sum() + 0.02**2)
    seen = np.isfinite(votes).all(axis=-1) * weight[:, None]  # (2, T, J)
    with np.errstate(invalid="ignore"):  # frames without a vote: NaN, held below
        own, body = (np.nan_to_num(votes) * seen[..., None]).sum(axis=2) / seen.sum(axis=2)[..., None]
    root[~hip] = np.where(np.isfinite(own), own, body)[~hip]
    ok = np.isfinite(root).all(axis=1)
    if not ok.any():
        return np.zeros_like(root)
    last = np.maximum.accumulate(np.where(ok, t, -1))
    return root[np.where(last < 0, ok.argmax(), last)]


def bvh_text(offsets: np.ndarray, root: np.ndarray, rot: np.ndarray, frame_time: float) -> str:
    """The BVH file (cm) of offsets (J, 3) m, root positions (T, 3) m and world rotations (T, J, 3, 3)."""
    lines = ["HIERARCHY"]

    def joint(name: str, pad: str) -> None:
        root, offset = name == NAMES[0], _row(100 * offsets[INDEX[name]])
        lines.extend([f"{pad}{'ROOT' if root else 'JOINT'} {name}", pad + "{", f"{pad}  OFFSET {offset}"])
        lines.append(
            f"{pad}  CHANNELS {'6 Xposition Yposition Zposition' if root else '3'} Zrotation Xrotation Yrotation"
        )
        for child in CHILDREN[name]:
            joint(child, pad + "  ")
        end_site = [f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET {_row(30 * offsets[INDEX[name]])}", pad + "  }"]
        lines.extend([] if CHILDREN[name] else end_site)
        lines.append(pad + "}")

    joint(NAMES[0], "")
    parents = [0] + [INDEX[p] for _, p, *_ in SKELETON[1:]]
    local = np.swapaxes(rot[:, parents], -1, -2) @ rot
    local[:, 0] = rot[:, 0]
    with warnings.catch_warnings():  # gimbal lock: scipy sets the last angle to 0, the rotation is still exact
        warnings.simplefilter("ignore", UserWarning)
        euler = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(len(rot), -1)
    lines += ["MOTION", f"Frames: {len(rot)}", f"Frame Time: {frame_time:.8f}"]
    lines += [_row(row) for row in np.concatenate([100 * root, euler], axis=1)]
    return "\n".join(lines) + "\n"


def _row(values: np.ndarray) -> str:
    """Numbers (N,) separated by spaces, 4 decimals (no -0)."""
    return " ".join(f"{v:.4f}" for v in np.round(values, 4) + 0.0)


def write_bvh(tracks: list[Track], base: Path, fps: float) -> list[str]:
    """<base>_id<k>.bvh per track; one line per file with its FK distance from the 3D joints."""
    out = []
    for track in tracks:
        pos = bvh_positions(to_y_up(track.xyz))
        offsets = rest_offsets(pos)
        root = root_positions(pos)
        rot, fk = solve(pos, offsets, root)
        path = track_path(base, track, "bvh")
        atomic_write_text(path, bvh_text(offsets, root, rot, track.step / fps))
        error = np.linalg.norm(fk - pos, axis=-1)[:, [INDEX[n] for n in NAMES if n in JOINT_INDEX]]
        error = error[np.isfinite(error)]
        where = f"{100 * error.mean():.2f} cm (max {100 * error.max():.2f})" if len(error) else "- (no joints)"
        out.append(f"wrote {path}: {len(rot)} frames, FK within {where} of the 3D joints")
    return out
