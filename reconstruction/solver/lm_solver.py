"""A batched Levenberg-Marquardt (trust-region) solver for many independent least-squares problems.

A batch holds B units (persons, or joints) of N variables; the variables of a unit are split into C
contiguous components that do not interact (the face and the body of a person), and every (unit,
component) pair is its own problem with its own damping mu, step acceptance and convergence test.
All of them are stepped together, one stacked linear solve per iteration. The problem is given by a
:class:`Model` (see there); :func:`levenberg_marquardt` wraps plain callbacks with dense normal
equations (C = 1).

Damping follows H. B. Nielsen, "Damping parameter in Marquardt's method" (IMM-REP-1999-05), also
Madsen, Nielsen & Tingleff, "Methods for non-linear least squares problems" (2004), Alg. 3.16:
mu_0 = tau * max diag(H); the step solves (H + mu I) h = -g; gain ratio rho = actual / predicted
decrease with predicted = 0.5 h^T (mu h - g); rho > 0 accepts and sets mu *= max(1/3, 1 - (2 rho - 1)^3),
nu = 2; otherwise mu *= nu, nu *= 2. The damping is the trust-region radius in disguise (a larger mu
is a smaller region), which is how the paper's "trust region method" is realised here.

A model may offer a better but possibly indefinite curvature model (e.g. the exact Hessian). A
problem steps with the safe H until a step is accepted with rho >= SWITCH_RHO, then with the exact
one; when exact H + mu I is not positive definite (its Cholesky factorisation fails) the same
iteration falls back to H, and a rejected exact step is retried with H without raising the damping.
Near the optimum this converges quadratically where Gauss-Newton converges only linearly (large
residuals).

The linear systems of 3D poses are block-sparse (3x3 blocks per joint, coupled along the bones):
reconstruction/solver/block_solver.py solves them: densely per person for a few persons, by a batched
block elimination for many.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Callable, Protocol

import numpy as np

from reconstruction.solver.block_solver import spd_solve

Linearize = Callable[[np.ndarray, np.ndarray], tuple]
CostFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

# Status codes per problem.
RUNNING, CONVERGED_STEP, CONVERGED_COST, CONVERGED_GRADIENT, STALLED, MAX_ITERATIONS = 0, 1, 2, 3, 4, 5
MAX_DAMPING = 1e16  # relative to max diag(H): no step can reduce the cost any more
SWITCH_RHO = 0.25  # gain ratio of an accepted safe step after which the exact model is used
MIN_DAMPING_FACTOR = 1.0 / 3.0  # Nielsen: an accepted step shrinks mu by at most this factor
COMPRESS_BELOW = 0.8  # drop the stopped units when at most this share of the batch runs (else keep stepping 0)


@dataclass
class LMResult:
    """x (B, N) solutions; cost, iterations and status (see the codes) per problem, (B, C)."""

    x: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    status: np.ndarray


class Model(Protocol):
    """B units of N variables in C components (contiguous, from ``starts`` (C,)); ``has_exact`` (C,) bool
    marks components with an exact curvature model. A linearisation ``lin`` is any object with
    ``cost`` (b, C) and ``g`` (b, N) (the gradient) for the units idx (b,) it was made for."""

    starts: np.ndarray
    has_exact: np.ndarray

    def linearize(self, x: np.ndarray, idx: np.ndarray) -> Any:
        """Linearisation of the units idx (b,) at x (b, N)."""

    def trial(self, x: np.ndarray, idx: np.ndarray) -> Any:
        """What a trial point x (b, N) needs: at least its ``cost`` (b, C) (a full linearisation if cheaper)."""

    def accept(self, lin: Any, trial: Any, x: np.ndarray, idx: np.ndarray, ok: np.ndarray) -> Any:
        """lin with the (unit, component) problems where ok (b, C) replaced by the linearisation at x."""

    def take(self, lin: Any, keep: np.ndarray) -> Any:
        """lin of the units where keep (b,) bool."""

    def max_diagonal(self, lin: Any) -> np.ndarray:
        """max diag(H) of every problem, (b, C)."""

    def step(self, lin: Any, mu: np.ndarray, exact: np.ndarray, run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Steps solving (M + mu I) h = -g, M exact where flagged, else safe -> h (b, N), used exact (b, C).

        Components where run (b, C) is False get h = 0; a singular system gives a NaN step.
        """


@dataclass
class _State:
    """Per-problem solver state of the active units, (a, C) each, and their variables x (a, N)."""

    x: np.ndarray
    f: np.ndarray
    mu: np.ndarray
    nu: np.ndarray
    scale: np.ndarray
    exact: np.ndarray
    status: np.ndarray
    iterations: np.ndarray

    def take(self, keep: np.ndarray) -> "_State":
        """The state of the units where keep (a,) bool."""
        return _State(*(getattr(self, f.name)[keep] for f in fields(self)))


