"""Compiled (numba) loops of the tracker (tracker.py): the association's distances and the hit tracks' updates."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

_JIT = {"cache": True, "error_model": "numpy"}
MAD_TO_SD = 1.4826  # SD of a normal distribution per median absolute deviation


class Filters(NamedTuple):
    """The tracker's constants; variances in m^2."""

    unseen_var: float  # of a joint no view sees
    q: float  # process variance
    r2: float  # measurement variance
    rate: float  # the smoother's least rate
    floor2: float  # the smoother's process floor^2
    q0: float  # a new joint's process variance
    min_hits: int
    refresh: int  # hits between skeleton updates


class Bodies(NamedTuple):
    """The association's two sides: guesses (T, J, 3), seen (T, J); poses (P, J, 4), valid (P, J)."""

    guess: np.ndarray
    seen: np.ndarray
    poses3d: np.ndarray
    valid: np.ndarray
    core: np.ndarray  # (J,) the head and trunk joints


class Hits(NamedTuple):
    """One frame's hits: tracks (K,) of the state hit by persons (K,) of poses (P, J, 4)."""

    frame: int
    tracks: np.ndarray
    persons: np.ndarray
    poses3d: np.ndarray
    variance: np.ndarray  # (P, J) m^2
    lengths: np.ndarray  # (P, L) m
    out: np.ndarray  # (P, J, 4) takes the smoothed joints of confirmed tracks where smooth
    smooth: bool


@njit(**_JIT)
def centres(points: np.ndarray, ok: np.ndarray, core: np.ndarray) -> np.ndarray:
    """Mean of the ok head and trunk joints (else all ok): points (N, J, >= 3), ok (N, J), core (J,) -> (N, 3)."""
    N, J = ok.shape
    out = np.empty((N, 3))
    for i in range(N):
        any_core = False
        for j in range(J):
            any_core |= ok[i, j] and core[j]
        n = 0
        for j in range(J):
            n += ok[i, j] and (core[j] or not any_core)
        for c in range(3):
            s = 0.0
            for j in range(J):
                use = ok[i, j] and (core[j] or not any_core)
                v = points[i, j, c] if use else 0.0
                s = v if j == 0 else s + v
            out[i, c] = s / max(n, 1)
    return out


@njit(**_JIT)
def _mean_distance(bodies: Bodies, t: int, p: int, core_only: bool) -> float:
    """Mean distance (m) of guess t and pose p over the joints both have (the head and trunk ones if core_only)."""
    a, a_ok, b, b_ok = bodies.guess[t], bodies.seen[t], bodies.poses3d[p], bodies.valid[p]
    total, n = 0.0, 0
    for j in range(len(a_ok)):
        if (bodies.core[j] or not core_only) and a_ok[j] and b_ok[j]:
            dx, dy, dz = a[j, 0] - b[j, 0], a[j, 1] - b[j, 1], a[j, 2] - b[j, 2]
            total += np.sqrt(dx * dx + dy * dy + dz * dz)
            n += 1
    return total / n if n else np.inf


@njit(**_JIT)
def _pair_distance(bodies: Bodies, t: int, p: int) -> float:
    """Mean distance (m) of guess t and pose p over the head and trunk joints both have (all where they share none)."""
    d = _mean_distance(bodies, t, p, True)
    return d if np.isfinite(d) else _mean_distance(bodies, t, p, False)


