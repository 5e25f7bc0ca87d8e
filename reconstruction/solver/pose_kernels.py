"""Compiled (numba) Levenberg-Marquardt of the MLE / MAP pose problems, one (person, bone-graph component) at a time."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

RUNNING, CONVERGED_STEP, CONVERGED_COST, CONVERGED_GRADIENT, STALLED, MAX_ITERATIONS = 0, 1, 2, 3, 4, 5
MAX_DAMPING = 1e16  # relative to max diag(H): no step can reduce the cost any more
SWITCH_RHO = 0.25  # gain ratio of an accepted safe step after which the exact model is used
MIN_DAMPING_FACTOR = 1.0 / 3.0  # Nielsen: an accepted step shrinks mu by at most this factor
ROBUST_CODES = {"none": 0, "huber": 1, "cauchy": 2}
EPS_DEPTH = 1e-6  # m; projections of points behind a camera are clamped to this depth
_EPS = np.finfo(np.float64).eps

# error_model numpy: x / 0 = inf or NaN, no ZeroDivisionError branches. _nrt False: no reference counting (the
# kernels allocate nothing; the caller passes every array), which dominated the time of one-joint problems.
# Element-wise copies instead of array assignments for the same reason: those compile numba's shape-error messages.
_JIT = {"cache": True, "error_model": "numpy", "_nrt": False}
_INNER = {**_JIT, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}  # helpers called only from the kernels
_INLINE = {**_INNER, "inline": "always"}


class Problem(NamedTuple):
    """The kernels' problem (arrays in joint order)."""

    proj: np.ndarray  # (V, 3, 4)
    uv: np.ndarray  # (V, P, J, 2) px
    w: np.ndarray  # (V, P, J) 1/sigma, 0 unseen
    anchor: np.ndarray  # (P, J, 3)
    ref: np.ndarray  # (P, L) bone lengths (m)
    bw: np.ndarray  # (P, L) bone weights (1/m)
    tau2: float  # anchor weight^2
    robust: int  # ROBUST_CODES
    C2: float


class Settings(NamedTuple):
    """Stopping tests and the initial damping mu_0 = tau max diag(H)."""

    max_iterations: int
    xtol: float
    ftol: float
    gtol: float
    tau: float


class Plan(NamedTuple):
    """Block layout of one bone graph (J joints, L bones, C components); CSR lists as (ptr, idx) pairs."""

    pos_joint: np.ndarray  # (J,) joint at each position
    comp_start: np.ndarray  # (C + 1,) first position of each component, then J
    comp_bones_ptr: np.ndarray  # (C + 1,) CSR of the bones of each component
    comp_bones: np.ndarray
    comp_slots_ptr: np.ndarray  # (C + 1,) CSR of the block storage indices of each component
    comp_slots: np.ndarray
    bone_pa: np.ndarray  # (L,) positions of each bone's ends
    bone_pb: np.ndarray
    bone_slot: np.ndarray  # (L,) storage index of each bone's off-diagonal block
    slot: np.ndarray  # (J, J) storage index of block (i, j), i >= j, -1 where structurally zero
    later_ptr: np.ndarray  # (J + 1,) CSR of the positions i > k with a block (i, k)
    later_idx: np.ndarray


class Linearisation(NamedTuple):
    """Safe diagonal blocks D (J, 3, 3), gradient g (J, 3), safe bone blocks K and exact - safe Kr (L, 3, 3)."""

    D: np.ndarray
    g: np.ndarray
    K: np.ndarray
    Kr: np.ndarray


