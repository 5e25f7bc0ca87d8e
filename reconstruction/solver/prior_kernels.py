"""Compiled (numba) loops of the person prior (person_prior.py): joint information, bone variances and posteriors."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from reconstruction.solver.pose_kernels import EPS_DEPTH

_JIT = {"cache": True, "error_model": "numpy", "_nrt": False}
_INNER = {**_JIT, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}  # helpers of the kernels alone
_BIG = np.finfo(np.float64).max


@njit(**_JIT)
def information_sums(hom: np.ndarray, proj: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """Gauss-Newton information out (P, J, 3, 3) from hom (V, 3, P J) = M X, proj (V, 3, 4), 1/sigma w (V, P, J)."""
    V, P, J = w.shape
    for p in range(P):
        for j in range(J):
            a00 = a01 = a02 = a11 = a12 = a22 = 0.0  # the x rows' sums
            b00 = b01 = b02 = b11 = b12 = b22 = 0.0  # the y rows'
            for v in range(V):
                i = p * J + j
                z = hom[v, 2, i] + proj[v, 2, 3]
                z = z if z >= EPS_DEPTH or np.isnan(z) else EPS_DEPTH  # np.maximum
                x, y, s = (hom[v, 0, i] + proj[v, 0, 3]) / z, (hom[v, 1, i] + proj[v, 1, 3]) / z, w[v, p, j] / z
                r0 = (proj[v, 0, 0] - x * proj[v, 2, 0]) * s
                r1 = (proj[v, 0, 1] - x * proj[v, 2, 1]) * s
                r2 = (proj[v, 0, 2] - x * proj[v, 2, 2]) * s
                a00, a01, a02 = a00 + r0 * r0, a01 + r0 * r1, a02 + r0 * r2
                a11, a12, a22 = a11 + r1 * r1, a12 + r1 * r2, a22 + r2 * r2
                r0 = (proj[v, 1, 0] - y * proj[v, 2, 0]) * s
                r1 = (proj[v, 1, 1] - y * proj[v, 2, 1]) * s
                r2 = (proj[v, 1, 2] - y * proj[v, 2, 2]) * s
                b00, b01, b02 = b00 + r0 * r0, b01 + r0 * r1, b02 + r0 * r2
                b11, b12, b22 = b11 + r1 * r1, b12 + r1 * r2, b22 + r2 * r2
            a00, a01, a02, a11, a12, a22 = a00 + b00, a01 + b01, a02 + b02, a11 + b11, a12 + b12, a22 + b22
            out[p, j, 0, 0], out[p, j, 0, 1], out[p, j, 0, 2] = a00, a01, a02
            out[p, j, 1, 0], out[p, j, 1, 1], out[p, j, 1, 2] = a01, a11, a12
            out[p, j, 2, 0], out[p, j, 2, 1], out[p, j, 2, 2] = a02, a12, a22


@njit(**_INNER)
def _finite(a: float) -> float:
    """np.nan_to_num of one value: NaN -> 0, +-inf -> the largest finite float of that sign."""
    if np.isnan(a):
        return 0.0
    return _BIG if a > _BIG else (-_BIG if a < -_BIG else a)


@njit(**_INNER)
def _joint_covariances(info: np.ndarray, measured: np.ndarray, cov: np.ndarray, good: np.ndarray) -> None:
    """cov (P, J, 3, 3) = info^-1 (P, J, 3, 3) by cofactors where good (P, J): measured and well-conditioned, else 0."""
    for p in range(info.shape[0]):
        for j in range(info.shape[1]):
            a00, a01, a02 = _finite(info[p, j, 0, 0]), _finite(info[p, j, 0, 1]), _finite(info[p, j, 0, 2])
            a10, a11, a12 = _finite(info[p, j, 1, 0]), _finite(info[p, j, 1, 1]), _finite(info[p, j, 1, 2])
            a20, a21, a22 = _finite(info[p, j, 2, 0]), _finite(info[p, j, 2, 1]), _finite(info[p, j, 2, 2])
            c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
            c10, c11, c12 = a21 * a02 - a22 * a01, a22 * a00 - a20 * a02, a20 * a01 - a21 * a00
            c20, c21, c22 = a01 * a12 - a02 * a11, a02 * a10 - a00 * a12, a00 * a11 - a01 * a10
            det = a00 * c00 + a01 * c01 + a02 * c02
            trace = a00 + a11 + a22
            good[p, j] = measured[p, j] and det > 1e-9 * (trace / 3) ** 3.0 and trace > 0
            if not good[p, j]:
                c00 = c01 = c02 = c10 = c11 = c12 = c20 = c21 = c22 = 0.0
                det = 1.0
            cov[p, j, 0, 0], cov[p, j, 0, 1], cov[p, j, 0, 2] = c00 / det, c01 / det, c02 / det
            cov[p, j, 1, 0], cov[p, j, 1, 1], cov[p, j, 1, 2] = c10 / det, c11 / det, c12 / det
            cov[p, j, 2, 0], cov[p, j, 2, 1], cov[p, j, 2, 2] = c20 / det, c21 / det, c22 / det


@njit(**_JIT)
def bone_sums(
    X: np.ndarray,
    info: np.ndarray,
    measured: np.ndarray,
    pairs: np.ndarray,
    cov: np.ndarray,
    good: np.ndarray,
    n_out: np.ndarray,
    var_out: np.ndarray,
) -> None:
    """Bone lengths n_out (P, L) of X (P, J, 3), variances var_out (P, L) u^T (cov_a + cov_b) u (inf: end not good)."""
    _joint_covariances(info, measured, cov, good)
    for p in range(X.shape[0]):
        for l in range(pairs.shape[0]):
            a, b = pairs[l, 0], pairs[l, 1]
            d0, d1, d2 = X[p, a, 0] - X[p, b, 0], X[p, a, 1] - X[p, b, 1], X[p, a, 2] - X[p, b, 2]
            n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            m = max(n, 1e-12)
            u0, u1, u2 = d0 / m, d1 / m, d2 / m
            s00, s01, s02 = (
                cov[p, a, 0, 0] + cov[p, b, 0, 0],
                cov[p, a, 0, 1] + cov[p, b, 0, 1],
                cov[p, a, 0, 2] + cov[p, b, 0, 2],
            )
            s10, s11, s12 = (
                cov[p, a, 1, 0] + cov[p, b, 1, 0],
                cov[p, a, 1, 1] + cov[p, b, 1, 1],
                cov[p, a, 1, 2] + cov[p, b, 1, 2],
            )
            s20, s21, s22 = (
                cov[p, a, 2, 0] + cov[p, b, 2, 0],
                cov[p, a, 2, 1] + cov[p, b, 2, 1],
                cov[p, a, 2, 2] + cov[p, b, 2, 2],
            )
            t0, t1, t2 = u0 * s00 * u0, u0 * s01 * u1, u0 * s02 * u2
            t3, t4, t5 = u1 * s10 * u0, u1 * s11 * u1, u1 * s12 * u2
            t6, t7, t8 = u2 * s20 * u0, u2 * s21 * u1, u2 * s22 * u2
            var = (((t0 + t1) + (t2 + t3)) + ((t4 + t5) + (t6 + t7))) + t8
            n_out[p, l], var_out[p, l] = n, var if good[p, a] and good[p, b] else np.inf


class BoneModel(NamedTuple):
    """The hierarchical bone model of person_prior; (L,) arrays in m."""

    bone_ref: np.ndarray
    stature: np.ndarray  # bone_ref stature_sd
    proportion: np.ndarray  # bone_ref proportion_sd
    groups: np.ndarray  # (L,) in 0..G - 1
    tie2: float  # tie_sd^2
    outlier_sd: float
    use: np.ndarray  # (L,) bool work space
    scratch: np.ndarray  # (4, G) work space


@njit(**_JIT)
def bone_posteriors(
    lengths: np.ndarray, variances: np.ndarray, model: BoneModel, mean: np.ndarray, sd: np.ndarray
) -> None:
    """mean, sd (P, L): the posterior of each person's bones from lengths, variances (P, L), inverted in O(L)."""
    bone_ref, stature, proportion, groups, tie2, outlier_sd, use, scratch = model
    P, L = lengths.shape
    b, D, r, theta = scratch[0], scratch[1], scratch[2], scratch[3]
    for p in range(P):
        for l in range(L):
            use[l] = np.isfinite(variances[p, l]) and np.isfinite(lengths[p, l])
        for _ in range(2):  # once, then without the outlying bones
            d0, r0 = 1.0, 0.0
            for g in range(len(D)):
                b[g], D[g], r[g] = 0.0, 1.0, 0.0
            for l in range(L):
                if use[l]:
                    w, g = 1.0 / (variances[p, l] + tie2), groups[l]
                    y = lengths[p, l] - bone_ref[l]
                    d0 += w * stature[l] * stature[l]
                    b[g] += w * stature[l] * proportion[l]
                    D[g] += w * proportion[l] * proportion[l]
                    r0 += w * y * stature[l]
                    r[g] += w * y * proportion[l]
            s, t0 = d0, r0
            for g in range(len(D)):
                s -= b[g] * b[g] / D[g]
                t0 -= b[g] * r[g] / D[g]
            t0 /= s
            for g in range(len(D)):
                theta[g] = (r[g] - b[g] * t0) / D[g]
            outliers = False
            for l in range(L):
                g = groups[l]
                a0, ag = stature[l], proportion[l]
                mean[p, l] = bone_ref[l] + a0 * t0 + ag * theta[g]
                cov0g, covgg = -b[g] / (D[g] * s), 1.0 / D[g] + b[g] * b[g] / (D[g] * D[g] * s)
                var = a0 * a0 / s + 2.0 * a0 * ag * cov0g + ag * ag * covgg
                sd[p, l] = np.sqrt(var)
                noise = (variances[p, l] if use[l] else 0.0) + tie2
                if use[l] and abs(lengths[p, l] - mean[p, l]) / np.sqrt(noise + var) > outlier_sd:
                    use[l] = False
                    outliers = True
            if not outliers:
                break