def minimize(
    x0: np.ndarray,
    model: Model,
    max_iterations: int = 50,
    xtol: float = 1e-6,
    ftol: float = 1e-10,
    gtol: float = 1e-10,
    tau: float = 1e-3,
) -> LMResult:
    """Minimise the B x C independent costs of a model from x0 (B, N) -> LMResult.

    A problem stops when a safe step (accepted or not) has max |h| <= xtol (units of x), when an
    accepted step lowers the cost by at most ftol * cost, when max |g| <= gtol, when the damping
    exceeds MAX_DAMPING * max diag(H) (nothing left to gain), or after max_iterations steps.
    Stopped problems take no step; their units leave the batch once COMPRESS_BELOW of it is running.
    """
    x = np.array(x0, dtype=np.float64)
    B, N = x.shape
    seg = _Segments(np.asarray(model.starts), N)
    act = np.arange(B)
    lin = model.linearize(x, act)
    scale = model.max_diagonal(lin)
    scale = np.where(scale > 0, scale, 1.0)
    status = np.where(seg.max(np.abs(lin.g)) <= gtol, CONVERGED_GRADIENT, RUNNING)
    s = _State(
        x.copy(),
        np.array(lin.cost, dtype=np.float64),
        tau * scale,
        np.full(scale.shape, 2.0),
        scale,
        np.zeros(scale.shape, dtype=bool),
        status,
        np.zeros(scale.shape, dtype=np.int64),
    )
    out = _State(x, s.f.copy(), s.mu, s.nu, s.scale, s.exact, s.status.copy(), s.iterations.copy())
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # non-finite trials are rejected
        for _ in range(int(max_iterations)):
            run = s.status == RUNNING
            keep = run.any(axis=1)
            running = np.count_nonzero(keep)
            if running == 0:
                break
            if running <= COMPRESS_BELOW * len(keep):
                _store(out, s, act, ~keep)
                act, s, run, lin = act[keep], s.take(keep), run[keep], model.take(lin, keep)
            s.iterations += run
            h, used = model.step(lin, s.mu, s.exact & run, run)
            x_new = s.x + h
            trial = model.trial(x_new, act)
            predicted = 0.5 * seg.sum(h * (s.mu[:, seg.comp_of] * h - lin.g))
            actual = s.f - trial.cost
            h_max = seg.max(np.abs(h))  # NaN if h has a NaN
            rho = actual / predicted
            ok = run & (predicted > 0) & (rho > 0) & np.isfinite(trial.cost + h_max)
            s.exact &= ~used  # a failed exact step is retried with the safe model
            if ok.any():
                s.mu = np.where(ok, s.mu * np.maximum(MIN_DAMPING_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3), s.mu)
                s.nu[ok] = 2.0
                s.exact = np.where(ok, (rho >= SWITCH_RHO) & model.has_exact, s.exact)
                s.x = np.where(ok[:, seg.comp_of], x_new, s.x)
                lin = model.accept(lin, trial, x_new, act, ok)
                done = np.where(
                    h_max <= xtol,
                    CONVERGED_STEP,
                    np.where(
                        actual <= ftol * np.maximum(s.f, 0.0),
                        CONVERGED_COST,
                        np.where(seg.max(np.abs(lin.g)) <= gtol, CONVERGED_GRADIENT, RUNNING),
                    ),
                )
                s.f = np.where(ok, lin.cost, s.f)
                s.status = np.where(ok, done, s.status)
            rej = run & ~ok & ~used
            if rej.any():
                s.status[rej & (h_max <= xtol)] = CONVERGED_STEP
                s.mu = np.where(rej, s.mu * s.nu, s.mu)
                s.nu = np.where(rej, 2.0 * s.nu, s.nu)
                s.status[rej & (s.mu > MAX_DAMPING * s.scale) & (s.status == RUNNING)] = STALLED
    _store(out, s, act, np.ones(len(act), dtype=bool))
    out.status[out.status == RUNNING] = MAX_ITERATIONS
    return LMResult(out.x, out.f, out.iterations, out.status)


class _Segments:
    """Reductions over the variables of each component (contiguous from starts (C,)): (b, N) -> (b, C)."""

    def __init__(self, starts: np.ndarray, N: int) -> None:
        self.starts = starts
        self.comp_of = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, N)))  # (N,)
        self.one = len(starts) == 1
        self.indicator = (self.comp_of[:, None] == np.arange(len(starts))).astype(float)  # (N, C)

    def max(self, a: np.ndarray) -> np.ndarray:
        """Max per component."""
        if self.one or len(a) == 0:
            return np.max(a, axis=1, keepdims=True, initial=-np.inf) if len(a) else np.zeros((0, len(self.starts)))
        return np.maximum.reduceat(a, self.starts, axis=1)

    def sum(self, a: np.ndarray) -> np.ndarray:
        """Sum per component."""
        return a.sum(axis=1, keepdims=True) if self.one else a @ self.indicator


