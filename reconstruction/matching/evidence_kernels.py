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

from data.assignment import find_root


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
    """Epipolar lines F x (or F^T x) of every joint and the squares of their normals, l0^2 + l1^2 (the Sampson
    denominators' terms, once per joint rather than once per pair): uv (N, J, 2) -> (N, J, 4)."""
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
def _feet_columns(p: np.ndarray, cov: np.ndarray, has_p: np.ndarray, s: int, n: int) -> tuple:
    """Detections s:s + n as contiguous columns for :func:`_feet_terms`: x, y, cov00, cov11, cov01, cov10 (n,)
    float64 and has_p (n,) bool."""
    return (
        p[s : s + n, 0].copy(),
        p[s : s + n, 1].copy(),
        cov[s : s + n, 0, 0].copy(),
        cov[s : s + n, 1, 1].copy(),
        cov[s : s + n, 0, 1].copy(),
        cov[s : s + n, 1, 0].copy(),
        has_p[s : s + n].copy(),
    )


@njit(cache=True, error_model="numpy")
def _feet_terms(
    p: np.ndarray,
    cov: np.ndarray,
    i: int,
    floor2: float,
    far: float,
    cols: tuple,
    num: np.ndarray,
    den: np.ndarray,
    rejects: np.ndarray,
) -> None:
    """The feet term num / den (the operations and order of feet_uncertainty.mahalanobis_distances, squared) of
    detection i (which has feet) with each detection of cols (:func:`_feet_columns`), and rejects (n,): whether
    both have feet and the pair fails the test (num > far den). A loop without branches over contiguous columns,
    which LLVM vectorises (most pairs of a crowd fail here)."""
    x, y, c00, c11, c01, c10, has = cols
    p0, p1, a0, d0, b0 = p[i, 0], p[i, 1], cov[i, 0, 0], cov[i, 1, 1], cov[i, 0, 1] + cov[i, 1, 0]
    for t in range(len(x)):
        dx, dy = p0 - x[t], p1 - y[t]
        a = a0 + c00[t] + floor2
        c = d0 + c11[t] + floor2
        b = 0.5 * (b0 + c01[t] + c10[t])
        num[t], den[t] = c * dx * dx - 2 * b * dx * dy + a * dy * dy, a * c - b * b
        rejects[t] = has[t] & (den[t] > 0.0) & (num[t] > far * den[t])


