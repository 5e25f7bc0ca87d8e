"""Compiled loops of the evidence matcher: the chi-square of the detection pairs of view pairs; complete linkage."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from data.assignment import find_root


class Detections(NamedTuple):
    """A frame's N detections stacked over its V views (view v: offsets[v]:offsets[v + 1])."""

    uv: np.ndarray  # (N, J, 2) undistorted pixels
    var: np.ndarray  # (N, J) pixel variances, 0: unusable joint
    offsets: np.ndarray  # (V + 1,)
    has_p: np.ndarray  # (N,) bool
    p: np.ndarray  # (N, 2) the feet midpoint on the ground (m)
    cov: np.ndarray  # (N, 2, 2) its covariance
    floor2: float  # m^2, added to both feet variances
    fundamentals: np.ndarray  # (V, V, 3, 3) with x_b^T F[a, b] x_a = 0


class ChiTest(NamedTuple):
    """A pair passes when D^2 = feet + body / scale2 <= limits[dof] (D + 1,), D >= J + 2, and dof >= min_dof."""

    limits: np.ndarray
    min_dof: int
    cap: float  # most one joint adds: a swapped or hidden joint is one bad joint, not a wrong person
    scale2: float


class Sample(NamedTuple):
    """Noise calibration sample: body chi^2 / medians[body dof] (D + 1,) of each view pair's mutual best partners."""

    medians: np.ndarray
    evidence_per_dof: float  # partners by cost 0.5 chi^2 - evidence_per_dof dof
    size: int  # until there are size of them (0: no sample)


class LinkTests(NamedTuple):
    """What the merge needs to compute a link test not among the links."""

    det: Detections
    tested: np.ndarray  # (V, V) bool, True: every pair of the two views that passes the link test is a link
    test: ChiTest


@njit(cache=True, error_model="numpy")
def _popcount(x: np.int64) -> int:
    """Number of set bits of a non-negative 64-bit integer."""
    x = x - ((x >> 1) & 0x5555555555555555)
    x = (x & 0x3333333333333333) + ((x >> 2) & 0x3333333333333333)
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0F
    return int((x * 0x0101010101010101) >> 56) & 0xFF


