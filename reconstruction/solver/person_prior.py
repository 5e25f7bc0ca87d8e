"""What the MAP learns about each person from the MLE joints X (P, J, 3) before it applies the bone prior."""

from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv

from data.bone_lengths import BONE_NAMES
from reconstruction.solver.pose_kernels import EPS_DEPTH
from reconstruction.solver.prior_kernels import BoneModel, bone_posteriors, bone_sums, information_sums, noise_medians

STATURE_SD = 0.053  # relative SD of adult stature (0.09 m / 1.70 m), shared by every bone of a person
PROPORTION_SD = 0.02  # relative SD of one bone group's length given the stature (left = right)
OUTLIER_SD = 3.0  # a bone measured this many SD from its posterior is dropped and the posterior redone
# chi^2 medians by degrees of freedom: scipy.stats.chi2.median's own formula (scipy.stats is a slow import)
_CHI2_MEDIANS = np.concatenate([[np.nan], 2.0 * gammaincinv(np.arange(1, 64) / 2.0, 0.5)])


def chi2_medians(dof: np.ndarray) -> np.ndarray:
    """Median of chi^2 for each entry's degrees of freedom (NaN for 0): int array -> float array."""
    return _CHI2_MEDIANS[np.clip(dof, 0, len(_CHI2_MEDIANS) - 1)]


def project(X: np.ndarray, proj: np.ndarray, hom: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (V, P, J, 2) and clamped depths (V, P, J) of joints (P, J, 3) in views (V, 3, 4); hom: view_matmul."""
    P, J, _ = X.shape
    hom = (proj[:, :, :3] @ X.reshape(-1, 3).T if hom is None else hom) + proj[:, :, 3:]
    hom = hom.reshape(len(proj), 3, P, J)
    z = np.maximum(hom[:, 2], EPS_DEPTH)
    return np.stack([hom[:, 0] / z, hom[:, 1] / z], axis=-1), z


def view_matmul(X: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """M X of joints (P, J, 3) in views (V, 3, 4), translation not added: (V, 3, P J), as in :func:`project`."""
    return np.ascontiguousarray(proj[:, :, :3] @ X.reshape(-1, 3).T, dtype=np.float64)


def joint_information(
    X: np.ndarray, proj: np.ndarray, inv_sigma: np.ndarray, hom: np.ndarray | None = None
) -> np.ndarray:
    """Gauss-Newton information of every joint (model sigma units): (P, J, 3), (V, 3, 4), (V, P, J) -> (P, J, 3, 3)."""
    hom = view_matmul(X, proj) if hom is None else hom
    info = np.empty(X.shape[:2] + (3, 3))
    w = np.ascontiguousarray(inv_sigma, dtype=np.float64)
    information_sums(hom, np.ascontiguousarray(proj, dtype=np.float64), w, info)
    return info


def noise_scale(
    X: np.ndarray,  # (P, J, 3)
    uv: np.ndarray,  # (V, P, J, 2)
    inv_sigma: np.ndarray,  # (V, P, J) 1/sigma, 0 unseen
    proj: np.ndarray,  # (V, 3, 4)
    floor: float = 0.01,
    hom: np.ndarray | None = None,  # view_matmul of X
) -> np.ndarray:
    """Each person's 2D noise over the sigma model from MLE residuals -> (P,) >= floor; 1 without a joint in 2 views."""
    hom = view_matmul(X, proj) if hom is None else hom
    median, ratio = np.empty(len(X)), np.empty(X.shape[1])
    as_float = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    noise_medians(hom, as_float(proj), as_float(uv), as_float(inv_sigma), _CHI2_MEDIANS, ratio, median)
    return np.maximum(np.sqrt(np.where(median < 0, 1.0, median)), floor)  # median -1: no joint in >= 2 views


def bone_groups(names: tuple[str, ...] = BONE_NAMES) -> np.ndarray:
    """Group index of every bone, left and right of one bone sharing a group: (L,) int."""
    keys = [n.removeprefix("left_").removeprefix("right_") for n in names]
    order = {k: g for g, k in enumerate(dict.fromkeys(keys))}
    return np.array([order[k] for k in keys], dtype=np.int64)


def bone_variances(
    X: np.ndarray, info: np.ndarray, pairs: np.ndarray, measured: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bone lengths (P, L) of X (P, J, 3), their variances (P, L) from info (P, J, 3, 3); inf: an end not measured."""
    P, J, L = X.shape[0], X.shape[1], len(pairs)
    cov, good = np.empty((P, J, 3, 3)), np.empty((P, J), dtype=bool)
    n, var = np.empty((P, L)), np.empty((P, L))
    X, pairs = np.ascontiguousarray(X, dtype=np.float64), np.ascontiguousarray(pairs, dtype=np.int64)
    info, measured = np.ascontiguousarray(info, dtype=np.float64), np.ascontiguousarray(measured, dtype=bool)
    bone_sums(X, info, measured, pairs, cov, good, n, var)
    return n, var


def proportion_sds(
    bone_ref: np.ndarray, bone_std: np.ndarray, placement_sd: float, stature_sd: float = STATURE_SD
) -> np.ndarray:
    """Relative SD of each bone given the stature and the placement SD (m): (L,), (L,) -> (L,), 0 where none is left."""
    rest = np.asarray(bone_std, dtype=np.float64) ** 2 - placement_sd**2 - (stature_sd * np.asarray(bone_ref)) ** 2
    return np.sqrt(np.maximum(rest, 0.0)) / np.maximum(bone_ref, 1e-9)


def person_bone_lengths(
    lengths: np.ndarray,  # (P, L) measured
    variances: np.ndarray,  # (P, L), inf = unmeasured
    bone_ref: np.ndarray,  # (L,) population means
    proportion_sd: np.ndarray,  # (L,) relative
    tie_sd: float,  # m
    groups: np.ndarray,  # (L,)
    stature_sd: float = STATURE_SD,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and SD (P, L) of each person's bones; an outlier bone (OUTLIER_SD) is dropped and redone once."""
    P, L = lengths.shape
    G = int(groups.max()) + 1 if L else 0
    bone_ref = np.array(bone_ref, dtype=np.float64)  # a writable copy: one kernel type for read-only tables too
    mean, sd = np.empty((P, L)), np.empty((P, L))
    model = BoneModel(
        bone_ref=bone_ref,
        stature=bone_ref * stature_sd,
        proportion=bone_ref * np.asarray(proportion_sd, dtype=np.float64),
        groups=np.ascontiguousarray(groups, dtype=np.int64),
        tie2=float(tie_sd) ** 2,
        outlier_sd=OUTLIER_SD,
        use=np.empty(L, dtype=bool),
        scratch=np.empty((4, G)),
    )
    as_float = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    bone_posteriors(as_float(lengths), as_float(variances), model, mean, sd)
    return mean, sd
