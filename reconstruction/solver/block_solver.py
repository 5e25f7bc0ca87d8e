"""Block-sparse symmetric positive definite systems of 3D poses, batched over persons.

The normal equations of a pose are 3x3 blocks per joint, coupled along the bones. :func:`solve_dense`
assembles each component and factorises it with LAPACK (fast for a few persons); :func:`solve_blocks`
eliminates the joints of all persons at once in the order of an :func:`elimination_plan` (fast for
many persons: a handful of vectorised 3x3 operations per level). Both report, per person and joint
block, whether the system was positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import lapack
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from data.geometry.linalg import inverse_3x3  # noqa: F401  (the solver's block inverse; re-exported)


@lru_cache(maxsize=32)
def graph_components(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> tuple[np.ndarray, ...]:
    """Joint sets connected by the edges (a, b), singletons included: J, E pairs -> (j,) sorted arrays.

    Ordered by first joint; cached (the graph of a bone table never changes).
    """
    pairs_arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs_arr)), (pairs_arr[:, 0], pairs_arr[:, 1])), shape=(num_joints, num_joints))
    _, label = connected_components(graph, directed=False)
    return tuple(np.flatnonzero(label == k) for k in np.unique(label))


def spd_solve(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """Cholesky solve of a symmetric (n, n) system: -> x (n,), whether A was positive definite."""
    _, x, info = lapack.dposv(A.T, b, overwrite_a=1)  # symmetric: A.T is F-ordered, no copy; A is scratch
    return x, info == 0


_DIAG3 = (np.arange(3), np.arange(3))  # the diagonal entries of blocks stored first


@dataclass(frozen=True)
class Level:
    """Joints eliminated together (no two adjacent) and the index arrays of their block operations.

    Blocks live in one array (3, 3, n_blocks, b): block j < J is the diagonal block of joint j, the
    others are the off-diagonal blocks of joint pairs (original bones and fill-in) in both orders.
    A pair (i, a) joins pivot i to a remaining neighbour a; a triple (i, a, c) updates block (a, c)
    by -L_ai A_ic with L_ai = A_ai A_ii^-1.
    """

    pivots: np.ndarray  # (k,) joints
    pair_pivot: np.ndarray  # (m,) position in pivots of each pair's pivot
    pair_joint: np.ndarray  # (m,) the neighbour a
    pair_block: np.ndarray  # (m,) block (a, i)
    pair_sum: np.ndarray | None  # (k, m) 1 where pair belongs to pivot (sums L^T x per pivot); None: one each
    joint_targets: np.ndarray  # (u,) distinct neighbours
    joint_sum: np.ndarray | None  # (u, m) 1 where pair has that neighbour (sums rhs updates); None: one each
    tri_pair: np.ndarray  # (t,) pair (i, a) of each triple
    tri_block: np.ndarray  # (t,) block (i, c)
    block_targets: np.ndarray  # (v,) distinct blocks (a, c) updated
    block_sum: np.ndarray | None  # (v, t) 1 where triple updates that block; None: one each


@dataclass(frozen=True)
class EliminationPlan:
    """Order of a block elimination of a joint graph: the levels and the number of blocks.

    Blocks 0..J-1 are the diagonal ones, J..J+E-1 the input edges (a, b), J+E..J+2E-1 the same
    transposed (b, a), then the fill-in.
    """

    num_joints: int
    num_edges: int
    num_blocks: int
    levels: tuple[Level, ...]


@lru_cache(maxsize=32)
def elimination_plan(num_joints: int, edges: tuple[tuple[int, int], ...]) -> EliminationPlan:
    """Greedy minimum-degree elimination of a joint graph, in levels of non-adjacent joints: J, E pairs -> plan.

    Each level takes, lowest degree first, joints of degree <= max(2, least degree of a joint with a
    neighbour) that are not adjacent to one already taken: leaves and every other link of a chain go
    at once (a chain of n joints takes log2 n levels, COCO-23 six) and the fill-in stays small (a joint of
    degree 2 adds at most one block; the torso cycle gets one).
    """
    adj: list[set[int]] = [set() for _ in range(num_joints)]
    E = len(edges)
    block: dict[tuple[int, int], int] = {}  # diagonal blocks, edges (a, b), edges (b, a), then fill-in
    for e, (a, b) in enumerate(edges):
        block[(int(a), int(b))], block[(int(b), int(a))] = num_joints + e, num_joints + E + e
        adj[a].add(int(b))
        adj[b].add(int(a))
    fill = num_joints + 2 * E

    def link(a: int, b: int) -> None:
        nonlocal fill
        if (a, b) not in block:
            block[(a, b)], block[(b, a)] = fill, fill + 1
            fill += 2
        adj[a].add(b)
        adj[b].add(a)

    remaining, levels = set(range(num_joints)), []
    while remaining:
        degree = {j: len(adj[j]) for j in remaining}
        limit = max(2, min((d for d in degree.values() if d > 0), default=2))
        chosen: list[int] = []
        blocked: set[int] = set()
        for j in sorted(remaining, key=lambda j: (degree[j], j)):
            if degree[j] <= limit and j not in blocked:
                chosen.append(j)
                blocked |= adj[j] | {j}
        pairs = [(k, i, a) for k, i in enumerate(chosen) for a in sorted(adj[i])]
        triples = [(p, i, c) for p, (_, i, a) in enumerate(pairs) for c in sorted(adj[i])]
        for i in chosen:
            for a in adj[i]:
                adj[a].discard(i)
            for a in adj[i]:
                for c in adj[i]:
                    if a < c:
                        link(a, c)
            remaining.discard(i)
        levels.append(_level(chosen, pairs, triples, block))
    return EliminationPlan(num_joints, E, fill, tuple(levels))


def _level(chosen: list[int], pairs: list, triples: list, block: dict) -> Level:
    """Index arrays of one elimination level (see :class:`Level`)."""
    pair_joint = np.array([a for _, _, a in pairs], dtype=np.int64)
    targets = [block[(pairs[p][2], c)] if pairs[p][2] != c else c for p, _, c in triples]
    joints, joint_of = np.unique(pair_joint, return_inverse=True)
    blocks, block_of = np.unique(np.array(targets, dtype=np.int64), return_inverse=True)
    return Level(
        np.array(chosen, dtype=np.int64),
        np.array([k for k, _, _ in pairs], dtype=np.int64),
        pair_joint,
        np.array([block[(a, i)] for _, i, a in pairs], dtype=np.int64),
        _indicator(np.array([k for k, _, _ in pairs], dtype=np.int64), len(chosen)),
        joints,
        _indicator(joint_of, len(joints)),
        np.array([p for p, _, _ in triples], dtype=np.int64),
        np.array([block[(i, c)] for _, i, c in triples], dtype=np.int64),
        blocks,
        _indicator(block_of, len(blocks)),
    )


def _indicator(rows: np.ndarray, n: int) -> np.ndarray | None:
    """(n, len(rows)) matrix with a 1 at (rows[k], k); None when it is the identity (nothing to sum)."""
    if n == len(rows) and np.array_equal(rows, np.arange(n)):
        return None
    out = np.zeros((n, len(rows)))
    out[rows, np.arange(len(rows))] = 1.0
    return out


def solve_blocks(
    plan: EliminationPlan,
    diag: np.ndarray,
    off: np.ndarray,
    rhs: np.ndarray,
    damping: np.ndarray | None = None,
    check: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve b block-sparse symmetric systems by block elimination -> x (3, J, b), pivots positive definite (J, b).

    Batch last: diag (3, 3, J, b) diagonal blocks, plus damping (J, b) times I if given; off
    (3, 3, E, b) the symmetric off-diagonal block of each plan edge (a, b); rhs (3, J, b). The system
    is positive definite iff every pivot is; where one is not, the solution of that joint's component
    is meaningless. check=False skips the test (all True).
    """
    J, b = diag.shape[2:]
    E = plan.num_edges
    blk = np.empty((3, 3, plan.num_blocks, b))
    blk[:, :, :J] = diag
    if damping is not None:
        blk[_DIAG3[0], _DIAG3[1], :J] += damping
    blk[:, :, J : J + E] = off
    blk[:, :, J + E : J + 2 * E] = off.transpose(1, 0, 2, 3)
    blk[:, :, J + 2 * E :] = 0.0
    r = rhs.copy()
    pd = np.ones((J, b), dtype=bool)
    factors = []
    for lv in plan.levels:
        inv, ok = inverse_3x3(blk[:, :, lv.pivots], check)
        if check:
            pd[lv.pivots] = ok
        L = None
        if len(lv.pair_joint):
            L = _mul(blk[:, :, lv.pair_block], inv[:, :, lv.pair_pivot])  # L_ai = A_ai A_ii^-1
            update = _mul(L[:, :, lv.tri_pair], blk[:, :, lv.tri_block])
            blk[:, :, lv.block_targets] -= _sum_rows(lv.block_sum, update)
            rhs_update = np.einsum("ijmb,jmb->imb", L, r[:, lv.pivots[lv.pair_pivot]])  # L_ai r_i
            r[:, lv.joint_targets] -= _sum_rows(lv.joint_sum, rhs_update)
        factors.append((inv, L))
    x = np.zeros((3, J, b))
    for lv, (inv, L) in zip(reversed(plan.levels), reversed(factors)):
        y = np.einsum("ijkb,jkb->ikb", inv, r[:, lv.pivots])  # A_ii^-1 r_i
        if L is not None:
            y -= _sum_rows(lv.pair_sum, np.einsum("ijmb,imb->jmb", L, x[:, lv.pair_joint]))  # - sum_a L_ai^T x_a
        x[:, lv.pivots] = y
    return x, pd