@njit(cache=True, error_model="numpy")
def _masks(var: np.ndarray) -> np.ndarray:
    """Bit masks of the usable joints (var > 0) of every detection, 62 joints per word: (N, J) -> (N, W) int64."""
    N, J = var.shape
    out = np.zeros((N, (J + 61) // 62), dtype=np.int64)
    for i in range(N):
        for k in range(J):
            if var[i, k] > 0.0:
                out[i, k // 62] |= np.int64(1) << (k % 62)
    return out


@njit(cache=True, error_model="numpy")
def _lines(uv: np.ndarray, F: np.ndarray, transpose: bool) -> np.ndarray:
    """Epipolar lines F x (or F^T x) of the joints and l0^2 + l1^2 (Sampson): (N, J, 2) -> (N, J, 4)."""
    N, J = uv.shape[0], uv.shape[1]
    out = np.empty((N, J, 4))
    for i in range(N):
        for k in range(J):
            x, y = uv[i, k, 0], uv[i, k, 1]
            for r in range(3):
                if transpose:
                    out[i, k, r] = F[0, r] * x + F[1, r] * y + F[2, r]
                else:
                    out[i, k, r] = F[r, 0] * x + F[r, 1] * y + F[r, 2]
            out[i, k, 3] = out[i, k, 0] * out[i, k, 0] + out[i, k, 1] * out[i, k, 1]
    return out


@njit(cache=True, error_model="numpy")
def _feet_columns(det: Detections, s: int, n: int) -> tuple:
    """Detections s:s + n as contiguous columns x, y, cov00, cov11, cov01, cov10 (n,) and has_p (n,)."""
    p, cov = det.p, det.cov
    return (
        p[s : s + n, 0].copy(),
        p[s : s + n, 1].copy(),
        cov[s : s + n, 0, 0].copy(),
        cov[s : s + n, 1, 1].copy(),
        cov[s : s + n, 0, 1].copy(),
        cov[s : s + n, 1, 0].copy(),
        det.has_p[s : s + n].copy(),
    )


@njit(cache=True, error_model="numpy")
def _feet_terms(det: Detections, i: int, far: float, cols: tuple, num, den, rejects) -> None:
    """Squared Mahalanobis feet term num / den (n,) of detection i with cols; rejects (n,): num > far den."""
    x, y, c00, c11, c01, c10, has = cols
    p, cov, floor2 = det.p, det.cov, det.floor2
    p0, p1, a0, d0, b0 = p[i, 0], p[i, 1], cov[i, 0, 0], cov[i, 1, 1], cov[i, 0, 1] + cov[i, 1, 0]
    for t in range(len(x)):
        dx, dy = p0 - x[t], p1 - y[t]
        a = a0 + c00[t] + floor2
        c = d0 + c11[t] + floor2
        b = 0.5 * (b0 + c01[t] + c10[t])
        num[t], den[t] = c * dx * dx - 2 * b * dx * dy + a * dy * dy, a * c - b * b
        rejects[t] = has[t] & (den[t] > 0.0) & (num[t] > far * den[t])


@njit(cache=True, error_model="numpy")
def _view_pair(det: Detections, masks, F, sa, na, sb, nb, test: ChiTest, q, ints, floats, n):
    """Append the passing pairs of sa:sa + na x sb:sb + nb to ints (q, i, j, dof), floats (chi^2, feet) -> new n."""
    uv, var, has_p = det.uv, det.var, det.has_p
    limits, min_dof, cap, scale2 = test
    J = var.shape[1]
    la, lb = _lines(uv[sa : sa + na], F, False), _lines(uv[sb : sb + nb], F, True)
    far = limits[2 + J] * (1.0 + 1e-9)  # above it, rounding cannot bring the feet term back under the limit
    cols, num, den = _feet_columns(det, sb, nb), np.empty(nb), np.empty(nb)
    rejects, visit = np.empty(nb, dtype=np.bool_), np.empty(nb, np.int64)
    for ai in range(na):
        i = sa + ai
        m = nb
        if has_p[i]:
            _feet_terms(det, i, far, cols, num, den, rejects)
            m = 0
            for bj in range(nb):  # the b detections left, in order, without a branch per detection
                visit[m] = bj
                m += 1 - np.int64(rejects[bj])
        for t in range(m):
            bj = visit[t] if has_p[i] else t
            j = sb + bj
            f = np.sqrt(max(num[bj] / den[bj], 0.0)) ** 2 if has_p[i] and has_p[j] else np.nan
            dof, d2 = (0, 0.0) if np.isnan(f) else (2, f)
            if d2 > limits[2 + J]:  # the cheap test: no body evidence can save these feet
                continue
            possible = dof
            for w in range(masks.shape[1]):
                possible += _popcount(masks[i, w] & masks[j, w])
            if possible < min_dof or d2 > limits[possible]:
                continue
            failed = False
            for w in range(masks.shape[1]):  # the joints both see, in order: the set bits of the common mask
                common = masks[i, w] & masks[j, w]
                while common != 0 and not failed:
                    low = common & -common
                    common ^= low
                    k = 62 * w + _popcount(low - 1)
                    e = uv[j, k, 0] * la[ai, k, 0] + uv[j, k, 1] * la[ai, k, 1] + la[ai, k, 2]
                    denom = var[j, k] * la[ai, k, 3] + var[i, k] * lb[bj, k, 3]
                    if denom > 0.0:
                        d2 += min(e * e / denom, cap) / scale2
                        dof += 1
                        failed = d2 > limits[possible]
            if dof == 0:  # joints in common but no usable line: nothing tested (kept as inf, linked; merge_linked)
                d2 = np.inf
            elif dof < min_dof or d2 > limits[dof]:
                continue
            ints[n, 0], ints[n, 1], ints[n, 2], ints[n, 3] = q, i, j, dof
            floats[n, 0], floats[n, 1] = d2, f
            n += 1
    return n


@njit(cache=True, error_model="numpy")
def pairs_chi2(det: Detections, view_pairs, q0: int, test: ChiTest, sample: Sample, ints, floats, ratios, n, nr):
    """Passing pairs of view_pairs (K, 2) from q0 into ints (M, 4), floats (M, 2), ratios (R,) -> (n, nr, done)."""
    offsets = det.offsets
    masks = _masks(det.var)
    for q in range(q0, len(view_pairs)):
        a, b = view_pairs[q, 0], view_pairs[q, 1]
        sa, sb = offsets[a], offsets[b]
        na, nb = offsets[a + 1] - sa, offsets[b + 1] - sb
        if n + na * nb > len(ints):
            return n, nr, q
        first = n
        n = _view_pair(det, masks, det.fundamentals[a, b], sa, na, sb, nb, test, q, ints, floats, n)
        if sample.size > 0:
            nr = _mutual_best_ratios(ints, floats, first, n, sa, sb, na, nb, test.scale2, sample, ratios, nr)
            if nr >= sample.size:
                return n, nr, q + 1
    return n, nr, len(view_pairs)


@njit(cache=True, error_model="numpy")
def _mutual_best_ratios(ints, floats, first, n, sa, sb, na, nb, scale2, sample: Sample, ratios, nr):
    """Append body chi^2 / medians[dof] of the mutual best partners of rows first:n to ratios -> the new nr."""
    best_row_cost, best_row = np.full(na, np.inf), np.full(na, -1)
    best_col_cost, best_col = np.full(nb, np.inf), np.full(nb, -1)
    for k in range(first, n):
        f0 = floats[k, 1] if np.isfinite(floats[k, 1]) else 0.0
        body = (floats[k, 0] - f0) * scale2
        c = 0.5 * (f0 + body / scale2) - sample.evidence_per_dof * ints[k, 3]
        i, j = ints[k, 1] - sa, ints[k, 2] - sb
        if c < best_row_cost[i]:
            best_row_cost[i], best_row[i] = c, k
        if c < best_col_cost[j]:
            best_col_cost[j], best_col[j] = c, k
    medians = sample.medians
    for i in range(na):
        k = best_row[i]
        if k < 0 or best_col[ints[k, 2] - sb] != k:
            continue
        body_dof = ints[k, 3] - (2 if np.isfinite(floats[k, 1]) else 0)
        if body_dof > 0:
            f0 = floats[k, 1] if np.isfinite(floats[k, 1]) else 0.0
            ratios[nr] = (floats[k, 0] - f0) * scale2 / medians[min(body_dof, len(medians) - 1)]
            nr += 1
    return nr


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def merge_linked(ga: np.ndarray, gb: np.ndarray, view_of: np.ndarray, links: np.ndarray, lazy: LinkTests):
    """Complete-linkage merge of edges (ga[k], gb[k]) (E,) in order, links (L, 2) -> root of every detection (N,)."""
    masks = _masks(lazy.det.var)
    n = len(view_of)
    indptr, partners = _adjacency(links, n)
    row = (np.empty((1, 4), dtype=np.int64), np.empty((1, 2)))
    parent, tail, nxt, size = np.arange(n), np.arange(n), np.full(n, -1), np.ones(n, dtype=np.int64)
    views = np.empty(n, dtype=np.int64)
    for i in range(n):
        views[i] = np.int64(1) << view_of[i]
    for k in range(len(ga)):
        a, b = find_root(parent, ga[k]), find_root(parent, gb[k])
        if a == b or (views[a] & views[b]) != 0:
            continue
        if not _all_linked(a, b, nxt, indptr, partners, view_of, masks, lazy, row):
            continue
        if size[a] < size[b]:
            a, b = b, a
        parent[b] = a
        views[a] |= views[b]
        nxt[tail[a]] = b
        tail[a] = tail[b]
        size[a] += size[b]
    for i in range(n):
        parent[i] = find_root(parent, i)
    return parent


@njit(cache=True, error_model="numpy")
def _all_linked(a, b, nxt, indptr, partners, view_of, masks, lazy: LinkTests, row) -> bool:
    """Whether every member x of person a (a linked list: nxt) is linked to every member y of person b."""
    has_p = lazy.det.has_p
    x = a
    while x >= 0:
        y = b
        while y >= 0:
            common = 0
            for w in range(masks.shape[1]):
                common += _popcount(masks[x, w] & masks[y, w])
            linked = common == 0 and not (has_p[x] and has_p[y])  # nothing to test
            for t in range(indptr[x], indptr[x + 1]):  # x's partners: a short list
                linked = linked or partners[t] == y
            if not linked and not lazy.tested[view_of[x], view_of[y]]:
                linked = _linked_now(x, y, view_of, masks, lazy, row)
            if not linked:
                return False
            y = nxt[y]
        x = nxt[x]
    return True


@njit(cache=True, error_model="numpy")
def _linked_now(x, y, view_of, masks, lazy: LinkTests, row) -> bool:
    """Whether detections x and y (other views) pass the link test: pairs_chi2's loop, then the calibrated D^2."""
    if view_of[x] > view_of[y]:
        x, y = y, x
    F = lazy.det.fundamentals[view_of[x], view_of[y]]
    ints, floats = row
    n = _view_pair(lazy.det, masks, F, x, 1, y, 1, lazy.test, 0, ints, floats, 0)
    scale2, feet = lazy.test.scale2, floats[0, 1] if np.isfinite(floats[0, 1]) else 0.0
    return n == 1 and feet + (floats[0, 0] - feet) * scale2 / scale2 <= lazy.test.limits[ints[0, 3]]
