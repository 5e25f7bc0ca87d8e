"""The compiled MLE / MAP solver: a symbolic plan of the bone graph, then the numba kernels of pose_kernels.py.

:func:`solve_poses_compiled` solves the same (person, component) problems as
:func:`reconstruction.solver.map_solver.solve_poses` (same residuals, damping, acceptance and stopping
tests), but each one in compiled loops, so its time is arithmetic rather than numpy call overhead:
a few tens of microseconds per person. The plan (elimination order, fill-in, block storage) is built
once per bone graph and cached.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from reconstruction.solver import pose_kernels
from reconstruction.solver.block_solver import graph_components
from reconstruction.solver.lm_solver import LMResult
from reconstruction.solver.map_estimation import PoseProblem


@dataclass(frozen=True)
class SolverPlan:
    """Block layout of the normal equations of one bone graph (J joints, L bones); positions = elimination order.

    Components are contiguous runs of positions; within one, joints are eliminated lowest degree
    first (leaves, then chains), which keeps the fill-in of the COCO-23 skeleton to a few blocks.
    """

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


@lru_cache(maxsize=32)
def solver_plan(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> SolverPlan:
    """The plan of J joints with bones (a, b): J, L pairs -> SolverPlan (cached per graph)."""
    adj: dict[int, set[int]] = {j: set() for j in range(num_joints)}
    for a, b in pairs:
        adj[a].add(b)
        adj[b].add(a)
    comps = [c.tolist() for c in graph_components(num_joints, pairs)]
    pos_joint, comp_start, filled = [], [0], []
    for comp in comps:
        order, later = _min_degree_order(comp, adj)
        pos_joint += order
        filled += later
        comp_start.append(len(pos_joint))
    position = {j: k for k, j in enumerate(pos_joint)}
    slot = np.full((num_joints, num_joints), -1, dtype=np.int64)
    later_ptr, later_idx, comp_slots, comp_slots_ptr = [0], [], [], [0]
    n_slots = 0
    for c in range(len(comps)):
        for k in range(comp_start[c], comp_start[c + 1]):
            rows = sorted(position[a] for a in filled[k])
            for i in [k] + rows:
                slot[i, k] = n_slots
                comp_slots.append(n_slots)
                n_slots += 1
            later_idx += rows
            later_ptr.append(len(later_idx))
        comp_slots_ptr.append(len(comp_slots))
    comp_of = np.repeat(np.arange(len(comps)), np.diff(comp_start))
    pa = np.array([position[a] for a, _ in pairs], dtype=np.int64)
    pb = np.array([position[b] for _, b in pairs], dtype=np.int64)
    bone_comp = comp_of[pa] if len(pairs) else np.zeros(0, dtype=np.int64)
    bones = np.argsort(bone_comp, kind="stable").astype(np.int64)
    as_int = lambda a: np.asarray(a, dtype=np.int64)  # noqa: E731
    return SolverPlan(
        as_int(pos_joint),
        as_int(comp_start),
        as_int(np.searchsorted(bone_comp[bones], np.arange(len(comps) + 1))),
        bones,
        as_int(comp_slots_ptr),
        as_int(comp_slots),
        pa,
        pb,
        slot[np.maximum(pa, pb), np.minimum(pa, pb)],
        slot,
        as_int(later_ptr),
        as_int(later_idx),
    )


def plan_arrays(plan: SolverPlan) -> tuple[np.ndarray, ...]:
    """The plan's arrays in the order the kernels unpack them (pose_kernels.solve_all's ``plan``)."""
    return (
        plan.pos_joint,
        plan.comp_start,
        plan.comp_bones_ptr,
        plan.comp_bones,
        plan.comp_slots_ptr,
        plan.comp_slots,
        plan.bone_pa,
        plan.bone_pb,
        plan.bone_slot,
        plan.slot,
        plan.later_ptr,
        plan.later_idx,
    )


def scratch(J: int, L: int, n_blocks: int) -> tuple:
    """The kernels' work arrays (pose_kernels.solve_all's ``work``): x, x_new, h (J, 3), B (n_blocks, 3, 3), and
    two linearisations (D (J, 3, 3), g (J, 3), K, Kr (L, 3, 3))."""
    lin = lambda: (np.empty((J, 3, 3)), np.empty((J, 3)), np.empty((L, 3, 3)), np.empty((L, 3, 3)))  # noqa: E731
    return np.empty((J, 3)), np.empty((J, 3)), np.empty((J, 3)), np.empty((n_blocks, 3, 3)), lin(), lin()


def person_bones(problem: PoseProblem, on: np.ndarray, P: int) -> tuple[np.ndarray, np.ndarray]:
    """Each person's reference lengths and weights of the bones switched on: -> (P, L_on), (P, L_on)."""
    n = int(np.count_nonzero(on))
    ref, weight = np.empty((P, n)), np.empty((P, n))
    ref[:] = np.asarray(problem.bone_ref, dtype=np.float64)[..., on]  # (L,) or (P, L)
    weight[:] = np.asarray(problem.bone_weight, dtype=np.float64)[..., on]
    return ref, weight