def _store(out: _State, s: _State, act: np.ndarray, mask: np.ndarray) -> None:
    """Write the state of the active units where mask (a,) into the full-batch output."""
    idx = act[mask]
    out.x[idx], out.f[idx], out.status[idx], out.iterations[idx] = (
        s.x[mask],
        s.f[mask],
        s.status[mask],
        s.iterations[mask],
    )


# --- dense callbacks --------------------------------------------------------------------------------
@dataclass
class _Dense:
    """A dense linearisation: cost (b, 1), H (b, N, N), g (b, N), exact H (b, N, N) or None."""

    cost: np.ndarray
    H: np.ndarray
    g: np.ndarray
    He: np.ndarray | None


class DenseModel:
    """A Model of one component from callbacks (see :func:`levenberg_marquardt`)."""

    starts = np.zeros(1, dtype=np.int64)

    def __init__(self, linearize: Linearize, cost: CostFn) -> None:
        self._linearize, self._cost = linearize, cost
        self.has_exact = np.zeros(1, dtype=bool)

    def linearize(self, x: np.ndarray, idx: np.ndarray) -> _Dense:
        """Callback linearisation; the first one decides whether there is an exact model."""
        out = self._linearize(x, idx)
        He = np.asarray(out[3], dtype=np.float64) if len(out) > 3 and out[3] is not None else None
        self.has_exact = np.array([He is not None])
        return _Dense(
            np.asarray(out[0], dtype=np.float64)[:, None],
            np.asarray(out[1], dtype=np.float64),
            np.asarray(out[2], dtype=np.float64),
            He,
        )

    def trial(self, x: np.ndarray, idx: np.ndarray) -> _Dense:
        """Only the cost of a trial point."""
        return _Dense(np.asarray(self._cost(x, idx), dtype=np.float64)[:, None], None, None, None)

    def accept(self, lin: _Dense, trial: _Dense, x: np.ndarray, idx: np.ndarray, ok: np.ndarray) -> _Dense:
        """Relinearise the accepted units."""
        rows = ok[:, 0]
        new = self.linearize(x[rows], idx[rows])
        lin = self.take(lin, np.ones(len(rows), dtype=bool))
        lin.cost[rows], lin.H[rows], lin.g[rows] = new.cost, new.H, new.g
        if lin.He is not None:
            lin.He[rows] = new.He
        return lin

    def take(self, lin: _Dense, keep: np.ndarray) -> _Dense:
        """The units where keep."""
        return _Dense(lin.cost[keep], lin.H[keep], lin.g[keep], None if lin.He is None else lin.He[keep])

    def max_diagonal(self, lin: _Dense) -> np.ndarray:
        """max diag(H), (b, 1)."""
        return np.max(np.diagonal(lin.H, axis1=1, axis2=2), axis=1, initial=0.0)[:, None]

    def step(self, lin: _Dense, mu: np.ndarray, exact: np.ndarray, run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Dense LAPACK solves, exact model first where flagged."""
        N = lin.g.shape[1]
        h, used = np.zeros_like(lin.g), exact[:, 0].copy()
        for i in np.flatnonzero(run[:, 0]):
            damp = mu[i, 0] * np.eye(N)
            ok = False
            if used[i]:
                h[i], ok = spd_solve(lin.He[i] + damp, -lin.g[i])
                used[i] = ok
            if not ok:
                h[i], ok = spd_solve(lin.H[i] + damp, -lin.g[i])
                h[i] = h[i] if ok else np.nan
        return h, used[:, None]


def levenberg_marquardt(
    x0: np.ndarray,
    linearize: Linearize,
    cost: CostFn,
    max_iterations: int = 50,
    xtol: float = 1e-6,
    ftol: float = 1e-10,
    gtol: float = 1e-10,
    tau: float = 1e-3,
) -> LMResult:
    """Minimise B independent costs from x0 (B, N) given by callbacks over a subset idx of the batch -> LMResult.

    ``linearize(x (b, N), idx (b,)) -> (cost (b,), H (b, N, N), g (b, N)[, H_exact (b, N, N) | None])``
    with cost = 0.5 |r|^2, H = J^T J (or any positive semi-definite model of the cost's curvature)
    and g = J^T r; ``cost(x (b, N), idx (b,)) -> (b,)``. See :func:`minimize` for the stopping rules.
    """
    return minimize(x0, DenseModel(linearize, cost), max_iterations, xtol, ftol, gtol, tau)
