"""Batched small linear algebra shared by the geometry and the solver."""

from __future__ import annotations

import numpy as np

_CYCLIC = np.ix_([1, 2, 0, 1, 2], [1, 2, 0, 1, 2])  # E[i, j] = A[(i + 1) % 3, (j + 1) % 3]


def inverse_3x3(A: np.ndarray, check: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Inverses (inf / NaN if singular), positive definiteness (if check) of symmetric (3, 3, ...) -> same, (...)."""
    E = A[_CYCLIC]  # cofactor (i, j) = A[i+1, j+1] A[i+2, j+2] - A[i+1, j+2] A[i+2, j+1], mod 3
    cof = E[:3, :3] * E[1:4, 1:4] - E[:3, 1:4] * E[1:4, :3]
    det = (A[0] * cof[0]).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = cof / det
    return inv, ((A[0, 0] > 0) & (cof[2, 2] > 0) & (det > 0)) if check else None
