"""Compiled loops of the evidence matcher: the chi-square of every detection pair of the view pairs of a
frame, and the complete-linkage merge.

Each pair's body evidence is a sum over the joints both detections see of the Sampson distance to the
epipolar geometry, added to the feet term; the loop stops as soon as a pair cannot pass its gate any
more, so unrelated pairs (most of a crowd's) cost one or two joints each, and only the pairs that pass
are returned (a crowd's view pair has ~1 per detection, not Na x Nb).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _popcount(x: np.int64) -> int:
    """Number of set bits of a non-negative 64-bit integer."""
    x = x - ((x >> 1) & 0x5555555555555555)
    x = (x & 0x3333333333333333) + ((x >> 2) & 0x3333333333333333)
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0F
    return int((x * 0x0101010101010101) >> 56) & 0xFF


@njit(cache=True)
def _masks(var: np.ndarray) -> np.ndarray:
    """Bit masks of the usable joints (var > 0) of every detection, 62 joints per word: (N, J) -> (N, W) int64."""
    N, J = var.shape
    out = np.zeros((N, (J + 61) // 62), dtype=np.int64)
    for i in range(N):
        for k in range(J):
            if var[i, k] > 0.0:
                out[i, k // 62] |= np.int64(1) << (k % 62)
    return out


@njit(cache=True, inline="always")
def _common(masks: np.ndarray, i: int, j: int) -> int:
    """Number of joints usable in both detections i and j (rows of _masks)."""
    common = 0
    for w in range(masks.shape[1]):
        common += _popcount(masks[i, w] & masks[j, w])
    return common


@njit(cache=True)
def _lines(uv: np.ndarray, F: np.ndarray, transpose: bool) -> np.ndarray:
    """Epipolar lines F x (or F^T x) of every joint: uv (N, J, 2) -> (N, J, 3)."""
    N, J = uv.shape[0], uv.shape[1]
    out = np.empty((N, J, 3))
    for i in range(N):
        for k in range(J):
            x, y = uv[i, k, 0], uv[i, k, 1]
            for r in range(3):
                if transpose:
                    out[i, k, r] = F[0, r] * x + F[1, r] * y + F[2, r]
                else:
                    out[i, k, r] = F[r, 0] * x + F[r, 1] * y + F[r, 2]
    return out


@njit(cache=True, inline="always")
def _feet_quad(p, cov, i, j, floor2) -> tuple[float, float]:
    """Numerator and denominator of the squared Mahalanobis distance of two feet midpoints, in the operations
    and order of feet_uncertainty.mahalanobis_distances (so that sqrt(max(num / den, 0)) ** 2 is its square)."""
    dx, dy = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1]
    a = cov[i, 0, 0] + cov[j, 0, 0] + floor2
    c = cov[i, 1, 1] + cov[j, 1, 1] + floor2
    b = 0.5 * (cov[i, 0, 1] + cov[i, 1, 0] + cov[j, 0, 1] + cov[j, 1, 0])
    return c * dx * dx - 2 * b * dx * dy + a * dy * dy, a * c - b * b


@njit(cache=True)
def _grow(buf: np.ndarray, n: int) -> np.ndarray:
    """buf with room for at least n rows (doubling)."""
    if n <= len(buf):
        return buf
    out = np.empty((max(n, 2 * len(buf)),) + buf.shape[1:], dtype=buf.dtype)
    out[: len(buf)] = buf
    return out


@njit(cache=True)
def _view_pair(dets, F, sa, na, sb, nb, test, out, n) -> int:
    """Append the detection pairs of views a (detections sa:sa + na) and b (sb:sb + nb) that pass to out
    (i, j, chi^2, dof, feet; see pairs_chi2), from row n: -> the new n. dets = (uv, var, masks, has_p, p, cov),
    test = (limits, min_dof, cap, scale2, floor2). One loop, no calls per pair: numba's reference counting of
    array arguments would cost more than the test of an unrelated pair."""
    uv, var, masks, has_p, p, cov = dets
    limits, min_dof, cap, scale2, floor2 = test
    gi, gj, chi2, dofs, feet = out
    J = var.shape[1]
    la, lb = _lines(uv[sa : sa + na], F, False), _lines(uv[sb : sb + nb], F, True)
    far = limits[2 + J] * (1.0 + 1e-9)  # above it, rounding cannot bring the feet term back under the limit
    for ai in range(na):
        i = sa + ai
        for bj in range(nb):
            j = sb + bj
            f = np.nan
            if has_p[i] and has_p[j]:
                num, den = _feet_quad(p, cov, i, j, floor2)
                if den > 0.0 and num > far * den:  # fails the feet test below: skip the division and root
                    continue
                f = np.sqrt(max(num / den, 0.0)) ** 2
            dof = 0
            d2 = 0.0
            if not np.isnan(f):
                dof = 2
                d2 = f
                if d2 > limits[2 + J]:  # the cheap test: no body evidence can save these feet
                    continue
            common = 0
            for w in range(masks.shape[1]):
                common += _popcount(masks[i, w] & masks[j, w])
            possible = dof + common
            if possible < min_dof or d2 > limits[possible]:
                continue
            for k in range(J):
                if var[i, k] > 0.0 and var[j, k] > 0.0:
                    l0, l1, l2 = la[ai, k, 0], la[ai, k, 1], la[ai, k, 2]
                    e = uv[j, k, 0] * l0 + uv[j, k, 1] * l1 + l2
                    m0, m1 = lb[bj, k, 0], lb[bj, k, 1]
                    denom = var[j, k] * (l0 * l0 + l1 * l1) + var[i, k] * (m0 * m0 + m1 * m1)
                    if denom > 0.0:
                        d2 += min(e * e / denom, cap) / scale2
                        dof += 1
                        if d2 > limits[possible]:
                            break
            if dof == 0:  # joints in common but no usable line: nothing tested (kept as inf, linked; merge_linked)
                d2 = np.inf
            elif dof < min_dof or d2 > limits[dof]:
                continue
            gi[n], gj[n], chi2[n], dofs[n], feet[n] = i, j, d2, dof, f
            n += 1
    return n


@njit(cache=True)
def pairs_chi2(
    uv: np.ndarray,
    var: np.ndarray,
    offsets: np.ndarray,
    has_p: np.ndarray,
    p: np.ndarray,
    cov: np.ndarray,
    floor2: float,
    fundamentals: np.ndarray,
    view_pairs: np.ndarray,
    limits: np.ndarray,
    min_dof: int,
    cap: float,
    scale2: float,
    medians: np.ndarray,
    evidence_per_dof: float,
    sample: int,
):
    """The detection pairs of view pairs (a, b) that pass: -> pair (E,) (row of view_pairs), i, j (E,) global
    detection indices, chi^2 (E,) = feet + body / scale2, dof (E,), feet (E,) (NaN without a feet term),
    calibration ratios (R,) and the number of view pairs done.

    Detections of all views are stacked (view v: offsets[v]:offsets[v + 1]): uv (N, J, 2) undistorted pixels,
    var (N, J) pixel variances (0 = joint not usable), has_p (N,), p (N, 2), cov (N, 2, 2) the feet midpoint
    on the ground and its covariance; fundamentals (V, V, 3, 3) with x_b^T F[a, b] x_a = 0. A pair passes when
    its chi^2 passes limits (D + 1,) at its dof (>= min_dof); one joint adds at most cap (an outlying joint,
    e.g. a left / right swap, counts as a bad joint, not as a wrong person); the loop over joints stops as
    soon as a pair fails. With sample > 0 the view pairs stop once the body chi^2 / medians[body dof] of the
    mutual best partners (cost 0.5 chi^2 - evidence_per_dof * dof) number at least sample.
    """
    dets, test = (uv, var, _masks(var), has_p, p, cov), (limits, min_dof, cap, scale2, floor2)
    cap_e = 16
    pair, gi, gj = np.empty(cap_e, np.int64), np.empty(cap_e, np.int64), np.empty(cap_e, np.int64)
    chi2, dofs, feet = np.empty(cap_e), np.empty(cap_e, np.int64), np.empty(cap_e)
    ratios = np.empty(16)
    n, nr, done = 0, 0, 0
    for q in range(len(view_pairs)):
        a, b = view_pairs[q, 0], view_pairs[q, 1]
        sa, sb = offsets[a], offsets[b]
        na, nb = offsets[a + 1] - sa, offsets[b + 1] - sb
        first = n
        if n + na * nb > len(pair):  # room for every pair of this view pair
            pair, gi, gj = _grow(pair, n + na * nb), _grow(gi, n + na * nb), _grow(gj, n + na * nb)
            chi2, dofs, feet = _grow(chi2, n + na * nb), _grow(dofs, n + na * nb), _grow(feet, n + na * nb)
        n = _view_pair(dets, fundamentals[a, b], sa, na, sb, nb, test, (gi, gj, chi2, dofs, feet), n)
        pair[first:n] = q
        done = q + 1
        if sample > 0:
            found = (gi[first:n] - sa, gj[first:n] - sb, chi2[first:n], dofs[first:n], feet[first:n])
            ratios, nr = _mutual_best_ratios(found, na, nb, scale2, medians, evidence_per_dof, ratios, nr)
            if nr >= sample:
                break
    return pair[:n], gi[:n], gj[:n], chi2[:n], dofs[:n], feet[:n], ratios[:nr], done


@njit(cache=True)
def _mutual_best_ratios(found, na, nb, scale2, medians, evidence_per_dof, ratios, nr):
    """Append body chi^2 / medians[body dof] of the mutual best partners of one view pair's detection pairs,
    found = (local i, local j, chi^2, dof, feet) sorted by i, then j, to ratios[:nr]: -> (ratios, nr)."""
    li, lj, chi2, dof, feet = found
    best_row_cost, best_row = np.full(na, np.inf), np.full(na, -1)
    best_col_cost, best_col = np.full(nb, np.inf), np.full(nb, -1)
    body = np.empty(len(chi2))
    for k in range(len(chi2)):
        f0 = feet[k] if np.isfinite(feet[k]) else 0.0
        body[k] = (chi2[k] - f0) * scale2
        c = 0.5 * (f0 + body[k] / scale2) - evidence_per_dof * dof[k]
        if c < best_row_cost[li[k]]:
            best_row_cost[li[k]], best_row[li[k]] = c, k
        if c < best_col_cost[lj[k]]:
            best_col_cost[lj[k]], best_col[lj[k]] = c, k
    for i in range(na):
        k = best_row[i]
        if k < 0 or best_col[lj[k]] != k:
            continue
        body_dof = dof[k] - (2 if np.isfinite(feet[k]) else 0)
        if body_dof > 0:
            ratios = _grow(ratios, nr + 1)
            ratios[nr] = body[k] / medians[min(body_dof, len(medians) - 1)]
            nr += 1
    return ratios, nr


@njit(cache=True)
def _find(parent: np.ndarray, i: int) -> int:
    """Root of i, with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def _adjacency(links: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric adjacency of n nodes from (L, 2) links, by counting sort: indptr (n + 1,), partners (2 L,)."""
    indptr = np.zeros(n + 1, dtype=np.int64)
    for k in range(len(links)):
        indptr[links[k, 0] + 1] += 1
        indptr[links[k, 1] + 1] += 1
    for x in range(n):
        indptr[x + 1] += indptr[x]
    fill = indptr[:-1].copy()
    partners = np.empty(2 * len(links), dtype=np.int64)
    for k in range(len(links)):
        x, y = links[k, 0], links[k, 1]
        partners[fill[x]], partners[fill[y]] = y, x
        fill[x] += 1
        fill[y] += 1
    return indptr, partners


@njit(cache=True, inline="always")
def _is_linked(indptr: np.ndarray, partners: np.ndarray, x: int, y: int) -> bool:
    """Whether y is among the partners[indptr[x]:indptr[x + 1]] of x (a short list: a linear scan)."""
    for k in range(indptr[x], indptr[x + 1]):
        if partners[k] == y:
            return True
    return False


@njit(cache=True)
def merge_linked(
    ga: np.ndarray, gb: np.ndarray, view_of: np.ndarray, links: np.ndarray, has_feet: np.ndarray, var: np.ndarray
) -> np.ndarray:
    """Complete-linkage merging of edges (ga[k], gb[k]) in the given order -> root of every detection (N,).

    Two components join when no view is in both and every x of one is linked to every y of the other (links
    (L, 2): pairs of detections, either order); a pair that shares no evidence (not both has_feet (N,), no
    joint usable in both, var (N, J) > 0) has nothing to test and counts as linked. Members are kept as
    linked lists (head, next, tail per root).
    """
    masks = _masks(var)
    n = len(view_of)
    indptr, partners = _adjacency(links, n)
    parent = np.arange(n)
    views = np.zeros(n, dtype=np.int64)
    nxt = np.full(n, -1)
    tail = np.arange(n)
    size = np.ones(n, dtype=np.int64)
    for i in range(n):
        views[i] = np.int64(1) << view_of[i]
    for k in range(len(ga)):
        a, b = _find(parent, ga[k]), _find(parent, gb[k])
        if a == b or (views[a] & views[b]) != 0:
            continue
        ok = True
        x = a
        while x >= 0 and ok:
            y = b
            while y >= 0:
                untestable = not (has_feet[x] and has_feet[y]) and _common(masks, x, y) == 0
                if not untestable and not _is_linked(indptr, partners, x, y):
                    ok = False
                    break
                y = nxt[y]
            x = nxt[x]
        if not ok:
            continue
        if size[a] < size[b]:
            a, b = b, a
        parent[b] = a
        views[a] |= views[b]
        nxt[tail[a]] = b
        tail[a] = tail[b]
        size[a] += size[b]
    for i in range(n):
        parent[i] = _find(parent, i)
    return parent
