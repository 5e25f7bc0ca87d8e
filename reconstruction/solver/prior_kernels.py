"""Compiled (numba) loops of the person prior's statistics (person_prior.py): per-joint 3x3 sums over the views.

Same arithmetic in the same order as the numpy formulas they replace (bit-identical results), without
their (V, P, J, 3, 3) temporaries. Compiled like pose_kernels: numpy's error model, no reference counting
(the caller allocates every array).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = {"cache": True, "error_model": "numpy", "_nrt": False}


@njit(**_JIT)
def information_sums(xy: np.ndarray, z: np.ndarray, proj: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """out (P, J, 3, 3) = sum over k = x, y of sum over views of r r^T, r = (M_k - xy_k M_2) w / z: the
    Gauss-Newton information of each joint from its pixels xy (V, P, J, 2), depths z (V, P, J), views proj
    (V, 3, 4) and 1/sigma w (V, P, J) (0 unseen)."""
    V, P, J = w.shape
    for p in range(P):
        for j in range(J):
            b00 = b01 = b02 = b11 = b12 = b22 = 0.0
            for k in range(2):
                a00 = a01 = a02 = a11 = a12 = a22 = 0.0
                for v in range(V):
                    s, x = w[v, p, j] / z[v, p, j], xy[v, p, j, k]
                    r0 = (proj[v, k, 0] - x * proj[v, 2, 0]) * s
                    r1 = (proj[v, k, 1] - x * proj[v, 2, 1]) * s
                    r2 = (proj[v, k, 2] - x * proj[v, 2, 2]) * s
                    a00, a01, a02 = a00 + r0 * r0, a01 + r0 * r1, a02 + r0 * r2
                    a11, a12, a22 = a11 + r1 * r1, a12 + r1 * r2, a22 + r2 * r2
                b00, b01, b02, b11, b12, b22 = b00 + a00, b01 + a01, b02 + a02, b11 + a11, b12 + a12, b22 + a22
            out[p, j, 0, 0], out[p, j, 0, 1], out[p, j, 0, 2] = b00, b01, b02
            out[p, j, 1, 0], out[p, j, 1, 1], out[p, j, 1, 2] = b01, b11, b12
            out[p, j, 2, 0], out[p, j, 2, 1], out[p, j, 2, 2] = b02, b12, b22
