"""Compiled (numba) kernels of the MLE / MAP pose problems: linearisation, block Cholesky, Levenberg-Marquardt.

The same problem, damping rule, step acceptance and stopping tests as the batched numpy solver
(:mod:`reconstruction.solver.lm_solver` with :mod:`reconstruction.solver.map_estimation`), one (person, bone-graph
component) problem at a time in compiled loops: a crowd of small problems costs arithmetic, not
numpy call overhead. The normal equations are 3x3 blocks per joint coupled along the bones, factorised
by a block Cholesky in the elimination order of a :class:`reconstruction.solver.compiled_solver.SolverPlan`
(joints at solver *positions*, components contiguous; ``slot[i, j]`` (i >= j) is the storage of block
(i, j) including the fill-in; ``later[k]`` the positions i > k with a block (i, k)).

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


@njit(cache=True)
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


@njit(cache=True)
def _add_outer(A: np.ndarray, s: float, a0: float, a1: float, a2: float) -> None:
    """A (3, 3) += s a a^T."""
    A[0, 0] += s * a0 * a0
    A[0, 1] += s * a0 * a1
    A[0, 2] += s * a0 * a2
    A[1, 1] += s * a1 * a1
    A[1, 2] += s * a1 * a2
    A[2, 2] += s * a2 * a2
    A[1, 0] = A[0, 1]
    A[2, 0] = A[0, 2]
    A[2, 1] = A[1, 2]


@njit(cache=True, inline="always")
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
    V = proj.shape[0]
    cost = 0.0
    for k in range(s, e):
        j = pos_joint[k]
        Dk, gk = D[k], g[k]
        Dk[:, :] = 0.0
        X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
        dx0, dx1, dx2 = X0 - anchor[p, j, 0], X1 - anchor[p, j, 1], X2 - anchor[p, j, 2]
        cost += 0.5 * tau2 * (dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
        gk[0], gk[1], gk[2] = tau2 * dx0, tau2 * dx1, tau2 * dx2
        for v in range(V):
            wv = w[v, p, j]
            if wv <= 0.0:
                continue
            M = proj[v]
            h0 = M[0, 0] * X0 + M[0, 1] * X1 + M[0, 2] * X2 + M[0, 3]
            h1 = M[1, 0] * X0 + M[1, 1] * X1 + M[1, 2] * X2 + M[1, 3]
            depth = max(M[2, 0] * X0 + M[2, 1] * X1 + M[2, 2] * X2 + M[2, 3], _EPS_DEPTH)
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
            # dr_x/dX = -s_x (M0 - px M2), dr_y/dX = -s_y (M1 - py M2)
            a0, a1, a2 = M[0, 0] - px * M[2, 0], M[0, 1] - px * M[2, 1], M[0, 2] - px * M[2, 2]
            b0, b1, b2 = M[1, 0] - py * M[2, 0], M[1, 1] - py * M[2, 1], M[1, 2] - py * M[2, 2]
            _add_outer(Dk, sx * sx, a0, a1, a2)
            _add_outer(Dk, sy * sy, b0, b1, b2)
            ex, ey = -sx * rx, -sy * ry
            gk[0] += ex * a0 + ey * b0
            gk[1] += ex * a1 + ey * b1
            gk[2] += ex * a2 + ey * b2
        Dk[0, 0] += tau2
        Dk[1, 1] += tau2
        Dk[2, 2] += tau2
    return cost


@njit(cache=True, inline="always")
def _bone_terms(
    x: np.ndarray,
    bones: np.ndarray,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    ref: np.ndarray,
    bw: np.ndarray,
    D: np.ndarray,
    g: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
) -> float:
    """Prior cost of the bones; adds their gradients to g and safe blocks K to D, writes K and Kr (L, 3, 3)."""
    cost = 0.0
    for l in bones:
        a, b = bone_pa[l], bone_pb[l]
        d0, d1, d2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if n > 1e-12:
            u0, u1, u2 = d0 / n, d1 / n, d2 / n
        else:
            u0, u1, u2 = 0.0, 0.0, 1.0
        wl = bw[l]
        r = wl * (ref[l] - n)
        cost += 0.5 * r * r
        gr = -wl * r
        g[a, 0] += gr * u0
        g[a, 1] += gr * u1
        g[a, 2] += gr * u2
        g[b, 0] -= gr * u0
        g[b, 1] -= gr * u1
        g[b, 2] -= gr * u2
        # K = w^2 u u^T + max(curv, 0) (I - u u^T), Kr = min(curv, 0) (I - u u^T), curv = w^2 (1 - ref / n)
        curv = wl * wl * (1.0 - ref[l] / max(n, 1e-12))
        pos, neg = max(curv, 0.0), min(curv, 0.0)
        Kl, Krl = K[l], Kr[l]
        Kl[:, :] = 0.0
        Krl[:, :] = 0.0
        _add_outer(Kl, wl * wl - pos, u0, u1, u2)
        _add_outer(Krl, -neg, u0, u1, u2)
        for i in range(3):
            Kl[i, i] += pos
            Krl[i, i] += neg
        for i in range(3):
            for m in range(3):
                D[a, i, m] += Kl[i, m]
                D[b, i, m] += Kl[i, m]
    return cost


@njit(cache=True)
def linearize(
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
    bones: np.ndarray,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    ref: np.ndarray,
    bw: np.ndarray,
    D: np.ndarray,
    g: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
) -> float:
    """Cost, gradient g (J, 3), safe diagonal blocks D (J, 3, 3) and bone blocks K, Kr (L, 3, 3) of positions s:e.

    x (J, 3) holds the joints at solver positions; person p of uv (V, P, J, 2), w (V, P, J) (1/sigma,
    0 unseen), anchor (P, J, 3) in original joint order. bones: the component's bone indices. K is the
    safe (positive semi-definite) bone block, Kr = exact - safe (see map_estimation.linear_blocks).
    """
    cost = _likelihood_terms(x, s, e, p, pos_joint, proj, uv, w, anchor, tau2, robust, C2, D, g)
    return cost + _bone_terms(x, bones, bone_pa, bone_pb, ref, bw, D, g, K, Kr)


@njit(cache=True)
def _cholesky3(A: np.ndarray) -> bool:
    """In-place lower Cholesky factor of a symmetric 3x3 block (upper part zeroed); False if not positive definite."""
    a00 = A[0, 0]
    if not a00 > 0.0:
        return False
    l00 = np.sqrt(a00)
    l10, l20 = A[1, 0] / l00, A[2, 0] / l00
    a11 = A[1, 1] - l10 * l10
    if not a11 > 0.0:
        return False
    l11 = np.sqrt(a11)
    l21 = (A[2, 1] - l20 * l10) / l11
    a22 = A[2, 2] - l20 * l20 - l21 * l21
    if not a22 > 0.0:
        return False
    A[0, 0], A[0, 1], A[0, 2] = l00, 0.0, 0.0
    A[1, 0], A[1, 1], A[1, 2] = l10, l11, 0.0
    A[2, 0], A[2, 1], A[2, 2] = l20, l21, np.sqrt(a22)
    return True


@njit(cache=True)
def _lower_solve(L: np.ndarray, y: np.ndarray) -> None:
    """y (3,) <- L^-1 y for a lower 3x3 factor."""
    y[0] = y[0] / L[0, 0]
    y[1] = (y[1] - L[1, 0] * y[0]) / L[1, 1]
    y[2] = (y[2] - L[2, 0] * y[0] - L[2, 1] * y[1]) / L[2, 2]


@njit(cache=True)
def _upper_solve(L: np.ndarray, y: np.ndarray) -> None:
    """y (3,) <- L^-T y for a lower 3x3 factor."""
    y[2] = y[2] / L[2, 2]
    y[1] = (y[1] - L[2, 1] * y[2]) / L[1, 1]
    y[0] = (y[0] - L[1, 0] * y[1] - L[2, 0] * y[2]) / L[0, 0]


@njit(cache=True, inline="always")
def _assemble(
    s: int,
    e: int,
    D: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
    mu: float,
    exact: bool,
    bones: np.ndarray,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    bone_slot: np.ndarray,
    slot: np.ndarray,
    slots: np.ndarray,
    B: np.ndarray,
) -> None:
    """Blocks of M + mu I of positions s:e into B (n_blocks, 3, 3): M safe, or exact (+ Kr on the bones)."""
    for q in slots:
        B[q, :, :] = 0.0
    for k in range(s, e):
        Bk = B[slot[k, k]]
        Bk[:, :] = D[k]
        for i in range(3):
            Bk[i, i] += mu
    for l in bones:
        Bl, Ba, Bb = B[bone_slot[l]], B[slot[bone_pa[l], bone_pa[l]]], B[slot[bone_pb[l], bone_pb[l]]]
        for i in range(3):
            for m in range(3):
                Bl[i, m] -= K[l, i, m]
                if exact:
                    Bl[i, m] -= Kr[l, i, m]
                    Ba[i, m] += Kr[l, i, m]
                    Bb[i, m] += Kr[l, i, m]


@njit(cache=True, inline="always")
def _factorize(s: int, e: int, slot: np.ndarray, later_ptr: np.ndarray, later_idx: np.ndarray, B: np.ndarray) -> bool:
    """Right-looking block Cholesky of positions s:e in place (B holds L); False if not positive definite."""
    for k in range(s, e):
        Lkk = B[slot[k, k]]
        if not _cholesky3(Lkk):
            return False
        for t in range(later_ptr[k], later_ptr[k + 1]):
            A = B[slot[later_idx[t], k]]  # L_ik = A_ik Lkk^-T: each row solves Lkk x = row
            for r in range(3):
                _lower_solve(Lkk, A[r])
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i = later_idx[t]
            Li = B[slot[i, k]]
            for t2 in range(later_ptr[k], t + 1):
                j = later_idx[t2]
                Lj, T = B[slot[j, k]], B[slot[i, j]]
                for r in range(3):
                    for c in range(3):
                        T[r, c] -= Li[r, 0] * Lj[c, 0] + Li[r, 1] * Lj[c, 1] + Li[r, 2] * Lj[c, 2]
    return True


@njit(cache=True, inline="always")
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
        _lower_solve(B[slot[k, k]], h[k])
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i = later_idx[t]
            Li = B[slot[i, k]]
            for r in range(3):
                h[i, r] -= Li[r, 0] * h[k, 0] + Li[r, 1] * h[k, 1] + Li[r, 2] * h[k, 2]
    for k in range(e - 1, s - 1, -1):  # L^T h = y
        for t in range(later_ptr[k], later_ptr[k + 1]):
            i = later_idx[t]
            Li = B[slot[i, k]]
            for c in range(3):
                h[k, c] -= Li[0, c] * h[i, 0] + Li[1, c] * h[i, 1] + Li[2, c] * h[i, 2]
        _upper_solve(B[slot[k, k]], h[k])


@njit(cache=True)
def solve_component(
    s: int,
    e: int,
    D: np.ndarray,
    K: np.ndarray,
    Kr: np.ndarray,
    g: np.ndarray,
    mu: float,
    exact: bool,
    bones: np.ndarray,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    bone_slot: np.ndarray,
    slot: np.ndarray,
    slots: np.ndarray,
    later_ptr: np.ndarray,
    later_idx: np.ndarray,
    B: np.ndarray,
    h: np.ndarray,
) -> bool:
    """(M + mu I) h = -g on positions s:e by block Cholesky (M exact or safe) -> h (J, 3); False if not PD.

    D (J, 3, 3), K and Kr (L, 3, 3) from :func:`linearize`; slots: the block storage indices of this
    component; B (n_blocks, 3, 3) scratch.
    """
    _assemble(s, e, D, K, Kr, mu, exact, bones, bone_pa, bone_pb, bone_slot, slot, slots, B)
    if not _factorize(s, e, slot, later_ptr, later_idx, B):
        return False
    _substitute(s, e, g, slot, later_ptr, later_idx, B, h)
    return True


@njit(cache=True, inline="always")
def _abs_max(a: np.ndarray, s: int, e: int) -> float:
    """max |a[s:e]| of a (J, 3) array."""
    out = 0.0
    for k in range(s, e):
        for i in range(3):
            out = max(out, abs(a[k, i]))
    return out


@njit(cache=True, inline="always")
def _max_diagonal(D: np.ndarray, s: int, e: int) -> float:
    """max diag of the blocks D[s:e] (J, 3, 3)."""
    out = 0.0
    for k in range(s, e):
        for i in range(3):
            out = max(out, D[k, i, i])
    return out


@njit(cache=True)
def solve_all(
    X: np.ndarray,
    proj: np.ndarray,
    uv: np.ndarray,
    w: np.ndarray,
    anchor: np.ndarray,
    tau2: float,
    robust: int,
    C2: float,
    ref: np.ndarray,
    bw: np.ndarray,
    pos_joint: np.ndarray,
    comp_start: np.ndarray,
    comp_bones_ptr: np.ndarray,
    comp_bones: np.ndarray,
    comp_slots_ptr: np.ndarray,
    comp_slots: np.ndarray,
    bone_pa: np.ndarray,
    bone_pb: np.ndarray,
    bone_slot: np.ndarray,
    slot: np.ndarray,
    later_ptr: np.ndarray,
    later_idx: np.ndarray,
    max_iterations: int,
    xtol: float,
    ftol: float,
    gtol: float,
    tau: float,
    cost_out: np.ndarray,
    it_out: np.ndarray,
    status_out: np.ndarray,
) -> None:
    """Levenberg-Marquardt of every (person, component) problem; X (P, J, 3) is updated in place (original order).

    ref, bw (P, L): each person's bone reference lengths and weights. cost_out, it_out, status_out (P, C)
    receive the final cost, iterations and status of each problem.
    """
    P, J = X.shape[0], X.shape[1]
    L = ref.shape[1]
    C = len(comp_start) - 1
    n_blocks = slot.max() + 1
    x, x_new, h = np.empty((J, 3)), np.empty((J, 3)), np.empty((J, 3))
    D, D_t, g, g_t = np.empty((J, 3, 3)), np.empty((J, 3, 3)), np.empty((J, 3)), np.empty((J, 3))
    K, K_t, Kr, Kr_t = np.empty((L, 3, 3)), np.empty((L, 3, 3)), np.empty((L, 3, 3)), np.empty((L, 3, 3))
    B = np.empty((n_blocks, 3, 3))
    for p in range(P):
        ref_p, bw_p = ref[p], bw[p]
        for k in range(J):
            x[k] = X[p, pos_joint[k]]
        for c in range(C):
            s, e = comp_start[c], comp_start[c + 1]
            bones = comp_bones[comp_bones_ptr[c] : comp_bones_ptr[c + 1]]
            slots = comp_slots[comp_slots_ptr[c] : comp_slots_ptr[c + 1]]
            f = linearize(
                x,
                s,
                e,
                p,
                pos_joint,
                proj,
                uv,
                w,
                anchor,
                tau2,
                robust,
                C2,
                bones,
                bone_pa,
                bone_pb,
                ref_p,
                bw_p,
                D,
                g,
                K,
                Kr,
            )
            scale = _max_diagonal(D, s, e)
            scale = scale if scale > 0.0 else 1.0
            status = CONVERGED_GRADIENT if _abs_max(g, s, e) <= gtol else RUNNING
            mu, nu, exact, it = tau * scale, 2.0, False, 0
            has_exact = len(bones) > 0
            while status == RUNNING and it < max_iterations:
                it += 1
                used = False
                ok = False
                if exact:
                    ok = solve_component(
                        s,
                        e,
                        D,
                        K,
                        Kr,
                        g,
                        mu,
                        True,
                        bones,
                        bone_pa,
                        bone_pb,
                        bone_slot,
                        slot,
                        slots,
                        later_ptr,
                        later_idx,
                        B,
                        h,
                    )
                    used = ok
                if not ok and not solve_component(
                    s,
                    e,
                    D,
                    K,
                    Kr,
                    g,
                    mu,
                    False,
                    bones,
                    bone_pa,
                    bone_pb,
                    bone_slot,
                    slot,
                    slots,
                    later_ptr,
                    later_idx,
                    B,
                    h,
                ):
                    h[s:e] = np.nan
                predicted = 0.0
                for k in range(s, e):
                    for i in range(3):
                        predicted += 0.5 * h[k, i] * (mu * h[k, i] - g[k, i])
                        x_new[k, i] = x[k, i] + h[k, i]
                h_max = _abs_max(h, s, e) if not np.isnan(predicted) else np.nan  # NaN step: never accepted
                f_t = linearize(
                    x_new,
                    s,
                    e,
                    p,
                    pos_joint,
                    proj,
                    uv,
                    w,
                    anchor,
                    tau2,
                    robust,
                    C2,
                    bones,
                    bone_pa,
                    bone_pb,
                    ref_p,
                    bw_p,
                    D_t,
                    g_t,
                    K_t,
                    Kr_t,
                )
                actual = f - f_t
                rho = actual / predicted if predicted != 0.0 else np.nan
                accept = predicted > 0.0 and rho > 0.0 and np.isfinite(f_t + h_max)
                if used:
                    exact = False  # a failed exact step is retried with the safe model
                if accept:
                    mu *= max(MIN_DAMPING_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3)
                    nu = 2.0
                    exact = rho >= SWITCH_RHO and has_exact
                    x[s:e] = x_new[s:e]
                    D, D_t, g, g_t, K, K_t, Kr, Kr_t = D_t, D, g_t, g, K_t, K, Kr_t, Kr
                    if h_max <= xtol:
                        status = CONVERGED_STEP
                    elif actual <= ftol * max(f, 0.0):
                        status = CONVERGED_COST
                    elif _abs_max(g, s, e) <= gtol:
                        status = CONVERGED_GRADIENT
                    f = f_t
                elif not used:
                    if h_max <= xtol:
                        status = CONVERGED_STEP
                    mu *= nu
                    nu *= 2.0
                    if mu > MAX_DAMPING * scale and status == RUNNING:
                        status = STALLED
            cost_out[p, c] = f
            it_out[p, c] = it
            status_out[p, c] = MAX_ITERATIONS if status == RUNNING else status
        for k in range(J):
            X[p, pos_joint[k]] = x[k]