@njit(**_JIT)
def noise_medians(
    hom: np.ndarray,  # (V, 3, P J) = M X (person_prior.view_matmul)
    proj: np.ndarray,
    uv: np.ndarray,  # (V, P, J, 2) px
    w: np.ndarray,  # (V, P, J) 1/sigma
    medians: np.ndarray,  # chi^2 medians by degrees of freedom
    ratio: np.ndarray,  # (J,) scratch
    out: np.ndarray,
) -> None:
    """out (P,): median over joints seen in n >= 2 views of RSS / median(chi^2(2n - 3)), -1 without any."""
    V, P, J = w.shape
    for p in range(P):
        n = 0
        for j in range(J):
            rss, views = 0.0, 0
            for v in range(V):
                if w[v, p, j] > 0:
                    z = hom[v, 2, p * J + j] + proj[v, 2, 3]
                    z = z if z >= EPS_DEPTH or np.isnan(z) else EPS_DEPTH  # np.maximum
                    dx = uv[v, p, j, 0] - (hom[v, 0, p * J + j] + proj[v, 0, 3]) / z
                    dy = uv[v, p, j, 1] - (hom[v, 1, p * J + j] + proj[v, 1, 3]) / z
                    rss += (dx * dx + dy * dy) * (w[v, p, j] * w[v, p, j])
                    views += 1
            if views >= 2:  # insertion into the sorted ratios of this person
                value, i = rss / medians[min(2 * views - 3, len(medians) - 1)], n
                while i > 0 and (value < ratio[i - 1] or (np.isnan(ratio[i - 1]) and not np.isnan(value))):  # NaN last
                    ratio[i] = ratio[i - 1]
                    i -= 1
                ratio[i] = value
                n += 1
        out[p] = 0.5 * (ratio[max(n - 1, 0) // 2] + ratio[n // 2]) if n > 0 else -1.0