@njit(cache=True, error_model="numpy")
def _view_pair(
    uv, var, masks, has_p, p, cov, floor2, F, sa, na, sb, nb, limits, min_dof, cap, scale2, q, ints, floats, n
):
    """Append the detection pairs of views a (detections sa:sa + na) and b (sb:sb + nb) that pass to ints
    (view pair q, i, j, dof) and floats (chi^2, feet) from row n (see pairs_chi2): -> the new n. One loop, no
    calls per pair: numba's reference counting of array arguments would cost more than an unrelated pair. The
    feet test runs first for all of b at once (:func:`_feet_terms`); the loop visits the others."""
    J = var.shape[1]
    la, lb = _lines(uv[sa : sa + na], F, False), _lines(uv[sb : sb + nb], F, True)
    far = limits[2 + J] * (1.0 + 1e-9)  # above it, rounding cannot bring the feet term back under the limit
    cols, num, den = _feet_columns(p, cov, has_p, sb, nb), np.empty(nb), np.empty(nb)
    rejects, visit = np.empty(nb, dtype=np.bool_), np.empty(nb, np.int64)
    for ai in range(na):
        i = sa + ai
        m = nb
        if has_p[i]:
            _feet_terms(p, cov, i, floor2, far, cols, num, den, rejects)
            m = 0
            for bj in range(nb):  # the b detections left, in order, without a branch per detection
                visit[m] = bj
                m += 1 - np.int64(rejects[bj])
        for t in range(m):
            bj = visit[t] if has_p[i] else t
            j = sb + bj
            f = np.nan
            if has_p[i] and has_p[j]:
                f = np.sqrt(max(num[bj] / den[bj], 0.0)) ** 2
            dof = 0
            d2 = 0.0
            if not np.isnan(f):
                dof = 2
                d2 = f
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
def pairs_chi2(
    uv,
    var,
    offsets,
    has_p,
    p,
    cov,
    floor2,
    fundamentals,
    view_pairs,
    q0,
    limits,
    min_dof,
    cap,
    scale2,
    medians,
    evidence_per_dof,
    sample,
    ints,
    floats,
    ratios,
    n,
    nr,
):
    """The detection pairs of the view pairs (a, b) (rows q0, q0 + 1, ... of view_pairs) that pass -> (rows of
    ints / floats used, of ratios used, view pairs done); it stops before a view pair that ints has no room
    for (all its detection pairs) and after the one that completes the calibration sample.

    Detections of all views are stacked (view v: offsets[v]:offsets[v + 1]): uv (N, J, 2) undistorted pixels,
    var (N, J) pixel variances (0 = joint not usable), has_p (N,), p (N, 2), cov (N, 2, 2) the feet midpoint
    on the ground and its covariance; fundamentals (V, V, 3, 3) with x_b^T F[a, b] x_a = 0. A pair passes when
    its chi^2 = feet + body / scale2 passes limits (D + 1,), D >= J + 2, at its dof (>= min_dof); one joint adds at most
    cap (an outlying joint, e.g. a left / right swap, counts as a bad joint, not as a wrong person); the loop
    over joints stops as soon as a pair fails. Out, from rows n and nr: ints (M, 4) (view pair row, i, j
    global indices, dof), floats (M, 2) (chi^2, inf where untestable and kept as linked; feet term, NaN where
    none). With sample > 0, the body chi^2 / medians[body dof] (medians (D + 1,)) of each view pair's mutual best
    partners (cost 0.5 chi^2 - evidence_per_dof * dof) go to ratios (R,), until there are sample of them.
    """
    masks = _masks(var)
    for q in range(q0, len(view_pairs)):
        a, b = view_pairs[q, 0], view_pairs[q, 1]
        sa, sb = offsets[a], offsets[b]
        na, nb = offsets[a + 1] - sa, offsets[b + 1] - sb
        if n + na * nb > len(ints):
            return n, nr, q
        first = n
        F = fundamentals[a, b]
        n = _view_pair(
            uv, var, masks, has_p, p, cov, floor2, F, sa, na, sb, nb, limits, min_dof, cap, scale2, q, ints, floats, n
        )  # noqa: E501
        if sample > 0:
            nr = _mutual_best_ratios(
                ints, floats, first, n, sa, sb, na, nb, scale2, medians, evidence_per_dof, ratios, nr
            )  # noqa: E501
            if nr >= sample:
                return n, nr, q + 1
    return n, nr, len(view_pairs)


