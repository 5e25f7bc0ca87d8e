"""The rig check's sync part: cameras whose 2D poses fit the others' best shifted by a few frames."""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations
from typing import Mapping

import numpy as np

from data.geometry.camera import Camera
from data.geometry.check_rig import Finding, RigTolerances, _frames, epipolar_residuals
from data.multiview import ViewDetections


@dataclass(frozen=True)
class SyncTolerances:
    """The tolerances of the sync check."""

    max_shift: int = 5  # shifts tried, frames either way
    window: int = 60  # the first frames of the file looked at
    max_pairings: int = 2000  # camera pairs x shifts x frames (of the window, evenly spread, >= 2): the cost
    ratio: float = 1.5  # the best shift's median residual at most 1 / ratio of the unshifted one
    min_joints: int = 50  # matched joints each of the two medians rests on


def _table(cams: list[Camera], kps: dict[int, list[np.ndarray]], base: list[int], tol: RigTolerances, s: int) -> dict:
    """|Epipolar residuals| (n,) px of camera a's frame f + d against b's frame f, f in base: {(a, b, d): residuals}."""
    out = {}
    for (a, b), d in ((pair, d) for pair in combinations(range(len(cams)), 2) for d in range(-s, s + 1)):
        got = [
            epipolar_residuals(cams[a], cams[b], kps[f + d][a], kps[f][b], tol.min_joints)
            for f in base
            if f + d in kps and len(kps[f + d][a]) and len(kps[f][b])
        ]
        out[a, b, d] = out[b, a, -d] = np.abs(np.concatenate(got or [[]]))
    return out


def _fit(table: dict, v: int, others: list[int], d: int) -> tuple[float, int]:
    """Camera v's median residual (px) shifted by d against the others, and the joints it rests on."""
    pooled = np.concatenate([table[v, u, d] for u in others] or [[]])
    return (float(np.median(pooled)), len(pooled)) if len(pooled) else (np.inf, 0)


def _shift(table: dict, v: int, others: list[int], s: int, tol: RigTolerances, sync: SyncTolerances) -> tuple:
    """(ratio unshifted / best, best shift d, both residuals) of camera v, or None when the rule does not hold."""
    fits = {d: _fit(table, v, others, d) for d in range(-s, s + 1)}
    d = min((d for d in fits if fits[d][1] >= sync.min_joints), key=lambda d: fits[d][0], default=0)
    (r0, n0), (rd, _) = fits[0], fits[d]
    if d == 0 or n0 < sync.min_joints or r0 < max(sync.ratio * rd, tol.min_residual_px):
        return None
    return r0 / max(rd, 1e-9), d, r0, rd


def sync_findings(
    cams: list[Camera],
    views_by_frame: Mapping[int, list[ViewDetections]],
    tol: RigTolerances = RigTolerances(),
    offsets: Mapping[str, int] | None = None,
    sync: SyncTolerances = SyncTolerances(),
) -> dict[int, Finding]:
    """{view: warning} for the cameras whose 2D poses {frame: V ViewDetections} fit the others' best shifted."""
    s, keys = sync.max_shift, sorted(views_by_frame)[: sync.window]
    frames = max(sync.max_pairings // (len(cams) * (len(cams) - 1) // 2 * (2 * s + 1)), 2)
    base = keys[:: -(-len(keys) // frames)] if keys else []
    used = sorted({f + d for f in base for d in range(-s, s + 1)} & set(views_by_frame))
    kps = dict(zip(used, _frames({f: views_by_frame[f] for f in used}, replace(tol, max_frames=len(used)))))
    table, out = _table(cams, kps, base, tol, s), {}
    while len(cams) - len(out) >= 2:  # the worst camera first, then the others against the cameras left
        left = [u for u in range(len(cams)) if u not in out]
        found = {v: _shift(table, v, [u for u in left if u != v], s, tol, sync) for v in left}
        found = {v: f for v, f in found.items() if f is not None}
        if not found:
            break
        v = max(found, key=lambda v: found[v][0])
        out[v] = _warning(cams[v].name, *found[v][1:], offsets or {})
    return out


def _warning(name: str, d: int, r0: float, rd: float, offsets: Mapping[str, int]) -> Finding:
    """The one-line warning of a camera whose frame f + d fits the others' frame f, with the offsets that fix it."""
    given = {str(k): int(n) for k, n in offsets.items()}
    fix = ", ".join(f"{k}: {n}" for k, n in {**given, name: given.get(name, 0) + d}.items())
    fit = f"median epipolar residual {rd:.1f} px, {r0:.1f} px unshifted"
    where = f"its frame f {'+-'[d < 0]} {abs(d)} fits the other cameras' frame f ({fit})"
    return Finding("warning", f'camera {name!r}: out of sync by {abs(d)} frames? {where}: "dataset.offsets={{{fix}}}"')