@njit(**_JIT)
def pair_mean_distances(bodies: Bodies, rows: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """out[rows, cols] (T, P) = the pair distances of the pairs (K,) x2 of guesses and poses."""
    for k in range(len(rows)):
        out[rows[k], cols[k]] = _pair_distance(bodies, rows[k], cols[k])


@njit(**_JIT)
def near_mean_distances(bodies: Bodies, ca: np.ndarray, cb: np.ndarray, radius: float, out: np.ndarray) -> None:
    """out (T, P) = the pair distances where finite centres ca (T, 3), cb (P, 3) lie within radius (one pass)."""
    for t in range(len(ca)):
        if not (np.isfinite(ca[t, 0]) and np.isfinite(ca[t, 1]) and np.isfinite(ca[t, 2])):
            continue
        for p in range(len(cb)):
            if not (np.isfinite(cb[p, 0]) and np.isfinite(cb[p, 1]) and np.isfinite(cb[p, 2])):
                continue
            dx, dy, dz = ca[t, 0] - cb[p, 0], ca[t, 1] - cb[p, 1], ca[t, 2] - cb[p, 2]
            if np.sqrt(dx * dx + dy * dy + dz * dz) <= radius:
                out[t, p] = _pair_distance(bodies, t, p)


@njit(**_JIT)
def _maximum(a: float, b: float) -> float:
    """np.maximum of two floats (NaN if either is)."""
    return a if a >= b or np.isnan(a) else b


@njit(**_JIT)
def smooth_joints(st: tuple, t: int, pose: np.ndarray, variance: np.ndarray, dt: float, f: Filters) -> None:
    """Adaptive random-walk smoother of track t's joints in place, with pose (J, 4), variances (J,) after dt frames."""
    sx, sp, sq = st.sx[t], st.sp[t], st.sq[t]
    rate = _maximum(f.rate, 1.0 / st.hits[t])
    for j in range(len(sp)):
        obs = pose[j, 3] > 0
        fresh, upd = obs and not st.seen[t, j], obs and st.seen[t, j]
        var = variance[j]
        moving = var >= f.unseen_var  # a joint no view fixes moves on with the motion filter's velocity
        x0 = sx[j, 0] + dt * (st.velocity[t, j, 0] if moving else 0.0)
        x1 = sx[j, 1] + dt * (st.velocity[t, j, 1] if moving else 0.0)
        x2 = sx[j, 2] + dt * (st.velocity[t, j, 2] if moving else 0.0)
        i0, i1, i2 = pose[j, 0] - x0, pose[j, 1] - x1, pose[j, 2] - x2
        q = sq[j]
        if upd:
            excess = (i0 * i0 + i1 * i1 + i2 * i2) / 3 - sp[j] - var
            q = (1 - rate) * q + rate * _maximum(excess, f.floor2)
        p = sp[j] + dt * q
        gain = p / (p + var)
        if upd:
            sx[j, 0], sx[j, 1], sx[j, 2] = x0 + gain * i0, x1 + gain * i1, x2 + gain * i2
            sp[j] = (1 - gain) * p
        elif fresh:
            sx[j, 0], sx[j, 1], sx[j, 2] = pose[j, 0], pose[j, 1], pose[j, 2]
            sp[j] = var
        else:
            sx[j, 0], sx[j, 1], sx[j, 2] = x0, x1, x2
            sp[j] = p
        sq[j] = f.q0 if fresh else q


@njit(**_JIT)
def kalman_joints(st: tuple, t: int, pose: np.ndarray, variance: np.ndarray, dt: float, f: Filters) -> None:
    """Constant-velocity Kalman predict and update of track t's joints in place with pose (J, 4), variances (J,)."""
    position, velocity, p00, p01, p11 = st.position[t], st.velocity[t], st.p00[t], st.p01[t], st.p11[t]
    a00, a01, a11 = 2 * dt, dt**2, f.q * dt**4 / 4
    b01, c11 = f.q * dt**3 / 2, f.q * dt**2
    for j in range(len(p00)):
        c00 = p00[j] + a00 * p01[j] + a01 * p11[j] + a11
        c01 = p01[j] + dt * p11[j] + b01
        d11 = p11[j] + c11
        obs = pose[j, 3] > 0 and variance[j] < f.unseen_var  # a joint no view fixes is no measurement
        upd, new = obs and st.seen[t, j], obs and not st.seen[t, j]
        k0, k1 = c00 / (c00 + f.r2), c01 / (c00 + f.r2)
        for c in range(3):
            x = position[j, c] + dt * velocity[j, c]
            innov = pose[j, c] - x
            position[j, c] = x + k0 * innov if upd else (pose[j, c] if new else x)
            if upd:
                velocity[j, c] = velocity[j, c] + k1 * innov
        st.live[t, j] = obs
        p00[j] = (1 - k0) * c00 if upd else c00
        p11[j] = d11 - k1 * c01 if upd else d11
        p01[j] = (1 - k0) * c01 if upd else c01
        st.seen[t, j] = st.seen[t, j] or obs


@njit(**_JIT)
def _select(buf: np.ndarray, m: int, k: int) -> float:
    """The k-th smallest of buf[:m] (no NaN), buf reordered so that buf[k + 1:m] holds none smaller (quickselect)."""
    lo, hi = 0, m - 1
    while lo < hi:
        pivot, i, j = buf[(lo + hi) // 2], lo, hi
        while i <= j:
            while buf[i] < pivot:
                i += 1
            while buf[j] > pivot:
                j -= 1
            if i <= j:
                buf[i], buf[j] = buf[j], buf[i]
                i, j = i + 1, j - 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return buf[k]


@njit(**_JIT)
def _sorted_median(values: np.ndarray, count: int, lo: int, hi: int, buf: np.ndarray) -> float:
    """0.5 (s[lo] + s[hi]) of values (W,) sorted NaN last (NaN if count is 0), without sorting; buf (W,) scratch."""
    m = 0
    for v in values:
        if not np.isnan(v):
            buf[m] = v
            m += 1
    if count == 0 or hi >= m:  # numpy's pick would be a NaN
        return np.nan
    low = _select(buf, m, lo)
    high = low
    if hi > lo:
        high = buf[lo + 1]
        for i in range(lo + 2, m):
            high = buf[i] if buf[i] < high else high
    return 0.5 * (low + high)


@njit(**_JIT)
def robust_skeleton(bones: np.ndarray, median: np.ndarray, se: np.ndarray, count: np.ndarray, buf: np.ndarray) -> None:
    """One track's robust bone lengths from bones (W, L): median, standard error se, count (L,); buf (2, W) scratch."""
    W, L = bones.shape
    for b in range(L):
        n = 0
        for w in range(W):
            n += np.isfinite(bones[w, b])
        lo, hi = max(n - 1, 0) // 2, min(n // 2, max(W - 1, 0))
        for w in range(W):  # the column into a contiguous row: one type of _sorted_median to compile
            buf[1, w] = bones[w, b]
        m = _sorted_median(buf[1], n, lo, hi, buf[0])
        for w in range(W):
            buf[1, w] = np.abs(bones[w, b] - m)
        mad = _sorted_median(buf[1], n, lo, hi, buf[0])
        sd = MAD_TO_SD * mad if n > 1 else np.nan
        median[b], count[b] = m, n
        se[b] = sd / np.sqrt(max(n, 1)) if np.isfinite(sd) else np.inf


@njit(**_JIT)
def correct_tracks(st: tuple, h: Hits, f: Filters) -> None:
    """Each hit track's smoother, motion filter, bone window and robust skeleton, in place in st (a TrackState)."""
    bones = st.bones
    buf = np.empty((2, bones.shape[1]))
    for k in range(len(h.tracks)):
        t, p = h.tracks[k], h.persons[k]
        dt = float(h.frame - st.last_frame[t])
        smooth_joints(st, t, h.poses3d[p], h.variance[p], dt, f)
        kalman_joints(st, t, h.poses3d[p], h.variance[p], dt, f)
        st.last_frame[t] = h.frame
        st.hits[t] += 1
        st.confirmed[t] |= st.hits[t] >= f.min_hits
        for b in range(bones.shape[2]):  # element-wise: an array assignment compiles numba's broadcasting
            bones[t, st.slot[t], b] = h.lengths[p, b]
        st.slot[t] = (st.slot[t] + 1) % bones.shape[1]
        if st.hits[t] % f.refresh == 0:
            robust_skeleton(bones[t], st.skel_median[t], st.skel_se[t], st.skel_count[t], buf)
        if h.smooth and st.confirmed[t]:
            for j in range(h.poses3d.shape[1]):
                if h.poses3d[p, j, 3] > 0:
                    h.out[p, j, 0], h.out[p, j, 1], h.out[p, j, 2] = st.sx[t, j, 0], st.sx[t, j, 1], st.sx[t, j, 2]