@njit(cache=True, error_model="numpy")
def _mutual_best_ratios(ints, floats, first, n, sa, sb, na, nb, scale2, medians, evidence_per_dof, ratios, nr):
    """Append body chi^2 / medians[body dof] of the mutual best partners among the rows first:n (one view pair,
    sorted by i, then j) to ratios from nr (room for min(na, nb) more): -> the new nr."""
    best_row_cost, best_row = np.empty(na), np.empty(na, dtype=np.int64)
    best_col_cost, best_col = np.empty(nb), np.empty(nb, dtype=np.int64)
    for i in range(na):
        best_row_cost[i], best_row[i] = np.inf, -1
    for j in range(nb):
        best_col_cost[j], best_col[j] = np.inf, -1
    for k in range(first, n):
        f0 = floats[k, 1] if np.isfinite(floats[k, 1]) else 0.0
        body = (floats[k, 0] - f0) * scale2
        c = 0.5 * (f0 + body / scale2) - evidence_per_dof * ints[k, 3]
        i, j = ints[k, 1] - sa, ints[k, 2] - sb
        if c < best_row_cost[i]:
            best_row_cost[i], best_row[i] = c, k
        if c < best_col_cost[j]:
            best_col_cost[j], best_col[j] = c, k
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
def merge_linked(
    ga: np.ndarray,
    gb: np.ndarray,
    view_of: np.ndarray,
    links: np.ndarray,
    has_feet: np.ndarray,
    var: np.ndarray,
    untested: tuple,
) -> np.ndarray:
    """Complete-linkage merging of edges (ga[k], gb[k]) in the given order -> root of every detection (N,).

    Two components join when no view is in both and every x of one is linked to every y of the other (links
    (L, 2): pairs of detections, either order); a pair that shares no evidence (not both has_feet (N,), no
    joint usable in both, var (N, J) > 0) has nothing to test and counts as linked. In a pair of views whose
    link tests were not all computed (``untested``: evidence.untested_links), a pair that is not among the links
    is tested when the merge asks (:func:`_linked_now`): 100 people in 7 views ask 40-75 per frame, not the
    ~9,000 pairs inside the link test but outside the gate. Members are kept as linked lists (head, next, tail
    per root).
    """
    masks = _masks(var)
    n = len(view_of)
    indptr, partners = _adjacency(links, n)
    tested, row = untested[5], (np.empty((1, 4), dtype=np.int64), np.empty((1, 2)))
    parent, tail = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    views, nxt, size = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    for i in range(n):
        parent[i], tail[i], nxt[i], size[i] = i, i, -1, 1
        views[i] = np.int64(1) << view_of[i]
    for k in range(len(ga)):
        a, b = find_root(parent, ga[k]), find_root(parent, gb[k])
        if a == b or (views[a] & views[b]) != 0:
            continue
        ok = True
        x = a
        while x >= 0 and ok:
            y = b
            while y >= 0:
                common = 0
                for w in range(masks.shape[1]):
                    common += _popcount(masks[x, w] & masks[y, w])
                linked = common == 0 and not (has_feet[x] and has_feet[y])  # nothing to test
                for t in range(indptr[x], indptr[x + 1]):  # x's partners: a short list
                    linked = linked or partners[t] == y
                if not linked and not tested[view_of[x], view_of[y]]:
                    linked = _linked_now(x, y, view_of, masks, var, has_feet, untested, row)
                if not linked:
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
        parent[i] = find_root(parent, i)
    return parent


@njit(cache=True, error_model="numpy")
def _linked_now(x, y, view_of, masks, var, has_p, untested, row) -> bool:
    """Whether detections x and y (other views) pass the link test, computed now: the loop of :func:`pairs_chi2` for
    the one pair, then the test of :func:`gated_rows` on its D^2 (:func:`calibrated_chi2`'s arithmetic)."""
    uv, p, cov, floor2, fundamentals, _, limits, min_dof, cap, scale2 = untested
    if view_of[x] > view_of[y]:
        x, y = y, x
    F = fundamentals[view_of[x], view_of[y]]
    ints, floats = row
    n = _view_pair(
        uv, var, masks, has_p, p, cov, floor2, F, x, 1, y, 1, limits, min_dof, cap, scale2, 0, ints, floats, 0
    )
    return n == 1 and _calibrated(floats[0, 0], floats[0, 1], scale2, scale2) <= limits[ints[0, 3]]


@njit(cache=True, error_model="numpy")
def _calibrated(d2: float, feet: float, computed_at: float, scale2: float) -> float:
    """D^2 = feet + body / scale2 of a chi^2 d2 computed at the scale computed_at (feet term feet, or NaN)."""
    feet = feet if np.isfinite(feet) else 0.0
    return feet + (d2 - feet) * computed_at / scale2  # model units: the kernel's scale undone


