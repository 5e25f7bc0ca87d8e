"""A batched Levenberg-Marquardt (trust-region) solver for many independent least-squares problems.

Every problem b has its own state x_b (N,), damping mu_b and convergence test, so a batch of persons
(or joints) is solved with one stacked linear solve per iteration. The problem is given by two
callbacks over a subset ``idx`` of the batch:

- ``linearize(x (b, N), idx (b,)) -> (cost (b,), H (b, N, N), g (b, N)[, H_exact (b, N, N) | None])``
  with cost = 0.5 |r|^2 (or the robust cost), H = J^T J (or any positive semi-definite model of the
  cost's curvature) and g = J^T r, the gradient;
- ``cost(x (b, N), idx (b,)) -> (b,)``.

Damping follows H. B. Nielsen, "Damping parameter in Marquardt's method" (IMM-REP-1999-05), also
Madsen, Nielsen & Tingleff, "Methods for non-linear least squares problems" (2004), Alg. 3.16:
mu_0 = tau * max diag(H); the step solves (H + mu I) h = -g; gain ratio rho = actual / predicted
decrease with predicted = 0.5 h^T (mu h - g); rho > 0 accepts and sets mu *= max(1/3, 1 - (2 rho - 1)^3),
nu = 2; otherwise mu *= nu, nu *= 2. The damping is the trust-region radius in disguise (a larger mu
is a smaller region), which is how the paper's "trust region method" is realised here.

The optional H_exact is a better but possibly indefinite curvature model (e.g. the exact Hessian).
A problem steps with the safe H until a step is accepted with rho >= SWITCH_RHO, then with H_exact;
when H_exact + mu I is not positive definite (its Cholesky factorisation fails) the same iteration
falls back to H, and a rejected exact step is retried with H without raising the damping. Near the
optimum this converges quadratically where Gauss-Newton converges only linearly (large residuals).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.linalg import lapack

Linearize = Callable[[np.ndarray, np.ndarray], tuple]
CostFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

# Status codes per problem.
RUNNING, CONVERGED_STEP, CONVERGED_COST, CONVERGED_GRADIENT, STALLED, MAX_ITERATIONS = 0, 1, 2, 3, 4, 5
MAX_DAMPING = 1e16  # relative to max diag(H): no step can reduce the cost any more
SWITCH_RHO = 0.25   # gain ratio of an accepted safe step after which the exact model is used
CHOLESKY_MIN_N = 30  # from this size a loop of LAPACK dposv beats numpy's batched LU on one core


@dataclass
class LMResult:
    """x (B, N) solutions, cost (B,), iterations (B,) and status (B,) per problem (see the codes)."""

    x: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    status: np.ndarray


def levenberg_marquardt(x0: np.ndarray, linearize: Linearize, cost: CostFn, max_iterations: int = 50,
                        xtol: float = 1e-6, ftol: float = 1e-10, gtol: float = 1e-10,
                        tau: float = 1e-3) -> LMResult:
    """Minimise B independent costs from x0 (B, N) -> LMResult.

    A problem stops when a safe step (accepted or not) has max |h| <= xtol (units of x), when an
    accepted step lowers the cost by at most ftol * cost, when max |g| <= gtol, when the damping
    exceeds MAX_DAMPING * max diag(H) (nothing left to gain), or after max_iterations steps.
    """
    x = np.array(x0, dtype=np.float64)
    B, N = x.shape
    f, H, g, He = _unpack(linearize(x, np.arange(B)), copy=True)
    scale = np.max(np.diagonal(H, axis1=1, axis2=2), axis=1, initial=0.0)
    scale = np.where(scale > 0, scale, 1.0)
    mu, nu = tau * scale, np.full(B, 2.0)
    exact = np.zeros(B, dtype=bool)
    iterations = np.zeros(B, dtype=np.int64)
    status = np.where(np.max(np.abs(g), axis=1, initial=0.0) <= gtol, CONVERGED_GRADIENT, RUNNING)
    for _ in range(int(max_iterations)):
        act = np.flatnonzero(status == RUNNING)
        if len(act) == 0:
            break
        iterations[act] += 1
        h, used = _steps(H, He, g, mu, exact, act)
        x_new = x[act] + h
        f_new = cost(x_new, act)
        predicted = 0.5 * np.einsum("bn,bn->b", h, mu[act, None] * h - g[act])
        actual = f[act] - f_new
        rho = np.where(predicted > 0, actual / np.where(predicted > 0, predicted, 1.0), -1.0)
        ok = np.isfinite(f_new) & np.all(np.isfinite(h), axis=1) & (rho > 0)
        acc = act[ok]
        mu[acc] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho[ok] - 1.0) ** 3)
        nu[acc] = 2.0
        exact[acc] = (rho[ok] >= SWITCH_RHO) & (He is not None)
        retry = ~ok & used                              # failed exact step: retry with the safe model
        exact[act[retry]] = False
        rej, h_rej = act[~ok & ~used], h[~ok & ~used]
        status[rej[np.max(np.abs(h_rej), axis=1, initial=0.0) <= xtol]] = CONVERGED_STEP
        mu[rej] *= nu[rej]
        nu[rej] *= 2.0
        status[rej[(mu[rej] > MAX_DAMPING * scale[rej]) & (status[rej] == RUNNING)]] = STALLED
        if len(acc):
            x[acc] = x_new[ok]
            f_acc, H[acc], g[acc], He_acc = _unpack(linearize(x_new[ok], acc))
            if He is not None:
                He[acc] = He_acc
            small_step = np.max(np.abs(h[ok]), axis=1) <= xtol
            small_gain = actual[ok] <= ftol * np.maximum(f[acc], 0.0)
            f[acc] = f_acc
            flat = np.max(np.abs(g[acc]), axis=1) <= gtol
            status[acc] = np.select([small_step, small_gain, flat],
                                    [CONVERGED_STEP, CONVERGED_COST, CONVERGED_GRADIENT], RUNNING)
    status[status == RUNNING] = MAX_ITERATIONS
    return LMResult(x, f, iterations, status)


def _unpack(out: tuple, copy: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(cost, H, g, H_exact or None) from a linearize result of 3 or 4 arrays, as float arrays (copies if asked)."""
    convert = np.array if copy else np.asarray
    f, H, g = (convert(a, dtype=np.float64) for a in out[:3])
    He = convert(out[3], dtype=np.float64) if len(out) > 3 and out[3] is not None else None
    if He is not None and copy and np.shares_memory(He, H):
        He = He.copy()
    return f, H, g, He