def _sum_rows(S: np.ndarray | None, a: np.ndarray) -> np.ndarray:
    """Sums of the entries (axis -2) of a (..., m, b) selected by the rows of S (u, m) -> (..., u, b); S None: a."""
    if S is None:
        return a
    return np.matmul(S, a.reshape(-1, a.shape[-2], a.shape[-1])).reshape(a.shape[:-2] + (len(S), a.shape[-1]))


def _mul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Products of 3x3 matrices stored first: (3, 3, ...) x 2 -> (3, 3, ...)."""
    return np.einsum("ij...,jk...->ik...", A, B)


def solve_dense(
    diag: np.ndarray,
    off: np.ndarray,
    edges: np.ndarray,
    rhs: np.ndarray,
    ranges: list[tuple[int, int]],
    run: np.ndarray,
    damping: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve the same systems as :func:`solve_blocks` by assembling each component densely -> x (3, J, b), pd (b, C).

    ranges[c] = (first, end) joints of component c (contiguous, no edge between components); run
    (b, C) selects the systems to solve (the others give x = 0). One LAPACK Cholesky per system.
    """
    J, b = diag.shape[2:]
    x, pd = np.zeros((b, J, 3)), np.ones(run.shape, dtype=bool)
    for c, (s, e) in enumerate(ranges):
        rows = np.flatnonzero(run[:, c])
        if len(rows) == 0:
            continue
        D = diag[:, :, s:e, rows]
        if damping is not None:
            D = D.copy()
            D[_DIAG3] += damping[s:e, rows]
        if e - s == 1:  # a joint without bones: vectorised 3x3 solve
            inv, pd[rows, c] = inverse_3x3(D[:, :, 0])
            x[rows, s] = np.einsum("ijb,jb->bi", inv, rhs[:, s, rows])
            continue
        inside = (edges[:, 0] >= s) & (edges[:, 0] < e)
        A = _assemble(D, off[:, :, inside][..., rows], edges[inside] - s)
        rhs_c = rhs[:, s:e, rows].transpose(2, 1, 0).reshape(len(rows), -1)
        for k, i in enumerate(rows):
            sol, pd[i, c] = spd_solve(A[k], rhs_c[k])
            x[i, s:e] = sol.reshape(-1, 3)
    return x.transpose(2, 1, 0), pd


def _assemble(diag: np.ndarray, off: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Dense symmetric matrices from diagonal blocks (3, 3, J, b) and edge blocks (3, 3, E, b): -> (b, 3J, 3J)."""
    J, b = diag.shape[2:]
    out = np.zeros((b, 3 * J, 3 * J))
    blocks = out.reshape(b, J, 3, J, 3)
    jj = np.arange(J)
    blocks[:, jj, :, jj] = diag.transpose(2, 3, 0, 1)
    if len(edges):
        blocks[:, edges[:, 0], :, edges[:, 1]] = off.transpose(2, 3, 0, 1)
        blocks[:, edges[:, 1], :, edges[:, 0]] = off.transpose(2, 3, 1, 0)
    return out
