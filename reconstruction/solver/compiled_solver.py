"""The MLE / MAP least-squares problem and its solve: a symbolic plan of the bone graph, then pose_kernels' loops."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from reconstruction.solver import pose_kernels
from reconstruction.solver.pose_kernels import Linearisation, Plan, Problem, Settings, Work

ROBUST_LOSSES = tuple(pose_kernels.ROBUST_CODES)


@dataclass(frozen=True)
class PoseProblem:
    """The least-squares problem of P persons with J joints each (shapes in the field comments)."""

    proj: np.ndarray  # (V, 3, 4) projection matrices of undistorted pixels
    uv: np.ndarray  # (V, P, J, 2) observed undistorted pixels (anything where unseen)
    inv_sigma: np.ndarray  # (V, P, J) 1 / sigma (1/px), 0 where the joint is not seen
    bone_pairs: np.ndarray  # (L, 2) joint indices of each bone; L may be 0
    bone_ref: np.ndarray  # (L,) reference lengths (m), or (P, L): one table per person
    bone_weight: np.ndarray  # (L,) or (P, L) prior_weight / sigma_l (1/m); 0 switches a bone off
    anchor: np.ndarray  # (P, J, 3) Tikhonov anchor (m): tau (1/m) far below an observed joint's curvature fixes
    anchor_weight: float = 1e-3  # only the directions nothing else determines (a 1-view joint's depth)
    robust: str = "none"  # none | huber | cauchy on the reprojection residuals (scipy's rho)
    robust_scale: float = 3.0  # in sigma units

    def take(self, idx: np.ndarray) -> "PoseProblem":
        """The problem of a subset of persons: idx (b,) -> PoseProblem with P = b."""
        per_person = {k: getattr(self, k)[idx] for k in ("bone_ref", "bone_weight") if np.ndim(getattr(self, k)) == 2}
        return PoseProblem(
            **{**self.__dict__, "uv": self.uv[:, idx], "inv_sigma": self.inv_sigma[:, idx], "anchor": self.anchor[idx]},
            **per_person,
        )


class SolveStats(NamedTuple):
    """Final cost, iterations and status (pose_kernels' codes) of every (person, component) problem, (P, C)."""

    cost: np.ndarray
    iterations: np.ndarray
    status: np.ndarray


def graph_components(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> list[np.ndarray]:
    """Joint sets connected by bones, singletons included, ordered by first joint: J, ((a, b), ...) -> [(j,) int]."""
    parent = list(range(num_joints))

    def root(a: int) -> int:
        while parent[a] != a:
            a = parent[a]
        return a

    for a, b in pairs:
        parent[root(a)] = root(b)
    roots = np.array([root(j) for j in range(num_joints)], dtype=np.int64)
    return [np.flatnonzero(roots == r) for r in dict.fromkeys(roots.tolist())]


def _min_degree_order(joints: list[int], adj: dict[int, set[int]]) -> tuple[list[int], list[set[int]]]:
    """Greedy minimum-degree elimination of one component -> order, filled neighbour sets of each eliminated joint."""
    adj = {j: set(adj[j]) for j in joints}
    order, later = [], []
    while adj:
        k = min(adj, key=lambda j: (len(adj[j]), j))
        nbrs = adj.pop(k)
        for a in nbrs:
            adj[a].discard(k)
            adj[a] |= nbrs - {a}
        order.append(k)
        later.append(nbrs)
    return order, later


def _slots(num_joints: int, comp_start: list[int], filled: list[set[int]], position: dict) -> tuple:
    """Block storage of the factor: slot (J, J), later (ptr, idx) and the slots of each component (ptr, idx)."""
    slot = np.full((num_joints, num_joints), -1, dtype=np.int64)
    later_ptr, later_idx, comp_slots, comp_slots_ptr = [0], [], [], [0]
    for c in range(len(comp_start) - 1):
        for k in range(comp_start[c], comp_start[c + 1]):
            rows = sorted(position[a] for a in filled[k])
            for i in [k] + rows:
                slot[i, k] = len(comp_slots)
                comp_slots.append(len(comp_slots))
            later_idx += rows
            later_ptr.append(len(later_idx))
        comp_slots_ptr.append(len(comp_slots))
    return slot, later_ptr, later_idx, comp_slots_ptr, comp_slots


@lru_cache(maxsize=32)
def solver_plan(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> Plan:
    """The plan of J joints with bones (a, b); within a component joints go lowest degree first (little fill-in)."""
    adj: dict[int, set[int]] = {j: set() for j in range(num_joints)}
    for a, b in pairs:
        adj[a].add(b)
        adj[b].add(a)
    pos_joint, comp_start, filled = [], [0], []
    for comp in graph_components(num_joints, pairs):
        order, later = _min_degree_order(comp.tolist(), adj)
        pos_joint += order
        filled += later
        comp_start.append(len(pos_joint))
    position = {j: k for k, j in enumerate(pos_joint)}
    slot, later_ptr, later_idx, comp_slots_ptr, comp_slots = _slots(num_joints, comp_start, filled, position)
    comp_of = np.repeat(np.arange(len(comp_start) - 1), np.diff(comp_start))
    pa = np.array([position[a] for a, _ in pairs], dtype=np.int64)
    pb = np.array([position[b] for _, b in pairs], dtype=np.int64)
    bone_comp = comp_of[pa] if len(pairs) else np.zeros(0, dtype=np.int64)
    bones = np.argsort(bone_comp, kind="stable").astype(np.int64)
    as_int = lambda a: np.asarray(a, dtype=np.int64)  # noqa: E731
    return Plan(
        pos_joint=as_int(pos_joint),
        comp_start=as_int(comp_start),
        comp_bones_ptr=as_int(np.searchsorted(bone_comp[bones], np.arange(len(comp_start)))),
        comp_bones=bones,
        comp_slots_ptr=as_int(comp_slots_ptr),
        comp_slots=as_int(comp_slots),
        bone_pa=pa,
        bone_pb=pb,
        bone_slot=slot[np.maximum(pa, pb), np.minimum(pa, pb)],
        slot=slot,
        later_ptr=as_int(later_ptr),
        later_idx=as_int(later_idx),
    )


@lru_cache(maxsize=32)
def _work(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> Work:
    """The solver's scratch arrays for solver_plan(num_joints, pairs), made once (a solve overwrites what it reads)."""
    plan = solver_plan(num_joints, pairs)
    J, L, blocks = num_joints, len(pairs), np.empty((int(plan.slot.max()) + 1, 3, 3))
    lin = (_linearisation(J, L), _linearisation(J, L))
    return Work(x=np.empty((J, 3)), x_new=np.empty((J, 3)), h=np.empty((J, 3)), B=blocks, lin=lin[0], trial=lin[1])


def _linearisation(J: int, L: int) -> Linearisation:
    """Uninitialised work arrays of one linearisation of J joints and L bones."""
    return Linearisation(D=np.empty((J, 3, 3)), g=np.empty((J, 3)), K=np.empty((L, 3, 3)), Kr=np.empty((L, 3, 3)))


def _kernel_problem(problem: PoseProblem, on: np.ndarray, P: int) -> Problem:
    """The kernels' Problem with the bones ``on`` (L,) bool, each person's table (P, L_on) (broadcast from (L,))."""
    ref, weight = np.empty((P, int(np.count_nonzero(on)))), np.empty((P, int(np.count_nonzero(on))))
    ref[:] = np.asarray(problem.bone_ref, dtype=np.float64)[..., on]
    weight[:] = np.asarray(problem.bone_weight, dtype=np.float64)[..., on]
    as_float = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return Problem(
        proj=as_float(problem.proj),
        uv=as_float(problem.uv),
        w=as_float(problem.inv_sigma),
        anchor=as_float(problem.anchor),
        ref=ref,
        bw=weight,
        tau2=float(problem.anchor_weight) ** 2,
        robust=pose_kernels.ROBUST_CODES[problem.robust],
        C2=float(problem.robust_scale) ** 2,
    )


def solve_poses(
    problem: PoseProblem, X0: np.ndarray, max_iterations: int = 15, xtol: float = 1e-6, ftol: float = 1e-10
) -> tuple[np.ndarray, SolveStats]:
    """Minimise the problem's cost from X0 (P, J, 3) -> (P, J, 3) and the stats of the (P, C) problems."""
    X = np.array(X0, dtype=np.float64)
    P, J, _ = X.shape
    L = len(problem.bone_pairs)
    on = (np.asarray(problem.bone_weight).reshape(-1, L) > 0).any(axis=0) if L else np.zeros(0, dtype=bool)
    pairs = np.asarray(problem.bone_pairs, dtype=np.int64).reshape(-1, 2)[on]
    key = tuple(map(tuple, pairs.tolist()))
    plan = solver_plan(J, key)
    C = len(plan.comp_start) - 1
    stats = SolveStats(np.zeros((P, C)), np.zeros((P, C), dtype=np.int64), np.zeros((P, C), dtype=np.int64))
    if P:
        settings = Settings(
            max_iterations=int(max_iterations), xtol=float(xtol), ftol=float(ftol), gtol=1e-10, tau=1e-3
        )
        pose_kernels.solve_all(X, _kernel_problem(problem, on, P), plan, settings, _work(J, key), *stats)
    return X, stats
