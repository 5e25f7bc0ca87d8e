"""Compiled passes of the 2D pixel sigma model (:func:`reconstruction.solver.map_estimation.joint_sigma`) and of the
solver's observations: one pass over the joints each instead of numpy's masks, divisions and ``where`` (the
observations of a 100-person 7-view frame: 146 -> 51 us). The scores' powers stay numpy's (its pow differs from
libm's by an ulp, and is most of joint_sigma's time), so the sigmas are the same numbers as numpy's arithmetic gives."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def sigmas_of_joints(points: np.ndarray, spread: np.ndarray, powed: np.ndarray, sigma_min: float) -> np.ndarray:
    """max(sigma_min, spread / powed) of the seen joints (score > 0, finite pixel), inf elsewhere: points (N, J, 3),
    spread (N,) the box's sqrt(sigma_px^2 + (c size)^2), powed (N, J) the scores' powers -> (N, J) (NaN as np.maximum)."""
    N, J = powed.shape
    out = np.empty((N, J))
    for n in range(N):
        for j in range(J):
            if points[n, j, 2] > 0.0 and np.isfinite(points[n, j, 0]) and np.isfinite(points[n, j, 1]):
                v = spread[n] / powed[n, j]
                out[n, j] = v if (v != v or v > sigma_min) else sigma_min
            else:
                out[n, j] = np.inf
    return out


@njit(cache=True, error_model="numpy")
def observations(points: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The solver's pixels (N, J, 2) (np.nan_to_num of points' x, y) and 1 / sigma (N, J) (0 where sigma is not
    finite) of points (N, J, 3) and their sigmas (N, J)."""
    N, J = sigma.shape
    big = np.finfo(np.float64).max
    uv, inv = np.empty((N, J, 2)), np.empty((N, J))
    for n in range(N):
        for j in range(J):
            for i in range(2):
                x = points[n, j, i]
                uv[n, j, i] = x if np.isfinite(x) else (0.0 if x != x else (big if x > 0 else -big))
            s = sigma[n, j]
            inv[n, j] = 1.0 / s if np.isfinite(s) else 0.0
    return uv, inv