@njit(cache=True, error_model="numpy")
def calibrated_chi2(floats: np.ndarray, first: int, loosest: float, scale2: float) -> np.ndarray:
    """D^2 = feet + body / scale2 of the rows of :func:`pairs_chi2`: floats (E, 2) (chi^2 at the scale each row was
    computed with, loosest for rows < first and scale2 after; feet term or NaN) -> (E,). The feet term keeps its
    own model (its ground floor is foot size and calibration, not pixel noise); a missing one adds nothing."""
    out = np.empty(len(floats))
    for k in range(len(floats)):
        out[k] = _calibrated(floats[k, 0], floats[k, 1], loosest if k < first else scale2, scale2)
    return out


@njit(cache=True, error_model="numpy")
def gated_rows(pair, gi, gj, d2, dof, limits, link2, evidence_per_dof, offsets, view_pairs, num_pairs):
    """The detection pairs (E,) (view pair row, global indices, D^2, dof) sorted by view pair, split by the tests:
    -> starts (K + 1,), their rows (M,), local indices da, db (M,) and costs 0.5 D^2 - evidence_per_dof dof (M,) of the M rows that
    pass (finite D^2 <= limits[dof]), view pair q's rows at starts[q]:starts[q + 1]; links (L, 2): global indices of
    the rows that pass the link test (D^2 <= limits[dof] link2; an untestable row, inf at dof 0, does)."""
    E = len(d2)
    starts = np.zeros(num_pairs + 1, dtype=np.int64)
    rows, da, db = np.empty(E, dtype=np.int64), np.empty(E, dtype=np.int64), np.empty(E, dtype=np.int64)
    cost = np.empty(E)
    links = np.empty((E, 2), dtype=np.int64)
    m, n_links = 0, 0
    for k in range(E):
        limit = limits[dof[k]]
        if d2[k] <= limit * link2:
            links[n_links, 0], links[n_links, 1] = gi[k], gj[k]
            n_links += 1
        if d2[k] <= limit and np.isfinite(d2[k]):
            q = pair[k]
            rows[m] = k
            da[m], db[m] = gi[k] - offsets[view_pairs[q, 0]], gj[k] - offsets[view_pairs[q, 1]]
            cost[m] = 0.5 * d2[k] - evidence_per_dof * dof[k]
            starts[q + 1] += 1
            m += 1
    for q in range(num_pairs):
        starts[q + 1] += starts[q]
    return starts, rows[:m], da[:m], db[:m], cost[:m], links[:n_links]


@njit(cache=True, error_model="numpy")
def merge_persons(ga, gb, view_of, links, has_feet, var, untested):
    """:func:`merge_linked` of the edges (ga, gb) (E,) in the given order -> person of every detection (N,) (persons
    numbered by their smallest detection) and the persons' sizes."""
    root = merge_linked(ga, gb, view_of, links, has_feet, var, untested)
    n = len(root)
    rank, size = np.full(n, -1, dtype=np.int64), np.zeros(n, dtype=np.int64)
    persons = 0
    for i in range(n):
        if root[i] == i:
            rank[i] = persons
            persons += 1
    person = np.empty(n, dtype=np.int64)
    for i in range(n):
        person[i] = rank[root[i]]
        size[person[i]] += 1
    return person, size[:persons]


@njit(cache=True, error_model="numpy")
def usable_keypoints(kp: np.ndarray, min_score: float, out: np.ndarray, ok: np.ndarray, bad: np.ndarray) -> None:
    """Keypoints (N, J, 3) -> out (N, J, 3) with the joints not ok zeroed, ok (N, J) (finite, score >= min_score)
    and bad (N,) (some keypoint not finite)."""
    N, J = ok.shape
    for n in range(N):
        bad[n] = False
        for j in range(J):
            x, y, s = kp[n, j, 0], kp[n, j, 1], kp[n, j, 2]
            finite = np.isfinite(x) and np.isfinite(y) and np.isfinite(s)
            bad[n] |= not finite
            ok[n, j] = finite and s >= min_score
            if ok[n, j]:
                out[n, j, 0], out[n, j, 1], out[n, j, 2] = x, y, s
            else:
                out[n, j, 0], out[n, j, 1], out[n, j, 2] = 0.0, 0.0, 0.0