@lru_cache(maxsize=32)
def _kernel_plan(num_joints: int, pairs: bytes) -> tuple[tuple[np.ndarray, ...], int, int]:
    """The plan of J joints and bones (int64 (L, 2) as bytes) as the kernels take it: arrays, blocks, components."""
    plan = solver_plan(num_joints, tuple(map(tuple, np.frombuffer(pairs, dtype=np.int64).reshape(-1, 2).tolist())))
    return plan_arrays(plan), int(plan.slot.max()) + 1, len(plan.comp_start) - 1


def solve_poses_compiled(
    problem: PoseProblem,
    X0: np.ndarray,
    max_iterations: int = 15,
    xtol: float = 1e-6,
    ftol: float = 1e-10,
    gtol: float = 1e-10,
    tau: float = 1e-3,
) -> tuple[np.ndarray, LMResult]:
    """Minimise the problem's cost from X0 (P, J, 3) -> (P, J, 3) and the LMResult of the (P, C) problems.

    Bones of weight 0 for every person are dropped (they would only join components); bone_ref and
    bone_weight may be (L,) for all persons or (P, L), one table per person. The LMResult's x is (P, 3J).
    """
    X = np.array(X0, dtype=np.float64)
    P, J, _ = X.shape
    L = len(problem.bone_pairs)
    on = (np.asarray(problem.bone_weight).reshape(-1, L) > 0).any(axis=0) if L else np.zeros(0, dtype=bool)
    pairs = np.asarray(problem.bone_pairs, dtype=np.int64).reshape(-1, 2)[on]
    plan, n_blocks, C = _kernel_plan(J, pairs.tobytes())
    cost, iterations, status = np.zeros((P, C)), np.zeros((P, C), dtype=np.int64), np.zeros((P, C), dtype=np.int64)
    if P:
        data = (
            np.ascontiguousarray(problem.proj, dtype=np.float64),
            np.ascontiguousarray(problem.uv, dtype=np.float64),
            np.ascontiguousarray(problem.inv_sigma, dtype=np.float64),
            np.ascontiguousarray(problem.anchor, dtype=np.float64),
            *person_bones(problem, on, P),
        )
        tau2, C2 = float(problem.anchor_weight) ** 2, float(problem.robust_scale) ** 2
        settings = (int(max_iterations), float(xtol), float(ftol), float(gtol), float(tau))
        robust = pose_kernels.ROBUST_CODES[problem.robust]
        args = (tau2, robust, C2, plan, settings, scratch(J, len(pairs), n_blocks))
        pose_kernels.solve_all(X, data, *args, cost, iterations, status)
    return X, LMResult(X.reshape(P, 3 * J), cost, iterations, status)