class Work(NamedTuple):
    """Scratch: x, x_new, h (J, 3) at solver positions, B (n_blocks, 3, 3), the current and the trial linearisation."""

    x: np.ndarray
    x_new: np.ndarray
    h: np.ndarray
    B: np.ndarray
    lin: Linearisation
    trial: Linearisation


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
    cost: float, X0: float, X1: float, X2: float, p: int, j: int, prob: Problem, derivatives: bool
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """Joint j of person p at (X0, X1, X2) -> cost + its terms, gradient (3), block (00 01 02 11 12 22)."""
    proj, tau2 = prob.proj, prob.tau2
    dx0, dx1, dx2 = X0 - prob.anchor[p, j, 0], X1 - prob.anchor[p, j, 1], X2 - prob.anchor[p, j, 2]
    cost += 0.5 * tau2 * (dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
    g0, g1, g2 = tau2 * dx0, tau2 * dx1, tau2 * dx2
    d00 = d01 = d02 = d11 = d12 = d22 = 0.0
    for v in range(proj.shape[0]):
        wv = prob.w[v, p, j]
        if wv <= 0.0:
            continue
        h0 = proj[v, 0, 0] * X0 + proj[v, 0, 1] * X1 + proj[v, 0, 2] * X2 + proj[v, 0, 3]
        h1 = proj[v, 1, 0] * X0 + proj[v, 1, 1] * X1 + proj[v, 1, 2] * X2 + proj[v, 1, 3]
        depth = max(proj[v, 2, 0] * X0 + proj[v, 2, 1] * X1 + proj[v, 2, 2] * X2 + proj[v, 2, 3], EPS_DEPTH)
        px, py = h0 / depth, h1 / depth
        rx, ry = (prob.uv[v, p, j, 0] - px) * wv, (prob.uv[v, p, j, 1] - py) * wv
        sx = sy = wv / depth
        if prob.robust == 0:
            cost += 0.5 * (rx * rx + ry * ry)
        else:
            cx, rsx, jsx = _robust(rx, prob.robust, prob.C2)
            cy, rsy, jsy = _robust(ry, prob.robust, prob.C2)
            cost += 0.5 * (cx + cy)
            rx, ry, sx, sy = rx * rsx, ry * rsy, sx * jsx, sy * jsy
        if not derivatives:
            continue
        a0, a1, a2 = (  # dr_x/dX = -s_x (M0 - px M2), dr_y/dX = -s_y (M1 - py M2)
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
def _outer_plus_identity(A: np.ndarray, l: int, c: float, d: float, u0: float, u1: float, u2: float) -> None:
    """A[l] (3, 3) = c u u^T + d I."""
    A[l, 0, 0], A[l, 0, 1], A[l, 0, 2] = c * u0 * u0 + d, c * u0 * u1, c * u0 * u2
    A[l, 1, 0], A[l, 1, 1], A[l, 1, 2] = c * u0 * u1, c * u1 * u1 + d, c * u1 * u2
    A[l, 2, 0], A[l, 2, 1], A[l, 2, 2] = c * u0 * u2, c * u1 * u2, c * u2 * u2 + d


@njit(**_INNER)
def _bone_terms(x: np.ndarray, c: int, p: int, prob: Problem, plan: Plan, lin: Linearisation) -> float:
    """Prior cost of component c's bones of person p; adds to lin.g and lin.D, writes lin.K and lin.Kr."""
    cost = 0.0
    D, g, K, Kr = lin
    for t in range(plan.comp_bones_ptr[c], plan.comp_bones_ptr[c + 1]):
        l = plan.comp_bones[t]
        a, b = plan.bone_pa[l], plan.bone_pb[l]
        d0, d1, d2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if n > 1e-12:
            u0, u1, u2 = d0 / n, d1 / n, d2 / n
        else:
            u0, u1, u2 = 0.0, 0.0, 1.0
        wl = prob.bw[p, l]
        r = wl * (prob.ref[p, l] - n)
        cost += 0.5 * r * r
        gr = -wl * r
        g[a, 0], g[a, 1], g[a, 2] = g[a, 0] + gr * u0, g[a, 1] + gr * u1, g[a, 2] + gr * u2
        g[b, 0], g[b, 1], g[b, 2] = g[b, 0] - gr * u0, g[b, 1] - gr * u1, g[b, 2] - gr * u2
        curv = wl * wl * (1.0 - prob.ref[p, l] / max(n, 1e-12))
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
    """In-place lower Cholesky factor of the symmetric 3x3 block B[q] (upper part zeroed); False if not PD."""
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
def _assemble(c: int, lin: Linearisation, mu: float, exact: bool, plan: Plan, B: np.ndarray) -> None:
    """Blocks of M + mu I of component c into B (n_blocks, 3, 3): M safe, or exact (+ Kr on the bones)."""
    D, _, K, Kr = lin
    slot = plan.slot
    for t in range(plan.comp_slots_ptr[c], plan.comp_slots_ptr[c + 1]):
        B[plan.comp_slots[t]] = 0.0
    for k in range(plan.comp_start[c], plan.comp_start[c + 1]):
        q = slot[k, k]
        for i in range(3):
            for m in range(3):
                B[q, i, m] = D[k, i, m]
            B[q, i, i] += mu
    for t in range(plan.comp_bones_ptr[c], plan.comp_bones_ptr[c + 1]):
        l = plan.comp_bones[t]
        ql, qa, qb = plan.bone_slot[l], slot[plan.bone_pa[l], plan.bone_pa[l]], slot[plan.bone_pb[l], plan.bone_pb[l]]
        for i in range(3):
            for m in range(3):
                B[ql, i, m] -= K[l, i, m]
                if exact:
                    B[ql, i, m] -= Kr[l, i, m]
                    B[qa, i, m] += Kr[l, i, m]
                    B[qb, i, m] += Kr[l, i, m]


@njit(**_INNER)
def _factorize(s: int, e: int, plan: Plan, B: np.ndarray) -> bool:
    """Right-looking block Cholesky of positions s:e in place (B holds L); False if not positive definite."""
    slot, later_ptr, later_idx = plan.slot, plan.later_ptr, plan.later_idx
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
def _substitute(s: int, e: int, g: np.ndarray, plan: Plan, B: np.ndarray, h: np.ndarray) -> None:
    """h (J, 3) = -(L L^T)^-1 g on positions s:e, L the factor in B."""
    slot, later_ptr, later_idx = plan.slot, plan.later_ptr, plan.later_idx
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
    c: int, lin: Linearisation, mu: float, exact: bool, plan: Plan, B: np.ndarray, h: np.ndarray
) -> bool:
    """(M + mu I) h = -g on component c by block Cholesky (M exact or safe) -> h (J, 3); False if not PD."""
    s, e = plan.comp_start[c], plan.comp_start[c + 1]
    _assemble(c, lin, mu, exact, plan, B)
    if not _factorize(s, e, plan, B):
        return False
    _substitute(s, e, lin.g, plan, B, h)
    return True


@njit(**_INNER)
def linearize(x: np.ndarray, c: int, p: int, prob: Problem, plan: Plan, lin: Linearisation) -> float:
    """Cost of component c of person p at x (J, 3) (solver positions); writes lin (see :class:`Linearisation`)."""
    cost = 0.0
    D, g = lin.D, lin.g
    for k in range(plan.comp_start[c], plan.comp_start[c + 1]):
        cost, g0, g1, g2, d00, d01, d02, d11, d12, d22 = _joint_terms(
            cost, x[k, 0], x[k, 1], x[k, 2], p, plan.pos_joint[k], prob, True
        )
        g[k, 0], g[k, 1], g[k, 2] = g0, g1, g2
        D[k, 0, 0], D[k, 0, 1], D[k, 0, 2] = d00, d01, d02
        D[k, 1, 0], D[k, 1, 1], D[k, 1, 2] = d01, d11, d12
        D[k, 2, 0], D[k, 2, 1], D[k, 2, 2] = d02, d12, d22
    return cost + _bone_terms(x, c, p, prob, plan, lin)


@njit(**_INNER)
def cost_only(x: np.ndarray, c: int, p: int, prob: Problem, plan: Plan) -> float:
    """The cost of :func:`linearize` alone (the same number): for a trial whose derivatives nobody reads."""
    cost = 0.0
    for k in range(plan.comp_start[c], plan.comp_start[c + 1]):
        cost = _joint_terms(cost, x[k, 0], x[k, 1], x[k, 2], p, plan.pos_joint[k], prob, False)[0]
    prior = 0.0
    for t in range(plan.comp_bones_ptr[c], plan.comp_bones_ptr[c + 1]):
        l = plan.comp_bones[t]
        a, b = plan.bone_pa[l], plan.bone_pb[l]
        d0, d1, d2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        r = prob.bw[p, l] * (prob.ref[p, l] - np.sqrt(d0 * d0 + d1 * d1 + d2 * d2))
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
def _step(c: int, lin: Linearisation, mu: float, exact: bool, plan: Plan, B: np.ndarray, h: np.ndarray) -> bool:
    """The damped step h of component c (exact model where asked and PD, else safe; NaN where neither) -> exact used."""
    ok = solve_component(c, lin, mu, exact, plan, B, h)
    used = ok and exact
    if not ok and exact:  # exact model not positive definite: the safe one (not exact = False, typed bool)
        ok = solve_component(c, lin, mu, not exact, plan, B, h)
    if not ok:
        for k in range(plan.comp_start[c], plan.comp_start[c + 1]):
            h[k, 0] = h[k, 1] = h[k, 2] = np.nan
    return used


@njit(**_INNER)
def _accepted(mu: float, rho: float, h_max: float, actual: float, f_old: float, g_max: float, st: Settings):
    """Damping and status after an accepted step (Nielsen's rule; step, cost and gradient tests in this order)."""
    mu *= max(MIN_DAMPING_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3)
    if h_max <= st.xtol:
        return mu, CONVERGED_STEP
    if actual <= st.ftol * max(f_old, 0.0):
        return mu, CONVERGED_COST
    return mu, CONVERGED_GRADIENT if g_max <= st.gtol else RUNNING


@njit(**_INNER)
def _rejected(mu: float, nu: float, h_max: float, scale: float, st: Settings) -> tuple[float, float, int]:
    """Damping mu, its growth nu and status after a rejected step."""
    status = CONVERGED_STEP if h_max <= st.xtol else RUNNING
    mu *= nu
    if mu > MAX_DAMPING * scale and status == RUNNING:
        status = STALLED
    return mu, nu * 2.0, status


@njit(**_INNER)
def _predicted(x: np.ndarray, h: np.ndarray, g: np.ndarray, mu: float, s: int, e: int, x_new: np.ndarray) -> float:
    """Predicted decrease 0.5 h^T (mu h - g) of the step h on positions s:e; writes x_new = x + h."""
    predicted = 0.0
    for k in range(s, e):
        for i in range(3):
            predicted += 0.5 * h[k, i] * (mu * h[k, i] - g[k, i])
            x_new[k, i] = x[k, i] + h[k, i]
    return predicted


@njit(**_INNER)
def _solve_problem(c: int, p: int, prob: Problem, plan: Plan, st: Settings, work: Work) -> tuple[float, int, int]:
    """Levenberg-Marquardt of person p's component c from work.x (J, 3) (updated) -> cost, iterations, status."""
    x, x_new, h, B, lin, trial = work
    s, e = plan.comp_start[c], plan.comp_start[c + 1]
    f = linearize(x, c, p, prob, plan, lin)
    scale = _max_diagonal(lin.D, s, e)
    scale = scale if scale > 0.0 else 1.0
    status = CONVERGED_GRADIENT if _abs_max(lin.g, s, e) <= st.gtol else RUNNING
    # exact starts False, typed bool: a literal False would compile a second specialisation of _step
    mu, nu, exact, it = st.tau * scale, 2.0, scale < 0.0, 0
    has_exact = plan.comp_bones_ptr[c + 1] > plan.comp_bones_ptr[c]
    while status == RUNNING and it < st.max_iterations:
        it += 1
        used = _step(c, lin, mu, exact, plan, B, h)
        predicted = _predicted(x, h, lin.g, mu, s, e, x_new)
        h_max = _abs_max(h, s, e) if not np.isnan(predicted) else np.nan  # NaN step: never accepted
        if h_max <= st.xtol:  # the last trial, accepted or not: its derivatives go unread
            f_t = cost_only(x_new, c, p, prob, plan)
        else:
            f_t = linearize(x_new, c, p, prob, plan, trial)
        actual = f - f_t
        rho = actual / predicted if predicted != 0.0 else np.nan
        if used:
            exact = False  # a failed exact step is retried with the safe model
        if predicted > 0.0 and rho > 0.0 and np.isfinite(f_t + h_max):
            exact = rho >= SWITCH_RHO and has_exact
            for k in range(s, e):
                x[k, 0], x[k, 1], x[k, 2] = x_new[k, 0], x_new[k, 1], x_new[k, 2]
            lin, trial = trial, lin
            mu, status = _accepted(mu, rho, h_max, actual, f, _abs_max(lin.g, s, e), st)
            nu, f = 2.0, f_t
        elif not used:
            mu, nu, status = _rejected(mu, nu, h_max, scale, st)
    return f, it, MAX_ITERATIONS if status == RUNNING else status


@njit(**_INNER)
def _point_step(
    g0: float, g1: float, g2: float, b00: float, b01: float, b02: float, b11: float, b12: float, b22: float
) -> tuple[float, float, float]:
    """-B^-1 g of one symmetric 3x3 block B (distinct entries) by _cholesky3's arithmetic; NaN if B is not PD."""
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
def _abs_max3(a: float, b: float, c: float) -> float:
    """max(0, |a|, |b|, |c|) in _abs_max's order."""
    return max(max(max(0.0, abs(a)), abs(b)), abs(c))


@njit(**_INNER)
def _solve_point(x: np.ndarray, k: int, p: int, j: int, prob: Problem, st: Settings) -> tuple[float, int, int]:
    """:func:`_solve_problem` of a one-joint component (every MLE problem) at position k of x, in scalars."""
    X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
    f, g0, g1, g2, d00, d01, d02, d11, d12, d22 = _joint_terms(0.0, X0, X1, X2, p, j, prob, True)
    scale = max(max(max(0.0, d00), d11), d22)
    scale = scale if scale > 0.0 else 1.0
    status = CONVERGED_GRADIENT if _abs_max3(g0, g1, g2) <= st.gtol else RUNNING
    mu, nu, it = st.tau * scale, 2.0, 0
    while status == RUNNING and it < st.max_iterations:
        it += 1
        h0, h1, h2 = _point_step(g0, g1, g2, d00 + mu, d01, d02, d11 + mu, d12, d22 + mu)
        predicted = 0.0  # summed in _predicted's order
        predicted += 0.5 * h0 * (mu * h0 - g0)
        predicted += 0.5 * h1 * (mu * h1 - g1)
        predicted += 0.5 * h2 * (mu * h2 - g2)
        n0, n1, n2 = X0 + h0, X1 + h1, X2 + h2
        h_max = _abs_max3(h0, h1, h2) if not np.isnan(predicted) else np.nan
        # a step under xtol ends the solve, accepted or not: that trial's cost alone
        trial = _joint_terms(0.0, n0, n1, n2, p, j, prob, not h_max <= st.xtol)
        actual = f - trial[0]
        rho = actual / predicted if predicted != 0.0 else np.nan
        if predicted > 0.0 and rho > 0.0 and np.isfinite(trial[0] + h_max):
            X0, X1, X2 = n0, n1, n2
            f_old = f
            f, g0, g1, g2, d00, d01, d02, d11, d12, d22 = trial
            mu, status = _accepted(mu, rho, h_max, actual, f_old, _abs_max3(g0, g1, g2), st)
            nu = 2.0
        else:
            mu, nu, status = _rejected(mu, nu, h_max, scale, st)
    x[k, 0], x[k, 1], x[k, 2] = X0, X1, X2
    return f, it, MAX_ITERATIONS if status == RUNNING else status


@njit(**_JIT)
def solve_all(
    X: np.ndarray,
    prob: Problem,
    plan: Plan,
    st: Settings,
    work: Work,
    cost: np.ndarray,
    it: np.ndarray,
    status: np.ndarray,
) -> None:
    """Levenberg-Marquardt of every (person, component): X (P, J, 3) in place; final cost, it, status (P, C)."""
    pos_joint, comp_start, x = plan.pos_joint, plan.comp_start, work.x
    for p in range(X.shape[0]):
        for k in range(X.shape[1]):
            for i in range(3):
                x[k, i] = X[p, pos_joint[k], i]
        for c in range(len(comp_start) - 1):
            s = comp_start[c]
            if comp_start[c + 1] - s == 1:  # one joint, no bone
                result = _solve_point(x, s, p, pos_joint[s], prob, st)
            else:
                result = _solve_problem(c, p, prob, plan, st, work)
            cost[p, c], it[p, c], status[p, c] = result
        for k in range(X.shape[1]):
            for i in range(3):
                X[p, pos_joint[k], i] = x[k, i]