def _steps(H: np.ndarray, He: np.ndarray | None, g: np.ndarray, mu: np.ndarray, exact: np.ndarray,
           act: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Damped steps of the active problems and whether each used H_exact: -> (a, N), (a,) bool.

    Solves (M + mu I) h = -g with M = H_exact where flagged, else H; a flagged problem whose
    H_exact + mu I is not positive definite uses H. A singular system gives a NaN step.
    """
    N = H.shape[1]
    use = exact[act] if He is not None else np.zeros(len(act), dtype=bool)
    if He is None and N < CHOLESKY_MIN_N:
        A = H[act] + mu[act, None, None] * np.eye(N)
        try:
            return np.linalg.solve(A, -g[act][..., None])[..., 0], use
        except np.linalg.LinAlgError:
            pass
    steps = -g[act]
    A = np.where(use[:, None, None], He[act], H[act]) if He is not None else H[act]
    A = A + mu[act, None, None] * np.eye(N)
    for i in range(len(act)):
        _, h, info = lapack.dposv(A[i].T, steps[i], overwrite_a=1)    # symmetric: .T is F-ordered, no copy
        if info > 0 and use[i]:
            use[i] = False
            safe = H[act[i]] + mu[act[i]] * np.eye(N)
            _, h, info = lapack.dposv(safe.T, steps[i], overwrite_a=1)
        steps[i] = h if info == 0 else np.nan
    return steps, use
