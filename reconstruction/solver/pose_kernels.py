"""Compiled (numba) kernels of the MLE / MAP pose problems: linearisation, block Cholesky, Levenberg-Marquardt.

The same problem, damping rule, step acceptance and stopping tests as the batched numpy solver
(:mod:`reconstruction.solver.lm_solver` with :mod:`reconstruction.solver.map_estimation`), one (person, bone-graph
component) problem at a time in compiled loops: a crowd of small problems costs arithmetic, not
numpy call overhead. The normal equations are 3x3 blocks per joint coupled along the bones, factorised
by a block Cholesky in the elimination order of a :class:`reconstruction.solver.compiled_solver.SolverPlan`
(joints at solver *positions*, components contiguous; ``slot[i, j]`` (i >= j) is the storage of block
(i, j) including the fill-in; ``later[k]`` the positions i > k with a block (i, k)). A component of one
joint (every problem of the MLE, which has no bones) is solved in scalars by :func:`_solve_point`, with the
same arithmetic: its iterations would otherwise be mostly call overhead.

Status codes are those of :mod:`reconstruction.solver.lm_solver`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from reconstruction.solver.lm_solver import (
    CONVERGED_COST,
    CONVERGED_GRADIENT,
    CONVERGED_STEP,
    MAX_DAMPING,
    MAX_ITERATIONS,
    MIN_DAMPING_FACTOR,
    RUNNING,
    STALLED,
    SWITCH_RHO,
)

ROBUST_CODES = {"none": 0, "huber": 1, "cauchy": 2}
_EPS_DEPTH = 1e-6  # m, as reconstruction.solver.map_estimation
_EPS = np.finfo(np.float64).eps


# error_model numpy: x / 0 = inf or NaN, no ZeroDivisionError branches (they cost run and compile time).
# _nrt False: no reference counting; the kernels allocate nothing (the caller passes every array, see
# compiled_solver.scratch), and the counts numba kept on every array view and tuple of arrays passed
# between the kernels were most of the time of a small (one-joint) problem: 2x faster, half the compile time.
# Element-wise copies instead of array assignments for the same reason: those compile numba's shape-error messages.
_JIT = {"cache": True, "error_model": "numpy", "_nrt": False}
# helpers called only from the kernels: without the CPython and C wrappers numba compiles for every function
_INNER = {**_JIT, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}
_INLINE = {**_INNER, "inline": "always"}  # _step alone: 0.3 s less compile, no slower (inlining more is slower)


@njit(**_INNER)
def _robust(r: float, kind: int, C2: float) -> tuple[float, float, float]:
    """Cost term C^2 rho(r^2 / C^2), residual scale and Jacobian scale of one raw residual (scipy's rho)."""
    z = r * r / C2
    if kind == 1:  # huber
        if z <= 1.0:
            rho, d1, d2 = z, 1.0, 0.0
        else:
            sq = np.sqrt(z)
            rho, d1, d2 = 2.0 * sq - 1.0, 1.0 / sq, -0.5 / (sq * z)
    else:  # cauchy
        rho, d1, d2 = np.log1p(z), 1.0 / (1.0 + z), -1.0 / ((1.0 + z) * (1.0 + z))
    j_scale = np.sqrt(max(d1 + 2.0 * d2 * z, _EPS))
    return C2 * rho, d1 / j_scale, j_scale


@njit(**_INNER)
def _joint_terms(
    cost: float,
    X0: float,
    X1: float,
    X2: float,
    p: int,
    j: int,
    proj: np.ndarray,
    uv: np.ndarray,
    w: np.ndarray,
    anchor: np.ndarray,
    tau2: float,
    robust: int,
    C2: float,
    derivatives: bool,
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """Joint j of person p at (X0, X1, X2): cost + its likelihood and anchor terms, its gradient (3) and the
    distinct entries of its block (00, 01, 02, 11, 12, 22); without ``derivatives`` the same cost, by the same
    operations, and the gradient and block of the anchor alone (for a trial whose derivatives go unread)."""
    dx0, dx1, dx2 = X0 - anchor[p, j, 0], X1 - anchor[p, j, 1], X2 - anchor[p, j, 2]
    cost += 0.5 * tau2 * (dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
    g0, g1, g2 = tau2 * dx0, tau2 * dx1, tau2 * dx2
    d00 = d01 = d02 = d11 = d12 = d22 = 0.0
    for v in range(proj.shape[0]):
        wv = w[v, p, j]
        if wv <= 0.0:
            continue
        h0 = proj[v, 0, 0] * X0 + proj[v, 0, 1] * X1 + proj[v, 0, 2] * X2 + proj[v, 0, 3]
        h1 = proj[v, 1, 0] * X0 + proj[v, 1, 1] * X1 + proj[v, 1, 2] * X2 + proj[v, 1, 3]
        depth = max(proj[v, 2, 0] * X0 + proj[v, 2, 1] * X1 + proj[v, 2, 2] * X2 + proj[v, 2, 3], _EPS_DEPTH)
        px, py = h0 / depth, h1 / depth
        rx, ry = (uv[v, p, j, 0] - px) * wv, (uv[v, p, j, 1] - py) * wv
        sx = sy = wv / depth
        if robust == 0:
            cost += 0.5 * (rx * rx + ry * ry)
        else:
            cx, rsx, jsx = _robust(rx, robust, C2)
            cy, rsy, jsy = _robust(ry, robust, C2)
            cost += 0.5 * (cx + cy)
            rx, ry, sx, sy = rx * rsx, ry * rsy, sx * jsx, sy * jsy
        if not derivatives:
            continue
        # dr_x/dX = -s_x (M0 - px M2), dr_y/dX = -s_y (M1 - py M2)
        a0, a1, a2 = (
            proj[v, 0, 0] - px * proj[v, 2, 0],
            proj[v, 0, 1] - px * proj[v, 2, 1],
            proj[v, 0, 2] - px * proj[v, 2, 2],
        )
        b0, b1, b2 = (
            proj[v, 1, 0] - py * proj[v, 2, 0],
            proj[v, 1, 1] - py * proj[v, 2, 1],
            proj[v, 1, 2] - py * proj[v, 2, 2],
        )
        q = sx * sx
        d00, d01, d02 = d00 + q * a0 * a0, d01 + q * a0 * a1, d02 + q * a0 * a2
        d11, d12, d22 = d11 + q * a1 * a1, d12 + q * a1 * a2, d22 + q * a2 * a2
        q = sy * sy
        d00, d01, d02 = d00 + q * b0 * b0, d01 + q * b0 * b1, d02 + q * b0 * b2
        d11, d12, d22 = d11 + q * b1 * b1, d12 + q * b1 * b2, d22 + q * b2 * b2
        ex, ey = -sx * rx, -sy * ry
        g0, g1, g2 = g0 + (ex * a0 + ey * b0), g1 + (ex * a1 + ey * b1), g2 + (ex * a2 + ey * b2)
    return cost, g0, g1, g2, d00 + tau2, d01, d02, d11 + tau2, d12, d22 + tau2


@njit(**_INNER)
def _likelihood_terms(
    x: np.ndarray,
    s: int,
    e: int,
    p: int,
    pos_joint: np.ndarray,
    proj: np.ndarray,
    uv: np.ndarray,
    w: np.ndarray,
    anchor: np.ndarray,
    tau2: float,
    robust: int,
    C2: float,
    D: np.ndarray,
    g: np.ndarray,
) -> float:
    """Likelihood + anchor cost of positions s:e; writes their blocks D (J, 3, 3) and gradients g (J, 3)."""
    cost = 0.0
    for k in range(s, e):
        X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
        cost, g0, g1, g2, d00, d01, d02, d11, d12, d22 = _joint_terms(
            cost, X0, X1, X2, p, pos_joint[k], proj, uv, w, anchor, tau2, robust, C2, True
        )
        g[k, 0], g[k, 1], g[k, 2] = g0, g1, g2
        D[k, 0, 0], D[k, 0, 1], D[k, 0, 2] = d00, d01, d02
        D[k, 1, 0], D[k, 1, 1], D[k, 1, 2] = d01, d11, d12
        D[k, 2, 0], D[k, 2, 1], D[k, 2, 2] = d02, d12, d22
    return cost


@njit(**_INNER)
def _outer_plus_identity(A: np.ndarray, l: int, c: float, d: float, u0: float, u1: float, u2: float) -> None:
    """A[l] (3, 3) = c u u^T + d I."""
    A[l, 0, 0], A[l, 0, 1], A[l, 0, 2] = c * u0 * u0 + d, c * u0 * u1, c * u0 * u2
    A[l, 1, 0], A[l, 1, 1], A[l, 1, 2] = c * u0 * u1, c * u1 * u1 + d, c * u1 * u2
    A[l, 2, 0], A[l, 2, 1], A[l, 2, 2] = c * u0 * u2, c * u1 * u2, c * u2 * u2 + d


@njit(**_INNER)
def _bone_terms(
    x: np.ndarray,
    bones: np.ndarray,
    b0: int,
    b1: int,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    ref: np.ndarray,
    bw: np.ndarray,
    p: int,
    D: np.ndarray,
    g: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
) -> float:
    """Prior cost of the bones bones[b0:b1] of person p (ref, bw (P, L)); adds their gradients to g and safe
    blocks K to D, writes K and Kr (L, 3, 3)."""
    cost = 0.0
    for t in range(b0, b1):
        l = bones[t]
        a, b = bone_pa[l], bone_pb[l]
        d0, d1, d2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if n > 1e-12:
            u0, u1, u2 = d0 / n, d1 / n, d2 / n
        else:
            u0, u1, u2 = 0.0, 0.0, 1.0
        wl = bw[p, l]
        r = wl * (ref[p, l] - n)
        cost += 0.5 * r * r
        gr = -wl * r
        g[a, 0], g[a, 1], g[a, 2] = g[a, 0] + gr * u0, g[a, 1] + gr * u1, g[a, 2] + gr * u2
        g[b, 0], g[b, 1], g[b, 2] = g[b, 0] - gr * u0, g[b, 1] - gr * u1, g[b, 2] - gr * u2
        # K = w^2 u u^T + max(curv, 0) (I - u u^T), Kr = min(curv, 0) (I - u u^T), curv = w^2 (1 - ref / n)
        curv = wl * wl * (1.0 - ref[p, l] / max(n, 1e-12))
        pos, neg = max(curv, 0.0), min(curv, 0.0)
        _outer_plus_identity(K, l, wl * wl - pos, pos, u0, u1, u2)
        _outer_plus_identity(Kr, l, -neg, neg, u0, u1, u2)
        for i in range(3):
            for m in range(3):
                D[a, i, m] += K[l, i, m]
                D[b, i, m] += K[l, i, m]
    return cost


@njit(**_INNER)
def _cholesky3(B: np.ndarray, q: int) -> bool:
    """In-place lower Cholesky factor of the symmetric 3x3 block B[q] (upper part zeroed); False if not positive definite."""
    a00 = B[q, 0, 0]
    if not a00 > 0.0:
        return False
    l00 = np.sqrt(a00)
    l10, l20 = B[q, 1, 0] / l00, B[q, 2, 0] / l00
    a11 = B[q, 1, 1] - l10 * l10
    if not a11 > 0.0:
        return False
    l11 = np.sqrt(a11)
    l21 = (B[q, 2, 1] - l20 * l10) / l11
    a22 = B[q, 2, 2] - l20 * l20 - l21 * l21
    if not a22 > 0.0:
        return False
    B[q, 0, 0], B[q, 0, 1], B[q, 0, 2] = l00, 0.0, 0.0
    B[q, 1, 0], B[q, 1, 1], B[q, 1, 2] = l10, l11, 0.0
    B[q, 2, 0], B[q, 2, 1], B[q, 2, 2] = l20, l21, np.sqrt(a22)
    return True


@njit(**_INNER)
def _lower_solve(B: np.ndarray, q: int, y0: float, y1: float, y2: float) -> tuple[float, float, float]:
    """L^-1 y for the lower 3x3 factor L = B[q]."""
    y0 = y0 / B[q, 0, 0]
    y1 = (y1 - B[q, 1, 0] * y0) / B[q, 1, 1]
    return y0, y1, (y2 - B[q, 2, 0] * y0 - B[q, 2, 1] * y1) / B[q, 2, 2]


@njit(**_INNER)
def _upper_solve(B: np.ndarray, q: int, y0: float, y1: float, y2: float) -> tuple[float, float, float]:
    """L^-T y for the lower 3x3 factor L = B[q]."""
    y2 = y2 / B[q, 2, 2]
    y1 = (y1 - B[q, 2, 1] * y2) / B[q, 1, 1]
    return (y0 - B[q, 1, 0] * y1 - B[q, 2, 0] * y2) / B[q, 0, 0], y1, y2


@njit(**_INNER)
def _assemble(
    c: int, D: np.ndarray, K: np.ndarray, Kr: np.ndarray, mu: float, exact: bool, plan: tuple, B: np.ndarray
) -> None:
    """Blocks of M + mu I of component c into B (n_blocks, 3, 3): M safe, or exact (+ Kr on the bones)."""
    _, comp_start, bones_ptr, bones, slots_ptr, slots, bone_pa, bone_pb, bone_slot, slot, _, _ = plan
    for t in range(slots_ptr[c], slots_ptr[c + 1]):
        B[slots[t]] = 0.0
    for k in range(comp_start[c], comp_start[c + 1]):
        q = slot[k, k]
        for i in range(3):
            for m in range(3):
                B[q, i, m] = D[k, i, m]
            B[q, i, i] += mu
    for t in range(bones_ptr[c], bones_ptr[c + 1]):
        l = bones[t]
        ql, qa, qb = bone_slot[l], slot[bone_pa[l], bone_pa[l]], slot[bone_pb[l], bone_pb[l]]
        for i in range(3):
            for m in range(3):
                B[ql, i, m] -= K[l, i, m]
                if exact:
                    B[ql, i, m] -= Kr[l, i, m]
                    B[qa, i, m] += Kr[l, i, m]
                    B[qb, i, m] += Kr[l, i, m]


@njit(**_INNER)
def _factorize(s: int, e: int, slot: np.ndarray, later_ptr: np.ndarray, later_idx: np.ndarray, B: np.ndarray) -> bool:
    """Right-looking block Cholesky of positions s:e in place (B holds L); False if not positive definite."""
    for k in range(s, e):
        qk = slot[k, k]
        if not _cholesky3(B, qk):
            return False
        for t in range(later_ptr[k], later_ptr[k + 1]):
            q = slot[later_idx[t], k]  # L_ik = A_ik Lkk^-T: each row solves Lkk x = row
            for r in range(3):
                B[q, r, 0], B[q, r, 1], B[q, r, 2] = _lower_solve(B, qk, B[q, r, 0], B[q, r, 1], B[q, r, 2])
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i = later_idx[t]
            qi = slot[i, k]
            for t2 in range(later_ptr[k], t + 1):
                j = later_idx[t2]
                qj, qt = slot[j, k], slot[i, j]
                for r in range(3):
                    for c in range(3):
                        B[qt, r, c] -= B[qi, r, 0] * B[qj, c, 0] + B[qi, r, 1] * B[qj, c, 1] + B[qi, r, 2] * B[qj, c, 2]
    return True


@njit(**_INNER)
def _substitute(
    s: int,
    e: int,
    g: np.ndarray,
    slot: np.ndarray,
    later_ptr: np.ndarray,
    later_idx: np.ndarray,
    B: np.ndarray,
    h: np.ndarray,
) -> None:
    """h (J, 3) = -(L L^T)^-1 g on positions s:e, L the factor in B."""
    for k in range(s, e):
        h[k, 0], h[k, 1], h[k, 2] = -g[k, 0], -g[k, 1], -g[k, 2]
    for k in range(s, e):  # L y = -g
        h[k, 0], h[k, 1], h[k, 2] = _lower_solve(B, slot[k, k], h[k, 0], h[k, 1], h[k, 2])
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i, q = later_idx[t], slot[later_idx[t], k]
            for r in range(3):
                h[i, r] -= B[q, r, 0] * h[k, 0] + B[q, r, 1] * h[k, 1] + B[q, r, 2] * h[k, 2]
    for k in range(e - 1, s - 1, -1):  # L^T h = y
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i, q = later_idx[t], slot[later_idx[t], k]
            for c in range(3):
                h[k, c] -= B[q, 0, c] * h[i, 0] + B[q, 1, c] * h[i, 1] + B[q, 2, c] * h[i, 2]
        h[k, 0], h[k, 1], h[k, 2] = _upper_solve(B, slot[k, k], h[k, 0], h[k, 1], h[k, 2])


@njit(**_JIT)
def solve_component(
    c: int,
    D: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
    g: np.ndarray,
    mu: float,
    exact: bool,
    plan: tuple,
    B: np.ndarray,
    h: np.ndarray,
) -> bool:
    """(M + mu I) h = -g on component c by block Cholesky (M exact or safe) -> h (J, 3); False if not PD.

    D (J, 3, 3), g (J, 3), K and Kr (L, 3, 3) from :func:`linearize`; plan: the SolverPlan's arrays
    (:func:`reconstruction.solver.compiled_solver.plan_arrays`); B (n_blocks, 3, 3) scratch.
    """
    s, e, slot, later_ptr, later_idx = plan[1][c], plan[1][c + 1], plan[9], plan[10], plan[11]
    _assemble(c, D, K, Kr, mu, exact, plan, B)
    if not _factorize(s, e, slot, later_ptr, later_idx, B):
        return False
    _substitute(s, e, g, slot, later_ptr, later_idx, B, h)
    return True


@njit(**_INNER)
def linearize(
    x: np.ndarray,
    c: int,
    p: int,
    data: tuple,
    tau2: float,
    robust: int,
    C2: float,
    plan: tuple,
    D: np.ndarray,
    g: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
) -> float:
    """Cost, gradient g (J, 3), safe diagonal blocks D (J, 3, 3) and bone blocks K, Kr (L, 3, 3) of component c.

    x (J, 3) holds the joints at solver positions; data = (proj (V, 3, 4), uv (V, P, J, 2), w (V, P, J)
    1/sigma (0 unseen), anchor (P, J, 3) in original joint order, ref and bw (P, L) bone lengths and
    weights); person p. K is the safe (positive semi-definite) bone block, Kr = exact - safe (see
    map_estimation.linear_blocks).
    """
    proj, uv, w, anchor, ref, bw = data
    pos_joint, comp_start, bones_ptr, bones, _, _, bone_pa, bone_pb, _, _, _, _ = plan
    s, e = comp_start[c], comp_start[c + 1]
    cost = _likelihood_terms(x, s, e, p, pos_joint, proj, uv, w, anchor, tau2, robust, C2, D, g)
    return cost + _bone_terms(x, bones, bones_ptr[c], bones_ptr[c + 1], bone_pa, bone_pb, ref, bw, p, D, g, K, Kr)


@njit(**_INNER)
def _cost(x: np.ndarray, c: int, p: int, data: tuple, tau2: float, robust: int, C2: float, plan: tuple) -> float:
    """The cost of :func:`linearize` alone (the same number): for a trial whose derivatives nobody reads."""
    proj, uv, w, anchor, ref, bw = data
    pos_joint, comp_start, bones_ptr, bones, _, _, bone_pa, bone_pb, _, _, _, _ = plan
    cost = 0.0
    for k in range(comp_start[c], comp_start[c + 1]):
        X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
        cost = _joint_terms(cost, X0, X1, X2, p, pos_joint[k], proj, uv, w, anchor, tau2, robust, C2, False)[0]
    prior = 0.0
    for t in range(bones_ptr[c], bones_ptr[c + 1]):
        l = bones[t]
        a, b = bone_pa[l], bone_pb[l]
        d0, d1, d2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        r = bw[p, l] * (ref[p, l] - np.sqrt(d0 * d0 + d1 * d1 + d2 * d2))
        prior += 0.5 * r * r
    return cost + prior


@njit(**_INNER)
def _abs_max(a: np.ndarray, s: int, e: int) -> float:
    """max |a[s:e]| of a (J, 3) array."""
    out = 0.0
    for k in range(s, e):
        for i in range(3):
            out = max(out, abs(a[k, i]))
    return out


@njit(**_INNER)
def _max_diagonal(D: np.ndarray, s: int, e: int) -> float:
    """max diag of the blocks D[s:e] (J, 3, 3)."""
    out = 0.0
    for k in range(s, e):
        for i in range(3):
            out = max(out, D[k, i, i])
    return out


@njit(**_INLINE)
def _step(c: int, lin: tuple, mu: float, exact: bool, plan: tuple, B: np.ndarray, h: np.ndarray) -> bool:
    """The damped step h of component c (the exact model where asked and positive definite, else the safe
    one; NaN where neither is) -> whether the exact model was used."""
    D, g, K, Kr = lin
    ok = solve_component(c, D, K, Kr, g, mu, exact, plan, B, h)
    used = ok and exact
    if not ok and exact:  # exact model not positive definite: the safe one (not exact = False, typed bool)
        ok = solve_component(c, D, K, Kr, g, mu, not exact, plan, B, h)
    if not ok:
        for k in range(plan[1][c], plan[1][c + 1]):
            h[k, 0] = h[k, 1] = h[k, 2] = np.nan
    return used


@njit(**_INNER)
def _solve_problem(
    x: np.ndarray,
    c: int,
    p: int,
    data: tuple,
    tau2: float,
    robust: int,
    C2: float,
    plan: tuple,
    settings: tuple,
    work: tuple,
) -> tuple[float, int, int]:
    """Levenberg-Marquardt of person p's component c from x (J, 3) (updated in place) -> cost, iterations, status.

    settings = (max_iterations, xtol, ftol, gtol, tau); work: scratch (x_new, h, B, lin, trial), lin and trial
    each (D, g, K, Kr) (see :func:`linearize`).
    """
    max_iterations, xtol, ftol, gtol, tau = settings
    x_new, h, B, lin, trial = work
    s, e = plan[1][c], plan[1][c + 1]
    f = linearize(x, c, p, data, tau2, robust, C2, plan, lin[0], lin[1], lin[2], lin[3])
    scale = _max_diagonal(lin[0], s, e)
    scale = scale if scale > 0.0 else 1.0
    status = CONVERGED_GRADIENT if _abs_max(lin[1], s, e) <= gtol else RUNNING
    # exact starts False, typed bool: a literal False would compile a second specialisation of _step
    mu, nu, exact, it = tau * scale, 2.0, scale < 0.0, 0
    has_exact = plan[2][c + 1] > plan[2][c]
    while status == RUNNING and it < max_iterations:
        it += 1
        used = _step(c, lin, mu, exact, plan, B, h)
        predicted = 0.0
        for k in range(s, e):
            for i in range(3):
                predicted += 0.5 * h[k, i] * (mu * h[k, i] - lin[1][k, i])
                x_new[k, i] = x[k, i] + h[k, i]
        h_max = _abs_max(h, s, e) if not np.isnan(predicted) else np.nan  # NaN step: never accepted
        if h_max <= xtol:  # the last trial, accepted or not (see the tests below): its derivatives go unread
            f_t = _cost(x_new, c, p, data, tau2, robust, C2, plan)
        else:
            f_t = linearize(x_new, c, p, data, tau2, robust, C2, plan, trial[0], trial[1], trial[2], trial[3])
        actual = f - f_t
        rho = actual / predicted if predicted != 0.0 else np.nan
        accept = predicted > 0.0 and rho > 0.0 and np.isfinite(f_t + h_max)
        if used:
            exact = False  # a failed exact step is retried with the safe model
        if accept:
            mu *= max(MIN_DAMPING_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            exact = rho >= SWITCH_RHO and has_exact
            for k in range(s, e):  # element-wise: an array assignment compiles numba's shape-error formatting
                x[k, 0], x[k, 1], x[k, 2] = x_new[k, 0], x_new[k, 1], x_new[k, 2]
            lin, trial = trial, lin
            if h_max <= xtol:
                status = CONVERGED_STEP
            elif actual <= ftol * max(f, 0.0):
                status = CONVERGED_COST
            elif _abs_max(lin[1], s, e) <= gtol:
                status = CONVERGED_GRADIENT
            f = f_t
        elif not used:
            if h_max <= xtol:
                status = CONVERGED_STEP
            mu *= nu
            nu *= 2.0
            if mu > MAX_DAMPING * scale and status == RUNNING:
                status = STALLED
    return f, it, MAX_ITERATIONS if status == RUNNING else status


@njit(**_INNER)
def _point_step(
    g0: float, g1: float, g2: float, b00: float, b01: float, b02: float, b11: float, b12: float, b22: float
) -> tuple[float, float, float]:
    """-B^-1 g of one symmetric 3x3 block B (distinct entries) by the arithmetic of _cholesky3 and the two
    triangular solves; NaN if B is not positive definite."""
    if not b00 > 0.0:
        return np.nan, np.nan, np.nan
    l00 = np.sqrt(b00)
    l10, l20 = b01 / l00, b02 / l00
    a11 = b11 - l10 * l10
    if not a11 > 0.0:
        return np.nan, np.nan, np.nan
    l11 = np.sqrt(a11)
    l21 = (b12 - l20 * l10) / l11
    a22 = b22 - l20 * l20 - l21 * l21
    if not a22 > 0.0:
        return np.nan, np.nan, np.nan
    l22 = np.sqrt(a22)
    y0 = -g0 / l00
    y1 = (-g1 - l10 * y0) / l11
    y2 = (-g2 - l20 * y0 - l21 * y1) / l22
    y2 = y2 / l22
    y1 = (y1 - l21 * y2) / l11
    return (y0 - l10 * y1 - l20 * y2) / l00, y1, y2


@njit(**_INNER)
def _solve_point(
    x: np.ndarray, k: int, p: int, j: int, data: tuple, tau2: float, robust: int, C2: float, settings: tuple
) -> tuple[float, int, int]:
    """:func:`_solve_problem` of a component of one joint (no bone: every MLE problem), the joint at position k
    of x, in scalars: the same arithmetic and decisions without the block machinery's call overhead."""
    max_iterations, xtol, ftol, gtol, tau = settings
    proj, uv, w, anchor = data[0], data[1], data[2], data[3]
    X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
    f, g0, g1, g2, d00, d01, d02, d11, d12, d22 = _joint_terms(
        0.0, X0, X1, X2, p, j, proj, uv, w, anchor, tau2, robust, C2, True
    )
    scale = max(max(max(0.0, d00), d11), d22)
    scale = scale if scale > 0.0 else 1.0
    status = CONVERGED_GRADIENT if max(max(max(0.0, abs(g0)), abs(g1)), abs(g2)) <= gtol else RUNNING
    mu, nu, it = tau * scale, 2.0, 0
    while status == RUNNING and it < max_iterations:
        it += 1
        h0, h1, h2 = _point_step(g0, g1, g2, d00 + mu, d01, d02, d11 + mu, d12, d22 + mu)
        predicted = 0.0  # summed in _solve_problem's order
        predicted += 0.5 * h0 * (mu * h0 - g0)
        predicted += 0.5 * h1 * (mu * h1 - g1)
        predicted += 0.5 * h2 * (mu * h2 - g2)
        n0, n1, n2 = X0 + h0, X1 + h1, X2 + h2
        h_max = max(max(max(0.0, abs(h0)), abs(h1)), abs(h2)) if not np.isnan(predicted) else np.nan
        # a step under xtol ends the solve, accepted or not (see _solve_problem): that trial's cost alone
        trial = _joint_terms(0.0, n0, n1, n2, p, j, proj, uv, w, anchor, tau2, robust, C2, not h_max <= xtol)
        actual = f - trial[0]
        rho = actual / predicted if predicted != 0.0 else np.nan
        if predicted > 0.0 and rho > 0.0 and np.isfinite(trial[0] + h_max):
            mu *= max(MIN_DAMPING_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            X0, X1, X2 = n0, n1, n2
            f_old = f
            f, g0, g1, g2, d00, d01, d02, d11, d12, d22 = trial
            if h_max <= xtol:
                status = CONVERGED_STEP
            elif actual <= ftol * max(f_old, 0.0):
                status = CONVERGED_COST
            elif max(max(max(0.0, abs(g0)), abs(g1)), abs(g2)) <= gtol:
                status = CONVERGED_GRADIENT
        else:
            if h_max <= xtol:
                status = CONVERGED_STEP
            mu *= nu
            nu *= 2.0
            if mu > MAX_DAMPING * scale and status == RUNNING:
                status = STALLED
    x[k, 0], x[k, 1], x[k, 2] = X0, X1, X2
    return f, it, MAX_ITERATIONS if status == RUNNING else status


@njit(**_JIT)
def solve_all(
    X: np.ndarray,
    data: tuple,
    tau2: float,
    robust: int,
    C2: float,
    plan: tuple,
    settings: tuple,
    work: tuple,
    cost_out: np.ndarray,
    it_out: np.ndarray,
    status_out: np.ndarray,
) -> None:
    """Levenberg-Marquardt of every (person, component) problem; X (P, J, 3) is updated in place (original order).

    data: see :func:`linearize`; plan: the SolverPlan's arrays; settings and work (scratch): see
    :func:`_solve_problem`. cost_out, it_out, status_out (P, C) receive the final cost, iterations and
    status of each problem.
    """
    pos_joint, comp_start = plan[0], plan[1]
    x = work[0]
    for p in range(X.shape[0]):
        for k in range(X.shape[1]):
            for i in range(3):
                x[k, i] = X[p, pos_joint[k], i]
        for c in range(len(comp_start) - 1):
            s = comp_start[c]
            if comp_start[c + 1] - s == 1:  # one joint, no bone
                result = _solve_point(x, s, p, pos_joint[s], data, tau2, robust, C2, settings)
            else:
                result = _solve_problem(x, c, p, data, tau2, robust, C2, plan, settings, work[1:])
            cost_out[p, c], it_out[p, c], status_out[p, c] = result
        for k in range(X.shape[1]):
            for i in range(3):
                X[p, pos_joint[k], i] = x[k, i]
